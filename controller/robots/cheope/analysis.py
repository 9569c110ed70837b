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
from controller.robots.cheope.entry import build_cheope, cheope_mass_model
from controller.robots.cheope.model import CheopeRobot, jacobian, joint_swing_rad, singularity_measures
from controller.robots.performance import (
    Ellipsoid,
    MassModel,
    cartesian_stiffness,
    force_ellipsoid,
    jacobian_indices,
    mass_ellipsoid,
    stiffness_ellipsoid,
    velocity_ellipsoid,
)
from controller.tasks.circle_path import CirclePath


def _cond(robot: CheopeRobot, p: np.ndarray) -> float:
    return jacobian_indices(jacobian(robot.geometry, p)).condition_number


def workspace_sections(
    robot: CheopeRobot, out: Path, xs_m: tuple[float, ...] = (-0.08, 0.0, 0.08), n: int = 81
) -> dict[str, float]:
    ys = np.linspace(-0.20, 0.20, n)
    zs = np.linspace(0.30, 0.70, n)
    fig, axes = plt.subplots(1, len(xs_m), figsize=(5 * len(xs_m), 4.6), sharey=True)
    usable = 0
    for ax, x in zip(axes, xs_m, strict=True):
        grid = np.full((n, n), np.nan)
        for i, z in enumerate(zs):
            for j, y in enumerate(ys):
                p = np.array([x, y, z])
                if robot.check_pose(p).ok:
                    grid[i, j] = _cond(robot, p)
                    usable += 1
        im = ax.pcolormesh(
            ys, zs, grid, shading="auto", cmap="viridis", vmin=1.0, vmax=robot.limits.max_condition_number
        )
        ax.set_title(f"x = {x:+.2f} m")
        ax.set_xlabel("y [m]")
        ax.set_ylabel("z [m]")
        ax.set_aspect("equal")
    fig.colorbar(im, ax=axes, label="cond(J) [-] where every limit holds")
    fig.suptitle("Cheope usable workspace, YZ sections (blank: a limit or margin is violated)")
    fig.savefig(out / "cheope_workspace.png", dpi=110)
    plt.close(fig)
    cell = (ys[1] - ys[0]) * (zs[1] - zs[0])
    return {"usable_section_area_m2": round(usable * cell / len(xs_m), 5)}


def _ellipse_xy(ell: Ellipsoid, n: int = 72) -> np.ndarray:
    """The section of an ellipsoid with the XY plane through its centre (reach per direction)."""
    th = np.linspace(0, 2 * np.pi, n)
    return np.array(
        [
            ell.reach(np.array([math.cos(t), math.sin(t), 0.0])) * np.array([math.cos(t), math.sin(t)])
            for t in th
        ]
    )


