"""The control computer's side: the law, the loop shell, the service and its command line.

Set before anything imports numpy: its BLAS (OpenBLAS) starts a pool of worker threads under the
normal scheduler at import (one on a 2-CPU machine), and hands a large enough product to them.
The law's algebra is 3x3 and gains nothing from threads, and a loop at SCHED_FIFO that waits
for a pool thread a busy machine preempts is held up by it (docs/concepts/realtime.md). One
thread: no pool. Child processes (the simulator, the recording's writer) inherit it. A program
that imported numpy before this package keeps its pool; setting the variable explicitly wins.

Then python-can's MF4 format is kept from importing asammdf (pandas, pyarrow and a thread of
theirs) into every process; what reads or writes ``.mf4`` loads it (``controller.mf4_support``).

Then ``controller.compiled_law`` decides, once per process and before any of them is imported,
whether the step's modules run compiled by mypyc or from their sources.
"""

import os

for _pool in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_pool, "1")

from controller import mf4_support  # noqa: E402  (before anything imports python-can)

mf4_support.defer()

# The law's compiled modules, or their sources where the compilation is not theirs (module text).
from controller import compiled_law  # noqa: E402, F401  (after the pools' variables, before numpy)
