"""A live status line on the terminal while ``cheope demo`` or ``cheope run`` runs.

Where the run is: elapsed time, mode, the task's phase, the lap, the force error so far and the
late cycles, a few times a second. Only on a terminal, and never with ``--json``
(``status_wanted``).

The loop thread does not draw it. ``StatusObserver`` (a loop observer) adds a few numbers per
cycle and every ``interval_s`` writes one JSON line to a pipe with one non-blocking ``write``
(dropped if the pipe is full: the next line replaces it). A child process
(``python -m controller.shell.status_line``) reads the lines and draws them with rich's ``Live``
on the terminal the controller was started from; it ends at the end of its input, erasing the
line, before the summary is printed. A process and not a thread for the same reason as the
recorder's writer (docs/concepts/design-decisions.md): a thread drawing with rich would take the GIL the
loop needs at its deadlines.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from enum import Enum
from typing import IO, TYPE_CHECKING

from controller.child_process import child_environment, python_module_command

if TYPE_CHECKING:  # the drawing process imports this module: it must not load the law (numpy, Ruckig)
    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
    from controller.core.ports import CycleTiming

DEFAULT_INTERVAL_S = 0.25
LATE_FRACTION = 0.1  # a cycle woke more than this fraction of a period late: the run summary's definition
_STOP_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class StatusSnapshot:
    """Where a run is; the input of ``status_text``."""

    run: int  # 1 for the first run of the command, 2 for the contour demo's position-control comparison
    elapsed_s: float  # since the loop started, by the cycle index
    mode: str
    phase: str  # the task's phase ("" before the task starts)
    lap: int | None  # the lap in progress, from 1; None for a task that counts no laps
    laps: int | None  # how many the task runs
    force_error_rms_n: float | None  # while tracking, so far; None before any
    force_error_samples: int
    late_cycles: int  # woke more than 10 % of a period late, or skipped
    fault: str = ""


def status_text(s: StatusSnapshot) -> str:
    """One line, e.g. `` 12.5 s  RUNNING  TRACKING  lap 2/5  force error 0.31 N RMS  late cycles 3``.

    A second run of the same command (the contour demo's comparison) starts with ``run 2``.
    """
    parts = [f"{s.elapsed_s:5.1f} s", s.mode]
    if s.run > 1:
        parts.insert(0, f"run {s.run}")
    if s.phase:
        parts.append(s.phase)
    if s.lap is not None:
        parts.append(f"lap {s.lap}/{s.laps}" if s.laps else f"lap {s.lap}")
    if s.force_error_rms_n is not None:
        parts.append(f"force error {s.force_error_rms_n:.2f} N RMS")
    parts.append(f"late cycles {s.late_cycles}")
    if s.fault:
        parts.append(f"fault: {s.fault}")
    return "  ".join(parts)


def status_wanted(as_json: bool, stream: IO[str]) -> bool:
    """A status line only for a person at a terminal: not with ``--json``, not into a pipe or a file."""
    if as_json:
        return False
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


def _phase_name(task_state: object) -> str:
    phase = getattr(task_state, "phase", None)
    return phase.name if isinstance(phase, Enum) else ""


class StatusObserver:
    """Loop observer: accumulates where the run is; ``write`` gets one JSON line every ``interval_s``.

    The tasks' own state says the rest: a task state with ``lap`` (0-based) counts laps, one
    with ``force_error_n`` in its ``TRACKING`` phase has a force error (the contour task).
    """

    def __init__(
        self,
        write: Callable[[bytes], None],
        period_s: float,
        laps: int | None = None,
        interval_s: float = DEFAULT_INTERVAL_S,
    ) -> None:
        self.write = write
        self.period_s = period_s
        self.laps = laps
        self.every = max(1, round(interval_s / period_s))
        self.run = 0
        self._last_cycle = -1
        self._late = 0
        self._sum_sq = 0.0
        self._samples = 0

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        if cycle <= self._last_cycle or self.run == 0:  # the loop starts at cycle 0: a new run
            self.run += 1
            self._late = 0
            self._sum_sq = 0.0
            self._samples = 0
            self._last_cycle = -1
        skipped = cycle - self._last_cycle - 1  # deadlines the loop skipped (overruns)
        self._late += skipped + (timing.wake_error_s > LATE_FRACTION * self.period_s)
        ts = state.task_state
        err = getattr(ts, "force_error_n", None)
        if err is not None and _phase_name(ts) == "TRACKING":
            self._sum_sq += err * err
            self._samples += 1
        if cycle // self.every != self._last_cycle // self.every:
            self.write(json.dumps(asdict(self.snapshot(cycle, state))).encode() + b"\n")
        self._last_cycle = cycle

    def snapshot(self, cycle: int, state: ControllerState) -> StatusSnapshot:
        ts = state.task_state
        lap = getattr(ts, "lap", None)
        return StatusSnapshot(
            run=self.run,
            elapsed_s=cycle * self.period_s,
            mode=state.mode.name,
            phase=_phase_name(ts),
            lap=lap + 1 if isinstance(lap, int) else None,
            laps=self.laps if isinstance(lap, int) else None,
            force_error_rms_n=math.sqrt(self._sum_sq / self._samples) if self._samples else None,
            force_error_samples=self._samples,
            late_cycles=self._late,
            fault=state.fault_reason,
        )


class StatusDisplay:
    """The drawing process and the pipe to it; ``observer()`` makes the loop's side."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.proc = proc
        assert proc.stdin is not None  # stdin=PIPE
        self._fd = proc.stdin.fileno()
        os.set_blocking(self._fd, False)
        self.dropped = 0

    def write(self, line: bytes) -> None:
        """One non-blocking write; a full pipe (the drawing lags) or a gone process drops the line."""
        if self._fd < 0:
            return
        try:
            os.write(self._fd, line)
        except BlockingIOError:
            self.dropped += 1
        except OSError:
            self._fd = -1

    def observer(self, period_s: float, laps: int | None = None) -> StatusObserver:
        return StatusObserver(self.write, period_s, laps)

    def close(self) -> None:
        """End of input: the process erases the line and exits (killed if it does not within 5 s)."""
        self._fd = -1
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        try:
            self.proc.wait(_STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


@contextmanager
def live_status(enabled: bool) -> Iterator[StatusDisplay | None]:
    """The status line's process while the block runs (None when not ``enabled``)."""
    if not enabled:
        yield None
        return
    proc = subprocess.Popen(
        python_module_command("controller.shell.status_line"), stdin=subprocess.PIPE, env=child_environment()
    )
    display = StatusDisplay(proc)
    try:
        yield display
    finally:
        display.close()


def draw(lines: IO[bytes]) -> None:
    """The drawing process: each JSON line replaces the status line, until the input ends."""
    from rich.console import Console
    from rich.live import Live
    from rich.text import Text

    with Live(Text(""), console=Console(), auto_refresh=False, transient=True) as live:
        for raw in lines:
            try:
                snapshot = StatusSnapshot(**json.loads(raw))
            except (ValueError, TypeError):
                continue
            live.update(Text(status_text(snapshot)), refresh=True)


def main(argv: list[str] | None = None) -> int:
    signal.signal(
        signal.SIGINT, signal.SIG_IGN
    )  # Ctrl-C reaches the whole group: the controller stops the run
    draw(sys.stdin.buffer)
    return 0


if __name__ == "__main__":
    sys.exit(main())
