"""The 3-nSPU's commands, ``cheope plan`` and ``cheope plan-bench`` (seed 004's planner): declared as
plug-in commands under ``cheope.commands`` (controller/commands.py) like any robot's own commands, so
the command line names no robot."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import TYPE_CHECKING

from controller.cli_arguments import count_or_zero, positive_count
from controller.cli_output import progress_line, strict_json
from controller.commands import Command
from controller.config import ConfigError
from controller.output_paths import check_output_dir

if TYPE_CHECKING:
    from controller.config import Config
    from controller.robots.nspu.kinematics import Pose


def _pose_arg(text: str, what: str) -> Pose:
    import numpy as np

    from controller.core.rotations import rpy
    from controller.robots.nspu.kinematics import Pose

    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError as err:
        raise ConfigError(f"--{what} {text!r}: expected 6 numbers X,Y,Z,ROLL,PITCH,YAW [m, rad]") from err
    if len(vals) != 6 or not all(np.isfinite(vals)):
        raise ConfigError(f"--{what} {text!r}: expected 6 finite numbers X,Y,Z,ROLL,PITCH,YAW [m, rad]")
    return Pose(np.array(vals[:3]), rpy(*vals[3:]))


def _plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--from",
        dest="start",
        metavar="X,Y,Z,ROLL,PITCH,YAW",
        help="start pose [m, rad] (default: the config's robot.nspu.start_*)",
    )
    p.add_argument(
        "--to",
        dest="goal",
        metavar="X,Y,Z,ROLL,PITCH,YAW",
        help="goal pose [m, rad] (default: the config's robot.nspu.goal_*)",
    )
    p.add_argument(
        "--paper-example",
        action="store_true",
        help="seed 004 section 4: (0,0,25) aul RPY(0,0,-pi/6) -> (-0.4,-0.2,35) aul RPY(0,0,-pi/2)",
    )
    p.add_argument(
        "--no-type2-check",
        action="store_true",
        help="allow plans crossing the type-II singularity det M = 0 (the paper's assumptions; warns)",
    )
    p.add_argument(
        "--json", action="store_true", help="print the report as one JSON object (strict: null for NaN)"
    )
    p.add_argument("--output-dir", metavar="DIR", help="write the plan's PNG plots here")
    p.add_argument("--plot", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir


def run_plan(args: argparse.Namespace, cfg: Config) -> int:
    from controller.robots.nspu.analysis import plan_nspu
    from controller.robots.nspu.entry import nspu_poses
    from controller.robots.nspu.planning.nonholonomic import paper_example_poses

    plot = check_output_dir(args.output_dir, "--output-dir") if args.output_dir else None
    start, goal = (
        paper_example_poses(cfg.robot.model("nspu").length_unit_m)
        if args.paper_example
        else nspu_poses(cfg.robot.model("nspu"))
    )
    if args.start:
        start = _pose_arg(args.start, "from")
    if args.goal:
        goal = _pose_arg(args.goal, "to")
    if args.no_type2_check:
        print(
            "cheope plan: warning: the type-II singularity check is off; the plan may cross det M = 0",
            file=sys.stderr,
        )
    with progress_line("cheope plan") as progress:
        progress("planning")
        report = plan_nspu(cfg, start, goal, not args.no_type2_check, plot)
    print(strict_json(report) if args.json else "\n".join(f"{k}: {v}" for k, v in report.items()))
    return 0 if report["ok"] else 1


def _plan_bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pairs", type=positive_count, default=100, help="number of pose pairs (default 100)")
    p.add_argument("--seed", type=count_or_zero, default=0, help="seed of the pairs (default 0)")
    p.add_argument(
        "--json", action="store_true", help="print the report as one JSON object (strict: null for NaN)"
    )


def run_plan_bench(args: argparse.Namespace, cfg: Config) -> int:
    from controller.robots.nspu.planner_benchmark import format_report, run_benchmark

    if args.pairs < 1:
        raise ConfigError(f"--pairs {args.pairs}: must be >= 1")
    log = logging.getLogger("cheope.plan-bench")
    with progress_line("cheope plan-bench") as progress:

        def each_pair(line: str) -> None:
            log.info("%s", line)
            progress(f"{line}; pairs 0..{args.pairs - 1}")

        report = run_benchmark(cfg, args.pairs, args.seed, each_pair)
    print(strict_json(report) if args.json else format_report(report))
    return 0


# entry points cheope.commands: plan, plan-bench (pyproject.toml)
PLAN = Command(
    "3-nSPU: plan a non-holonomic motion (seed 004) and report it", _plan_arguments, run_plan, ("nspu",)
)
PLAN_BENCH = Command(
    "3-nSPU: the planner over random seeded pose pairs; success, time, error",
    _plan_bench_arguments,
    run_plan_bench,
    ("nspu",),
)
