"""The simulator's true contact force, shared live with the process that runs the demo.

The controller sees the force sensor's measurement; how well force control did is told by the
force the simulator's environment really exerts. In simulated time the demo reads it from the
in-process plant; over a bus the simulator is another process, and it writes the force of every
SYNC into a small file mapped into both processes' memory (in /dev/shm where there is one) that
the demo's observers read each cycle. A diagnostic, never an input of the law: nothing the
controller decides depends on it.

The block holds the forces of the last two SYNCs, each with the time the SYNC reached the
machine (CLOCK_MONOTONIC, one clock for every process): a sequence number, then twice t [s],
Fx, Fy, Fz [N]. Over a bus the loop hands cycle k to its observers after it sent cycle k+1's
SYNC (controller/shell/loop.py, step 5), and the simulator may have answered that one already:
the reader asks for the force as it was when cycle k's step ended (``CycleTiming.stepped_s``),
the newer of the two SYNCs before then, not simply the latest.

The writer bumps the sequence to an odd number before it writes and to the next even one after;
a reader that finds it odd, or changed under it, takes the last value it read whole.

A memory file and ``mmap``, not ``multiprocessing.shared_memory``: that one registers its blocks
with multiprocessing's resource tracker, which removed the block under a demo that used a process
pool (the 3-nSPU's) and left it failing at its end on a block already gone.

The file is the reader's ``memfd``, sealed against shrinking and growing, which the simulator
opens through ``/proc/<reader's pid>/fd/<fd>``: a mapped file that shrinks under its readers ends
them with SIGBUS, and an outside tester's ``truncate -s 0 /dev/shm/cheope-true-force-*`` killed
a demo so (exit code 135, no summary). Sealed, a truncation fails (EPERM) for everyone. The
block has no name in /dev/shm either, so a demo killed with SIGKILL leaves nothing behind;
``remove_stale_blocks`` still removes the named blocks of versions before it.
"""

from __future__ import annotations

import fcntl
import math
import mmap
import os
import struct
import tempfile
from pathlib import Path

_LAYOUT = struct.Struct("<Q4d4d")  # sequence, then two slots of t [s], Fx, Fy, Fz [N]
_SLOT = struct.Struct("<4d")
_ZERO = (0.0, 0.0, 0.0)


PREFIX = "cheope-true-force-"  # + the demo's process id, "-", its bus port (controller/shell/demo.py)


def remove_stale_blocks(directory: Path) -> list[Path]:
    """Remove the blocks of demos that are gone: a demo killed (SIGKILL) cannot remove its own, and
    each one left a file in /dev/shm (an outside tester's finding). Returns what it removed."""
    removed = []
    for path in directory.glob(f"{PREFIX}*-*"):
        pid = path.name[len(PREFIX) :].partition("-")[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:  # gone; PermissionError: alive, another user's
            path.unlink(missing_ok=True)
            removed.append(path)
        except PermissionError:
            pass
    return removed


def tap_path(name: str) -> Path:
    """Where named blocks lived (``remove_stale_blocks``): /dev/shm where there is one, else the temp dir."""
    shm = Path("/dev/shm")
    return (shm if shm.is_dir() else Path(tempfile.gettempdir())) / name


_SEALS = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL  # the block's size, for good


class TrueForceTap:
    """The writing side (the simulator process): ``write`` at every SYNC."""

    def __init__(self, path: str) -> None:
        """Map the block the reader made at ``path`` (``FileNotFoundError`` when there is none)."""
        fd = os.open(path, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, _LAYOUT.size)
        finally:
            os.close(fd)
        self._sequence = 0

    def write(self, sync_s: float, fx_n: float, fy_n: float, fz_n: float) -> None:
        """The force of the SYNC that reached the machine at ``sync_s`` (CLOCK_MONOTONIC) [N]."""
        buf = self._map
        self._sequence += 1
        struct.pack_into("<Q", buf, 0, 2 * self._sequence - 1)
        _SLOT.pack_into(buf, 8 + _SLOT.size * (self._sequence % 2), sync_s, fx_n, fy_n, fz_n)
        struct.pack_into("<Q", buf, 0, 2 * self._sequence)

    def close(self) -> None:
        self._map.close()


class TrueForceReader:
    """The reading side (the demo): makes the block, reads the latest force, closes the block (it goes
    with the last process that holds it)."""

    def __init__(self, name: str) -> None:
        """A block of its own, ``name`` its memory file's name (module text)."""
        remove_stale_blocks(tap_path(name).parent)
        fd = os.memfd_create(name, os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
        try:
            os.ftruncate(fd, _LAYOUT.size)
            fcntl.fcntl(fd, fcntl.F_ADD_SEALS, _SEALS)
            self._map = mmap.mmap(fd, _LAYOUT.size)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd  # kept open: the simulator opens the block through it
        self.path = Path(f"/proc/{os.getpid()}/fd/{fd}")
        _LAYOUT.pack_into(self._map, 0, 0, -math.inf, *_ZERO, -math.inf, *_ZERO)
        self._last = _ZERO

    @property
    def name(self) -> str:
        """What the simulator is given (``cheope sim --true-force-tap``): the block's path, while
        this reader is open."""
        return str(self.path)

    def read(self, as_of_s: float = math.inf) -> tuple[float, float, float]:
        """The force [N] of the simulator's latest SYNC that reached the machine by ``as_of_s``
        (CLOCK_MONOTONIC; by default the latest of all). Zero before the first; the older of the
        two kept when both came later (a reader two SYNCs behind); NaN reads as the latest."""
        sequence, t0, *f0, t1, f1x, f1y, f1z = _LAYOUT.unpack_from(self._map, 0)
        if sequence % 2 == 0 and _LAYOUT.unpack_from(self._map, 0)[0] == sequence:
            (older_s, older), (newer_s, newer) = sorted(((t0, tuple(f0)), (t1, (f1x, f1y, f1z))))
            if newer_s > -math.inf:
                in_time = newer_s <= as_of_s or math.isnan(as_of_s) or older_s == -math.inf
                self._last = newer if in_time else older
        return self._last

    def close(self) -> None:
        self._map.close()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
