"""``cheope bench``'s arguments, their checks and the command itself."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from controller.cli_output import strict_json
from controller.errors import InputError
from controller.realtime import RealtimeOptions
from controller.tools.bench.cpu_hogs import MAX_HOGS
from controller.tools.bench.report import format_table
from controller.tools.bench.runner import FD_FROM_HZ, TOLERANT_SAFETY, run_bench


def _bench_tasks() -> tuple[str, ...]:
    """The tasks the bench can run over the bus: those of its robot, the shipped configuration's."""
    from controller.config import load_config, runnable_tasks

    return runnable_tasks(load_config().robot.kind)


def add_bench_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--config", help="TOML configuration (default: the shipped one)")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a configuration key"
    )
    ap.add_argument("--rates", default="400,1000", help="loop rates to measure [Hz], comma-separated")
    ap.add_argument(
        "--duration", type=float, default=300.0, help="seconds per rate with the simulator (default 300)"
    )
    ap.add_argument(
        "--compare", type=float, default=20.0, help="seconds per rate of loop shell vs naive sleep"
    )
    ap.add_argument(
        "--fd-from", type=float, default=FD_FROM_HZ, help="rates from this one up run on CAN FD [Hz]"
    )
    ap.add_argument("--late-fraction", type=float, default=0.1, help="late: woke this part of a period after")
    ap.add_argument("--sim-rt-priority", type=int, metavar="N", help="SCHED_FIFO priority of the simulator")
    ap.add_argument("--sim-cpu", metavar="CPUS", help="CPU affinity of the simulator")
    ap.add_argument(
        "--output-dir", default="bench", metavar="DIR", help="directory for bench.json and the PNG plots"
    )
    ap.add_argument("--out", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    ap.add_argument(
        "--task",
        choices=_bench_tasks(),
        default="path",
        help="the task over the bus: the circle (default), or another task of the configured robot "
        "(a task with an experiment, as the contour, runs its own length)",
    )
    ap.add_argument(
        "--schedulers",
        default="realtime,normal",
        help="run each rate with the real-time options (realtime) and/or without (normal)",
    )
    ap.add_argument(
        "--cyclictest",
        type=float,
        default=30.0,
        metavar="S",
        help="seconds of cyclictest beside each case (0: none)",
    )
    ap.add_argument(
        "--hogs",
        type=int,
        default=0,
        metavar="N",
        help="N busy processes at the normal priority beside each case (an ordinary busy machine)",
    )
    ap.add_argument(
        "--instructions",
        action="store_true",
        help="also machine instructions per cycle (valgrind's callgrind; a few minutes)",
    )
    ap.add_argument("--json", action="store_true", help="print the JSON instead of the table")
    ap.add_argument(
        "--strict",
        action="store_true",
        help="keep the configured safety reactions (default: late/missing frames only warn)",
    )


def checked_bench_arguments(
    args: argparse.Namespace, overrides: list[str]
) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The rates and schedulers, every argument and the configuration at each rate checked before
    any section runs (``--rates 0`` failed after two sections, leaving an empty ./bench)."""
    from controller.config import load_config, parse_override
    from controller.output_paths import check_output_dir

    try:
        rates = tuple(float(r) for r in args.rates.split(","))
    except ValueError:
        raise InputError(
            f"--rates {args.rates!r}: expected loop rates [Hz], comma-separated, e.g. 400,1000"
        ) from None
    for name, value, ok, allowed in (
        ("--duration", args.duration, args.duration > 0, "> 0"),
        ("--compare", args.compare, args.compare >= 0, ">= 0"),
        ("--cyclictest", args.cyclictest, args.cyclictest >= 0, ">= 0"),
        ("--fd-from", args.fd_from, args.fd_from > 0, "> 0"),
        ("--hogs", args.hogs, 0 <= args.hogs <= MAX_HOGS, f"0 .. {MAX_HOGS}"),
        ("--late-fraction", args.late_fraction, 0 < args.late_fraction < 1, "in (0, 1)"),
    ):
        if not (math.isfinite(value) and ok):
            raise InputError(f"{name} {value:g}: must be {allowed}")
    sets = dict(parse_override(s) for s in overrides)
    for rate in rates:  # the configuration's own range check of loop.rate_hz, and the rest at that rate
        try:
            load_config(args.config, {**sets, "loop.rate_hz": rate})
        except InputError as err:
            raise InputError(f"--rates {args.rates}: {err}") from None
    schedulers = tuple(x.strip() for x in args.schedulers.split(",") if x.strip())
    unknown = [x for x in schedulers if x not in ("realtime", "normal")]
    if unknown or not schedulers:
        raise InputError(f"--schedulers {args.schedulers!r}: expected realtime, normal or both")
    check_output_dir(args.output_dir, "--output-dir")
    return rates, schedulers


def run_bench_command(args: argparse.Namespace, rt: RealtimeOptions) -> int:
    from controller.realtime import parse_cpus

    if args.sim_rt_priority is None and args.sim_cpu is None:
        sim_rt = rt.for_simulator()  # as the demo gives it: one step below the loop, on the other CPUs
    else:
        sim_rt = RealtimeOptions(
            priority=args.sim_rt_priority,
            cpus=parse_cpus(args.sim_cpu, "--sim-cpu") if args.sim_cpu is not None else (),
            lock_memory=rt.lock_memory,
            cpu_latency_us=rt.cpu_latency_us,
            required=rt.required,
        )
    overrides = list(args.set) if args.strict else [*TOLERANT_SAFETY, *args.set]
    if args.task != "path":
        overrides.insert(0, f'task.kind="{args.task}"')
    rates, schedulers = checked_bench_arguments(args, overrides)
    report = run_bench(
        rates,
        args.duration,
        args.compare,
        Path(args.output_dir),
        args.config,
        overrides,
        rt,
        sim_rt,
        late_fraction=args.late_fraction,
        fd_from_hz=args.fd_from,
        progress=lambda s: print(s, file=sys.stderr, flush=True),
        schedulers=schedulers,
        cyclictest_s=args.cyclictest,
        task=args.task,
        instructions=args.instructions,
        hogs=args.hogs,
    )
    print(strict_json(report, indent=2) if args.json else format_table(report))
    print(f"JSON: {Path(args.output_dir) / 'bench.json'}", file=sys.stderr)
    return 0
