# Before any module of this package: whether the cycle's modules run compiled by mypyc or from
# their sources, decided once per process (controller/compiled_law.py); this package's are among them.
from controller import compiled_law  # noqa: F401
