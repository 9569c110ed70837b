"""Plots for the 3-nSPU robot: planned motions (seed 004 Fig. 2-3) and singularity loci (seed 000 Fig. 7-8).

matplotlib with the Agg backend; every function writes PNG files into `out_dir` and returns their paths.
Lengths are drawn in the geometry's paper unit (aul; `geometry.length_unit_m` metres each) so the
figures compare with the papers'.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from controller.planning.nonholonomic import PlanResult, type2_measure
from controller.robots.nspu import NspuGeometry, controllability_det, euler_xzx


def plot_plan(result: PlanResult, out_dir: str | Path, prefix: str = "nspu_plan") -> list[Path]:
    """Write controls v(t), leg lengths l(t), and relative position/orientation trajectories (PNG)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    unit = result.geometry.length_unit_m
    t = result.t_s
    labels = ("1", "2", "3")
    paths: list[Path] = []

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))  # seed 004 Fig. 2
    for i in range(3):
        axes[0].plot(t, result.v_rad_s[:, i], label=f"v{labels[i]}")
        axes[1].plot(t, result.legs_m[:, i] / unit, label=f"l{labels[i]}")
    axes[0].set(xlabel="t [s]", ylabel="v [rad/s]", title="controls v(t)")
    axes[1].set(xlabel="t [s]", ylabel="leg length [aul]", title=f"leg lengths l(t) (1 aul = {unit} m)")
    for ax in axes:
        ax.grid(True)
        ax.legend()
    fig.suptitle(f"{result.status.value}: {result.iterations} iterations, E = {result.final_error:.2e}")
    fig.tight_layout()
    paths.append(out / f"{prefix}_controls_legs.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))  # seed 004 Fig. 3
    ep = result.position_error_m / unit
    rr = result.rotation_error
    for i, c in enumerate("xyz"):
        axes[0].plot(t, ep[:, i], label=f"e_p{c}")
        axes[1].plot(t, rr[:, i], label=f"r{c}")
    axes[0].set(xlabel="t [s]", ylabel="p(t) - p_d [aul]", title="relative position e_p(t)")
    axes[1].set(xlabel="t [s]", ylabel="[rad]", title="relative orientation r(t) = log(R R_d^T)")
    for ax in axes:
        ax.grid(True)
        ax.legend()
    fig.tight_layout()
    paths.append(out / f"{prefix}_relative_pose.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for i in range(3):
        axes[0].plot(t, result.leg_rates_m_s[:, i] / unit, label=f"u{labels[i]}")
    axes[0].set(xlabel="t [s]", ylabel="leg rate [aul/s]", title="leg-length rates u(t), seed 004 eq. (6)")
    axes[1].plot(t, result.type2_measure, label="normalised det M (eq. 26)")
    axes[1].plot(t, result.det_s, label="det S (eq. 27)")
    axes[1].axhline(0.0, color="k", lw=0.8)
    axes[1].set(xlabel="t [s]", title="singularity measures along the plan")
    for ax in axes:
        ax.grid(True)
        ax.legend()
    fig.tight_layout()
    paths.append(out / f"{prefix}_rates_singularity.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def _grid_values(
    geometry: NspuGeometry, eta: np.ndarray, xs: np.ndarray, ys: np.ndarray, z: float, which: str
) -> np.ndarray:
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    p = np.stack([X, Y, np.full_like(X, z)], axis=-1)
    with np.errstate(all="ignore"):
        if which == "type2":
            R = np.broadcast_to(euler_xzx(eta), X.shape + (3, 3))
            return type2_measure(geometry, p, R)
        x = np.concatenate([p, np.broadcast_to(eta, X.shape + (3,))], axis=-1)
        det_l = controllability_det(geometry, x)
        # L's columns have poles on det M = 0 (v_i = adj(M)/det M), where det L changes sign
        # without vanishing: mask a band around the type-II locus so only true zeros are drawn.
        R = np.broadcast_to(euler_xzx(eta), X.shape + (3, 3))
        return np.where(np.abs(type2_measure(geometry, p, R)) < 0.02, np.nan, det_l)


def plot_singularity_loci(
    geometry: NspuGeometry,
    out_dir: str | Path,
    euler_xzx_rad: tuple[float, float, float] = (0.0, 1.0, 0.0),
    xy_half_range_aul: float = 60.0,
    z_range_aul: tuple[float, float] = (5.0, 65.0),
    n_xy: int = 81,
    n_z: int = 7,
) -> list[Path]:
    """Zero loci of det M (seed 000 eq. (26), Fig. 7) and det L (eq. (35), Fig. 8) for a fixed orientation.

    The 3-D surfaces are drawn as their zero-level contours on n_z horizontal slices (3-D view)
    and the same contours seen from above (top view), coloured by height.  For det L a band
    |normalised det M| < 0.02 is masked: L has poles on the type-II locus, where det L changes
    sign without vanishing.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    unit = geometry.length_unit_m
    eta = np.asarray(euler_xzx_rad, dtype=float)
    xs = np.linspace(-xy_half_range_aul, xy_half_range_aul, n_xy) * unit
    zs = np.linspace(z_range_aul[0], z_range_aul[1], n_z) * unit
    paths: list[Path] = []
    cmap = plt.get_cmap("viridis")
    for which, title, fname in (
        ("type2", "type-II singularity locus det M = 0 (seed 000 eq. 26)", "nspu_singularity_locus.png"),
        ("ctrl", "controllability locus det L = 0 (seed 000 eq. 35)", "nspu_controllability_locus.png"),
    ):
        fig = plt.figure(figsize=(12, 5.5))
        ax3 = fig.add_subplot(1, 2, 1, projection="3d")
        ax2 = fig.add_subplot(1, 2, 2)
        for k, z in enumerate(zs):
            vals = _grid_values(geometry, eta, xs, xs, float(z), which)
            color = cmap(k / max(1, n_z - 1))
            fig_tmp, ax_tmp = plt.subplots()
            cs = ax_tmp.contour(xs / unit, xs / unit, np.ma.masked_invalid(vals), levels=[0.0])
            segs = cs.allsegs[0]
            plt.close(fig_tmp)
            for seg in segs:
                if len(seg) < 2:
                    continue
                ax3.plot(seg[:, 0], seg[:, 1], np.full(len(seg), z / unit), color=color, lw=1.2)
                ax2.plot(seg[:, 0], seg[:, 1], color=color, lw=1.2)
            ax2.plot([], [], color=color, label=f"z = {z / unit:.0f}")
        a = geometry.a_m / unit
        tri = np.vstack([a, a[:1]])
        ax2.plot(tri[:, 0], tri[:, 1], "k--", lw=0.8, label="frame triangle A_i")
        ax3.plot(tri[:, 0], tri[:, 1], 0 * tri[:, 0], "k--", lw=0.8)
        ax3.set(xlabel="x [aul]", ylabel="y [aul]", zlabel="z [aul]", title="3D view (zero contours per slice)")
        ax2.set(xlabel="x [aul]", ylabel="y [aul]", title="top view")
        ax2.set_aspect("equal")
        ax2.legend(fontsize=7, loc="upper right")
        fig.suptitle(f"{title}, XZX Euler angles {tuple(float(e) for e in eta)} rad")
        fig.tight_layout()
        paths.append(out / fname)
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths
