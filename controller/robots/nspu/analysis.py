"""Plots for the 3-nSPU robot: planned motions (seed 004 Fig. 2-3) and singularity loci (seed 000 Fig. 7-8).

matplotlib with the Agg backend; every function writes PNG files into `out_dir` and returns their paths.
Lengths are drawn in the geometry's paper unit (aul; `geometry.length_unit_m` metres each) so the
figures compare with the papers'.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import time
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from controller.config import Config
from controller.core.rotations import so3_log
from controller.robots.nspu.kinematics import NspuGeometry, controllability_det, euler_xzx
from controller.robots.nspu.planning.nonholonomic import PlanResult, type2_measure

if TYPE_CHECKING:
    from controller.robots.nspu.kinematics import Pose


def plot_plan(result: PlanResult, out_dir: str | Path, prefix: str = "nspu_plan") -> list[Path]:
    """Write the plan as PNG: pose against time, leg lengths and rates, the singularity distance along
    the motion, and the controls with the relative pose (seed 004 Fig. 2-3).  Any status: a failed
    plan's last iterate is drawn with its status in the titles, so the plots show why it failed."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = result.t_s
    cfg = result.config
    title = (
        f"{result.status.value}: {result.iterations} iterations, E = {result.final_error:.2e} "
        f"(plan time T = {cfg.horizon_s:g} s; streaming rescales time)"
    )
    paths: list[Path] = []

    def save(fig: Figure, name: str) -> None:
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        paths.append(out / f"{prefix}_{name}.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    rv = so3_log(result.R)
    goal_rv = so3_log(result.goal.R)
    for i, (c, col) in enumerate(zip("xyz", ("C0", "C1", "C2"), strict=True)):
        axes[0].plot(t, result.p_m[:, i] * 1e3, color=col, label=f"{c}")
        axes[0].axhline(result.goal.p_m[i] * 1e3, color=col, ls="--", lw=0.8)
        axes[1].plot(t, rv[:, i], color=col, label=f"r{c}")
        axes[1].axhline(goal_rv[i], color=col, ls="--", lw=0.8)
    axes[0].set(
        xlabel="plan time t [s]", ylabel="platform position [mm]", title="position p(t) (dashed: goal)"
    )
    axes[1].set(
        xlabel="plan time t [s]",
        ylabel="rotation vector [rad]",
        title="orientation r(t), [r] = log R(t) (dashed: goal)",
    )
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="best", fontsize=8)
    save(fig, "pose")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    g = result.geometry
    for i in range(3):
        axes[0].plot(t, result.legs_m[:, i] * 1e3, label=f"leg {i + 1}")
        axes[1].plot(t, result.leg_rates_m_s[:, i] * 1e3, label=f"leg {i + 1}")
    lo, hi = float(np.nanmin(result.legs_m)), float(np.nanmax(result.legs_m))
    for limit, name in ((g.leg_min_m, "stroke min"), (g.leg_max_m, "stroke max")):
        if lo - 0.02 <= limit <= hi + 0.02:  # draw a stroke limit only when it is near the motion
            axes[0].axhline(limit * 1e3, color="r", ls="--", lw=0.8, label=name)
    axes[0].set(xlabel="plan time t [s]", ylabel="leg length [mm]", title="leg lengths l(t)")
    axes[1].set(
        xlabel="plan time t [s]", ylabel="leg rate [mm/s]", title="leg rates u(t), seed 004 eq. (6), at T"
    )
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="best", fontsize=8)
    save(fig, "legs")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    tm = result.type2_measure
    sign = float(np.sign(tm[0])) if np.isfinite(tm[0]) and tm[0] != 0 else 1.0
    axes[0].plot(t, sign * tm, label="normalised det M x sign at start")
    axes[0].axhline(
        cfg.min_type2_measure, color="r", ls="--", lw=0.8, label=f"refusal limit {cfg.min_type2_measure:g}"
    )
    axes[0].axhline(
        cfg.avoidance_margin,
        color="orange",
        ls=":",
        lw=0.8,
        label=f"avoidance margin {cfg.avoidance_margin:g}",
    )
    axes[0].axhline(0.0, color="k", lw=0.8)
    axes[0].set(
        xlabel="plan time t [s]",
        ylabel="[-] (0: type-II singular)",
        title="distance from det M = 0 (seed 000 eq. 26)",
    )
    ds = result.det_s
    sgn_s = float(np.sign(ds[0])) if np.isfinite(ds[0]) and ds[0] != 0 else 1.0
    axes[1].plot(t, sgn_s * ds, label="det S x sign at start")
    axes[1].axhline(cfg.min_abs_det_s, color="r", ls="--", lw=0.8, label=f"limit {cfg.min_abs_det_s:g}")
    axes[1].axhline(0.0, color="k", lw=0.8)
    axes[1].set(
        xlabel="plan time t [s]",
        ylabel="[-] (0: system (7) singular)",
        title="det S along the motion (seed 000 eq. 27)",
    )
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="best", fontsize=8)
    save(fig, "singularity")

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))  # seed 004 Fig. 2 (controls) and Fig. 3 (relative pose)
    ep = result.position_error_m * 1e3
    rr = result.rotation_error
    for i in range(3):
        axes[0].plot(t, result.v_rad_s[:, i], label=f"v{i + 1}")
    for i, c in enumerate("xyz"):
        axes[1].plot(t, ep[:, i], label=f"e_p{c}")
        axes[2].plot(t, rr[:, i], label=f"r{c}")
    axes[0].set(xlabel="plan time t [s]", ylabel="v [rad/s]", title="controls v(t), seed 004 eq. (15)")
    axes[1].set(xlabel="plan time t [s]", ylabel="[mm]", title="relative position e_p = p - p_d")
    axes[2].set(xlabel="plan time t [s]", ylabel="[rad]", title="relative orientation [r] = log(R R_d^T)")
    for ax in axes:
        ax.grid(True)
        ax.legend(loc="best", fontsize=8)
    save(fig, "controls")
    return paths


