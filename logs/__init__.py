# Before any module of this package imports python-can: importing ``controller`` keeps its MF4
# format's asammdf out of this process until a ``.mf4`` file is written or read
# (controller/mf4_support.py).
import controller  # noqa: F401
