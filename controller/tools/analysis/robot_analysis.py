"""``cheope analyze`` and ``cheope plan`` for the 3-URU and the 3-nSPU (the configured geometry).

- ``analyze_uru``: workspace and singularity-locus sections (seed 003, Fig. 5-7) through
  ``uru_plots.plot_workspace_and_singularities``, plus the configured path's check and margins;
- ``analyze_nspu``: the type-II locus det M = 0 (seed 000 eq. (26), Fig. 7) and the
  controllability locus det L = 0 (eq. (35), Fig. 8) for XZX Euler angles (0, 1, 0) rad;
- ``plan_nspu``: one run of the seed 004 planner with its report (and plots).
No printing here: the CLI prints the returned dicts.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from controller.config import Config

if TYPE_CHECKING:
    from controller.robots.nspu import Pose


def analyze_uru(cfg: Config, out_dir: Path) -> dict[str, object]:
    from controller.robots import uru
    from controller.robots.builtin import build_uru
    from controller.robots.uru_robot import UruWorkspaceError
    from controller.tools.analysis.uru_plots import plot_workspace_and_singularities

    robot = build_uru(cfg.robot.model("uru"))
    files = plot_workspace_and_singularities(robot.geometry, out_dir)
    p = cfg.task.model("path")
    from controller.tasks.circle_path import CirclePath, TiltedCirclePath

    path = TiltedCirclePath(CirclePath(p.center_m, p.radius_m, p.speed_m_s, p.laps, p.ramp_s), p.normal)
    pts = path.points(p.check_samples)
    try:
        robot.check_path(pts)
        verdict = "accepted"
    except UruWorkspaceError as err:
        verdict = f"refused: {err}"
    fields = uru.singularity_fields(robot.geometry, pts)
    motors = np.array([robot.inverse_kinematics(x) for x in pts]) if verdict == "accepted" else None
    report: dict[str, object] = {
        "robot": "uru",
        "geometry": {
            "f_m": robot.geometry.f.tolist(),
            "r_m": robot.geometry.r.tolist(),
            "k": robot.geometry.k.tolist(),
            "d_b_m": robot.geometry.base_offset_m,
            "d_p_m": robot.geometry.platform_offset_m,
        },
        "path_check": verdict,
        "path_min_plane_distance_m": round(float(np.min(np.abs(pts))), 5),
        "path_min_workspace_margin_m": round(float(np.nanmin(fields["workspace_margin_m"])), 5),
        "path_min_abs_det_v": round(float(np.nanmin(np.abs(fields["translation_det_v"]))), 4),
        "path_min_abs_det_s": round(float(np.nanmin(np.abs(fields["actuation_det_s"]))), 4),
        "path_min_abs_det_a": round(float(np.nanmin(np.abs(fields["combined_det_a"]))), 4),
        "path_min_sin_th3": round(float(np.nanmin(fields["serial_min_sin_th3"])), 4),
        "plots": [str(f) for f in files],
    }
    if motors is not None:
        report["path_motor_range_rad"] = [
            [round(float(a), 4), round(float(b), 4)]
            for a, b in zip(motors.min(axis=0), motors.max(axis=0), strict=True)
        ]
    return report


def analyze_nspu(
    cfg: Config, out_dir: Path, euler_xzx_rad: tuple[float, float, float] = (0.0, 1.0, 0.0)
) -> dict[str, object]:
    from controller.planning.nonholonomic import type2_measure
    from controller.robots.builtin import build_nspu
    from controller.tools.analysis.nspu_plots import plot_singularity_loci

    robot = build_nspu(cfg.robot.model("nspu"))
    files = plot_singularity_loci(robot.geometry, out_dir, euler_xzx_rad=euler_xzx_rad)
    return {
        "robot": "nspu",
        "geometry": robot.geometry.name,
        "orientation_xzx_rad": list(euler_xzx_rad),
        "type2_measure_start": float(type2_measure(robot.geometry, robot.start.p_m, robot.start.R)),
        "type2_measure_goal": float(type2_measure(robot.geometry, robot.goal.p_m, robot.goal.R)),
        "plots": [str(f) for f in files],
    }


def plan_nspu(
    cfg: Config, start: Pose, goal: Pose, check_type2: bool, plot_dir: Path | None
) -> dict[str, object]:
    """Plan start -> goal (Pose) with the configured planner; the report says CONVERGED or why not."""
    from controller.planning.nonholonomic import plan_motion
    from controller.robots.builtin import nspu_geometry
    from controller.robots.nspu import so3_log
    from controller.tasks.planned_legs import planner_config

    geometry = nspu_geometry(cfg.robot.model("nspu"))
    pcfg = planner_config(cfg.robot.model("nspu"), check_type2=check_type2)
    t0, c0 = time.perf_counter(), time.process_time()
    res = plan_motion(geometry, start, goal, pcfg)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    out: dict[str, object] = {
        "status": res.status.value,
        "ok": res.ok,
        "message": res.message,
        "iterations": res.iterations,
        "final_error": res.final_error,
        "verified_error": res.verified_error,
        "plan_steps": res.plan_steps,
        "planning_time_s": round(elapsed, 3),
        "planning_cpu_s": round(cpu, 3),
        "error_history": [float(e) for e in res.error_history],
        "type2_check": check_type2,
    }
    if not check_type2:
        out["warning"] = (
            "the type-II singularity check is off (the paper's assumptions): the plan may cross "
            "det M = 0, where the platform is not controlled by the legs"
        )
    if res.ok:
        tm = res.type2_measure
        out.update(
            {
                "legs_range_m": [float(res.legs_m.min()), float(res.legs_m.max())],
                "max_leg_rate_m_s_at_T": float(np.abs(res.leg_rates_m_s).max()),
                "type2_sign_changes": int(np.sum(np.diff(np.sign(tm)) != 0)),
                "end_position_error_m": float(np.linalg.norm(res.p_m[-1] - goal.p_m)),
                "end_angle_error_rad": float(np.linalg.norm(so3_log(res.R[-1] @ goal.R.T))),
            }
        )
    if plot_dir is not None and np.all(np.isfinite(res.p_m)):  # a failed plan's plots show why
        from controller.tools.analysis.nspu_plots import plot_plan

        out["plots"] = [str(p) for p in plot_plan(res, plot_dir)]
    return out
