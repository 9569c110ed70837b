"""Non-holonomic motion planner for the 3-nSPU robot (seed 004, Tchon, Jakubiak, Grosch, Thomas).

Pipeline (seed 004 section 3-4):
* driftless system: u = l_dot, (p_dot, omega) = [[G, K], [S, J]]^-1 (u, 0)       seed 004 eq. (3)-(4)
* feedback u = G S^-1 (J - S G^-1 K) v = (G S^-1 J - K) v                          seed 004 eq. (6)
  turns it into  p_dot = S^-1 J v,  R_dot = -[v] R  (omega = -v)                   seed 004 eq. (7)
  Derivation: with omega = -v the constraint rows S p_dot + J omega = 0 give p_dot = S^-1 J v, and
  the actuator rows give u = G p_dot + K omega = (G S^-1 J - K) v.  Only S must be invertible for
  (6)-(7); G invertibility is only used for eq. (5).
* controls v = P(t) Lambda, truncated Fourier series with h harmonics            seed 004 eq. (15)
* error e = (p_T - p_d, log(R_T R_d^T))                                           seed 004 eq. (8), (13)
  (the printed "log(R_T) R_d^T" of eq. (8) is garbled; eq. (13) has log(R_T R_d^T), used here)
* Jacobian-inverse iteration Lambda <- Lambda - gamma J^# e                      seed 004 eq. (16)-(17)

Implementation choices (documented deviations / interpretations):
* The Jacobian of the end-point map d e / d Lambda comes from the variational equations of
  seed 004 eq. (10)-(12), integrated with the motion in one pass (`controller.robots.nspu.planning.endpoint_map`):
  d p_T / d Lambda and the spatial rotation sensitivity, then d e / d Lambda through
  (1/scale, J_l^-1(r_T)) with J_l^-1 the inverse left Jacobian of the rotation log.
* Integration: fixed-step Runge-Kutta-Munthe-Kaas of order 4 on R^3 x SO(3) (R stays on SO(3)),
  `plan_steps` steps (default 32) while iterating.  Error control: a converged plan is integrated
  again with `n_steps` (default 100) steps; if the two end points differ by more than
  `integration_tolerance` x tolerance, or the fine end error is not below the tolerance, the
  iteration goes on with twice the steps (up to n_steps).  The reported `verified_error` is
  the fine integration's; CONVERGED means it is below the tolerance.
* gamma is not printed in seed 004.  `PlannerConfig.gamma` (default 1, i.e. Newton) with an optional
  backtracking safeguard (`line_search`): a step is accepted only if the error decreases,
  otherwise gamma is halved.  With line_search=False the iteration is exactly eq. (17).
* Error norm: E = sqrt(|(p_T - p_d)/position_scale_m|^2 + |r_T|^2) (seed 004 section 4, the paper's
  total error in its own length unit); position_scale_m defaults to the geometry's length unit
  (1 aul = 1 cm for the paper example), so the paper's stopping threshold 1e-3 applies unchanged.
  The Newton step itself does not depend on this weighting (full-row-rank pseudo-inverse).

Singularities (beyond the paper, which only assumes S invertible):
* start/goal checks: |det S| and |normalised det M| (seed 000 eq. (26)) above limits, legs in stroke;
  if det S or det M has opposite signs at start and goal, every path crosses a singularity and the
  planner reports SINGULARITY at once.  This is the case for the seed 004 example on the seed 000
  geometry (normalised det M = -0.077 at the start, +0.104 at the goal): with
  `check_type2=False` (the paper's own assumptions) it converges in 6 iterations, E = 9.3e-4, but
  its plan crosses det M = 0 five times (the paper's initial guess already crosses it once).
* along the plan: after the error is below tolerance, if det S or det M come closer than the
  margins, null-space steps (I - J^# J) descend a penalty of the margins while -J^# e keeps the
  end point (at most `max_repair_iterations`, default 10); a plan is CONVERGED only if the signed
  measures stay above their limits everywhere.  The penalty's gradient chains the measures'
  pose gradients (complex steps) with the variational sensitivities at every sample.

Robustness (measured with `cheope plan-bench`, 100 seeded pairs; figures in docs/concepts/robots.md):
* the dominant failure of the direct iteration on random pairs was not convergence but the
  motion it converged to: it reached the goal while crossing det M = 0 (6 of the first 36
  pairs), and the null-space repair could not undo the crossing.  Different initial controls
  converge to different motions, so a failed attempt goes on from the next of
  `initial_guesses` (default 8) initial controls: the paper's, then variants with the signs of
  its four non-zero coefficients flipped (on those 6 pairs one of the first five variants gave
  a motion clear of det M = 0 without any repair).
* an attempt that stalls or runs out of iterations continues by homotopy from an easier goal
  (`continuation`): the goal moves from the end pose of the initial controls to the real goal,
  each intermediate goal reached by a few damped Newton steps from the previous solution;
* every Newton step is damped by backtracking (`line_search`) and capped (`max_step_norm`);
* `restarts` > 0 adds attempts from random perturbations of the first initial controls.

Failure reporting: `plan_motion` never raises for an expected planning outcome; it returns a
`PlanResult` whose `status` (`PlanStatus`) says CONVERGED or why not (budget exhausted, stalled,
singularity met, stroke exceeded, singular start/goal) with a message naming the value.
Only a CONVERGED result carries a valid plan; `PlanResult.raise_for_status()` raises `PlanningError`
otherwise.  Invalid arguments (bad config, non-finite poses) raise `PlanningError` directly.

Units: SI (m, s, rad).  The plan's time axis runs over [0, T] with T = `PlannerConfig.horizon_s`
(seed 004 uses T = 1); time scaling for the actuators is left to the caller: for t' = c t the leg
lengths are legs(t'/c) and the rates divide by c.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from controller.core.rotations import hat, so3_exp, so3_log
from controller.errors import RefusedError
from controller.robots.nspu.kinematics import (
    NspuGeometry,
    Pose,
    SingularityError,
    io_blocks,
    leg_lengths_batch,
    rkmk4_step,
)
from controller.robots.nspu.planning.endpoint_map import (
    Motion,
    Sensitivity,
    integrate_motion,
    integrate_motion_with_stages,
    integrate_with_sensitivity,
    sensitivity,
    so3_log_left_jacobian_inverse,
)

Array = NDArray[np.float64]


class PlanningError(RefusedError):
    """Invalid planner input, or `raise_for_status` on a failed plan."""


class PlanStatus(enum.Enum):
    """Outcome of `plan_motion`."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"  # error still above tolerance after the iteration budget
    STALLED = "stalled"  # no step (even damped) decreased the error
    SINGULARITY = "singularity"  # the planned trajectory meets det S ~ 0 or a type-II singularity
    LEG_STROKE = "leg_stroke"  # the planned leg lengths leave [leg_min_m, leg_max_m]
    SINGULAR_START = "singular_start"  # the start pose itself is singular or out of stroke
    BAD_GOAL = "bad_goal"  # the goal pose itself is singular or out of stroke (no plan could end there)


