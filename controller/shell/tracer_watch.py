"""Tracers attached to the controller's process, named by the CPU shield's guardian.

A tracer (``strace -f -p``, a debugger, ``py-spy record`` in its default mode, which stops the
process for each sample) holds the loop up from beside it: every system call of a thread that
``strace`` traces, and every sample ``py-spy`` takes, waits for the tracer, a task under the normal
scheduler on another CPU. An outside tester (2026-12-07, default ``cheope demo``, one run at a time,
nothing else running) measured 579 and 588 late cycles with ``strace -f -p`` attached for 10 s,
401 and 459 with ``py-spy record -r 100`` for 15 s, and 19 with ``py-spy record --nonblocking``,
against 15 and 29 in the quiet runs between them (docs/concepts/realtime.md).

Attaching one is the user's deliberate act, and ptrace needs no help from the traced process: the
controller cannot refuse it. What it can do is name it, so that a run with hundreds of late cycles
says why. The guardian, a process of its own off the loop's CPU, looks every ``SCAN_S`` at
``TracerPid`` in the status of each thread of the watched processes (proc(5)); at the end it
reports each tracer seen (the summary's ``cpu_shield.tracers``). A tracer that stops the process
only now and then (``py-spy``'s samples) is seen in some looks, not all: ``looks`` counts them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class Tracer:
    """One process seen tracing a watched thread: who it is, and when it was seen doing so."""

    pid: int
    name: str
    first_seen_s: float  # since the watch began
    last_seen_s: float
    looks: int  # looks that found it attached

    def report(self) -> dict[str, Any]:
        return {
            "pid": self.pid,
            "name": self.name,
            "seen_s": [round(self.first_seen_s, 1), round(self.last_seen_s, 1)],  # after the shield rose
            "looks": self.looks,
        }


def tracer_pid(status_text: str) -> int:
    """The ``TracerPid`` field of a ``/proc/PID/task/TID/status`` (0: none, or no such field)."""
    for line in status_text.splitlines():
        if line.startswith("TracerPid:"):
            value = line.split(":", 1)[1].strip()
            return int(value) if value.isdigit() else 0
    return 0


class TracerWatch:
    """The tracers of any thread of the processes ``pids``; ``scan`` looks once, ``report`` lists
    each tracer seen."""

    def __init__(
        self, pids: Iterable[int], proc: Path = Path("/proc"), clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.pids = tuple(pids)
        self.proc, self.clock, self.start_s = proc, clock, clock()
        self.seen: dict[int, Tracer] = {}

    def scan(self) -> None:
        now = self.clock() - self.start_s
        found: dict[int, None] = {}  # tracers of this look, in the order met (one look counts once)
        for pid in self.pids:
            try:
                threads = list((self.proc / str(pid) / "task").iterdir())
            except OSError:
                continue  # gone
            for thread in threads:
                try:
                    tracer = tracer_pid((thread / "status").read_text())
                except OSError:
                    continue
                if tracer:
                    found[tracer] = None
        for tracer in found:
            known = self.seen.get(tracer)
            if known is None:
                self.seen[tracer] = Tracer(tracer, self._name(tracer), now, now, 1)
            else:
                known.last_seen_s, known.looks = now, known.looks + 1

    def _name(self, pid: int) -> str:
        try:
            return (self.proc / str(pid) / "comm").read_text().strip()
        except OSError:
            return "?"

    def report(self) -> list[dict[str, Any]]:
        return [t.report() for t in sorted(self.seen.values(), key=lambda t: t.first_seen_s)]