def _grid_values(
    geometry: NspuGeometry, eta: np.ndarray, xs: np.ndarray, ys: np.ndarray, z: float, which: str
) -> np.ndarray:
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    p = np.stack([X, Y, np.full_like(X, z)], axis=-1)
    with np.errstate(all="ignore"):
        if which == "type2":
            R = np.broadcast_to(euler_xzx(eta), (*X.shape, 3, 3))
            return type2_measure(geometry, p, R)
        x = np.concatenate([p, np.broadcast_to(eta, (*X.shape, 3))], axis=-1)
        det_l = controllability_det(geometry, x)
        # L's columns have poles on det M = 0 (v_i = adj(M)/det M), where det L changes sign
        # without vanishing: mask a band around the type-II locus so only true zeros are drawn.
        R = np.broadcast_to(euler_xzx(eta), (*X.shape, 3, 3))
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
            ax2.plot([], [], color=color, label=f"z = {z / unit:.0f} aul")
        a = geometry.a_m / unit
        tri = np.vstack([a, a[:1]])
        ax2.plot(tri[:, 0], tri[:, 1], "k--", lw=0.8, label="frame triangle A_i")
        ax3.plot(tri[:, 0], tri[:, 1], 0 * tri[:, 0], "k--", lw=0.8)
        ax3.set(
            xlabel="x [aul]", ylabel="y [aul]", zlabel="z [aul]", title="3D view (zero contours per slice)"
        )
        ax2.set(xlabel="x [aul]", ylabel="y [aul]", title="top view")
        ax2.set_aspect("equal")
        ax2.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), title="slice height")
        fig.suptitle(
            f"{title}, XZX Euler angles {tuple(float(e) for e in eta)} rad; "
            f"lengths in the papers' unit, 1 aul = {unit:g} m"
        )
        fig.tight_layout()
        paths.append(out / fname)
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")  # the legend beside the top view stays in
        plt.close(fig)
    return paths


def plot_execution(recording: str | Path, out_dir: str | Path, name: str = "nspu_execution.png") -> Path:
    """The executed against the planned motion of a 3-nSPU run from its MCAP recording.

    Planned: the platform point P of the plan being streamed (the recorded ``tcp_reference_m``; each
    plan from a measured pose starts where the platform was measured). Executed: the pose tracker's
    samples (``inputs.tracker``, fresh ones only; needs ``tracker.enabled``). Position in mm, the
    rotation vector in mrad, against the run's time; the task's phase changes are marked.
    """
    from logs.reader import iter_decoded

    t_ref, ref, t_trk, pos, rot, t_phase, phases = [], [], [], [], [], [], []
    last_phase = ""
    for d in iter_decoded(recording, topics=("/cycle",)):
        c = d.message
        if len(c.state.tcp_reference_m) == 3:
            t_ref.append(c.t_s)
            ref.append(tuple(c.state.tcp_reference_m))
        if c.inputs.HasField("tracker") and c.inputs.tracker.fresh:
            t_trk.append(c.t_s)
            pos.append(tuple(c.inputs.tracker.position_m))
            rot.append(tuple(c.inputs.tracker.rotation_vector_rad))
        if c.state.task_phase != last_phase:
            last_phase = c.state.task_phase
            t_phase.append(c.t_s)
            phases.append(last_phase)
    if not t_trk:
        raise ValueError(f"{recording}: no pose tracker samples (run with --set tracker.enabled=true)")
    ref_mm, pos_mm, rot_mrad = np.array(ref) * 1e3, np.array(pos) * 1e3, np.array(rot) * 1e3
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for i, (ax, label) in enumerate(zip(axes.flat[:3], ("x", "y", "z"), strict=True)):
        ax.plot(t_trk, pos_mm[:, i], ".", ms=2, color="tab:orange", label="executed (tracker)")
        if len(ref):
            ax.plot(t_ref, ref_mm[:, i], ".", ms=1, color="tab:blue", label="planned (streamed plan)")
        ax.set_ylabel(f"P {label} [mm]")
    ax = axes.flat[3]
    for i, label in enumerate(("r_x", "r_y", "r_z")):
        ax.plot(t_trk, rot_mrad[:, i], ".", ms=2, label=f"{label} (tracker)")
    ax.set_ylabel("rotation vector [mrad]")
    for ax in axes.flat:
        for tp, _ph in zip(t_phase, phases, strict=True):
            ax.axvline(tp, color="0.8", lw=0.8)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("run time t [s]")
    fig.suptitle(
        "3-nSPU: executed against planned motion (phases: " + " -> ".join(dict.fromkeys(phases)) + ")",
        fontsize=10,
    )
    fig.tight_layout()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return out / name


if __name__ == "__main__":
    import sys

    print(plot_execution(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "."))


def analyze_nspu(
    cfg: Config, out_dir: Path, euler_xzx_rad: tuple[float, float, float] = (0.0, 1.0, 0.0)
) -> dict[str, object]:
    from controller.robots.nspu.analysis import plot_singularity_loci
    from controller.robots.nspu.entry import build_nspu
    from controller.robots.nspu.planning.nonholonomic import type2_measure

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
    from controller.core.rotations import so3_log
    from controller.robots.nspu.entry import nspu_geometry
    from controller.robots.nspu.planned_legs import planner_config
    from controller.robots.nspu.planning.nonholonomic import plan_motion

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
        from controller.robots.nspu.analysis import plot_plan

        out["plots"] = [str(p) for p in plot_plan(res, plot_dir)]
    return out
