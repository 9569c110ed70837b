"""Tests of the seed 004 non-holonomic motion planner on the seed 000 example geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from controller.core.rotations import so3_exp, so3_log
from controller.robot_registry import robot_entry
from controller.robots.nspu.kinematics import (
    NspuGeometry,
    Pose,
    integrate_leg_trajectory,
    io_blocks,
    leg_lengths_batch,
)
from controller.robots.nspu.planning.nonholonomic import (
    PlannerConfig,
    PlanningError,
    PlanStatus,
    controls,
    error_jacobian,
    feedback_leg_rates,
    fourier_basis,
    paper_example_poses,
    paper_initial_lambdas,
    plan_motion,
    pose_error,
    rollout,
    system7_field,
    type2_measure,
)

GEOM = NspuGeometry.paper_example()
UNIT = GEOM.length_unit_m
START, GOAL = paper_example_poses()


def _goal(dp_aul: list[float], dr: list[float]) -> Pose:
    return Pose(START.p_m + np.array(dp_aul) * UNIT, so3_exp(np.array(dr)) @ START.R)


PAIRS = {
    "near_a": _goal([0.56, -1.44, 2.04], [0.01, 0.01, 0.15]),
    "near_b": _goal([-1.85, -2.51, 2.13], [0.22, 0.23, -0.02]),
}


@pytest.fixture(scope="module")
def paper_plan():
    # seed 004 section 4; the type-II check must be off: see test_paper_example_is_rejected_by_default
    return plan_motion(GEOM, START, GOAL, PlannerConfig(check_type2=False))


@pytest.fixture(scope="module")
def near_plans():
    # 200 samples: test_plan_exposes_sampled_legs_and_consistent_rates differentiates them numerically
    return {
        k: plan_motion(GEOM, START, g, PlannerConfig(max_iterations=30, n_steps=200))
        for k, g in PAIRS.items()
    }


def test_fourier_controls_eq15() -> None:
    lam = paper_initial_lambdas()
    assert lam.shape == (15,)
    t = np.array([0.0, 0.25, 0.5])
    v = controls(lam, t, 1.0, 2)
    # v1 = 0.5 sin(2 pi t), v2 = 0.5 sin(2 pi t), v3 = 1 + 0.5 cos(2 pi t)
    assert np.allclose(v[:, 0], 0.5 * np.sin(2 * np.pi * t))
    assert np.allclose(v[:, 1], 0.5 * np.sin(2 * np.pi * t))
    assert np.allclose(v[:, 2], 1 + 0.5 * np.cos(2 * np.pi * t))
    assert fourier_basis(t, 1.0, 2).shape == (3, 5)


@pytest.mark.parametrize("steps", [32, 128])
def test_variational_jacobian_matches_finite_differences(steps: int) -> None:
    """d e / d Lambda from the variational equations (seed 004 eq. (10)-(12)) against central
    differences of the end-point map integrated with the same steps, at the paper's initial controls
    and at a random point.  The variational Jacobian is the continuous map's up to O(dt^4)
    (1.5e-6 relative at 32 steps measured), the differences are of the discrete map."""
    rng = np.random.default_rng(3)
    cfg = PlannerConfig(n_steps=steps)
    goal = PAIRS["near_a"]
    d = 1e-6
    for lam in (paper_initial_lambdas(), paper_initial_lambdas() + rng.normal(0.0, 0.3, 15)):
        e, jac = error_jacobian(GEOM, START, goal, lam, cfg, steps)
        batch = np.concatenate([lam[None], lam + d * np.eye(15), lam - d * np.eye(15)])
        _, ps, Rs = rollout(GEOM, START, batch, cfg)  # one vectorised rollout of the 31 controls
        errs = pose_error(ps[:, -1], Rs[:, -1], goal, UNIT)
        assert np.allclose(e, errs[0], rtol=0, atol=1e-12)
        fd = (errs[1:16] - errs[16:]).T / (2 * d)
        rel = np.max(np.abs(jac - fd)) / np.max(np.abs(fd))
        assert rel < (1e-4 if steps == 32 else 1e-7), rel


def test_singularity_penalty_gradient_matches_finite_differences() -> None:
    """The penalty's gradient (measures' pose gradients by complex steps chained with the variational
    sensitivities) against central differences of the penalty; a wide margin makes it active along
    most of the motion."""
    from controller.robots.nspu.planning.nonholonomic import _evaluate, singularity_measures

    cfg = PlannerConfig(avoidance_margin=0.5)
    det_s0, tm0 = singularity_measures(GEOM, START.p_m, START.R)
    signs = (float(np.sign(det_s0)), float(np.sign(tm0)))
    goal, lam, steps = PAIRS["near_a"], paper_initial_lambdas(), 64

    def penalty(x: np.ndarray) -> float:
        ev = _evaluate(GEOM, START, goal, x, cfg, UNIT, signs, steps)
        assert ev is not None
        return ev.penalty

    ev = _evaluate(GEOM, START, goal, lam, cfg, UNIT, signs, steps)
    assert ev is not None and ev.penalty > 0.1
    grad = ev.differentiate(GEOM, goal, cfg, UNIT, signs).grad_penalty
    d = 1e-6
    fd = np.array([(penalty(lam + d * u) - penalty(lam - d * u)) / (2 * d) for u in np.eye(15)])
    assert np.max(np.abs(grad - fd)) < 1e-6 * np.max(np.abs(fd))  # measured 5.9e-9


def test_feedback_transformation_eq6_eq7() -> None:
    """u of eq. (6) applied to eq. (11) yields p_dot = S^-1 J v and omega = -v (eq. (7))."""
    p, R = START.p_m, START.R
    v = np.array([0.3, -0.2, 0.5])
    u = feedback_leg_rates(GEOM, p, R, v)
    blk = io_blocks(GEOM, p, R)
    x = np.linalg.solve(blk.M, np.concatenate([u, np.zeros(3)]))
    pdot, w = system7_field(GEOM, p, R, v)
    assert np.allclose(x[:3], pdot) and np.allclose(x[3:], w) and np.allclose(w, -v)
    # printed form G S^-1 (J - S G^-1 K) v
    u2 = blk.G @ np.linalg.solve(blk.S, blk.J - blk.S @ np.linalg.solve(blk.G, blk.K)) @ v
    assert np.allclose(u, u2)


def test_paper_example_is_rejected_by_default() -> None:
    """Start and goal lie on opposite sides of det M = 0 (normalised det M -0.077 vs +0.104)."""
    assert type2_measure(GEOM, START.p_m, START.R) < 0 < type2_measure(GEOM, GOAL.p_m, GOAL.R)
    res = plan_motion(GEOM, START, GOAL)
    assert res.status is PlanStatus.SINGULARITY
    assert "opposite sides" in res.message
    with pytest.raises(PlanningError, match="singularity"):
        res.raise_for_status()


def test_paper_example_converges_with_paper_assumptions(paper_plan) -> None:
    res = paper_plan
    assert res.status is PlanStatus.CONVERGED, res.message
    assert res.final_error < 1e-3
    assert res.iterations <= 10
    assert np.all(np.diff(res.error_history) < 0)
    # end point of the sampled trajectory is the goal
    e = pose_error(res.p_m[-1], res.R[-1], GOAL, UNIT)
    assert np.linalg.norm(e) < 1e-3
    # integration accuracy: a finer rollout of the same controls changes the error by << tolerance
    _, ps, Rs = rollout(GEOM, START, res.lambdas, PlannerConfig(n_steps=800))
    assert np.linalg.norm(pose_error(ps[-1], Rs[-1], GOAL, UNIT)) < 1e-3
    # the plan crosses the type-II locus (why the default planner rejects this example)
    assert np.any(np.diff(np.sign(res.type2_measure)) != 0)


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_further_pose_pairs_converge_without_singularity(near_plans, name: str) -> None:
    res = near_plans[name]
    assert res.status is PlanStatus.CONVERGED, res.message
    assert res.final_error < 1e-3
    tm = res.type2_measure * np.sign(res.type2_measure[0])
    assert tm.min() >= res.config.min_type2_measure
    assert np.all(np.abs(res.det_s) >= res.config.min_abs_det_s)
    assert np.all((res.legs_m >= GEOM.leg_min_m) & (res.legs_m <= GEOM.leg_max_m))


def test_plan_exposes_sampled_legs_and_consistent_rates(near_plans) -> None:
    res = near_plans["near_a"]
    n = res.config.n_steps + 1
    assert res.t_s.shape == (n,) and res.legs_m.shape == (n, 3) and res.leg_rates_m_s.shape == (n, 3)
    assert np.allclose(res.legs_m, leg_lengths_batch(GEOM, res.p_m, res.R))
    # rates of eq. (6) are the time derivative of the sampled leg lengths
    d = np.gradient(res.legs_m, res.t_s, axis=0, edge_order=2)
    assert np.max(np.abs(d - res.leg_rates_m_s)) < 1e-3 * np.max(np.abs(res.leg_rates_m_s))
    assert np.allclose(res.legs_in(UNIT), res.legs_m / UNIT)


def test_forward_simulation_of_planned_legs_reaches_goal(near_plans) -> None:
    """Feeding the planned leg lengths (sampled, 401 points) to the pose integrator reaches the goal."""
    res = near_plans["near_b"]
    goal = PAIRS["near_b"]
    t, ps, Rs = rollout(GEOM, START, res.lambdas, PlannerConfig(n_steps=400))
    poses = integrate_leg_trajectory(GEOM, START, t, leg_lengths_batch(GEOM, ps, Rs), substeps=1)
    err = np.linalg.norm(pose_error(poses[-1].p_m, poses[-1].R, goal, UNIT))
    assert err < 2e-3
    mid = poses[200]
    assert np.linalg.norm(mid.p_m - ps[200]) < 1e-3 * UNIT
    assert np.linalg.norm(so3_log(mid.R @ Rs[200].T)) < 1e-3


def test_shipped_default_motion_converges_and_is_verified() -> None:
    """The configured default motion (controller/robots/nspu/nspu.toml) plans in a few iterations; the
    end error is below the tolerance in the finer verification integration too."""
    from controller.config import load_config
    from controller.robots.nspu.entry import nspu_geometry, nspu_poses
    from controller.robots.nspu.planned_legs import planner_config

    cfg = load_config(str(robot_entry("nspu").config_file), {})
    start, goal = nspu_poses(cfg.robot.model("nspu"))
    pcfg = planner_config(cfg.robot.model("nspu"))
    res = plan_motion(nspu_geometry(cfg.robot.model("nspu")), start, goal, pcfg)
    assert res.status is PlanStatus.CONVERGED, res.message
    assert res.iterations <= 10
    assert res.final_error < pcfg.tolerance and res.verified_error < pcfg.tolerance
    assert abs(res.verified_error - res.final_error) <= pcfg.integration_tolerance * pcfg.tolerance
    assert np.min(res.type2_measure * np.sign(res.type2_measure[0])) >= pcfg.min_type2_measure


def _pose(p: list[float], r: list[float]) -> Pose:
    return Pose(np.array(p), so3_exp(np.array(r)))


# pair 5 of `cheope plan-bench --seed 0`: the paper's initial controls converge to a motion that
# crosses det M = 0; the planner goes on from a sign variant of them
CROSSING_START = _pose([-0.00191, -0.00603, 0.24363], [0.00472, -0.03471, -0.48894])
CROSSING_GOAL = _pose([-0.01693, 0.01608, 0.23689], [-0.10317, 0.02549, -0.36037])


def test_next_initial_controls_after_a_crossing_motion() -> None:
    first = plan_motion(GEOM, CROSSING_START, CROSSING_GOAL, PlannerConfig(initial_guesses=1))
    assert first.status is PlanStatus.SINGULARITY and "null-space steps" in first.message
    res = plan_motion(GEOM, CROSSING_START, CROSSING_GOAL, PlannerConfig())
    assert res.status is PlanStatus.CONVERGED, res.message
    assert "guess 0: singularity" in res.message  # the failed first attempt is reported with the success
    tm = res.type2_measure * np.sign(res.type2_measure[0])
    assert tm.min() >= res.config.min_type2_measure and res.verified_error < res.config.tolerance


def test_budget_exhausted_is_reported() -> None:
    res = plan_motion(
        GEOM, START, PAIRS["near_b"], PlannerConfig(max_iterations=1, initial_guesses=1, continuation=False)
    )
    assert res.status is PlanStatus.MAX_ITERATIONS
    assert "after 1 iterations" in res.message and res.final_error > 1e-3
    with pytest.raises(PlanningError, match="max_iterations"):
        res.raise_for_status()


def test_singular_goal_pose_is_reported() -> None:
    # bisect the segment start -> paper goal to a pose on det M = 0
    def interp(s: float) -> Pose:
        return Pose((1 - s) * START.p_m + s * GOAL.p_m, so3_exp(s * so3_log(GOAL.R @ START.R.T)) @ START.R)

    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if type2_measure(GEOM, interp(mid).p_m, interp(mid).R) < 0:
            lo = mid
        else:
            hi = mid
    res = plan_motion(GEOM, START, interp(lo))
    assert res.status is PlanStatus.BAD_GOAL  # the goal, not the start (it said singular_start)
    assert "type-II" in res.message


def test_leg_stroke_violation_is_reported(paper_plan) -> None:
    legs = paper_plan.legs_m
    lo = min(
        leg_lengths_batch(GEOM, START.p_m, START.R).min(), leg_lengths_batch(GEOM, GOAL.p_m, GOAL.R).min()
    )
    assert legs.min() < lo - 1e-3  # the plan dips below both end lengths
    narrow = NspuGeometry(
        GEOM.a_m,
        GEOM.r,
        GEOM.b_platform_m,
        GEOM.w4_platform,
        leg_min_m=lo - 1e-4,
        leg_max_m=legs.max() + 1e-3,
        length_unit_m=UNIT,
    )
    res = plan_motion(narrow, START, GOAL, PlannerConfig(check_type2=False))
    assert res.status is PlanStatus.LEG_STROKE
    assert "stroke" in res.message


def test_invalid_inputs_raise() -> None:
    with pytest.raises(PlanningError, match="gamma"):
        PlannerConfig(gamma=0.0)
    with pytest.raises(PlanningError, match="initial_guesses"):
        PlannerConfig(initial_guesses=0)
    with pytest.raises(PlanningError, match="plan_steps"):
        PlannerConfig(plan_steps=400, n_steps=100)
    with pytest.raises(PlanningError, match="initial_lambdas"):
        plan_motion(GEOM, START, GOAL, initial_lambdas=np.zeros(4))


def test_plots_written(tmp_path: Path, near_plans) -> None:
    from controller.robots.nspu.analysis import plot_plan, plot_singularity_loci

    paths = plot_plan(near_plans["near_a"], tmp_path)
    paths += plot_singularity_loci(GEOM, tmp_path, n_xy=21, n_z=2)
    assert len(paths) == 6
    for p in paths:
        assert p.suffix == ".png" and p.stat().st_size > 10_000


@pytest.mark.parametrize("goal_m", [(0.0, 0.0, 5.0), (1e300, 0.0, 0.3)])
def test_a_goal_out_of_reach_is_a_bad_goal_by_its_legs_without_numpys_warnings(goal_m):
    """``cheope plan --to 0,0,5,...`` said singular_start for the goal, and 1e300 m printed numpy's
    overflow warnings and "U joint degenerate" (an outside tester's)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = plan_motion(GEOM, START, Pose(np.array(goal_m), np.eye(3)))
    assert res.status is PlanStatus.BAD_GOAL
    assert res.message.startswith("goal pose p=") and "leg lengths" in res.message