@dataclass(frozen=True)
class PlannerConfig:
    """Parameters of the seed 004 planner."""

    horizon_s: float = 1.0  # T [s], seed 004 section 4
    harmonics: int = 2  # h, seed 004 eq. (15)
    gamma: float = 1.0  # step of eq. (17) [-]
    tolerance: float = 1e-3  # stop when E < tolerance, seed 004 section 4
    max_iterations: int = 100  # iteration budget of each attempt (initial controls, homotopy)
    n_steps: int = 100  # RKMK4 steps over [0, T] of the result's samples and of the verification
    plan_steps: int = 32  # RKMK4 steps over [0, T] while iterating (doubled when the verification disagrees)
    integration_tolerance: float = 0.1  # allowed |e(plan_steps) - e(n_steps)| as a fraction of tolerance
    line_search: bool = True  # backtracking on gamma (False: plain eq. (17))
    max_halvings: int = 12  # backtracking depth
    max_step_norm: float = 2.0  # cap on |delta Lambda| per iteration [rad/s]; inf disables
    position_scale_m: float | None = None  # position unit of the error norm; None: geometry unit
    min_abs_det_s: float = 1e-2  # |det S| = |s1 . s2 x s3| below this: system (7) singular (eq. (27))
    check_type2: bool = True  # reject plans crossing/approaching the type-II locus det M = 0 (eq. (26))
    min_type2_measure: float = 5e-3  # lower bound of sigma0 * normalised det M along the plan
    avoid_singularities: bool = True  # null-space descent away from det M = 0 and det S = 0
    avoidance_margin: float = 0.02  # penalty active when the signed measures fall below this
    repair_error_bound: float = 100.0  # while repairing, error may grow up to this x tolerance
    max_repair_iterations: int = 10  # null-space steps away from a singularity before the attempt fails
    initial_guesses: int = 8  # initial controls tried in turn: the paper's, then its sign variants
    continuation: bool = (
        True  # after a stalled or exhausted direct iteration, the homotopy from an easier goal
    )
    continuation_first_step: float = 0.25  # first step of the homotopy parameter in (0, 1]
    continuation_min_step: float = 1.0 / 64  # give up the homotopy below this step
    continuation_iterations: int = 8  # Newton steps per intermediate goal
    continuation_tolerance: float = 1e-2  # error at which an intermediate goal counts as reached
    restarts: int = 0  # extra attempts from perturbed initial coefficients after a failure
    restart_scale: float = 0.5  # std of the perturbation of Lambda per restart [rad/s]
    restart_seed: int = 0  # seed of the restart perturbations (deterministic)

    def __post_init__(self) -> None:
        checks = {
            "horizon_s": self.horizon_s > 0,
            "harmonics": self.harmonics >= 0,
            "gamma": 0 < self.gamma <= 1.0,
            "tolerance": self.tolerance > 0,
            "max_iterations": self.max_iterations >= 0,
            "n_steps": self.n_steps >= 4,
            "plan_steps": 4 <= self.plan_steps <= self.n_steps,
            "integration_tolerance": 0 < self.integration_tolerance <= 1.0,
            "max_repair_iterations": self.max_repair_iterations >= 0,
            "initial_guesses": 1 <= self.initial_guesses <= 16,
            "continuation_first_step": 0 < self.continuation_first_step <= 1.0,
            "continuation_min_step": 0 < self.continuation_min_step <= self.continuation_first_step,
            "continuation_iterations": self.continuation_iterations >= 1,
            "continuation_tolerance": self.continuation_tolerance > 0,
            "max_step_norm": self.max_step_norm > 0,
        }
        for key, ok in checks.items():
            if not ok:
                hint = f" (allowed 4 ... n_steps = {self.n_steps})" if key == "plan_steps" else ""
                raise PlanningError(f"PlannerConfig.{key} out of range: {getattr(self, key)!r}{hint}")

    @property
    def n_params(self) -> int:
        return 3 * (2 * self.harmonics + 1)


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Result of `plan_motion`.  Arrays are sampled at t_s (n_steps + 1 samples over [0, T])."""

    status: PlanStatus
    message: str
    iterations: int
    error_history: Array  # E after each iteration (index 0: initial guess)
    lambdas: Array  # control coefficients Lambda, (6h+3,)
    config: PlannerConfig
    geometry: NspuGeometry
    start: Pose
    goal: Pose
    t_s: Array  # (N,) [s]
    v_rad_s: Array  # (N, 3) controls v of eq. (7) [rad/s]; omega = -v
    p_m: Array  # (N, 3) platform positions [m]
    R: Array  # (N, 3, 3) platform rotations
    legs_m: Array  # (N, 3) leg lengths [m]
    leg_rates_m_s: Array  # (N, 3) leg-length rates u of eq. (6) [m/s]
    det_s: Array = field(repr=False)  # (N,) det S along the trajectory
    type2_measure: Array = field(repr=False)  # (N,) normalised det M along the trajectory (eq. (26))
    verified_error: float = float("nan")  # E of the n_steps integration of the final controls
    plan_steps: int = 0  # integration steps the iteration ended with

    @property
    def ok(self) -> bool:
        return self.status is PlanStatus.CONVERGED

    @property
    def final_error(self) -> float:
        return float(self.error_history[-1])

    @property
    def position_error_m(self) -> Array:
        """e_p(t) = p(t) - p_d (seed 004 Fig. 3)."""
        return self.p_m - self.goal.p_m

    @property
    def rotation_error(self) -> Array:
        """r(t) with [r(t)] = log(R(t) R_d^T) (seed 004 Fig. 3)."""
        return so3_log(self.R @ self.goal.R.T)

    def legs_in(self, length_unit_m: float) -> Array:
        """Leg lengths in another length unit (e.g. the paper's aul: legs_in(geometry.length_unit_m))."""
        return self.legs_m / length_unit_m

    def raise_for_status(self) -> PlanResult:
        if not self.ok:
            raise PlanningError(f"motion planning failed ({self.status.value}): {self.message}")
        return self


# --------------------------------------------------------------------------------------------
# Controls and system (7)
# --------------------------------------------------------------------------------------------


def fourier_basis(t_s: Array, horizon_s: float, harmonics: int) -> Array:
    """Row of basis functions (1, sin w t, cos w t, ..., sin h w t, cos h w t), shape (..., 2h+1).

    seed 004 eq. (15) with w = 2 pi / T.
    """
    t = np.asarray(t_s, dtype=float)
    cols = [np.ones_like(t)]
    for k in range(1, harmonics + 1):
        arg = 2.0 * np.pi * k * t / horizon_s
        cols += [np.sin(arg), np.cos(arg)]
    return np.stack(cols, axis=-1)


def controls(lambdas: Array, t_s: Array, horizon_s: float, harmonics: int) -> Array:
    """v(t) = P(t) Lambda, Lambda ordered (lambda_{1,0..2h}, lambda_{2,..}, lambda_{3,..}); (..., N, 3)."""
    lam = np.asarray(lambdas, dtype=float)
    lam = lam.reshape((*lam.shape[:-1], 3, 2 * harmonics + 1))
    basis = fourier_basis(t_s, horizon_s, harmonics)  # (N, 2h+1)
    return np.einsum("nk,...ik->...ni", basis, lam)


def paper_initial_lambdas(harmonics: int = 2) -> Array:
    """Seed 004 section 4: all zero except lambda_11 = lambda_21 = lambda_32 = 0.5, lambda_30 = 1."""
    lam = np.zeros((3, 2 * harmonics + 1))
    lam[0, 1] = 0.5
    lam[1, 1] = 0.5
    lam[2, 2] = 0.5
    lam[2, 0] = 1.0
    return lam.reshape(-1)


def system7_field(geometry: NspuGeometry, p: Array, R: Array, v: Array) -> tuple[Array, Array]:
    """(p_dot, omega) = (S^-1 J v, -v), seed 004 eq. (7); batched.  SingularityError if S is singular."""
    blk = io_blocks(geometry, p, R)
    try:
        pdot = np.linalg.solve(blk.S, np.einsum("...ij,...j->...i", blk.J, v)[..., None])[..., 0]
    except np.linalg.LinAlgError as err:
        raise SingularityError("det S = 0 met while integrating system (7) (seed 004 eq. (7))") from err
    return pdot, -v


def feedback_leg_rates(geometry: NspuGeometry, p: Array, R: Array, v: Array) -> Array:
    """u = (G S^-1 J - K) v, seed 004 eq. (6) (= G S^-1 (J - S G^-1 K) v); batched."""
    blk = io_blocks(geometry, p, R)
    s_inv_j = np.linalg.solve(blk.S, blk.J)
    return np.einsum("...ij,...j->...i", blk.G @ s_inv_j - blk.K, v)


def rollout(
    geometry: NspuGeometry, start: Pose, lambdas: Array, config: PlannerConfig
) -> tuple[Array, Array, Array]:
    """Integrate system (7) for coefficient batch lambdas (B, n) or (n,).

    Returns t (N,), p (B?, N, 3), R (B?, N, 3, 3) with N = n_steps + 1.
    """
    lam = np.asarray(lambdas, dtype=float)
    single = lam.ndim == 1
    if single:  # one trajectory: the fast single-pose stepping of endpoint_map (same scheme)
        t1, p1, r1, _, _ = integrate_motion(
            geometry, start, lam, config.horizon_s, config.harmonics, config.n_steps
        )
        return t1, p1, r1
    lam2 = lam
    nb = lam2.shape[0]
    T, n = config.horizon_s, config.n_steps
    dt = T / n
    t = np.linspace(0.0, T, n + 1)
    t_half = t[:-1] + 0.5 * dt
    v_nodes = controls(lam2, t, T, config.harmonics)  # (B, N, 3)
    v_half = controls(lam2, t_half, T, config.harmonics)  # (B, N-1, 3)
    p = np.broadcast_to(start.p_m, (nb, 3)).copy()
    R = np.broadcast_to(start.R, (nb, 3, 3)).copy()
    ps = np.empty((nb, n + 1, 3))
    Rs = np.empty((nb, n + 1, 3, 3))
    ps[:, 0], Rs[:, 0] = p, R
    with np.errstate(all="ignore"):
        for k in range(n):  # batches: the model's vectorised rkmk4_step
            stage_v = iter((v_nodes[:, k], v_half[:, k], v_half[:, k], v_nodes[:, k + 1]))

            def field_fn(pp: Array, RR: Array, _stages: Iterator[Array] = stage_v) -> tuple[Array, Array]:
                return system7_field(geometry, pp, RR, next(_stages))

            p, R = rkmk4_step(field_fn, p, R, dt)
            ps[:, k + 1], Rs[:, k + 1] = p, R
    return t, ps, Rs


def pose_error(p_T: Array, R_T: Array, goal: Pose, position_scale_m: float) -> Array:
    """e = ((p_T - p_d)/scale, r_T) with [r_T] = log(R_T R_d^T), seed 004 eq. (8)/(13); batched."""
    ep = (np.asarray(p_T) - goal.p_m) / position_scale_m
    er = so3_log(np.asarray(R_T) @ goal.R.T)
    return np.concatenate([ep, er], axis=-1)


@dataclass(eq=False)
class _Eval:
    """Error and singularity penalty at one Lambda; its Jacobian and the penalty's gradient on demand
    (`differentiate`), so that rejected line-search candidates cost only the motion."""

    lam: Array
    motion: Motion
    e: Array
    det_s: Array
    tm: Array
    penalty: float
    feasible: bool  # trajectory passes the final singularity checks
    jac: Array = field(default_factory=lambda: np.zeros((6, 0)))
    grad_penalty: Array = field(default_factory=lambda: np.zeros(0))

    @property
    def norm(self) -> float:
        return float(np.linalg.norm(self.e))

    def differentiate(
        self,
        geometry: NspuGeometry,
        goal: Pose,
        config: PlannerConfig,
        scale: float,
        signs: tuple[float, float],
    ) -> _Eval:
        """Fill jac (6, n) and grad_penalty (n,) from the variational equations; returns self."""
        if self.jac.shape[1] == self.lam.size:
            return self
        with np.errstate(all="ignore"):
            d_pose = sensitivity(geometry, self.motion, self.lam, config.horizon_s, config.harmonics)
        sen = Sensitivity(self.motion.t_s, self.motion.p_m, self.motion.R, d_pose)
        _, self.jac = _error_and_jacobian(sen, goal, scale)
        self.jac = np.nan_to_num(self.jac)
        if config.avoid_singularities and self.penalty > 0.0:
            self.grad_penalty = _penalty_gradient(
                geometry, sen.p_m, sen.R, d_pose, self.det_s, self.tm, signs, config
            )
        else:
            self.grad_penalty = np.zeros(self.lam.size)
        return self


def _evaluate(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    lam: Array,
    config: PlannerConfig,
    scale: float,
    signs: tuple[float, float],
    steps: int,
) -> _Eval | None:
    """End-point error and singularity measures of one motion; None if S turns singular on the way."""
    try:
        with np.errstate(all="ignore"):
            motion = integrate_motion_with_stages(
                geometry, start, lam, config.horizon_s, config.harmonics, steps
            )
    except (np.linalg.LinAlgError, SingularityError):
        return None
    if not (np.all(np.isfinite(motion.p_m)) and np.all(np.isfinite(motion.R))):
        return None
    e = pose_error(motion.p_m[-1], motion.R[-1], goal, scale)
    with np.errstate(all="ignore"):
        det_s, tm = singularity_measures(geometry, motion.p_m, motion.R)
    feasible = _feasible(det_s, tm, signs, config)
    pen = float(_penalty(det_s, tm, signs[0], signs[1], config)) if config.avoid_singularities else 0.0
    return _Eval(
        lam=lam,
        motion=motion,
        e=e,
        det_s=det_s,
        tm=tm,
        penalty=pen if np.isfinite(pen) else float("inf"),
        feasible=feasible,
    )


def _error_and_jacobian(sen: Sensitivity, goal: Pose, scale: float) -> tuple[Array, Array]:
    """e of eq. (8)/(13) at T and d e / d Lambda (6, n) from the sensitivities at T."""
    e = pose_error(sen.p_m[-1], sen.R[-1], goal, scale)
    d_end = sen.d_pose[-1]
    return e, np.vstack([d_end[:3] / scale, so3_log_left_jacobian_inverse(e[3:]) @ d_end[3:]])


def error_jacobian(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    lambdas: Array,
    config: PlannerConfig,
    steps: int | None = None,
) -> tuple[Array, Array]:
    """End-point error e (6,) and its Jacobian d e / d Lambda (6, n) (seed 004 eq. (12)-(13)).

    From the variational equations integrated with `steps` (default config.plan_steps) RKMK4 steps;
    the position rows in the error's position unit (config.position_scale_m or the geometry's).
    """
    scale = geometry.length_unit_m if config.position_scale_m is None else config.position_scale_m
    sen = integrate_with_sensitivity(
        geometry,
        start,
        np.asarray(lambdas, dtype=float),
        config.horizon_s,
        config.harmonics,
        config.plan_steps if steps is None else steps,
    )
    return _error_and_jacobian(sen, goal, scale)


def _penalty_gradient(
    geometry: NspuGeometry,
    p: Array,
    R: Array,
    d_pose: Array,
    det_s: Array,
    tm: Array,
    signs: tuple[float, float],
    config: PlannerConfig,
) -> Array:
    """Gradient of `_penalty` of a trajectory with respect to Lambda.

    The measures' gradients with respect to the pose at each sample come from complex steps along
    the six tangent directions; chained with the sensitivities d_pose (N, 6, n) of the variational
    equations they give d(measure)/d Lambda at every sample.
    """
    h = 1e-20
    eye = np.eye(3)
    dp = np.zeros((6, 3), dtype=complex)
    dp[:3] = 1j * h * eye
    drot = np.zeros((6, 3, 3), dtype=complex)
    drot[3:] = 1j * h * hat(eye)
    with np.errstate(all="ignore"):
        ds_c, tm_c = singularity_measures(geometry, p[:, None] + dp, R[:, None] + drot @ R[:, None])
    g_s = np.einsum("nk,nkj->nj", np.imag(ds_c) / h, d_pose)  # (N, n): d det S / d Lambda per sample
    g_m = np.einsum("nk,nkj->nj", np.imag(tm_c) / h, d_pose)
    m = config.avoidance_margin
    grad = np.mean(-2.0 * np.maximum(0.0, m - signs[0] * det_s)[:, None] * signs[0] * g_s, axis=0)
    if config.check_type2:
        grad = grad + np.mean(-2.0 * np.maximum(0.0, m - signs[1] * tm)[:, None] * signs[1] * g_m, axis=0)
    return np.nan_to_num(grad / (m * m))


def _feasible(det_s: Array, tm: Array, signs: tuple[float, float], config: PlannerConfig) -> bool:
    """True if det S and (check_type2) normalised det M keep their start sign with margin along the plan."""
    ok = bool(np.all(signs[0] * det_s >= config.min_abs_det_s))
    if config.check_type2:
        ok = ok and bool(np.all(signs[1] * tm >= config.min_type2_measure))
    return ok


# --------------------------------------------------------------------------------------------
# Singularity / stroke checks
# --------------------------------------------------------------------------------------------


def type2_measure(geometry: NspuGeometry, p: Array, R: Array) -> Array:
    """Normalised det M (seed 000 eq. (26)) in [-1, 1]; batched.

    M's angular columns are divided by the mean platform radius (so all entries are lengths or
    dimensionless) and the determinant is divided by the product of the row norms (Hadamard
    ratio).  It vanishes exactly on the type-II singularity locus and is unit-independent.
    """
    M = io_blocks(geometry, p, R).M.copy()
    M[..., 3:] /= float(np.mean(np.linalg.norm(geometry.b_platform_m, axis=1)))
    row_norms = np.sqrt(np.sum(M * M, axis=-1))  # not np.linalg.norm: complex-step safe
    return np.linalg.det(M) / np.prod(row_norms, axis=-1)


def singularity_measures(geometry: NspuGeometry, p: Array, R: Array) -> tuple[Array, Array]:
    """(det S, normalised det M) at poses (..., 3), (..., 3, 3); seed 000 eq. (26)-(27)."""
    det_s = np.linalg.det(io_blocks(geometry, p, R).S)  # seed 000: det S = s1 . s2 x s3
    return det_s, type2_measure(geometry, p, R)


def _penalty(det_s: Array, tm: Array, sign_s: float, sign_m: float, config: PlannerConfig) -> Array:
    """Barrier-like penalty of trajectories (..., N) approaching det S = 0 or det M = 0."""
    m = config.avoidance_margin
    pen = np.mean(np.maximum(0.0, m - sign_s * det_s) ** 2, axis=-1)
    if config.check_type2:
        pen = pen + np.mean(np.maximum(0.0, m - sign_m * tm) ** 2, axis=-1)
    return np.nan_to_num(pen, nan=np.inf) / (m * m)


def check_pose(geometry: NspuGeometry, pose: Pose, config: PlannerConfig, label: str) -> str | None:
    """Why `pose` cannot be a start or goal (legs out of stroke, singular, too close to det M = 0), or None.

    The legs first: a pose far out of reach (a goal of 1e300 m) is out of stroke, which says why;
    its singularity measures overflowed (numpy's warnings on stderr) into "U joint degenerate"."""
    with np.errstate(over="ignore", invalid="ignore"):
        legs = leg_lengths_batch(geometry, pose.p_m, pose.R)
    if not (np.all(legs >= geometry.leg_min_m) and np.all(legs <= geometry.leg_max_m)):  # NaN too
        return f"{label} pose p={pose.p_m}: leg lengths {legs} m outside [{geometry.leg_min_m}, {geometry.leg_max_m}]"
    try:
        det_s, tm = singularity_measures(geometry, pose.p_m, pose.R)
    except SingularityError as err:
        return f"{label} pose p={pose.p_m}: {err}"
    if abs(det_s) < config.min_abs_det_s:
        return f"{label} pose p={pose.p_m}: |det S| = {abs(det_s):.3e} < {config.min_abs_det_s} (seed 000 eq. (27))"
    if config.check_type2 and abs(tm) < config.min_type2_measure:
        return (
            f"{label} pose p={pose.p_m}: normalised det M = {tm:.3e}, |.| < {config.min_type2_measure} "
            "(type-II singularity, seed 000 eq. (26))"
        )
    return None


# --------------------------------------------------------------------------------------------
# Planner
# --------------------------------------------------------------------------------------------


def plan_motion(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    config: PlannerConfig = PlannerConfig(),
    initial_lambdas: Array | None = None,
) -> PlanResult:
    """Plan controls steering the 3-nSPU from `start` to `goal` in T (seed 004 eq. (15)-(17)).

    initial_lambdas defaults to the seed 004 example's initial guess (`paper_initial_lambdas`) and its
    sign variants, tried in turn (`config.initial_guesses`; given initial_lambdas are the only
    guess); an attempt that stalls or runs out of iterations continues by homotopy
    (`config.continuation`); if all fail and config.restarts > 0, the planner retries from the
    first guess + N(0, restart_scale^2) perturbations drawn from a generator seeded with
    config.restart_seed (deterministic).  `iterations` counts the iterations of all attempts.  Returns a PlanResult; check `.ok` / `.status` or call
    `.raise_for_status()`.
    """
    lam = (
        paper_initial_lambdas(config.harmonics)
        if initial_lambdas is None
        else np.array(initial_lambdas, float)
    )
    if lam.shape != (config.n_params,) or not np.all(np.isfinite(lam)):
        raise PlanningError(
            f"initial_lambdas must be finite with shape ({config.n_params},), got {lam.shape}"
        )
    scale = geometry.length_unit_m if config.position_scale_m is None else config.position_scale_m
    if not scale > 0:
        raise PlanningError(f"position_scale_m must be positive, got {scale}")

    def fail(status: PlanStatus, message: str) -> PlanResult:
        return _build_result(
            geometry, start, goal, config, lam, status, message, [float("nan")], 0, None, config.plan_steps
        )

    for label, pose in (("start", start), ("goal", goal)):
        msg = check_pose(geometry, pose, config, label)
        if msg is not None:
            return fail(PlanStatus.SINGULAR_START if label == "start" else PlanStatus.BAD_GOAL, msg)
    det_s0, tm0 = singularity_measures(geometry, start.p_m, start.R)
    det_s1, tm1 = singularity_measures(geometry, goal.p_m, goal.R)
    if np.sign(det_s0) != np.sign(det_s1):
        return fail(
            PlanStatus.SINGULARITY,
            f"start and goal are separated by det S = 0 (det S = {det_s0:.3e} vs {det_s1:.3e}): "
            "system (7) cannot connect them without becoming singular",
        )
    if config.check_type2 and np.sign(tm0) != np.sign(tm1):
        return fail(
            PlanStatus.SINGULARITY,
            f"start and goal lie on opposite sides of the type-II singularity locus det M = 0 "
            f"(seed 000 eq. (26); normalised det M = {tm0:.3e} vs {tm1:.3e}): every path crosses it",
        )
    signs = (float(np.sign(det_s0)), float(np.sign(tm0)))
    rng = np.random.default_rng(config.restart_seed)
    attempts: list[str] = []
    guesses = (
        [lam] if initial_lambdas is not None else _initial_guesses(config.harmonics, config.initial_guesses)
    )
    iterations = 0
    res = fail(PlanStatus.MAX_ITERATIONS, "no attempt")
    for k, guess in enumerate(guesses):
        res = _plan_once(geometry, start, goal, config, guess, scale, signs)
        if (
            not res.ok
            and config.continuation
            and res.status in (PlanStatus.STALLED, PlanStatus.MAX_ITERATIONS)
        ):
            attempts.append(f"guess {k} direct: {res.status.value}: {res.message}")
            res = _plan_by_continuation(geometry, start, goal, config, guess, scale, signs, res.iterations)
        iterations += res.iterations
        if res.ok or res.status is PlanStatus.LEG_STROKE:
            break
        attempts.append(f"guess {k}: {res.status.value}: {res.message}")
    for k in range(config.restarts):
        if res.ok or res.status is PlanStatus.LEG_STROKE:
            break
        lam_k = guesses[0] + rng.normal(0.0, config.restart_scale, lam.shape)
        res = _plan_once(geometry, start, goal, config, lam_k, scale, signs)
        iterations += res.iterations
        if not res.ok:
            attempts.append(f"restart {k + 1}: {res.status.value}: {res.message}")
    if attempts:
        res = dataclasses.replace(
            res, message=res.message + f" | {len(attempts)} earlier: " + "; ".join(attempts)
        )
    return dataclasses.replace(res, iterations=iterations)


def _initial_guesses(harmonics: int, count: int) -> list[Array]:
    """The seed 004 example's initial controls, then variants with the signs of its four non-zero
    coefficients flipped (the order: flips that most often gave a plan clear of det M = 0 on
    `cheope plan-bench` pairs first).  Different initial controls converge to different motions:
    where the first crosses det M = 0 a variant often stays on the start's side."""
    order = [
        (1, 1, 1, 1),
        (-1, -1, 1, 1),
        (1, -1, 1, -1),
        (-1, 1, 1, 1),
        (1, -1, -1, -1),
        (-1, 1, -1, 1),
        (-1, -1, -1, 1),
        (1, 1, -1, -1),
        (1, 1, 1, -1),
        (-1, -1, 1, -1),
        (1, -1, 1, 1),
        (-1, 1, 1, -1),
        (1, 1, -1, 1),
        (-1, -1, -1, -1),
        (1, -1, -1, 1),
        (-1, 1, -1, -1),
    ]
    base = paper_initial_lambdas(harmonics).reshape(3, 2 * harmonics + 1)
    out = []
    for s11, s21, s32, s30 in order[: max(1, count)]:
        lam = base.copy()
        if harmonics >= 1:
            lam[0, 1] *= s11
            lam[1, 1] *= s21
        if harmonics >= 1:
            lam[2, 2] *= s32
        lam[2, 0] *= s30
        out.append(lam.reshape(-1))
    return out


def _newton(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    lam: Array,
    config: PlannerConfig,
    scale: float,
    tolerance: float,
    max_iterations: int,
) -> tuple[Array, int, bool]:
    """Damped Newton iteration of eq. (17) on the end error alone (line search, step cap), for the
    intermediate goals of the continuation: (coefficients, iterations, error below `tolerance`)."""
    plain = dataclasses.replace(config, avoid_singularities=False, check_type2=False)
    ev = _evaluate(geometry, start, goal, lam, plain, scale, (1.0, 1.0), config.plan_steps)
    if ev is None:
        return lam, 0, False
    for it in range(max_iterations):
        if ev.norm < tolerance:
            return lam, it, True
        step = -np.linalg.pinv(ev.differentiate(geometry, goal, plain, scale, (1.0, 1.0)).jac) @ ev.e
        norm = float(np.linalg.norm(step))
        if norm > config.max_step_norm:
            step *= config.max_step_norm / norm
        g = config.gamma
        for _ in range(config.max_halvings + 1):
            trial = _evaluate(
                geometry, start, goal, lam + g * step, plain, scale, (1.0, 1.0), config.plan_steps
            )
            if trial is not None and trial.norm < ev.norm:
                lam, ev = lam + g * step, trial
                break
            g *= 0.5
        else:
            return lam, it + 1, False
    return lam, max_iterations, ev.norm < tolerance


def _plan_by_continuation(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    config: PlannerConfig,
    lam: Array,
    scale: float,
    signs: tuple[float, float],
    iterations_so_far: int,
) -> PlanResult:
    """Homotopy from an easier goal: the end pose of the initial controls is reached already; the goal
    moves from there towards the real goal along the straight line in position and the geodesic in
    rotation, each intermediate goal solved by a few Newton steps from the previous solution; a step
    of the homotopy that fails is halved, one that succeeds grows.  The last stage is the full
    iteration (`_plan_once`: singularity repair, verification)."""
    try:
        _, ps, Rs, _, _ = integrate_motion(
            geometry, start, lam, config.horizon_s, config.harmonics, config.plan_steps
        )
    except np.linalg.LinAlgError:
        return _plan_once(geometry, start, goal, config, lam, scale, signs)
    p_from, r_from = ps[-1], Rs[-1]
    turn = so3_log(goal.R @ r_from.T)
    s, ds, used = 0.0, config.continuation_first_step, iterations_so_far
    while s < 1.0:
        s_try = min(1.0, s + ds)
        if s_try >= 1.0:
            break
        sub_goal = Pose(p_from + s_try * (goal.p_m - p_from), so3_exp(s_try * turn) @ r_from)
        budget = max(1, min(config.continuation_iterations, config.max_iterations + iterations_so_far - used))
        lam_try, its, ok = _newton(
            geometry, start, sub_goal, lam, config, scale, config.continuation_tolerance, budget
        )
        used += its
        if ok:
            lam, s, ds = lam_try, s_try, min(1.0, 1.5 * ds)
        else:
            ds *= 0.5
            if ds < config.continuation_min_step:
                break
        if used >= config.max_iterations + iterations_so_far:
            break
    res = _plan_once(geometry, start, goal, config, lam, scale, signs)
    note = f" (continuation reached {s:.2f} of the way from the initial end pose before the final iteration)"
    return dataclasses.replace(res, message=res.message + note, iterations=res.iterations + used)


def _plan_once(  # noqa: C901  (seed 004's iteration with its integration-accuracy and line-search branches)
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    config: PlannerConfig,
    lam: Array,
    scale: float,
    signs: tuple[float, float],
) -> PlanResult:
    """One run of the iteration from initial coefficients `lam`."""
    steps = config.plan_steps

    def result(
        status: PlanStatus,
        message: str,
        lam_: Array,
        errs: list[float],
        it: int,
        fine: tuple[Array, Array, Array] | None = None,
    ) -> PlanResult:
        return _build_result(geometry, start, goal, config, lam_, status, message, errs, it, fine, steps)

    errs: list[float] = []
    it = 0
    ev = _evaluate(geometry, start, goal, lam, config, scale, signs, steps)
    if ev is None:
        return result(
            PlanStatus.SINGULARITY,
            "initial controls: det S = 0 met while integrating system (7) (seed 004 eq. (7))",
            lam,
            [float("nan")],
            0,
        )
    errs.append(ev.norm)
    # Phase 1: Newton-type iteration of seed 004 eq. (17) on the error alone.
    # Phase 2 (avoid_singularities, when the trajectory approaches det S = 0 or det M = 0):
    #   steps -J^# e plus null-space descent of the singularity penalty, accepted when the penalty
    #   decreases while the error stays below `repair_error_bound` x tolerance; then the error is
    #   polished again with steps that may not raise the penalty.
    phase, repair_start = 1, 0
    while True:
        err_norm = ev.norm
        done = err_norm < config.tolerance
        if done and (not config.avoid_singularities or ev.feasible):
            fine = _fine_rollout(geometry, start, lam, config)
            if fine is not None:
                e_fine = pose_error(fine[1][-1], fine[2][-1], goal, scale)
                agree = (
                    float(np.linalg.norm(e_fine - ev.e)) <= config.integration_tolerance * config.tolerance
                )
                if agree and float(np.linalg.norm(e_fine)) < config.tolerance:
                    break
            if steps >= config.n_steps:
                return result(
                    PlanStatus.SINGULARITY,
                    f"error {err_norm:.3e} reached with {steps} steps but the "
                    f"verification integration failed (det S = 0 or non-finite)",
                    lam,
                    errs,
                    it,
                )
            steps = min(2 * steps, config.n_steps)  # error control: refine and go on iterating
            ev_ref = _evaluate(geometry, start, goal, lam, config, scale, signs, steps)
            if ev_ref is None:
                return result(
                    PlanStatus.SINGULARITY, f"iteration {it}: det S = 0 met with {steps} steps", lam, errs, it
                )
            ev = ev_ref
            errs[-1] = ev.norm  # the same iteration, integrated more accurately
            continue
        if done and phase == 1:
            phase, repair_start = 2, it
        if phase == 2 and it - repair_start >= config.max_repair_iterations:
            k = (
                int(np.argmin(signs[1] * ev.tm))
                if config.check_type2
                else int(np.argmin(signs[0] * ev.det_s))
            )
            return result(
                PlanStatus.SINGULARITY,
                f"the controls reached the goal (E < {config.tolerance}) on a motion too close to a singularity, "
                f"and {config.max_repair_iterations} null-space steps did not give a clear one: now E = {err_norm:.3e}, "
                f"closest normalised det M = {ev.tm[k]:.3e}, det S = {ev.det_s[k]:.3e} at t = {ev.motion.t_s[k]:.3f} s "
                f"(limits {config.min_type2_measure}, {config.min_abs_det_s})",
                lam,
                errs,
                it,
            )
        if it >= config.max_iterations:
            if err_norm < config.tolerance:
                return result(
                    PlanStatus.SINGULARITY,
                    f"error {err_norm:.3e} reached but the trajectory still approaches a singularity "
                    f"(penalty {ev.penalty:.3e}) after {it} iterations",
                    lam,
                    errs,
                    it,
                )
            return result(
                PlanStatus.MAX_ITERATIONS,
                f"error {err_norm:.3e} >= tolerance {config.tolerance} after {it} iterations",
                lam,
                errs,
                it,
            )
        ev.differentiate(geometry, goal, config, scale, signs)
        pinv = np.linalg.pinv(ev.jac)
        newton = -pinv @ ev.e  # seed 004 eq. (16)-(17): -J^# e
        repairing = phase == 2 and not ev.feasible and ev.penalty > 0.0
        if repairing:
            ns = -(ev.grad_penalty - pinv @ (ev.jac @ ev.grad_penalty))  # projected onto ker J
            nn2 = float(ns @ ns)
            if nn2 == 0.0:
                return result(
                    PlanStatus.SINGULARITY,
                    f"singularity penalty {ev.penalty:.3e} cannot be reduced in the null space (iteration {it})",
                    lam,
                    errs,
                    it,
                )
            step = newton + ns * (ev.penalty / nn2)  # Gauss-Newton length along the projected gradient
        else:
            step = newton
        norm = float(np.linalg.norm(step))
        if norm > config.max_step_norm:
            step *= config.max_step_norm / norm
        g = config.gamma
        accepted: _Eval | None = None
        for _ in range(config.max_halvings + 1):
            cand = lam + g * step
            trial = _evaluate(geometry, start, goal, cand, config, scale, signs, steps)
            if not config.line_search:
                accepted = trial
                break
            if trial is not None:
                if phase == 1:
                    ok = trial.norm < err_norm
                elif repairing:
                    ok = (
                        trial.penalty < ev.penalty
                        and trial.norm < config.repair_error_bound * config.tolerance
                    )
                else:
                    ok = trial.norm < err_norm and (trial.feasible or trial.penalty <= ev.penalty)
                if ok:
                    accepted = trial
                    break
            g *= 0.5
        if accepted is None:
            if not config.line_search:
                return result(
                    PlanStatus.SINGULARITY,
                    f"iteration {it + 1}: det S = 0 met while integrating system (7)",
                    cand,
                    errs,
                    it + 1,
                )
            status = PlanStatus.SINGULARITY if phase == 2 else PlanStatus.STALLED
            return result(
                status,
                f"no step decreased the {'singularity penalty' if repairing else 'error'} (error {err_norm:.3e}, "
                f"penalty {ev.penalty:.3e}; gamma down to {g:.2e}) at iteration {it}",
                lam,
                errs,
                it,
            )
        lam, ev = cand, accepted
        it += 1
        errs.append(ev.norm)
    return result(
        PlanStatus.CONVERGED,
        f"error {ev.norm:.3e} < {config.tolerance} after {it} iterations",
        lam,
        errs,
        it,
        fine,
    )


def _fine_rollout(
    geometry: NspuGeometry, start: Pose, lam: Array, config: PlannerConfig
) -> tuple[Array, Array, Array] | None:
    """The n_steps integration of the controls (the result's samples and the verification), or None."""
    try:
        with np.errstate(all="ignore"):
            t, ps, Rs = rollout(geometry, start, lam, config)
    except (np.linalg.LinAlgError, SingularityError):
        return None
    if not (np.all(np.isfinite(ps)) and np.all(np.isfinite(Rs))):
        return None
    return t, ps, Rs


def _build_result(
    geometry: NspuGeometry,
    start: Pose,
    goal: Pose,
    config: PlannerConfig,
    lam: Array,
    status: PlanStatus,
    message: str,
    errs: list[float],
    it: int,
    fine: tuple[Array, Array, Array] | None = None,
    plan_steps: int = 0,
) -> PlanResult:
    n = config.n_steps + 1
    t = np.linspace(0.0, config.horizon_s, n)
    v = controls(lam, t, config.horizon_s, config.harmonics)
    if fine is None:
        fine = _fine_rollout(geometry, start, lam, config)
    verified = float("nan")
    if fine is not None:
        t, ps, Rs = fine
        legs = leg_lengths_batch(geometry, ps, Rs)
        scale = geometry.length_unit_m if config.position_scale_m is None else config.position_scale_m
        with np.errstate(all="ignore"):  # a goal far out of reach (1e300 m): inf, not numpy's warning
            verified = float(np.linalg.norm(pose_error(ps[-1], Rs[-1], goal, scale)))
            rates = feedback_leg_rates(geometry, ps, Rs, v)
            det_s, tm = singularity_measures(geometry, ps, Rs)
    else:
        nan3 = np.full((n, 3), np.nan)
        ps, Rs, legs, rates = nan3, np.full((n, 3, 3), np.nan), nan3, nan3
        det_s, tm = np.full(n, np.nan), np.full(n, np.nan)
        if status is PlanStatus.CONVERGED:
            status, message = (
                PlanStatus.SINGULARITY,
                "final trajectory: det S = 0 met while integrating system (7)",
            )
    if status is PlanStatus.CONVERGED:
        bad = (
            ~np.isfinite(det_s)
            | (np.sign(det_s) != np.sign(det_s[0]))
            | (np.abs(det_s) < config.min_abs_det_s)
        )
        if config.check_type2:
            bad |= (np.sign(tm) != np.sign(tm[0])) | (np.abs(tm) < config.min_type2_measure)
        if np.any(bad) or not np.all(np.isfinite(ps)):
            k = int(np.argmax(bad)) if np.any(bad) else 0
            status = PlanStatus.SINGULARITY
            message = (
                f"planned trajectory meets a singularity at t = {t[k]:.3f} s: det S = {det_s[k]:.3e}, "
                f"normalised det M = {tm[k]:.3e} (limits {config.min_abs_det_s}, {config.min_type2_measure})"
            )
        elif np.any(legs < geometry.leg_min_m) or np.any(legs > geometry.leg_max_m):
            status = PlanStatus.LEG_STROKE
            message = (
                f"planned leg lengths span [{legs.min():.4f}, {legs.max():.4f}] m, stroke is "
                f"[{geometry.leg_min_m}, {geometry.leg_max_m}] m"
            )
    return PlanResult(
        status=status,
        message=message,
        iterations=it,
        error_history=np.asarray(errs, dtype=float),
        lambdas=np.asarray(lam, dtype=float),
        config=config,
        geometry=geometry,
        start=start,
        goal=goal,
        t_s=t,
        v_rad_s=v,
        p_m=ps,
        R=Rs,
        legs_m=legs,
        leg_rates_m_s=rates,
        det_s=det_s,
        type2_measure=tm,
        verified_error=verified,
        plan_steps=plan_steps,
    )


def paper_example_poses(length_unit_m: float = 0.01) -> tuple[Pose, Pose]:
    """Start and goal of seed 004 section 4 (positions in aul converted with length_unit_m)."""
    from controller.core.rotations import rpy

    start = Pose(np.array([0.0, 0.0, 25.0]) * length_unit_m, rpy(0.0, 0.0, -np.pi / 6))
    goal = Pose(np.array([-0.4, -0.2, 35.0]) * length_unit_m, rpy(0.0, 0.0, -np.pi / 2))
    return start, goal
