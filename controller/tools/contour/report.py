"""What the contour-tracking experiment shows (seed 001 §7, Fig. 8-9): per-lap figures and plots.

``ContourObserver`` collects, while the tool tracks the contour, the normal force, its error,
the commanded tangential speed, the measured TCP and the estimated normal. The summary gives
per lap the commanded and achieved tangential speed, the normal-force error (RMS, max) and
the contact losses, and over the constant-speed laps (IV and V) the correlation between the force error
and the robot's stiffness along the contour normal, k_n = k n^T J^T J n (seed 001 §6): the
paper reports a worse force error where the normal lies along the minor axis of the
stiffness ellipsoid, i.e. a negative correlation.

The same observer measures a position-controlled run (the comparison): there the normal
force is the in-plane magnitude of the measured force and the lap is the angle swept
around the nominal centre.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
from controller.core.ports import CompliantStructure, CycleTiming, LumpedMasses
from controller.robots.performance import mass_ellipsoid, stiffness_ellipsoid
from controller.tasks.contour_tracking import ContourPhase, ContourState

CORNER_RADIUS_M = 0.02  # samples where the contour's measured radius of curvature is below this are "corners"


@dataclass
class ContourObserver:
    """Samples of the tracking phase (or, for a position-controlled run, of the whole path)."""

    force_setpoint_n: float
    centre_m: tuple[float, float]
    laps: int
    # the simulator's true contact force [N] as it was at a time on the loop's clock, given the time
    # the cycle's step ended (the in-process plant's, or the simulator process's through
    # sim_backend/true_force_tap.py); None: a real robot, where only the measurement is known
    true_force: Callable[[float], Sequence[float]] | None = None
    t: list[float] = field(default_factory=list)
    lap: list[int] = field(default_factory=list)
    fn: list[float] = field(default_factory=list)
    speed_cmd: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    normal: list[tuple[float, float]] = field(default_factory=list)
    contact_losses: tuple[int, ...] = ()
    corner: list[bool] = field(
        default_factory=list
    )  # the measured normal turning on a radius under CORNER_RADIUS_M
    true_fn: list[float] = field(default_factory=list)  # the true contact force along the normal [N]
    max_true_force_n: float = 0.0  # the largest true contact force of the whole run [N]
    _swept: float = 0.0
    _last_angle: float | None = None
    _truth: Sequence[float] | None = None

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        ts = state.task_state
        tcp = state.tcp_measured_m
        self._truth = self.true_force(timing.stepped_s) if self.true_force is not None else None
        if self._truth is not None:
            f = self._truth
            self.max_true_force_n = max(
                self.max_true_force_n, math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            )
        if tcp is None or state.mode != Mode.RUNNING:
            return
        if isinstance(ts, ContourState):
            self.contact_losses = ts.contact_losses
            if ts.phase != ContourPhase.TRACKING:
                return
            self._append(t, ts.lap, ts.normal_force_n, ts.speed_m_s, tcp, ts.normal)
            self.corner.append(abs(ts.normal_rate_rad_s) * CORNER_RADIUS_M > max(ts.speed_m_s, 1e-3))
            return
        if state.tcp_reference_m is None or inputs.sensor is None:
            return  # a position-controlled comparison run, off its path
        f = inputs.sensor.force_n
        angle = math.atan2(tcp[1] - self.centre_m[1], tcp[0] - self.centre_m[0])
        if self._last_angle is not None:
            self._swept += (angle - self._last_angle + math.pi) % (2 * math.pi) - math.pi
        self._last_angle = angle
        lap = min(int(abs(self._swept) // (2 * math.pi)), self.laps - 1)
        n = (math.cos(angle), math.sin(angle))
        self._append(t, lap, math.hypot(f[0], f[1]), float("nan"), tcp, n)  # no commanded tangential speed

    def _append(
        self,
        t: float,
        lap: int,
        fn: float,
        speed: float,
        tcp: tuple[float, float, float],
        normal: tuple[float, float],
    ) -> None:
        self.t.append(t)
        self.lap.append(lap)
        self.fn.append(fn)
        self.speed_cmd.append(speed)
        self.xy.append((tcp[0], tcp[1]))
        self.normal.append(normal)
        if self._truth is not None:
            self.true_fn.append(self._truth[0] * normal[0] + self._truth[1] * normal[1])


def _normal_stiffness(
    robot: CompliantStructure, stiffness_n_m: float, xy: np.ndarray, height_m: float, normals: np.ndarray
) -> np.ndarray:
    out = np.empty(len(xy))
    for i, ((x, y), (nx, ny)) in enumerate(zip(xy, normals, strict=True)):
        jac = robot.jacobian(np.array([x, y, height_m]))
        jn = jac @ np.array([nx, ny, 0.0])
        out[i] = stiffness_n_m * float(jn @ jn)
    return out


def _soft_over_stiff(err: np.ndarray, kn: np.ndarray) -> float | None:
    """RMS force error where k_n is below its median over the RMS where it is above.

    A second, blunter reading of the same relation: the angle-binned correlation mixes in
    whatever else varies around the contour (the cogging's phase, the carriages' speeds);
    the two halves average over it. Above 1: worse along the minor axis, as in the paper.
    """
    if kn.size < 10:
        return None
    soft = kn < np.median(kn)
    stiff_rms = float(np.sqrt(np.mean(err[~soft] ** 2)))
    if not soft.any() or stiff_rms == 0.0:
        return None
    return round(float(np.sqrt(np.mean(err[soft] ** 2))) / stiff_rms, 3)


def constant_speed_laps(lap_speeds_m_s: tuple[float, ...] | None, laps: int) -> list[int]:
    """The laps (0-based) run at the speed of the lap before: the paper's laps IV and V.

    A lap at a new speed starts with the change of speed (laps I-III), a transient that
    would otherwise land in the contour-angle bins where the laps start. Without lap speeds
    (the position-controlled comparison, one lap) every lap counts; when every lap changes
    speed, the last lap does.
    """
    if not lap_speeds_m_s:
        return list(range(laps))
    n = min(laps, len(lap_speeds_m_s))
    const = [k for k in range(1, n) if lap_speeds_m_s[k] == lap_speeds_m_s[k - 1]]
    return const or ([n - 1] if n > 0 else [])


@dataclass(frozen=True)
class DirectionStatistics:
    """The force error against the stiffness along the normal, over the constant-speed laps."""

    error_n: np.ndarray  # per sample
    normal_stiffness_n_m: np.ndarray  # per sample, k n^T J^T J n
    bin_angle_deg: np.ndarray  # centres of the 10 deg bins of contour angle
    bin_error_rms_n: np.ndarray
    bin_stiffness_n_m: np.ndarray
    correlation: float | None


def direction_statistics(
    obs: ContourObserver,
    robot: CompliantStructure,
    stiffness_n_m: float,
    height_m: float,
    lap_speeds_m_s: tuple[float, ...] | None,
) -> DirectionStatistics:
    lap = np.array(obs.lap)
    xy = np.array(obs.xy)
    m = np.isin(lap, constant_speed_laps(lap_speeds_m_s, obs.laps))
    err = (obs.force_setpoint_n - np.array(obs.fn))[m]
    kn = _normal_stiffness(robot, stiffness_n_m, xy[m], height_m, np.array(obs.normal)[m])
    angle = np.degrees(np.arctan2(xy[m, 1] - obs.centre_m[1], xy[m, 0] - obs.centre_m[0]))
    bins = np.floor((angle + 180.0) / 10.0).astype(int)
    centres, bin_err, bin_k = [], [], []
    for b in np.unique(bins):
        sel = bins == b
        if np.count_nonzero(sel) >= 5:
            centres.append(-175.0 + 10.0 * b)
            bin_err.append(float(np.sqrt(np.mean(err[sel] ** 2))))
            bin_k.append(float(np.mean(kn[sel])))
    corr = float(np.corrcoef(bin_k, bin_err)[0, 1]) if len(bin_k) > 3 else None
    return DirectionStatistics(err, kn, np.array(centres), np.array(bin_err), np.array(bin_k), corr)


def contour_summary(
    obs: ContourObserver,
    robot: CompliantStructure,
    stiffness_n_m: float,
    height_m: float,
    lap_speeds_m_s: tuple[float, ...] | None,
) -> dict[str, object]:
    if not obs.t:  # faulted before tracking: what the part felt still counts (44dbcbc left it out)
        return {
            "samples": 0,
            **(
                {"max_true_contact_force_n": round(obs.max_true_force_n, 2)}
                if obs.true_force is not None
                else {}
            ),
            "laps": [],
            "force_error_vs_normal_stiffness_correlation": None,
            "force_error_rms_soft_over_stiff": None,
            "normal_stiffness_range_n_m": None,
        }
    t = np.array(obs.t)
    lap = np.array(obs.lap)
    err = obs.force_setpoint_n - np.array(obs.fn)
    xy = np.array(obs.xy)
    # the simulator's own: what the measurement's errors (a sensor offset, a spike) hide
    true_err = obs.force_setpoint_n - np.array(obs.true_fn) if len(obs.true_fn) == t.size else None
    laps = []
    for k in range(obs.laps):
        m = lap == k
        if np.count_nonzero(m) < 3:
            continue
        dist = np.sum(np.hypot(*np.diff(xy[m], axis=0).T))
        dur = t[m][-1] - t[m][0]
        laps.append(
            {
                "lap": k + 1,
                "speed_commanded_m_s": lap_speeds_m_s[k] if lap_speeds_m_s else None,
                "speed_achieved_m_s": round(float(dist / dur), 5) if dur > 0 else None,
                "force_error_rms_n": round(float(np.sqrt(np.mean(err[m] ** 2))), 4),
                "force_error_max_n": round(float(np.abs(err[m]).max()), 4),
                **(
                    {
                        "true_force_error_rms_n": round(float(np.sqrt(np.mean(true_err[m] ** 2))), 4),
                        "true_force_error_max_n": round(float(np.abs(true_err[m]).max()), 4),
                    }
                    if true_err is not None
                    else {}
                ),
                "contact_losses": int(obs.contact_losses[k])
                if k < len(obs.contact_losses)
                else int(np.count_nonzero(np.diff((np.array(obs.fn)[m] < 0.5).astype(int)) == 1)),
            }
        )
    d = direction_statistics(obs, robot, stiffness_n_m, height_m, lap_speeds_m_s)
    corr = d.correlation
    corner = np.array(obs.corner, dtype=bool) if len(obs.corner) == t.size else np.zeros(t.size, dtype=bool)
    return {
        "samples": int(t.size),
        **(
            {"max_true_contact_force_n": round(obs.max_true_force_n, 2)} if obs.true_force is not None else {}
        ),
        "laps": laps,
        "force_error_rms_n": round(float(np.sqrt(np.mean(err**2))), 4),
        "corners": {
            "samples": int(corner.sum()),
            "force_error_rms_n": round(float(np.sqrt(np.mean(err[corner] ** 2))), 4)
            if corner.any()
            else None,
            "force_error_rms_elsewhere_n": round(float(np.sqrt(np.mean(err[~corner] ** 2))), 4)
            if (~corner).any()
            else None,
        },
        "force_error_vs_normal_stiffness_correlation": None if corr is None else round(corr, 3),
        "force_error_rms_soft_over_stiff": _soft_over_stiff(d.error_n, d.normal_stiffness_n_m),
        "normal_stiffness_range_n_m": [
            round(float(d.normal_stiffness_n_m.min()), 0),
            round(float(d.normal_stiffness_n_m.max()), 0),
        ]
        if d.normal_stiffness_n_m.size
        else None,
    }


def plot_contour(
    obs: ContourObserver,
    robot: CompliantStructure,
    stiffness_n_m: float,
    masses: LumpedMasses,
    height_m: float,
    out: Path,
    title: str = "force control",
    lap_speeds_m_s: tuple[float, ...] | None = None,
) -> list[Path]:
    """Fig. 9: force and speed against time with the laps; Fig. 8: the contour and the error.

    The Fig. 8 panel shows the constant-speed laps (``constant_speed_laps``), with the colour
    scale clipped at their 99th percentile so that a single spike does not wash the map out,
    and beside it the error and the stiffness along the normal per 10 deg of contour angle.
    """
    if len(obs.t) < 3:
        return []  # nothing was tracked (the run faulted before contact): no plot to draw
    out.mkdir(parents=True, exist_ok=True)
    t = np.array(obs.t)
    fn = np.array(obs.fn)
    xy = np.array(obs.xy)
    lap = np.array(obs.lap)
    speed = np.r_[np.nan, np.hypot(*np.diff(xy, axis=0).T) / np.maximum(np.diff(t), 1e-9)]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    a1.plot(t, fn, lw=0.7, label="normal force")
    a1.axhline(obs.force_setpoint_n, color="k", ls="--", lw=0.8, label="setpoint")
    a1.set_ylabel("force [N]")
    a1.legend(loc="upper right", fontsize=8)
    k = max(1, int(0.02 / max(np.median(np.diff(t)), 1e-6))) if t.size > 2 else 1
    a2.plot(
        t, np.convolve(np.nan_to_num(speed), np.ones(k) / k, mode="same") * 1000, lw=0.8, label="achieved"
    )
    cmd = np.array(obs.speed_cmd) * 1000
    if np.isfinite(cmd).any():
        a2.plot(t, cmd, lw=0.8, ls="--", label="commanded")
    a2.set_ylabel("tangential speed [mm/s]")
    a2.set_xlabel("time [s]")
    a2.legend(loc="lower right", fontsize=8)
    bounds = np.r_[0, np.flatnonzero(np.diff(lap)) + 1, t.size - 1]
    for ax in (a1, a2):
        for b in bounds[1:-1]:
            ax.axvline(t[b], color="grey", lw=0.6)
    for lo, hi in itertools.pairwise(bounds):  # each lap named between its grey boundaries
        if lap[lo] >= 0 and hi > lo:
            a1.text(
                (t[lo] + t[hi]) / 2,
                1.0,
                f"lap {int(lap[lo]) + 1}",
                transform=a1.get_xaxis_transform(),
                ha="center",
                va="bottom",
                fontsize=8,
                color="grey",
            )
    a1.set_title(f"Contour tracking ({title}): force and speed, laps marked (cf. seed 001 Fig. 9)", pad=16)
    fig.tight_layout()
    p1 = out / f"contour_force_speed_{title.replace(' ', '_')}.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    fig, (ax, ab) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.1, 1.0]})
    shown = constant_speed_laps(lap_speeds_m_s, obs.laps)
    d = direction_statistics(obs, robot, stiffness_n_m, height_m, lap_speeds_m_s)  # over the same laps
    const = np.isin(lap, shown)
    err = np.abs(d.error_n)
    sc = ax.scatter(
        xy[const, 0] * 1000,
        xy[const, 1] * 1000,
        c=err,
        s=3,
        cmap="inferno_r",
        vmin=0.0,
        vmax=float(np.percentile(err, 99)) if err.size else None,
    )
    laps_shown = ", ".join(str(k + 1) for k in shown)
    fig.colorbar(sc, ax=ax, label=f"|normal-force error| [N], laps {laps_shown} (99th percentile clipped)")
    # stiffness and mass ellipses (XY sections) at 8 points of the contour
    c = np.array(obs.centre_m)
    r = float(np.median(np.hypot(*(xy - c).T))) if xy.size else 0.07
    for th in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        p = np.array([c[0] + r * np.cos(th), c[1] + r * np.sin(th), height_m])
        jac = robot.jacobian(p)
        for ell, colour, scale in (
            (stiffness_ellipsoid(jac, stiffness_n_m), "tab:blue", 12.0),
            (mass_ellipsoid(jac, masses), "tab:green", 12.0),
        ):
            dirs = np.linspace(0, 2 * np.pi, 60)
            reach = np.array([ell.reach(np.array([np.cos(d), np.sin(d), 0.0])) for d in dirs])
            reach = reach / reach.max() * scale
            ax.plot(
                (p[0] + 0.0) * 1000 + reach * np.cos(dirs) + 28 * np.cos(th),
                p[1] * 1000 + reach * np.sin(dirs) + 28 * np.sin(th),
                color=colour,
                lw=1,
            )
    ax.plot([], [], color="tab:blue", label="stiffness {K d : |d| <= 1}\n(XY section, shape only)")
    ax.plot([], [], color="tab:green", label="mass {M a : |a| <= 1}\n(XY section, shape only)")
    ax.legend(loc="center", fontsize=8)  # inside the contour, where nothing is drawn
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(
        f"Contour ({title}) and force error, with stiffness and mass ellipses (cf. Fig. 8)", fontsize=9
    )
    ab.plot(
        d.bin_angle_deg, d.bin_error_rms_n, "o-", color="tab:red", ms=3, label="force error RMS per 10 deg"
    )
    ab.set_xlabel("contour angle around the centre [deg]")
    ab.set_ylabel("normal-force error RMS [N]", color="tab:red")
    ab.set_xlim(-180, 180)
    ak = ab.twinx()
    ak.plot(
        d.bin_angle_deg,
        d.bin_stiffness_n_m / 1e6,
        "s--",
        color="tab:blue",
        ms=3,
        label="directional stiffness n^T K n, K = k J^T J",
    )
    ak.set_ylabel("directional stiffness along the normal n^T K n [N/µm]", color="tab:blue")
    handles = ab.get_legend_handles_labels()[0] + ak.get_legend_handles_labels()[0]
    ab.legend(handles, [str(h.get_label()) for h in handles], loc="upper right", fontsize=8)
    ratio = _soft_over_stiff(d.error_n, d.normal_stiffness_n_m)
    corr = "n/a" if d.correlation is None else f"{d.correlation:+.2f}"
    ab.set_title(
        f"error and directional stiffness along the normal, per 10 deg\n"
        f"correlation {corr}, RMS soft half / stiff half {ratio}",
        fontsize=9,
    )
    fig.tight_layout()
    p2 = out / f"contour_error_map_{title.replace(' ', '_')}.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    return [p1, p2]
