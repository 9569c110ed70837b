"""python-can's MF4 format, loaded only by what writes or reads ``.mf4`` files.

``import can`` imports every log format python-can has, and its MF4 module imports asammdf
whenever that is installed (the ``mf4`` extra, part of ``dev``): asammdf brings pandas and
pyarrow, and with them, in every process that imports python-can, the loop's included, 0.69 s of
start-up, about 100 MB of resident memory (locked there: the loop's process locks all it maps)
and pyarrow's allocator thread (``jemalloc_bg_thd``) at normal priority (measured on this
project's 2-CPU host, ``python -c "import can"``: 128.7 MB resident against 27.2 MB; with
the BLAS and OpenMP pools at one thread, as importing ``controller`` sets them, 2 threads
against 1). None of it is used by the controller, the simulator or the recording's writer.

So importing ``controller`` (the first package every process of this project imports) marks
asammdf as not importable, the import system's own way (``None`` in ``sys.modules``), and python-can
loads its MF4 module without it; ``load()`` takes the mark away and loads that module again, for
``cheope logs export --format mf4`` and for whatever reads an ``.mf4`` file. A program that
imported python-can or asammdf before ``controller`` keeps them as they are.

Standard library only: it runs in every process of the controller before anything else.
"""

from __future__ import annotations

import importlib
import sys
from types import ModuleType

MF4_DEPENDENCY = "asammdf"


def defer() -> None:
    """Keep asammdf out of ``import can`` until ``load()``: nothing to do if either came first."""
    if MF4_DEPENDENCY not in sys.modules and "can" not in sys.modules:
        # the import system's "not importable": importing it raises ModuleNotFoundError
        sys.modules[MF4_DEPENDENCY] = None  # type: ignore[assignment]


def load() -> ModuleType:
    """python-can's MF4 module with asammdf; ImportError if asammdf is not installed."""
    if MF4_DEPENDENCY in sys.modules and sys.modules[MF4_DEPENDENCY] is None:
        del sys.modules[MF4_DEPENDENCY]
    importlib.import_module(MF4_DEPENDENCY)
    mf4 = importlib.import_module("can.io.mf4")
    if getattr(mf4, "asammdf", None) is None:
        # loaded while asammdf was hidden: again, in place. python-can's MF4Writer and MF4Reader
        # (and subclasses of them made before) look asammdf up in this module's globals when used
        mf4 = importlib.reload(mf4)
    return mf4
