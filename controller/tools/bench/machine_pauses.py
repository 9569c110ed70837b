"""Where the machine itself stood still: gaps in each CPU's kernel events, beside a run's hold-ups.

A hold-up of the loop that nothing in the guest explains may be the host's: on a virtual machine
the hypervisor can stop running a vCPU, or all of them, and no priority inside the guest helps.
``/proc/stat``'s steal (the run summary's ``steal_s``) counts only what the host reports as
stolen; on this machine's VMs the loop was held up 24 ms while both CPUs' steal grew by one tick
or none. This tool looks from the kernel's own side instead. While a command runs it records,
with ftrace, every timer expiry, interrupt, softirq and context switch on every CPU (a handful of
events a millisecond; tracefs, root). A CPU that runs takes its scheduler tick (``CONFIG_HZ``:
every 4 ms at 250 Hz) whenever a task is on it, and the loop's CPU wakes on its timer every period;
so a span longer than ``--min-gap-ms`` without a single event on a CPU that has work is a span in
which that CPU did not run at all. Gaps on an idle CPU (no tick there) are not pauses; gaps on every
CPU at once, while the loop's timer was due, are.

When the command prints a run summary with a recording (``cheope demo --json``), each hold-up of
the recording (a cycle after skipped deadlines, or one that woke more than ``--late-ms`` after its
deadline) is listed with the gaps that overlap it on each CPU, and with what ran on each CPU then
besides that CPU's busiest task of the run (on the CPU the shield keeps for the loop, the loop)
and the idle task: a hold-up inside a gap of its own CPU, with nothing else run there, is the
machine's, not the loop's::

    python -m controller.tools.bench.machine_pauses [--hogs 2] [--json] -- cheope demo --json

Nothing else should run beside it: the trace sees every CPU.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

from controller.core.periods import deadlines_skipped
from controller.errors import DeviceError
from controller.shell.cpu_steal import steal_s_since, steal_ticks
from controller.tools.bench.cpu_hogs import MAX_HOGS, cpu_hogs

TRACEFS = Path("/sys/kernel/tracing")
# Every CPU that runs meets one of these within a tick; the hrtimer expiries are the ticks themselves
# and the loop's own wake-ups.
EVENTS = ("timer:hrtimer_expire_entry", "irq:irq_handler_entry", "irq:softirq_entry", "sched:sched_switch")
BUFFER_KB_PER_CPU = 32768  # about 3 000 events a second a CPU, some 50 bytes each: 3 minutes
MIN_GAP_S = 0.006  # above the 4-ms tick of a 250-Hz kernel, with its jitter
LATE_S = 0.002  # a wake-up this late is a hold-up worth naming
# "<comm>-<pid> [001] d.h1. 12345.678901: hrtimer_expire_entry: ..."
_EVENT = re.compile(r"\[(\d{3})\]\s+\S+\s+(\d+\.\d+):")
# "... sched_switch: prev_comm=swapper/1 prev_pid=0 prev_prio=120 prev_state=R ==> next_comm=cheope next_pid=77 ..."
_SWITCH = re.compile(r"sched_switch: .*==> next_comm=(.*) next_pid=(\d+)")
IDLE_PID = 0


class TraceError(DeviceError, RuntimeError):
    """The kernel's trace could not be set up or read."""


@dataclass(frozen=True)
class Gap:
    cpu: int
    start_s: float  # CLOCK_MONOTONIC of the last event before it
    length_s: float

    @property
    def end_s(self) -> float:
        return self.start_s + self.length_s


@dataclass(frozen=True)
class HoldUp:
    cycle: int
    t_s: float  # the cycle's time in the run
    skipped: int  # deadlines skipped before it
    wake_error_s: float
    start_s: float  # CLOCK_MONOTONIC: the deadline of the last cycle before it
    end_s: float  # when the recorder took it (the cycle's work was done)


@dataclass(frozen=True)
class CpuGaps:
    cpu: int
    events: int
    gaps: int
    total_s: float
    largest_s: float
    lost_events: int = 0  # overwritten in a full buffer: its gaps may be false