def _nice(value: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``value`` (a scale bar's length)."""
    power = 10.0 ** math.floor(math.log10(value))
    for m in (5.0, 2.0, 1.0):
        if m * power <= value:
            return m * power
    return power


def _si(value: float, unit: str) -> str:
    for factor, prefix in ((1e6, "M"), (1e3, "k"), (1.0, "")):
        if abs(value) >= factor:
            return f"{value / factor:g} {prefix}{unit}"
    return f"{value:g} {unit}"


def ellipse_sections(
    robot: CheopeRobot,
    masses: MassModel,
    stiffness_n_m: float,
    out: Path,
    zs_m: tuple[float, ...] = (0.45, 0.50, 0.55),
) -> None:
    """XY sections of the four ellipsoids (seed 001 Fig. 7), drawn at their grid points.

    Each ellipsoid is the image of a unit ball (see controller/robots/performance.py), so its
    size is in the unit of that image; one scale per kind (column), shown by a scale bar,
    the same for the three heights so that they compare. The stiffness ellipsoid is
    {K d : |d| <= 1 mm}: its radius along u is not the directional stiffness u^T K u.
    """
    kinds: tuple[tuple[str, str, str, Callable[[np.ndarray], Ellipsoid]], ...] = (
        ("force", "TCP force for |actuator forces| <= 1 N", "N", lambda j: force_ellipsoid(j)),
        ("velocity", "TCP speed for |actuator speeds| <= 1 m/s", "m/s", lambda j: velocity_ellipsoid(j)),
        (
            "stiffness",
            "force K d for |d| <= 1 mm",
            "N",
            lambda j: stiffness_ellipsoid(j, stiffness_n_m * 1e-3),
        ),
        ("mass", "force M a for |a| <= 1 m/s^2", "N", lambda j: mass_ellipsoid(j, masses)),
    )
    centres = [(x, y) for x in (-0.06, 0.0, 0.06) for y in (-0.06, 0.0, 0.06)]
    shapes: dict[tuple[int, int], list[tuple[tuple[float, float], np.ndarray]]] = {}
    for r, z in enumerate(zs_m):
        for c, (_, _, _, make) in enumerate(kinds):
            shapes[r, c] = [
                ((x, y), _ellipse_xy(make(jacobian(robot.geometry, np.array([x, y, z])))))
                for x, y in centres
                if robot.check_pose(np.array([x, y, z])).ok
            ]
    fig, axes = plt.subplots(len(zs_m), len(kinds), figsize=(15, 3.9 * len(zs_m)), squeeze=False)
    half_cell_m = 0.026  # the largest ellipse of a column fills most of the 0.06 m grid spacing
    for c, (name, what, unit, _) in enumerate(kinds):
        largest = max(
            (float(np.abs(sh).max()) for r in range(len(zs_m)) for _, sh in shapes[r, c]), default=1.0
        )
        scale = half_cell_m / largest  # plot metres per unit
        bar = _nice(largest)
        for r, z in enumerate(zs_m):
            ax = axes[r, c]
            for (x, y), sh in shapes[r, c]:
                ax.plot(x + scale * sh[:, 0], y + scale * sh[:, 1], lw=1.2, color="tab:blue")
                ax.plot(x, y, "k.", ms=3)
            ax.plot([-0.095, -0.095 + scale * bar], [-0.092, -0.092], color="k", lw=2.5)
            ax.text(-0.095, -0.086, f"{_si(bar, unit)}", fontsize=8, va="bottom")
            ax.set_aspect("equal")
            ax.set_xlim(-0.1, 0.1)
            ax.set_ylim(-0.1, 0.1)
            ticks = [-0.1, -0.05, 0.0, 0.05, 0.1]
            ax.set_xticks(ticks)
            ax.set_yticks(ticks)
            ax.tick_params(labelsize=8)
            ax.set_xlabel("x [m]", fontsize=8)
            ax.set_ylabel("y [m]", fontsize=8)
            ax.set_title(f"{name}, z = {z:.2f} m\n{what}", fontsize=9)
    fig.suptitle(
        "XY sections of the performance ellipsoids at grid points (dots) inside the usable workspace; "
        "bar: the scale of each column",
        fontsize=11,
    )
    fig.tight_layout()
    fig.savefig(out / "cheope_ellipses.png", dpi=110)
    plt.close(fig)


def path_margins(robot: CheopeRobot, path: CirclePath, out: Path, n: int = 361) -> dict[str, float]:
    """Each measure along the configured path in its own panel, against its limit (dashed)."""
    pts = path.points(n)
    meas = [singularity_measures(robot.geometry, p) for p in pts]
    cond = [_cond(robot, p) for p in pts]
    swing = [math.degrees(float(joint_swing_rad(robot.geometry, p).max())) for p in pts]
    s = np.linspace(0, 1, n)
    lim = robot.limits
    panels = (
        (
            "direct singularity measure",
            "|det W| [-]",
            [m.direct for m in meas],
            lim.min_direct_measure,
            "minimum",
        ),
        (
            "inverse singularity measure",
            "min_j |w_j . n_j| [-]",
            [m.inverse for m in meas],
            lim.min_inverse_measure,
            "minimum",
        ),
        (
            "structural singularity measure",
            "min |w_i x w_j| [-]",
            [m.structural for m in meas],
            lim.min_structural_measure,
            "minimum",
        ),
        ("condition number of J", "cond(J) [-]", cond, lim.max_condition_number, "maximum"),
        (
            "largest spherical-joint swing",
            "swing [deg]",
            swing,
            math.degrees(lim.joint_swing_limit_rad),
            "maximum",
        ),
    )
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
    for ax, (title, ylabel, values, limit, kind) in zip(axes.flat[: len(panels)], panels, strict=True):
        ax.plot(s, values, color="tab:blue", label="along the path")
        ax.axhline(limit, color="tab:red", ls="--", lw=1.0, label=f"configured {kind} ({limit:g})")
        lo, hi = min(min(values), limit), max(max(values), limit)
        pad = 0.08 * (hi - lo or 1.0)
        ax.set_ylim(lo - pad, hi + pad)  # the limit always in view, so the margin shows
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.set_xlabel("path parameter s [-] (fraction of the path's duration)")
        ax.legend(fontsize=8, loc="best")
        ax.grid(alpha=0.3)
    axes.flat[-1].axis("off")
    axes.flat[-1].text(
        0.0,
        0.5,
        f"path: circle of {path.radius_m * 1000:g} mm radius around\n"
        f"{tuple(round(float(v), 3) for v in path.center_m)} m, {path.laps:g} lap(s)\n\n"
        "singularity measures of seed 001 (of unit\n"
        "vectors: dimensionless); a point is refused\n"
        "below a minimum or above a maximum",
        fontsize=10,
        va="center",
    )
    fig.suptitle("Cheope: margins along the configured path", fontsize=12)
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
    robot = build_cheope(cfg.robot.model("cheope"))
    masses = cheope_mass_model(cfg.robot.model("cheope").mass)
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
        "velocity_capacity_y_over_x": round(
            velocity_ellipsoid(jac).reach(ey) / velocity_ellipsoid(jac).reach(ex), 3
        ),
        # Two stiffness ratios, which differ: the radius of the image ellipsoid {K d : |d| <= 1} along
        # x over y (the force for a unit displacement, whatever its direction) and the directional
        # stiffness u^T K u (the force along u for a unit displacement along u), K = k J^T J.
        "stiffness_image_reach_x_over_y": round(
            stiffness_ellipsoid(jac, 1.0).reach(ex) / stiffness_ellipsoid(jac, 1.0).reach(ey), 3
        ),
        "stiffness_directional_x_over_y": round(
            float(ex @ cartesian_stiffness(jac, 1.0) @ ex) / float(ey @ cartesian_stiffness(jac, 1.0) @ ey), 3
        ),
    }
    report.update(path_margins(robot, path, out))
    report.update(workspace_sections(robot, out))
    ellipse_sections(robot, masses, cfg.robot.model("cheope").mass.actuator_stiffness_n_m, out)
    report["plots"] = sorted(str(f) for f in out.glob("cheope_*.png"))
    return report
