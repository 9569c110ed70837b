"""``cheope analyze``: workspace, singularity margins and performance ellipsoids of a geometry.

Writes three PNG files and returns the figures as a dict:
- ``cheope_workspace.png``: YZ sections of the usable workspace at several X (seed 001
  Fig. 6), coloured by cond(J); a point is usable when it passes every configured limit
  (stroke, spherical-joint swing, singularity margins, condition number);
- ``cheope_ellipses.png``: XY sections of the force, velocity, stiffness and mass ellipsoids
  on a grid at three heights (seed 001 Fig. 7);
- ``cheope_path_margins.png``: the singularity measures, cond(J) and the joint swing along
  the configured path, against their limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from controller.config import Config
from controller.robots.builtin import cheope_from_config, mass_model_from_config
from controller.robots.cheope import CheopeRobot, jacobian, joint_swing_rad, singularity_measures
from controller.robots.performance import (
    Ellipsoid,
    MassModel,
    force_ellipsoid,
    jacobian_indices,
    mass_ellipsoid,
    stiffness_ellipsoid,
    velocity_ellipsoid,
)
from controller.tasks.circle_path import CirclePath


def _cond(robot: CheopeRobot, p: np.ndarray) -> float:
    return jacobian_indices(jacobian(robot.geometry, p)).condition_number


def workspace_sections(robot: CheopeRobot, out: Path, xs_m: tuple[float, ...] = (-0.08, 0.0, 0.08),
                       n: int = 81) -> dict[str, float]:
    ys = np.linspace(-0.20, 0.20, n)
    zs = np.linspace(0.30, 0.70, n)
    fig, axes = plt.subplots(1, len(xs_m), figsize=(5 * len(xs_m), 4.6), sharey=True)
    usable = 0
    for ax, x in zip(axes, xs_m):
        grid = np.full((n, n), np.nan)
        for i, z in enumerate(zs):
            for j, y in enumerate(ys):
                p = np.array([x, y, z])
                if robot.check_pose(p).ok:
                    grid[i, j] = _cond(robot, p)
                    usable += 1
        im = ax.pcolormesh(ys, zs, grid, shading="auto", cmap="viridis", vmin=1.0,
                           vmax=robot.limits.max_condition_number)
        ax.set_title(f"x = {x:+.2f} m")
        ax.set_xlabel("y [m]")
        ax.set_aspect("equal")
    axes[0].set_ylabel("z [m]")
    fig.colorbar(im, ax=axes, label="cond(J) where every limit holds")
    fig.suptitle("Cheope usable workspace, YZ sections (blank: a limit or margin is violated)")
    fig.savefig(out / "cheope_workspace.png", dpi=110)
    plt.close(fig)
    cell = (ys[1] - ys[0]) * (zs[1] - zs[0])
    return {"usable_section_area_m2": round(usable * cell / len(xs_m), 5)}


def _ellipse_xy(ell: Ellipsoid, n: int = 72) -> np.ndarray:
    """The section of an ellipsoid with the XY plane through its centre (reach per direction)."""
    th = np.linspace(0, 2 * np.pi, n)
    return np.array([ell.reach(np.array([math.cos(t), math.sin(t), 0.0])) * np.array([math.cos(t), math.sin(t)])
                     for t in th])


def ellipse_sections(robot: CheopeRobot, masses: MassModel, stiffness_n_m: float, out: Path,
                     zs_m: tuple[float, ...] = (0.45, 0.50, 0.55)) -> None:
    kinds: tuple[tuple[str, Callable[[np.ndarray], Ellipsoid]], ...] = (
        ("force", lambda j: force_ellipsoid(j)), ("velocity", lambda j: velocity_ellipsoid(j)),
        ("stiffness", lambda j: stiffness_ellipsoid(j, stiffness_n_m)),
        ("mass", lambda j: mass_ellipsoid(j, masses)))
    fig, axes = plt.subplots(len(zs_m), len(kinds), figsize=(14, 3.6 * len(zs_m)))
    centres = [(x, y) for x in (-0.06, 0.0, 0.06) for y in (-0.06, 0.0, 0.06)]
    for r, z in enumerate(zs_m):
        for c, (name, make) in enumerate(kinds):
            ax = axes[r, c]
            shapes = []
            for x, y in centres:
                p = np.array([x, y, z])
                if not robot.check_pose(p).ok:
                    continue
                shapes.append(((x, y), _ellipse_xy(make(jacobian(robot.geometry, p)))))
            scale = 0.025 / max(np.abs(s).max() for _, s in shapes) if shapes else 1.0
            for (x, y), s in shapes:
                ax.plot(x + scale * s[:, 0], y + scale * s[:, 1], lw=1.2)
                ax.plot(x, y, "k.", ms=2)
            ax.set_aspect("equal")
            ax.set_xlim(-0.1, 0.1)
            ax.set_ylim(-0.1, 0.1)
            ax.set_title(f"{name}, z = {z:.2f} m", fontsize=9)
            ax.tick_params(labelsize=7)
    fig.suptitle("XY sections of the performance ellipsoids (each kind to its own scale)")
    fig.tight_layout()
    fig.savefig(out / "cheope_ellipses.png", dpi=110)
    plt.close(fig)


def path_margins(robot: CheopeRobot, path: CirclePath, out: Path, n: int = 361) -> dict[str, float]:
    pts = path.points(n)
    meas = [singularity_measures(robot.geometry, p) for p in pts]
    cond = [_cond(robot, p) for p in pts]
    swing = [math.degrees(float(joint_swing_rad(robot.geometry, p).max())) for p in pts]
    s = np.linspace(0, 1, n)
    lim = robot.limits
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for label, values, low in (("direct |det W|", [m.direct for m in meas], lim.min_direct_measure),
                               ("inverse min|w.n|", [m.inverse for m in meas], lim.min_inverse_measure),
                               ("structural min|wi x wj|", [m.structural for m in meas], lim.min_structural_measure)):
        line, = axes[0].plot(s, values, label=label)
        axes[0].axhline(low, color=line.get_color(), ls="--", lw=0.8)
    axes[0].set_title("singularity measures (dashed: margins)")
    axes[0].legend(fontsize=8)
    axes[1].plot(s, cond)
    axes[1].axhline(lim.max_condition_number, color="r", ls="--")
    axes[1].set_title("cond(J)")
    axes[2].plot(s, swing)
    axes[2].axhline(math.degrees(lim.joint_swing_limit_rad), color="r", ls="--")
    axes[2].set_title("largest spherical-joint swing [deg]")
    for ax in axes:
        ax.set_xlabel("path parameter (time fraction)")
    fig.tight_layout()
    fig.savefig(out / "cheope_path_margins.png", dpi=110)
    plt.close(fig)
    return {
        "path_min_direct_measure": round(min(m.direct for m in meas), 4),
        "path_min_inverse_measure": round(min(m.inverse for m in meas), 4),
        "path_min_structural_measure": round(min(m.structural for m in meas), 4),
        "path_max_condition_number": round(max(cond), 3),
        "path_max_joint_swing_deg": round(max(swing), 2),
    }


def analyze_cheope(cfg: Config, out: Path) -> dict[str, object]:
    out.mkdir(parents=True, exist_ok=True)
    robot = cheope_from_config(cfg)
    masses = mass_model_from_config(cfg)
    p = cfg.task.model("path")
    path = CirclePath(p.center_m, p.radius_m, p.speed_m_s, p.laps, p.ramp_s)
    centre = np.asarray(p.center_m, dtype=float)
    jac = jacobian(robot.geometry, centre)
    ind = jacobian_indices(jac)
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    report: dict[str, object] = {
        "centre_m": list(p.center_m),
        "centre_q_m": [round(float(v), 5) for v in robot.inverse_kinematics(centre)],
        "centre_condition_number": round(ind.condition_number, 4),
        "centre_sigma_min": round(ind.sigma_min, 4),
        "centre_det_J": round(ind.det, 4),
        "force_capacity_x_over_y": round(force_ellipsoid(jac).reach(ex) / force_ellipsoid(jac).reach(ey), 3),
        "velocity_capacity_y_over_x": round(velocity_ellipsoid(jac).reach(ey) / velocity_ellipsoid(jac).reach(ex), 3),
        "stiffness_x_over_y": round(stiffness_ellipsoid(jac, 1.0).reach(ex) / stiffness_ellipsoid(jac, 1.0).reach(ey),
                                    3),
    }
    report.update(path_margins(robot, path, out))
    report.update(workspace_sections(robot, out))
    ellipse_sections(robot, masses, cfg.robot.mass.actuator_stiffness_n_m, out)
    report["plots"] = sorted(str(f) for f in out.glob("cheope_*.png"))
    return report