@dataclass(frozen=True)
class Switch:
    t_s: float
    task: str  # "comm-pid" of the task the CPU switched to
    pid: int


@dataclass
class CpuTrace:
    times: list[float] = field(default_factory=list)  # every event, sorted
    switches: list[Switch] = field(default_factory=list)  # the context switches among them, sorted


def read_cpu_trace(lines: Iterable[str]) -> CpuTrace:
    """One CPU's trace (``trace_clock`` mono: CLOCK_MONOTONIC): its events' times and its switches."""
    out = CpuTrace()
    for line in lines:
        m = _EVENT.search(line)
        if not m:
            continue
        t = float(m.group(2))
        out.times.append(t)
        sw = _SWITCH.search(line, m.end())
        if sw:
            out.switches.append(Switch(t, f"{sw.group(1)}-{sw.group(2)}", int(sw.group(2))))
    out.times.sort()
    out.switches.sort(key=lambda x: x.t_s)
    return out


def ran_during(switches: Sequence[Switch], start_s: float, end_s: float) -> dict[str, float]:
    """How long each task (not the idle task) ran on one CPU between ``start_s`` and ``end_s``."""
    out: dict[str, float] = {}
    current: Switch | None = None
    for sw in switches:
        if sw.t_s >= end_s:
            break
        if current is not None and current.pid != IDLE_PID and sw.t_s > start_s:
            out[current.task] = out.get(current.task, 0.0) + sw.t_s - max(current.t_s, start_s)
        current = sw
    if current is not None and current.pid != IDLE_PID and end_s > max(current.t_s, start_s):
        out[current.task] = out.get(current.task, 0.0) + end_s - max(current.t_s, start_s)
    return out


def gaps_of(cpu: int, times: Sequence[float], min_gap_s: float, within: tuple[float, float]) -> list[Gap]:
    """The spans longer than ``min_gap_s`` between two events of one CPU, inside ``within``
    (the command's run: before and after it an idle CPU takes no tick)."""
    lo, hi = within
    return [
        Gap(cpu, a, b - a) for a, b in itertools.pairwise(times) if b - a > min_gap_s and a >= lo and b <= hi
    ]


def all_at_once(gaps: dict[int, list[Gap]]) -> list[Gap]:
    """The spans in which every CPU was in a gap (cpu -1): the whole machine stood still."""
    cpus = sorted(gaps)
    if not cpus:
        return []
    common = [(g.start_s, g.end_s) for g in gaps[cpus[0]]]
    for cpu in cpus[1:]:
        common = [
            (max(a, g.start_s), min(b, g.end_s))
            for a, b in common
            for g in gaps[cpu]
            if g.start_s < b and a < g.end_s
        ]
    return [Gap(-1, a, b - a) for a, b in sorted(common) if b > a]


def summary_of(cpu: int, events: int, gaps: Sequence[Gap], lost: int = 0) -> CpuGaps:
    lengths = [g.length_s for g in gaps]
    return CpuGaps(cpu, events, len(gaps), sum(lengths), max(lengths, default=0.0), lost)


def overlapping(hold: HoldUp, gaps: Iterable[Gap]) -> list[Gap]:
    return [g for g in gaps if g.start_s < hold.end_s and hold.start_s < g.end_s]


@dataclass(frozen=True)
class RecordedRun:
    start_s: float  # CLOCK_MONOTONIC of its first and last cycle (when the recorder took them)
    end_s: float
    hold_ups: list[HoldUp]


