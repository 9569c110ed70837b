"""The contour task's own commands, declared as plug-in commands (``cheope.commands``,
controller/commands.py): ``cheope contour-scan``, ``contour-shapes`` and ``contour-stress`` run the
contour task against disturbances in simulated time (controller/tools/contour/scan.py and
contour_stress.py). ``cheope faults --contour-*``, their spelling before, still runs them."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from controller.cli_arguments import job_count
from controller.cli_output import progress_line
from controller.commands import Command
from controller.output_paths import check_output_dir

if TYPE_CHECKING:
    from pathlib import Path

    from controller.config import Config


def _arguments(jobs: bool) -> Callable[[argparse.ArgumentParser], None]:
    def add(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--json", action="store_true", help="print the rows and the summary as one JSON object"
        )
        p.add_argument("--output-dir", metavar="DIR", help="keep the scenarios' recordings in DIR")
        if jobs:
            p.add_argument(
                "--jobs",
                type=job_count,
                default=1,
                help="scenarios run in this many processes (default 1; at most the machine's CPUs)",
            )

    return add


def _keep(args: argparse.Namespace) -> Path | None:
    return check_output_dir(args.output_dir, "--output-dir") if args.output_dir else None


def run_contour_scan(args: argparse.Namespace, cfg: Config) -> int:
    from controller.tools.contour.scan import format_table, run_scan, summary

    keep = _keep(args)

    def progress(done: int, total: int, row: dict[str, object]) -> None:
        if sys.stderr.isatty():
            print(
                f"\r{done}/{total} {str(row['scenario'])[:50]:<50} {row['outcome']}",
                end="",
                file=sys.stderr,
                flush=True,
            )

    rows = run_scan(cfg, keep, args.jobs, progress)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    result = summary(rows, cfg.safety.max_contact_force_n)
    print(
        json.dumps({"rows": rows, "summary": result})
        if args.json
        else format_table(rows, cfg.safety.max_contact_force_n)
    )
    return 0 if result["targets_met"] else 1


def run_contour_shapes(args: argparse.Namespace, cfg: Config) -> int:
    from controller.tools.contour.scan import format_shapes, run_shapes, shapes_met

    shapes = run_shapes(cfg, _keep(args))
    print(json.dumps(shapes) if args.json else format_shapes(shapes))
    return 0 if shapes_met(shapes) else 1


def run_contour_stress(args: argparse.Namespace, cfg: Config) -> int:
    from controller.tools.contour import stress as contour_stress

    keep = _keep(args)
    margin_m = cfg.task.model("contour").envelope_margin_m
    with progress_line("cheope contour-stress") as update:
        rows = contour_stress.run_stress(
            cfg,
            keep,
            args.jobs,
            lambda done, total, row: update(f"{done}/{total} {row['scenario']}: {row['outcome']}"),
        )
    result = contour_stress.summary(rows, cfg.safety.max_contact_force_n, margin_m)
    print(
        json.dumps({"rows": rows, "summary": result})
        if args.json
        else contour_stress.format_table(rows, cfg.safety.max_contact_force_n, margin_m)
    )
    return 0 if result["targets_met"] else 1


# entry points cheope.commands (pyproject.toml)
CONTOUR_SCAN = Command(
    "contour task against force spikes, a notch, a bump, a drifting bias, stale and spoofed samples, in "
    "simulated time; exit 1 unless none exceeds safety.max_contact_force_n, 95 % of those to ride through "
    "end DONE and the rest retract with a named cause",
    _arguments(jobs=True),
    run_contour_scan,
)
CONTOUR_SHAPES = Command(
    "contour task, 3 laps at 40 mm/s on each workpiece shape, in simulated time; exit 1 unless each ends "
    "DONE without contact loss, force error RMS <= 1 N, under the limit",
    _arguments(jobs=False),
    run_contour_shapes,
)
CONTOUR_STRESS = Command(
    "contour task against what no scan was tuned to (misplaced parts, steep bumps, offset steps and "
    "drifts, long spikes, tares in contact), in simulated time; exit 1 unless none exceeds the limit or "
    "ends off the part unnamed, 90 % of those to ride through end DONE and the rest end named",
    _arguments(jobs=True),
    run_contour_stress,
)
