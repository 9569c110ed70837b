"""Workspace and singularity-locus plots of the LaMaViP 3-URU (seed 003, Fig. 5-7).

``plot_workspace_and_singularities(geometry, out_dir)`` writes three PNG files:

- ``uru_workspace_3d.png``: reachable-workspace boundary (eq. (29), cf. Fig. 7), the
  rotation-singularity planes (eq. (17), cf. Fig. 5) and the default path;
- ``uru_sections_z.png``: sections z = const through the workspace; colour = det V
  (translation, eq. (20)) in the top row and det S (actuation, eq. (35)) in the bottom row,
  with the zero contours of det V, det S and det A (eq. (36)), the coordinate-plane traces
  (rotation singularities, eq. (17)) and the workspace boundary (eq. (29) = serial loci
  eq. (28));
- ``uru_section_diagonal.png``: the same measures on the vertical plane x = y; its
  quadrants lie in the octants (+,+,+) (upper right, holds the default path), (-,-,+),
  (-,-,-) and (+,+,-).

Only matplotlib (Agg backend) and the pure model; the output directory is an argument.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import QuadMesh

from controller.config import Config
from controller.robots.uru.kinematics import (
    UruGeometry,
    default_path,
    singularity_fields,
    workspace_margin_m,
)

if TYPE_CHECKING:
    from matplotlib.lines import Line2D


_DET_S_POLE_MASK = 20.0


def _geometry_label(geom: UruGeometry) -> str:
    def fmt(a: np.ndarray) -> str:
        return "(" + ", ".join(f"{float(x):g}" for x in a) + ")"

    return (
        f"d_b = {geom.base_offset_m:g} m, d_p = {geom.platform_offset_m:g} m, f = {fmt(geom.f)} m, "
        f"r = {fmt(geom.r)} m, k = {fmt(geom.k)}, knee {geom.knee_sign:+d}"
    )


def _workspace_extent_m(geom: UruGeometry) -> float:
    """Half-size [m] of a cube that contains the reachable workspace (eq. (29))."""
    return float(np.max(geom.f + geom.r) + abs(geom.offset_m)) * 1.05


def _boundary_points(geom: UruGeometry, n_az: int = 60, n_el: int = 30) -> np.ndarray:
    """Points of the outer workspace boundary along rays from O (bisection on eq. (29) margin).

    Rays start from the point of the workspace nearest to O on the ray; rays that never enter
    the workspace are skipped. Shape (n_el, n_az, 3), NaN where a ray misses.
    """
    ext = _workspace_extent_m(geom) * 1.2
    az = np.linspace(0.0, 2.0 * math.pi, n_az)
    el = np.linspace(-math.pi / 2, math.pi / 2, n_el)
    azg, elg = np.meshgrid(az, el)
    dirs = np.stack([np.cos(elg) * np.cos(azg), np.cos(elg) * np.sin(azg), np.sin(elg)], axis=-1)
    radii = np.linspace(0.0, ext, 400)
    pts = dirs[..., None, :] * radii[:, None]
    inside = workspace_margin_m(geom, pts) >= 0.0
    out = np.full(dirs.shape, np.nan)
    for idx in np.ndindex(dirs.shape[:2]):
        mask = inside[idx]
        if not mask.any():
            continue
        last = int(np.nonzero(mask)[0][-1])
        lo, hi = radii[last], radii[min(last + 1, radii.size - 1)]
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            if workspace_margin_m(geom, dirs[idx] * mid) >= 0.0:
                lo = mid
            else:
                hi = mid
        out[idx] = dirs[idx] * lo
    return out


def _plot_3d(geom: UruGeometry, path: np.ndarray, fname: Path) -> None:
    bnd = _boundary_points(geom)
    ext = _workspace_extent_m(geom)
    fig = plt.figure(figsize=(7.5, 7))
    ax = fig.add_subplot(111, projection="3d")
    ax.plot_surface(
        bnd[..., 0],
        bnd[..., 1],
        bnd[..., 2],
        color="tab:blue",
        alpha=0.15,
        linewidth=0.3,
        edgecolor="tab:blue",
    )
    s = np.linspace(-ext, ext, 2)
    a, b = np.meshgrid(s, s)
    zero = np.zeros_like(a)
    for xx, yy, zz in ((zero, a, b), (a, zero, b), (a, b, zero)):
        ax.plot_surface(xx, yy, zz, color="tab:red", alpha=0.12, linewidth=0)
    ax.plot(path[:, 0], path[:, 1], path[:, 2], color="k", lw=2, label="default path (1st octant)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_xlim(-ext, ext)
    ax.set_ylim(-ext, ext)
    ax.set_zlim(-ext, ext)
    ax.set_box_aspect((1, 1, 1))
    ax.set_title(
        "3-URU reachable workspace (blue, seed 003 eq. (29))\n"
        "rotation-singularity planes x=0, y=0, z=0 (red, eq. (17))\n" + _geometry_label(geom),
        fontsize=9,
    )
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(fname, dpi=110)
    plt.close(fig)


def _section(
    ax: Axes,
    u: np.ndarray,
    w: np.ndarray,
    fields: dict[str, np.ndarray],
    key: str,
    vlim: float,
    title: str,
    axis_lines: list[tuple[str, np.ndarray, np.ndarray]],
    path_uv: np.ndarray | None,
) -> QuadMesh:
    """One section panel: colour map of ``fields[key]`` inside the workspace plus the loci."""
    inside = fields["workspace_margin_m"] >= 0.0
    val = np.where(inside, fields[key], np.nan)
    mesh = ax.pcolormesh(u, w, np.clip(val, -vlim, vlim), cmap="RdBu", vmin=-vlim, vmax=vlim, shading="auto")
    ax.contour(u, w, fields["workspace_margin_m"], levels=[0.0], colors="k", linewidths=1.2)
    # Wide green under the thin red coordinate-plane lines: parts of the det V = 0 surface lie on
    # the coordinate planes (mixed-sign octants) and would otherwise be hidden.
    styles = (
        ("translation_det_v", "tab:green", "-", 3.5),
        ("actuation_det_s", "tab:purple", "--", 1.6),
        ("combined_det_a", "tab:orange", ":", 1.6),
    )
    for fkey, col, ls, lw in styles:
        data = np.where(inside, fields[fkey], np.nan)
        if fkey == "actuation_det_s":
            # det S = det A / det V has poles on det V = 0, where it jumps through infinity:
            # mask them so that contour() does not draw a false det S = 0 line there.
            data = np.where(np.abs(data) < _DET_S_POLE_MASK, data, np.nan)
        if np.nanmin(data) < 0.0 < np.nanmax(data):
            ax.contour(u, w, data, levels=[0.0], colors=col, linestyles=ls, linewidths=lw)
    for _name, xs, ys in axis_lines:
        ax.plot(xs, ys, color="tab:red", lw=1.0)
    if path_uv is not None and len(path_uv):
        ax.plot(path_uv[:, 0], path_uv[:, 1], "k.", ms=2)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    return mesh


def _legend_handles() -> list[Line2D]:
    from matplotlib.lines import Line2D

    return [
        Line2D([], [], color="k", lw=1.2, label="workspace boundary eq. (29) = serial eq. (28)"),
        Line2D([], [], color="tab:red", lw=1.0, label="rotation sing. (coordinate planes) eq. (17)"),
        Line2D([], [], color="tab:green", lw=3.5, label="translation sing. det V = 0 eq. (20)"),
        Line2D([], [], color="tab:purple", ls="--", lw=1.6, label="actuation sing. det S = 0 eq. (35)"),
        Line2D([], [], color="tab:orange", ls=":", lw=1.6, label="combined det A = 0 eq. (36)"),
        Line2D([], [], color="k", marker=".", ls="", label="default path (near the section)"),
    ]


def _plot_z_sections(
    geom: UruGeometry, path: np.ndarray, fname: Path, z_levels_m: tuple[float, ...], n: int
) -> None:
    ext = _workspace_extent_m(geom)
    s = np.linspace(-ext, ext, n)
    xg, yg = np.meshgrid(s, s)
    fig, axes = plt.subplots(2, len(z_levels_m), figsize=(4.2 * len(z_levels_m), 8.6))
    meshes = []
    for col, zc in enumerate(z_levels_m):
        pts = np.stack([xg, yg, np.full_like(xg, zc)], axis=-1)
        fields = singularity_fields(geom, pts)
        near = path[np.abs(path[:, 2] - zc) < 0.01][:, :2]
        lines = [("x=0", np.zeros(2), np.array([-ext, ext])), ("y=0", np.array([-ext, ext]), np.zeros(2))]
        for row, (key, vlim, label) in enumerate(
            (("translation_det_v", 1.0, "det V (eq. (20))"), ("actuation_det_s", 5.0, "det S (eq. (35))"))
        ):
            ax = axes[row, col]
            meshes.append(
                (row, _section(ax, xg, yg, fields, key, vlim, f"z = {zc:.3f} m: colour {label}", lines, near))
            )
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
    fig.subplots_adjust(bottom=0.12, top=0.92, left=0.06, right=0.88, wspace=0.3, hspace=0.3)
    for row in range(2):
        mesh = next(m for r, m in meshes if r == row)
        box = axes[row, -1].get_position()
        cax = fig.add_axes((0.9, box.y0, 0.015, box.height))
        fig.colorbar(mesh, cax=cax, label=("det V", "det S (clipped to +-5)")[row])
    fig.legend(handles=_legend_handles(), loc="lower center", ncol=3, fontsize=8)
    fig.suptitle("3-URU sections z = const (cf. seed 003 Fig. 5-7)\n" + _geometry_label(geom), fontsize=10)
    fig.savefig(fname, dpi=110)
    plt.close(fig)


def _plot_diagonal(geom: UruGeometry, path: np.ndarray, fname: Path, n: int) -> None:
    ext = _workspace_extent_m(geom)
    s = np.linspace(-ext, ext, n)
    tg, zg = np.meshgrid(s, s)  # t: coordinate along (1, 1, 0)/sqrt(2)
    pts = np.stack([tg / math.sqrt(2.0), tg / math.sqrt(2.0), zg], axis=-1)
    fields = singularity_fields(geom, pts)
    t_path = (path[:, 0] + path[:, 1]) / math.sqrt(2.0)
    near = np.stack([t_path, path[:, 2]], axis=1)[np.abs(path[:, 0] - path[:, 1]) < 0.01]
    lines = [("x=y=0", np.zeros(2), np.array([-ext, ext])), ("z=0", np.array([-ext, ext]), np.zeros(2))]
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 5.6))
    for ax, (key, vlim, label) in zip(
        axes,
        (("translation_det_v", 1.0, "det V (eq. (20))"), ("actuation_det_s", 5.0, "det S (eq. (35))")),
        strict=True,
    ):
        mesh = _section(ax, tg, zg, fields, key, vlim, f"plane x = y: colour {label}", lines, near)
        ax.set_xlabel("(x + y)/sqrt(2) [m]")
        ax.set_ylabel("z [m]")
        fig.colorbar(mesh, ax=ax, shrink=0.8)
    fig.legend(handles=_legend_handles(), loc="lower center", ncol=3, fontsize=8)
    fig.suptitle(
        "3-URU section x = y (the z axis x = y = 0 is a double rotation singularity)\n"
        + _geometry_label(geom),
        fontsize=10,
    )
    fig.subplots_adjust(bottom=0.2, top=0.9)
    fig.savefig(fname, dpi=110)
    plt.close(fig)


def plot_workspace_and_singularities(
    geometry: UruGeometry,
    out_dir: str | Path,
    z_levels_m: tuple[float, ...] = (0.05, 0.12, 0.25),
    grid_points: int = 241,
) -> list[Path]:
    """Write the workspace / singularity PNGs for ``geometry`` into ``out_dir``; return their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = default_path(np.linspace(0.0, 1.0, 400))
    files = [out / "uru_workspace_3d.png", out / "uru_sections_z.png", out / "uru_section_diagonal.png"]
    _plot_3d(geometry, path, files[0])
    _plot_z_sections(geometry, path, files[1], z_levels_m, grid_points)
    _plot_diagonal(geometry, path, files[2], grid_points)
    return files


def analyze_uru(cfg: Config, out_dir: Path) -> dict[str, object]:
    from controller.robots.uru import kinematics as uru
    from controller.robots.uru.analysis import plot_workspace_and_singularities
    from controller.robots.uru.entry import build_uru
    from controller.robots.uru.model import UruWorkspaceError

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