def recorded_run(path: str, late_s: float = LATE_S) -> RecordedRun:
    """The recording's cycles on the monotonic clock (its ``clock_offset_ns`` undone), and its
    hold-ups: cycles after skipped deadlines, and cycles that woke more than ``late_s`` late."""
    from logs import messages as m
    from logs.bus_traffic import clock_offset_s
    from logs.reader import ReadReport, iter_decoded

    report = ReadReport(Path(path))
    rows = [(d.message, d.log_time_ns) for d in iter_decoded(path, (m.TOPIC_CYCLE,), report)]
    offset_s = clock_offset_s(report)
    if offset_s is None:
        raise ValueError(
            f"{path}: no clock offset in its session metadata: its times cannot meet the trace's"
        )
    period_s = float(report.metadata[m.META_SESSION].get("period_s", "0"))
    if not rows:
        raise ValueError(f"{path}: no cycle recorded")
    if period_s <= 0.0 and len(rows) > 1:  # a recording without it: its first two cycles
        period_s = rows[1][0].t_s - rows[0][0].t_s
    out = []
    for (before, _), (c, log_ns) in itertools.pairwise(rows):
        skipped = deadlines_skipped(c.t_s - before.t_s, period_s)
        if skipped or c.timing.wake_error_s > late_s:
            end_s = log_ns * 1e-9 - offset_s
            start_s = end_s - (c.t_s - before.t_s) - period_s  # the recorder takes a cycle in the next one
            out.append(HoldUp(c.cycle, c.t_s, skipped, c.timing.wake_error_s, start_s, end_s))
    return RecordedRun(rows[0][1] * 1e-9 - offset_s, rows[-1][1] * 1e-9 - offset_s, out)


@dataclass
class Trace:
    cpus: dict[int, CpuTrace] = field(default_factory=dict)
    lost: dict[int, int] = field(default_factory=dict)  # events a full buffer overwrote: false gaps


def tracefs_ready(root: Path = TRACEFS) -> bool:
    """Whether the kernel's trace is at ``root``, mounting it first where it is the system's and not
    mounted yet (a fresh machine)."""
    if root == TRACEFS and not (root / "tracing_on").exists():
        subprocess.run(["mount", "-t", "tracefs", "nodev", str(root)], check=False, capture_output=True)
    return (root / "tracing_on").exists()


@contextmanager
def kernel_trace(root: Path = TRACEFS, keep: Path | None = None) -> Iterator[Trace]:
    """Trace ``EVENTS`` on every CPU while the block runs; the ``Trace`` it yields is filled at its
    end, and each CPU's trace text is copied to ``keep``/cpuN.txt where given (what ran on a CPU
    around a hold-up, read by hand). The trace is switched off and its events cleared however it
    ends."""
    tracefs_ready(root)
    try:
        (root / "tracing_on").write_text("0")
        (root / "trace").write_text("")
        (root / "trace_clock").write_text("mono")
        (root / "buffer_size_kb").write_text(str(BUFFER_KB_PER_CPU))
        (root / "set_event").write_text("\n".join(EVENTS) + "\n")
    except OSError as e:
        raise TraceError(
            f"machine pauses: cannot set up the kernel's trace in {root} ({e}): run as root"
        ) from e
    trace = Trace()
    try:
        (root / "tracing_on").write_text("1")
        yield trace
        (root / "tracing_on").write_text("0")
        for cpu_dir in sorted((root / "per_cpu").glob("cpu*"), key=lambda p: int(p.name[3:])):
            cpu = int(cpu_dir.name[3:])
            trace.lost[cpu] = _stat(cpu_dir / "stats", "overrun")
            text = (cpu_dir / "trace").read_text()
            trace.cpus[cpu] = read_cpu_trace(text.splitlines())
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
                (keep / f"{cpu_dir.name}.txt").write_text(text)
    finally:
        (root / "tracing_on").write_text("0")
        (root / "set_event").write_text("")
        (root / "trace").write_text("")


def _stat(path: Path, key: str) -> int:
    for line in path.read_text().splitlines():
        name, _, value = line.partition(":")
        if name.strip() == key:
            return int(value.split()[0])
    return 0


@dataclass(frozen=True)
class HoldUpSeen:
    hold: HoldUp
    gaps: list[Gap]  # of any CPU, overlapping it
    # per CPU, the tasks that ran during it besides the idle task and the CPU's busiest task of the
    # run (the loop, on the CPU the shield keeps for it): what else held that CPU then
    others_s: dict[int, dict[str, float]]


@dataclass(frozen=True)
class Report:
    command: list[str]
    returncode: int
    run_s: tuple[float, float]  # CLOCK_MONOTONIC at the command's start and end
    span_s: tuple[float, float]  # where gaps were looked for: the recording's cycles, else run_s
    span_of: str  # which of the two, or why not the recording
    cpus: list[CpuGaps]
    machine_gaps: list[Gap]  # every CPU at once
    steal_s: dict[str, float]  # /proc/stat's steal over the same run, for comparison
    busiest: dict[int, str]  # each CPU's task that ran longest over the span
    hold_ups: list[HoldUpSeen]


