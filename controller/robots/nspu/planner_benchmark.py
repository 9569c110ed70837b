"""``cheope plan-bench``: the 3-nSPU planner over random, seeded pose pairs (issue 20's benchmark).

Pairs: a start drawn around the configured start (x, y within +-start_xy_m, z in start_z_range_m,
roll and pitch within +-start_tilt_rad, yaw within +-start_yaw_rad of the configured yaw), a goal
displaced from it by up to +-step_m per axis and +-step_rad per roll/pitch/yaw angle, the spread of
the pairs in issue 20's table (the shipped default motion moves 1.9, 2.5, 2.1 cm and 0.31 rad of
pitch).  A pair is kept only if both poses are regular and on the same side of det S = 0 and of
det M = 0 with the planner's margins, and their legs are inside the stroke (the planner's own
start/goal check, `nonholonomic.check_pose`); others are redrawn, so every pair has a plan in
principle.  Same seed, same pairs.

Prints one row per status, the success rate, the planning time p50/p95 and the verified end
errors; `--json` prints everything.  Not part of `make test` (about a second a pair).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from controller.config import Config


@dataclass(frozen=True)
class PairSpread:
    """How far the random pairs spread (m, rad)."""

    start_xy_m: float = 0.01
    start_z_range_m: tuple[float, float] = (0.24, 0.28)
    start_tilt_rad: float = 0.08
    start_yaw_rad: float = 0.1
    step_m: float = 0.025
    step_rad: float = 0.15


def random_pairs(
    cfg: Config, count: int, seed: int, spread: PairSpread = PairSpread()
) -> list[tuple[object, object]]:
    """`count` (start, goal) Pose pairs that pass the planner's start/goal checks (module doc)."""
    from controller.core.rotations import rpy
    from controller.robots.nspu.entry import nspu_geometry, nspu_poses
    from controller.robots.nspu.kinematics import Pose
    from controller.robots.nspu.planned_legs import planner_config
    from controller.robots.nspu.planning.nonholonomic import check_pose, singularity_measures

    geometry = nspu_geometry(cfg.robot.model("nspu"))
    pcfg = planner_config(cfg.robot.model("nspu"))
    base, _ = nspu_poses(cfg.robot.model("nspu"))
    base_yaw = float(np.arctan2(base.R[1, 0], base.R[0, 0]))
    rng = np.random.default_rng(seed)
    pairs: list[tuple[object, object]] = []
    draws = 0
    while len(pairs) < count:
        draws += 1
        if draws > 200 * count:
            raise RuntimeError(
                f"only {len(pairs)} of {count} admissible pairs in {draws} draws: spread too wide"
            )
        s = spread
        p0 = np.array(
            [
                rng.uniform(-s.start_xy_m, s.start_xy_m),
                rng.uniform(-s.start_xy_m, s.start_xy_m),
                rng.uniform(*s.start_z_range_m),
            ]
        )
        a0 = np.array(
            [
                rng.uniform(-s.start_tilt_rad, s.start_tilt_rad),
                rng.uniform(-s.start_tilt_rad, s.start_tilt_rad),
                base_yaw + rng.uniform(-s.start_yaw_rad, s.start_yaw_rad),
            ]
        )
        p1 = p0 + rng.uniform(-s.step_m, s.step_m, 3)
        a1 = a0 + rng.uniform(-s.step_rad, s.step_rad, 3)
        start, goal = Pose(p0, rpy(*a0)), Pose(p1, rpy(*a1))
        if check_pose(geometry, start, pcfg, "start") or check_pose(geometry, goal, pcfg, "goal"):
            continue
        ds0, tm0 = singularity_measures(geometry, start.p_m, start.R)
        ds1, tm1 = singularity_measures(geometry, goal.p_m, goal.R)
        if np.sign(ds0) != np.sign(ds1) or np.sign(tm0) != np.sign(tm1):
            continue
        pairs.append((start, goal))
    return pairs


