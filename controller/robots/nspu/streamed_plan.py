"""A converged motion plan of the 3-nSPU streamed as leg references: resampled and time-scaled.

``time_scale_plan`` turns a plan of seed 004 (controls over a unit horizon) into leg positions,
velocities and accelerations on a uniform grid of task time, slowed to a fraction of the
actuators' limits (see ``controller/robots/nspu/planned_legs.py`` for how the task plays it); both the
planned-legs task and its correction planner use it, so it lives apart from both.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from controller.robots.nspu.kinematics import leg_lengths_batch
from controller.robots.nspu.planning.nonholonomic import PlanResult, controls, feedback_leg_rates, rollout

# A sample of the streamed plan: leg positions, velocities, accelerations, planned platform position.
LegsSample = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, float, float]]


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s(x) = 10x^3 - 15x^4 + 6x^5 and s'(x) (quintic, zero slope and curvature at 0 and 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10.0 - 15.0 * x + 6.0 * x * x), 30.0 * x * x * (1.0 - x) ** 2


def _hermite(t: np.ndarray, y: np.ndarray, dy: np.ndarray, tq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite interpolant of samples (t, y, dy) [(N,), (N, 3), (N, 3)] and its derivative at tq."""
    k = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, t.size - 2)
    h = (t[k + 1] - t[k])[:, None]
    s = ((tq - t[k])[:, None]) / h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    val = h00 * y[k] + h10 * h * dy[k] + h01 * y[k + 1] + h11 * h * dy[k + 1]
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    der = (d00 * y[k] + d01 * y[k + 1]) / h + d10 * dy[k] + d11 * dy[k + 1]
    return val, der


@dataclass(frozen=True, eq=False)
class StreamedPlan:
    """Time-scaled leg references on a uniform grid of task time [0, duration_s]."""

    t_s: np.ndarray  # (N,)
    legs_m: np.ndarray  # (N, 3)
    rates_m_s: np.ndarray  # (N, 3)
    accel_m_s2: np.ndarray  # (N, 3)
    platform_m: np.ndarray  # (N, 3) planned platform position (for the reference TCP)
    duration_s: float
    scale: float  # D / T
    peaks: tuple[float, float, float]  # max |velocity|, |acceleration|, |jerk| of the legs at duration_s

    def sample(self, tau: float) -> LegsSample:
        """Leg positions, velocities, accelerations and the planned platform position at task time tau."""
        t = self.t_s
        tau = min(max(tau, 0.0), self.duration_s)
        k = min(int(tau / self.duration_s * (t.size - 1)), t.size - 2)
        h = t[k + 1] - t[k]
        s = (tau - t[k]) / h
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        y, dy = self.legs_m, self.rates_m_s
        pos = h00 * y[k] + h10 * h * dy[k] + h01 * y[k + 1] + h11 * h * dy[k + 1]
        vel = (1 - s) * dy[k] + s * dy[k + 1]
        acc = (1 - s) * self.accel_m_s2[k] + s * self.accel_m_s2[k + 1]
        plat = (1 - s) * self.platform_m[k] + s * self.platform_m[k + 1]
        return tuple(pos.tolist()), tuple(vel.tolist()), tuple(acc.tolist()), tuple(plat.tolist())


def time_scale_plan(
    plan: PlanResult,
    max_velocity: float,
    max_acceleration: float,
    max_jerk: float,
    limit_fraction: float = 0.5,
    stream_steps: int = 1000,
) -> StreamedPlan:
    """Resample a converged plan and time-scale it to ``limit_fraction`` of the actuators' limits (see module doc)."""
    plan.raise_for_status()
    if not 0.0 < limit_fraction <= 1.0:
        raise ValueError(f"limit_fraction must be in (0, 1], got {limit_fraction}")
    cfg = dataclasses.replace(plan.config, n_steps=stream_steps)
    horizon = cfg.horizon_s
    t, ps, rs = rollout(plan.geometry, plan.start, plan.lambdas, cfg)
    legs = leg_lengths_batch(plan.geometry, ps, rs)
    rates = feedback_leg_rates(
        plan.geometry, ps, rs, controls(plan.lambdas, t, horizon, cfg.harmonics)
    )  # eq. (6)
    tau = np.linspace(0.0, 1.0, stream_steps + 1)  # task time at D = T, in units of T

    def profile(duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x = tau  # tau / D on the uniform grid
        s, ds = _smoothstep(x)
        sig = horizon * s
        pos, der = _hermite(t, legs, rates, sig)
        vel = der * (horizon * ds / duration)[:, None]
        tq = tau * duration
        acc = np.gradient(vel, tq, axis=0, edge_order=2)
        jerk = np.gradient(acc, tq, axis=0, edge_order=2)
        plat = np.stack([np.interp(sig, t, ps[:, i]) for i in range(3)], axis=1)
        return pos, vel, acc, jerk, plat

    _, v1, a1, j1, _ = profile(horizon)
    pv, pa, pj = float(np.abs(v1).max()), float(np.abs(a1).max()), float(np.abs(j1).max())
    f = limit_fraction
    scale = max(
        pv / (f * max_velocity), math.sqrt(pa / (f * max_acceleration)), (pj / (f * max_jerk)) ** (1 / 3)
    )
    duration = horizon * scale
    pos, vel, acc, jerk, plat = profile(duration)
    acc[0] = acc[-1] = 0.0  # exact: s'' = 0 at both ends
    peaks = (float(np.abs(vel).max()), float(np.abs(acc).max()), float(np.abs(jerk).max()))
    return StreamedPlan(tau * duration, pos, vel, acc, plat, duration, scale, peaks)