def run(
    command: Sequence[str],
    hogs: int,
    min_gap_s: float,
    late_s: float,
    root: Path = TRACEFS,
    keep: Path | None = None,
) -> tuple[Report, str]:
    """Run ``command`` under the trace (with ``hogs`` busy processes beside it); the report and the
    command's standard output."""
    steal0 = steal_ticks()
    with kernel_trace(root, keep) as trace, cpu_hogs(hogs):
        t0 = time.monotonic()
        done = subprocess.run(list(command), stdout=subprocess.PIPE, text=True, check=False)
        t1 = time.monotonic()
    recorded, span_of = None, "the command's run (no recording in its output)"
    recording = _recording_of(done.stdout)
    if recording:
        try:
            recorded, span_of = recorded_run(recording, late_s), f"the cycles of {recording}"
        except (OSError, ValueError) as e:  # missing, unreadable, damaged: the command's output is still kept
            span_of = f"the command's run ({e})"
    span = (recorded.start_s, recorded.end_s) if recorded else (t0, t1)
    cpus = trace.cpus
    gaps = {cpu: gaps_of(cpu, c.times, min_gap_s, span) for cpu, c in cpus.items()}
    everything = sorted((g for gs in gaps.values() for g in gs), key=lambda g: g.start_s)
    busiest = {cpu: _busiest(ran_during(c.switches, *span)) for cpu, c in cpus.items()}
    holds = (
        [HoldUpSeen(h, overlapping(h, everything), _others(cpus, busiest, h)) for h in recorded.hold_ups]
        if recorded
        else []
    )
    report = Report(
        list(command),
        done.returncode,
        (t0, t1),
        span,
        span_of,
        [summary_of(cpu, len(cpus[cpu].times), gaps[cpu], trace.lost.get(cpu, 0)) for cpu in sorted(cpus)],
        all_at_once(gaps),
        steal_s_since(steal0),
        busiest,
        holds,
    )
    return report, done.stdout


def _busiest(ran: dict[str, float]) -> str:
    return max(ran, key=lambda task: ran[task]) if ran else ""


def _others(cpus: dict[int, CpuTrace], busiest: dict[int, str], h: HoldUp) -> dict[int, dict[str, float]]:
    out = {}
    for cpu, c in cpus.items():
        ran = {k: v for k, v in ran_during(c.switches, h.start_s, h.end_s).items() if k != busiest[cpu]}
        if ran:
            out[cpu] = ran
    return out


def _recording_of(stdout: str) -> str:
    """The recording a ``--json`` run summary names, or ''."""
    try:
        summary = json.loads(stdout)
    except ValueError:
        return ""
    rec = summary.get("recording") if isinstance(summary, dict) else None
    path = rec.get("path", "") if isinstance(rec, dict) else ""
    return path if isinstance(path, str) else ""