def run_benchmark(
    cfg: Config, count: int = 100, seed: int = 0, progress: Callable[[str], None] | None = None
) -> dict[str, object]:
    """Plan every pair with the configured planner; per-pair rows and the summary figures."""
    from controller.core.rotations import so3_log
    from controller.robots.nspu.entry import nspu_geometry
    from controller.robots.nspu.kinematics import Pose
    from controller.robots.nspu.planned_legs import planner_config
    from controller.robots.nspu.planning.nonholonomic import plan_motion

    geometry = nspu_geometry(cfg.robot.model("nspu"))
    pcfg = planner_config(cfg.robot.model("nspu"))
    rows: list[dict[str, object]] = []
    for k, (start, goal) in enumerate(random_pairs(cfg, count, seed)):
        assert isinstance(start, Pose) and isinstance(goal, Pose)
        t0, c0 = time.perf_counter(), time.process_time()
        res = plan_motion(geometry, start, goal, pcfg)
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        rows.append(
            {
                "pair": k,
                "status": res.status.value,
                "ok": res.ok,
                "iterations": res.iterations,
                "time_s": elapsed,
                "cpu_s": cpu,
                "verified_error": res.verified_error,
                "message": res.message,
                "start": [*start.p_m.tolist(), *so3_log(start.R).tolist()],
                "goal": [*goal.p_m.tolist(), *so3_log(goal.R).tolist()],
            }
        )
        if progress is not None:
            progress(
                f"pair {k}: {res.status.value}, {res.iterations} iterations, {elapsed:.3f} s ({cpu:.3f} s CPU)"
            )
    times = np.array([float(r["time_s"]) for r in rows])  # type: ignore[arg-type]
    cpus = np.array([float(r["cpu_s"]) for r in rows])  # type: ignore[arg-type]
    ok = [r for r in rows if r["ok"]]
    errs = np.array([float(r["verified_error"]) for r in ok])  # type: ignore[arg-type]
    statuses: dict[str, int] = {}
    for r in rows:
        statuses[str(r["status"])] = statuses.get(str(r["status"]), 0) + 1
    return {
        "pairs": len(rows),
        "seed": seed,
        "success_rate": len(ok) / len(rows),
        "statuses": statuses,
        "time_s": {
            "p50": float(np.percentile(times, 50)),
            "p95": float(np.percentile(times, 95)),
            "max": float(times.max()),
        },
        "cpu_s": {
            "p50": float(np.percentile(cpus, 50)),
            "p95": float(np.percentile(cpus, 95)),
            "max": float(cpus.max()),
        },
        "load_average_1min": os.getloadavg()[0],
        "verified_error": {
            "p50": float(np.median(errs)) if errs.size else None,
            "max": float(errs.max()) if errs.size else None,
        },
        "iterations_p50": float(np.median([float(r["iterations"]) for r in ok])) if ok else None,  # type: ignore[arg-type]
        "rows": rows,
    }


def format_report(report: dict[str, object]) -> str:
    t, c, e, statuses = report["time_s"], report["cpu_s"], report["verified_error"], report["statuses"]
    assert isinstance(t, dict) and isinstance(c, dict) and isinstance(e, dict) and isinstance(statuses, dict)
    lines = [
        f"pairs               {report['pairs']} (seed {report['seed']})",
        f"success             {float(report['success_rate']) * 100:.0f} %   "  # type: ignore[arg-type]
        + ", ".join(f"{k} {v}" for k, v in sorted(statuses.items())),
        f"planning time       p50 {t['p50']:.3f} s, p95 {t['p95']:.3f} s, max {t['max']:.3f} s (wall)",
        (
            f"planning CPU time   p50 {c['p50']:.3f} s, p95 {c['p95']:.3f} s, max {c['max']:.3f} s "
            f"(machine load average at the end {report['load_average_1min']:.1f})"
        ),
        f"end error E         p50 {e['p50']:.2e}, max {e['max']:.2e} (verified integration; tolerance in the config)"
        if e["p50"] is not None
        else "end error E         no success",
        f"iterations          p50 {report['iterations_p50']}",
    ]
    rows = report["rows"]
    assert isinstance(rows, list)
    for r in rows:
        if not r["ok"]:
            lines.append(f"  pair {r['pair']}: {r['status']}: {r['message']}")
    return "\n".join(lines)
