"""How the contact force answers a hold-up of the loop, from a contour recording.

A hold-up is a cycle the contour task itself treats as one (``contour_tracking.loop_held_up``):
the loop woke late (``inputs.late``) or a drive's or the sensor's frame is missing. For the
tracking cycles of the laps asked for (by default 3-5, the demo's laps at 60 mm/s) this prints the
force error's RMS by how many cycles came since the last hold-up, so that a force that rings on
after one shows for how long; and how often the drives stood, a hold-up longer than their
segment and their periods of extrapolation (``actuators.extrapolation_s`` of the recording's
configuration; sim_backend/drive.py):

    python -m controller.tools.contour.holdup_response RECORDING.mcap [--laps 3,4,5]
"""

from __future__ import annotations

import argparse
import bisect
import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from controller.core.control_law import hold_up_effect
from controller.core.periods import deadlines_skipped
from controller.tasks.contour_tracking import loop_held_up
from drivers.node_setup import DRIVE_DEFAULT_EXTRAPOLATION_PERIODS
from logs.messages import inputs_from_pb
from logs.reader import ReadReport, iter_decoded, recorded_config

BIN_EDGES = (0, 1, 5, 10, 20, 40, 80, 160, 320, 640)  # cycles since the last hold-up


@dataclass(frozen=True)
class TrackingCycle:
    lap: int  # 1-based, as the run's summary counts them
    tracking: bool  # the task tracked the contour this cycle
    force_error_n: float
    held_up: bool
    t_s: float  # the cycle's deadline
    wake_error_s: float  # how late the loop woke for it: when its SYNC went out, after the deadline
    targets_withheld: bool = False  # its SYNC went without the last step's targets (CycleInputs)


@dataclass(frozen=True)
class SinceBin:
    first: int  # cycles since the last hold-up, from ...
    last: int | None  # ... to (None: and beyond)
    cycles: int
    rms_n: float


def read_cycles(path: str, report: ReadReport | None = None) -> list[TrackingCycle]:
    """The contour task's cycles of a recording (those with a lap), in order."""
    out = []
    for d in iter_decoded(path, ["/cycle"], report):
        c = d.message
        values = c.state.task_values
        if "lap" not in values:
            continue
        inputs = inputs_from_pb(c.inputs)
        lap, tracking = int(values["lap"]) + 1, c.state.task_phase == "TRACKING"
        out.append(
            TrackingCycle(
                lap,
                tracking,
                values["force_error_n"],
                loop_held_up(inputs),
                c.t_s,
                c.timing.wake_error_s,
                inputs.targets_withheld,
            )
        )
    return out


def recorded_extrapolation_periods(report: ReadReport) -> int:
    """The drives' periods of extrapolation in the recording's configuration (one before 0x2010,
    ``recorded_config_from_dict``, and without a readable configuration)."""
    cfg = recorded_config(report)
    return cfg.drive_extrapolation_periods if cfg is not None else DRIVE_DEFAULT_EXTRAPOLATION_PERIODS


def drives_held(
    cycles: Sequence[TrackingCycle], laps: Iterable[int], extrapolation_periods: int = 1
) -> list[float]:
    """The SYNC intervals [s] before the tracking cycles of ``laps`` after which the drives had stood
    long enough for the law to restart from rest (``drives_held``), by the law's own rule
    (control_law ``hold_up_effect``: after one hold-up, more than ``extrapolation_periods`` + 1
    deadlines skipped; a hold-up right after one counts on from it). A SYNC goes out when the loop
    wakes."""
    steps = [b.t_s - a.t_s for a, b in itertools.pairwise(cycles) if b.t_s > a.t_s]
    if not steps:
        return []
    period_s = min(steps)  # the loop's cycle times are its deadlines
    wanted = set(laps)
    out = []
    blind = 0  # the law's drives_blind_periods: a hold-up right after one counts on from it
    for a, b in itertools.pairwise(cycles):
        skipped = deadlines_skipped(b.t_s - a.t_s, period_s)
        interval_s = (b.t_s + b.wake_error_s) - (a.t_s + a.wake_error_s)
        _, held, blind = hold_up_effect(skipped, extrapolation_periods, blind, b.targets_withheld)
        if b.tracking and b.lap in wanted and held:
            out.append(interval_s)
    return out


def by_cycles_since_holdup(cycles: Sequence[TrackingCycle], laps: Iterable[int]) -> list[SinceBin]:
    """The force error's RMS of the tracking cycles of ``laps`` in bins of cycles since the last
    hold-up (counted over the whole run; before the first one a cycle is in the last bin)."""
    wanted = set(laps)
    sums = [0.0] * len(BIN_EDGES)
    counts = [0] * len(BIN_EDGES)
    since = BIN_EDGES[-1]
    for c in cycles:
        since = 0 if c.held_up else since + 1
        if c.tracking and c.lap in wanted:
            k = bisect.bisect_right(BIN_EDGES, since) - 1
            sums[k] += c.force_error_n * c.force_error_n
            counts[k] += 1
    return [
        SinceBin(
            BIN_EDGES[k],
            BIN_EDGES[k + 1] - 1 if k + 1 < len(BIN_EDGES) else None,
            counts[k],
            math.sqrt(sums[k] / counts[k]) if counts[k] else math.nan,
        )
        for k in range(len(BIN_EDGES))
    ]


def format_bins(bins: Sequence[SinceBin]) -> str:
    lines = ["cycles since hold-up  cycles  force error RMS [N]"]
    for b in bins:
        span = f"{b.first}-{b.last}" if b.last is not None else f"{b.first}-"
        lines.append(f"{span:>20}  {b.cycles:>6}  {b.rms_n:.3f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m controller.tools.contour.holdup_response", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("recording", help="an MCAP recording of a contour run")
    ap.add_argument("--laps", default="3,4,5", help="laps (1-based, comma-separated)")
    args = ap.parse_args(argv)
    report = ReadReport(Path(args.recording))
    cycles = read_cycles(args.recording, report)
    laps = [int(x) for x in args.laps.split(",")]
    extrapolation = recorded_extrapolation_periods(report)
    held = drives_held(cycles, laps, extrapolation)
    print(
        f"{sum(c.held_up for c in cycles if c.lap in laps and c.tracking)} hold-ups in laps {args.laps}; "
        f"{len(held)} of them skipped more deadlines than the drives' {extrapolation} periods of "
        f"extrapolation and one (they stood; the law restarted from rest)"
        + (f", the longest {max(held) * 1e3:.1f} ms" if held else "")
    )
    print(format_bins(by_cycles_since_holdup(cycles, laps)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