def format_report(r: Report) -> str:
    t0 = r.span_s[0]
    lines = [
        f"{' '.join(r.command)}: exit {r.returncode}, {r.run_s[1] - r.run_s[0]:.1f} s",
        f"  gaps of more than the least, in {r.span_of}: {r.span_s[1] - t0:.1f} s",
    ]
    for c in r.cpus:
        lines.append(
            f"  cpu{c.cpu}: {c.events} events; gaps: {c.gaps}, {c.total_s * 1e3:.1f} ms in all, "
            f"largest {c.largest_s * 1e3:.1f} ms; /proc/stat steal {r.steal_s.get(f'cpu{c.cpu}', 0.0):.2f} s"
            + (f"; {c.lost_events} events LOST (a full buffer): gaps may be false" if c.lost_events else "")
        )
    lines.append(
        f"  every CPU at once: {len(r.machine_gaps)} gaps, {sum(g.length_s for g in r.machine_gaps) * 1e3:.1f} ms"
    )
    lines += [f"    {g.length_s * 1e3:6.1f} ms, {g.start_s - t0:7.3f} s in" for g in r.machine_gaps]
    if r.hold_ups:
        inside = sum(1 for seen in r.hold_ups if seen.gaps)
        lines.append(f"  the recording's hold-ups: {len(r.hold_ups)}, {inside} overlapping a gap")
        lines.append(
            "    others: what ran on a CPU then besides its busiest task of the run: "
            + ", ".join(f"cpu{cpu} {task}" for cpu, task in sorted(r.busiest.items()))
        )
        for seen in r.hold_ups:
            h = seen.hold
            where = "; ".join(f"cpu{g.cpu} {g.length_s * 1e3:.1f} ms" for g in seen.gaps) or "no gap"
            others = "; ".join(
                f"cpu{cpu} {task} {t * 1e6:.0f} us"
                for cpu, ran in sorted(seen.others_s.items())
                for task, t in ran.items()
            )
            lines.append(
                f"    cycle {h.cycle} (t {h.t_s:.3f} s): {h.skipped} skipped, woke {h.wake_error_s * 1e3:.1f} ms late"
                f" | {where} | others: {others or 'none'}"
            )
    return "\n".join(lines)


def report_json(r: Report) -> dict[str, object]:
    return {
        "command": r.command,
        "returncode": r.returncode,
        "duration_s": round(r.run_s[1] - r.run_s[0], 3),
        "span_of": r.span_of,
        "span_s": round(r.span_s[1] - r.span_s[0], 3),
        "cpus": [asdict(c) for c in r.cpus],
        "machine_gaps": [
            {"at_s": round(g.start_s - r.span_s[0], 4), "length_s": round(g.length_s, 4)}
            for g in r.machine_gaps
        ],
        "steal_s": r.steal_s,
        "busiest": r.busiest,
        "hold_ups": [
            {
                **{k: v for k, v in asdict(seen.hold).items() if k not in ("start_s", "end_s")},
                "gaps": [{"cpu": g.cpu, "length_s": round(g.length_s, 4)} for g in seen.gaps],
                "others_s": {
                    str(cpu): {task: round(t, 6) for task, t in ran.items()}
                    for cpu, ran in seen.others_s.items()
                },
            }
            for seen in r.hold_ups
        ],
    }


def _terminated(signum: int, _frame: object) -> None:
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m controller.tools.bench.machine_pauses", description=__doc__.split("\n")[0]
    )
    ap.add_argument(
        "--hogs", type=int, default=0, help=f"busy processes beside the command (0 .. {MAX_HOGS})"
    )
    ap.add_argument("--min-gap-ms", type=float, default=MIN_GAP_S * 1e3, help="shortest gap reported [ms]")
    ap.add_argument(
        "--late-ms", type=float, default=LATE_S * 1e3, help="a wake-up this late is a hold-up [ms]"
    )
    ap.add_argument("--output", type=Path, help="write the command's standard output here")
    ap.add_argument("--keep-trace", type=Path, metavar="DIR", help="keep each CPU's trace text in DIR")
    ap.add_argument("--json", action="store_true", help="print the report as one JSON object")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND ...")
    args = ap.parse_args(argv)
    # a SIGTERM (a timeout, a kill) ends it as an exception, so that the trace is switched off and its
    # events cleared, the hogs killed and the command too: by default it ended the process with the
    # whole machine still traced
    signal.signal(signal.SIGTERM, _terminated)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        ap.error("no command: give it after --, e.g. -- cheope demo --json")
    if args.min_gap_ms <= 0 or args.late_ms <= 0:
        ap.error("--min-gap-ms and --late-ms must be > 0")
    if not 0 <= args.hogs <= MAX_HOGS:
        ap.error(f"--hogs {args.hogs}: must be 0 .. {MAX_HOGS}")
    try:
        report, stdout = run(
            command, args.hogs, args.min_gap_ms * 1e-3, args.late_ms * 1e-3, TRACEFS, args.keep_trace
        )
    except (TraceError, ValueError) as e:
        print(e, file=sys.stderr)
        return 2
    if args.output:
        args.output.write_text(stdout)
    print(json.dumps(report_json(report)) if args.json else format_report(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
