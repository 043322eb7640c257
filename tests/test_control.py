"""MPC-CBF building blocks: barrier, analytic Jacobians, solvers, statuses, validation."""

from __future__ import annotations

import numpy as np
import pytest

from trustnav.control import (
    BoundedProportionalReference,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    MpcProblem,
    SingleIntegrator,
    SlsqpSolver,
    SolveStatus,
    SqpSolver,
    VelocityTrackingCost,
    barrier,
    cbf_rows,
    make_problem,
)


def _si_problem(timing="paper", n_h=7, n_p=3, seed=0):
    rng = np.random.default_rng(seed)
    cfg = MpcConfig(horizon=n_h, timing=timing)
    prob = MpcProblem(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), cfg)
    peds = rng.uniform(5, 45, size=(n_p, 2))
    prob.set_stage(rng.uniform(5, 45, 2), peds, rng.normal(0, 1, (n_p, 2)), rng.uniform(0, 1, n_p))
    return prob, rng


def _bike_problem(timing="paper", n_h=7, n_p=3, seed=0, integration_step=0.01):
    rng = np.random.default_rng(seed)
    cfg = MpcConfig(horizon=n_h, dt=0.1, safety_radius=2.5, timing=timing)
    model = KinematicBicycle(integration_step=integration_step)
    prob = MpcProblem(model, LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg)
    peds = rng.uniform([10, -8], [40, 8], size=(n_p, 2))
    prob.set_stage([5.0, 0.5, 0.1, 6.0], peds, rng.normal(0, 1, (n_p, 2)), rng.uniform(0, 1, n_p), [0.01, 0.2])
    return prob, rng


def test_barrier_and_cbf_rows_follow_h_quad_and_cbf_imp():
    assert barrier([0.0, 0.0], [[3.0, 4.0]], 3.0)[0] == pytest.approx(25 - 9)
    ego = np.array([[0.0, 0.0], [1.0, 0.0]])
    ped, vel = np.array([[5.0, 0.0]]), np.array([[-10.0, 0.0]])
    dt, omg = 0.1, np.array([0.9])
    # paper timing: pedestrian at k+1 = (4, 0) in h(k+1)
    assert cbf_rows(ego, ped, vel, omg, 1.0, dt, "paper")[0, 0] == pytest.approx((9 - 1) - 0.9 * (25 - 1))
    # authors' code: pedestrian at k = (5, 0) in both terms
    assert cbf_rows(ego, ped, vel, omg, 1.0, dt, "authors_code")[0, 0] == pytest.approx((16 - 1) - 0.9 * (25 - 1))


def _bike_euler_problem(timing="paper", n_h=7, n_p=3, seed=0):
    return _bike_problem(timing, n_h, n_p, seed, integration_step=None)


@pytest.mark.parametrize("maker", [_si_problem, _bike_problem, _bike_euler_problem])
@pytest.mark.parametrize("timing", ["paper", "authors_code"])
def test_compiled_qp_matches_numpy_problem_and_finite_differences(maker, timing):
    prob, rng = maker(timing)
    u = prob.initial_guess() + rng.normal(0, 0.3, (prob.n_h, 2))
    u = np.clip(u, prob.ulo, prob.uhi)
    cost = prob.build(u)
    assert cost == pytest.approx(prob.cost_np(u), rel=1e-10, abs=1e-10)
    rows_np = prob.constraints_np(u)
    np.testing.assert_allclose(prob.g, rows_np[: prob.m_cbf], rtol=1e-10, atol=1e-9)
    eps = 1e-6
    flat = u.ravel()
    jac_fd = np.empty((prob.m_cbf, prob.n))
    grad_fd = np.empty(prob.n)
    for i in range(prob.n):
        up, dn = flat.copy(), flat.copy()
        up[i] += eps
        dn[i] -= eps
        jac_fd[:, i] = (prob.constraints_np(up)[: prob.m_cbf] - prob.constraints_np(dn)[: prob.m_cbf]) / (2 * eps)
        grad_fd[i] = (prob.cost_np(up) - prob.cost_np(dn)) / (2 * eps)
    np.testing.assert_allclose(prob.A[: prob.m_cbf], jac_fd, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(prob.f, grad_fd, rtol=1e-5, atol=1e-5)


def test_bicycle_first_cbf_row_depends_on_the_first_input_only_with_substeps():
    euler, _ = _bike_euler_problem()
    euler.build(euler.initial_guess())
    np.testing.assert_array_equal(euler.A[: euler.n_p], 0.0)  # one Euler step: decided by the state
    assert euler.n_decided == euler.n_p
    fine, _ = _bike_problem()
    fine.build(fine.initial_guess())
    assert fine.n_decided == 0
    assert np.abs(fine.A[: fine.n_p, :2]).max() > 1e-3  # u_0 moves x(1) within the step
    np.testing.assert_array_equal(fine.A[: fine.n_p, 2:], 0.0)  # later inputs do not


def test_bicycle_step_follows_the_continuous_car_on_a_curve():
    """`f_e` with 10 ms sub-steps stays within a centimetre of the continuous bicycle (integrated
    at 0.01 ms) over one 0.1 s step at 8 m/s, full lock and full throttle; one Euler step is
    8 cm off, which is how a car breaches R while every predicted CBF row holds."""
    x0, u = np.array([0.0, 0.0, 0.3, 8.0]), np.array([np.radians(35.0), 3.0])
    truth = KinematicBicycle(integration_step=1e-5).step(x0, u, 0.1)
    fine = KinematicBicycle().step(x0, u, 0.1)
    euler = KinematicBicycle(integration_step=None).step(x0, u, 0.1)
    assert np.linalg.norm(fine[:2] - truth[:2]) < 0.01
    assert np.linalg.norm(euler[:2] - truth[:2]) > 0.07
    # the error is first order in the sub-step: the 1 ms plant of the reliability study is 10 x closer
    plant = KinematicBicycle(integration_step=1e-3).step(x0, u, 0.1)
    assert np.linalg.norm(plant[:2] - truth[:2]) < 0.15 * np.linalg.norm(fine[:2] - truth[:2])
    # a plant in 10 ms steps is the controller's model exactly
    plant = x0
    for _ in range(10):
        plant = KinematicBicycle().step(plant, u, 0.01)
    np.testing.assert_allclose(plant, fine, atol=1e-12)


@pytest.mark.parametrize("maker", [_si_problem, _bike_problem])
@pytest.mark.parametrize("seed", [0, 4])  # feasible draws (others put a walker inside the margin)
def test_sqp_and_slsqp_reach_the_same_optimum(maker, seed):
    prob, _ = maker(n_p=2, seed=seed)
    fast = SqpSolver().solve(prob, prob.initial_guess())
    ref = SlsqpSolver().solve(prob, prob.initial_guess())
    assert fast.status is SolveStatus.OPTIMAL, fast.message
    assert ref.status is SolveStatus.OPTIMAL, ref.message
    assert fast.cost == pytest.approx(ref.cost, rel=1e-4, abs=1e-6)
    np.testing.assert_allclose(fast.inputs, ref.inputs, atol=1e-3)


def test_controller_accepts_changing_pedestrian_counts():
    cfg = MpcConfig(horizon=5, deadline=10.0)
    ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), cfg)
    x = np.array([20.0, 5.0])
    for n_p in (0, 1, 3, 2, 0):
        peds = np.column_stack([np.linspace(15, 25, n_p), np.full(n_p, 20.0)])
        sol = ctl.step(x, peds, np.zeros((n_p, 2)), np.full(n_p, 0.5))
        assert sol.status is SolveStatus.OPTIMAL
        assert sol.inputs.shape == (5, 2)
        x = SingleIntegrator().step(x, sol.control, cfg.dt)


def test_pedestrian_inside_margin_is_reported_and_not_silent():
    """A pedestrian appearing inside R in front of a fast bicycle: with one Euler step per dt the
    first CBF row is fixed by the current state (no input changes the next position), so it is
    reported as decided, not hidden; with sub-steps it is relaxed and says so. Either way the plan
    brakes."""
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, deadline=10.0)
    fine = MpcController(KinematicBicycle(), LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg)
    sol = fine.step([10.0, 0.0, 0.0, 10.0], [[11.5, 0.5]], [[0.0, 0.0]], [0.0])
    assert sol.status is SolveStatus.RELAXED and sol.slack_used and sol.first_row_violation > 1.0
    assert "relaxed" in sol.message
    assert sol.control[1] == pytest.approx(KinematicBicycle().accel_min)
    model = KinematicBicycle(integration_step=None)
    ctl = MpcController(model, LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg)
    sol = ctl.step([10.0, 0.0, 0.0, 10.0], [[11.5, 0.5]], [[0.0, 0.0]], [0.0])
    # row k = 0: ||(11, 0) - (11.5, 0.5)||^2 - R^2 - (1 - gamma)(||(10, 0) - ped||^2 - R^2), gamma = 0.03
    expected = (0.5 - 6.25) - 0.97 * (2.5 - 6.25)
    assert sol.decided_violation == pytest.approx(-expected)
    assert "fixed by the current state" in sol.message
    assert sol.control[1] < 0  # decelerating
    assert not sol.fallback


def test_invalid_inputs_and_configs_raise_clear_errors():
    with pytest.raises(ValueError, match="horizon N_h must be an integer >= 1"):
        MpcConfig(horizon=0)
    with pytest.raises(ValueError, match="timing must be one of"):
        MpcConfig(timing="later")
    with pytest.raises(ValueError, match="reference gain Kp"):
        BoundedProportionalReference(gain=0.0)
    with pytest.raises(ValueError, match="no MPC problem for model"):
        make_problem(SingleIntegrator(), LaneTrackingCost(start=(0, 0), goal=(1, 0)), MpcConfig())
    ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)))
    with pytest.raises(ValueError, match="one entry each"):
        ctl.step([0.0, 0.0], [[1.0, 1.0], [2.0, 2.0]], None, [0.5])
    with pytest.raises(ValueError, match=r"trust must lie in \[0, 1\]"):
        ctl.step([0.0, 0.0], [[1.0, 1.0]], None, [1.5])
    with pytest.raises(ValueError, match="single_integrator state must be 2 finite numbers"):
        ctl.step([0.0, np.nan], [[1.0, 1.0]], None, [0.5])


def test_reference_is_bounded_and_proportional():
    ref = BoundedProportionalReference(gain=1.5, v_max=10.0)
    np.testing.assert_allclose(ref.velocity([0, 0], [0, 2]), [0, 3])
    assert np.linalg.norm(ref.velocity([0, 0], [30, 40])) == pytest.approx(10.0)
    v = ref.velocities([0, 0], [0, 2], 20, 0.05)
    assert np.all(np.diff(v[:, 1]) < 0)  # rollout slows down along the horizon


# ---- issue 21 item 7: the bicycle's v >= 0 and a deterministic (iteration-budget) mode ----


class _PlanSolver:
    """A solver that returns a fixed plan as OPTIMAL (to drive the controller's checks)."""

    def __init__(self, plan):
        self.plan = np.asarray(plan, dtype=float)
        self.deadlines = []

    def solve(self, problem, u0, deadline=None):
        from trustnav.control.solvers import SolveResult, SolveStatus

        self.deadlines.append(deadline)
        return SolveResult(self.plan.copy(), SolveStatus.OPTIMAL, 1, 0.0, 0.0, False)


def test_bicycle_plan_below_rest_is_never_applied_unflagged():
    from trustnav.control import KinematicBicycle, LaneTrackingCost

    model = KinematicBicycle()
    plan = np.tile([0.0, -6.0], (7, 1))  # full braking from 1 m/s: v < 0 from the second step on
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5)
    ctl = MpcController(model, LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg, _PlanSolver(plan))
    sol = ctl.step([0.0, 0.0, 0.0, 1.0], np.zeros((0, 2)), None, [])
    assert model.state_limit_violation(model.rollout([0.0, 0.0, 0.0, 1.0], plan, 0.1)) > 0.5
    assert sol.state_repaired and "state limits" in sol.message
    assert sol.state_violation <= 1e-6
    assert sol.predicted_states[:, 3].min() >= -1e-9  # stops at rest, never reverses
    np.testing.assert_allclose(sol.predicted_states, model.rollout([0.0, 0.0, 0.0, 1.0], sol.inputs, 0.1))
    # a plan that keeps v >= 0 is applied as it is, unflagged
    keep = np.tile([0.0, -1.0], (7, 1))
    ctl2 = MpcController(model, LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg, _PlanSolver(keep))
    sol2 = ctl2.step([0.0, 0.0, 0.0, 5.0], np.zeros((0, 2)), None, [])
    assert not sol2.state_repaired and sol2.state_violation == 0.0
    np.testing.assert_array_equal(sol2.inputs, keep)


def test_bicycle_repair_plan_stops_at_rest_within_bounds():
    from trustnav.control import KinematicBicycle

    model = KinematicBicycle()
    u = np.array([[0.1, -6.0], [0.0, -6.0], [0.0, 2.0], [0.0, -6.0]])
    fixed = model.repair_plan([0.0, 0.0, 0.0, 0.9], u, 0.1)
    v = model.rollout([0.0, 0.0, 0.0, 0.9], fixed, 0.1)[:, 3]
    assert v.min() >= -1e-9 and fixed[0, 1] == pytest.approx(-6.0)  # 0.9 -> 0.3 m/s: kept
    assert fixed[1, 1] == pytest.approx(-3.0) and fixed[2, 1] == 2.0  # brakes to rest, keeps the rest
    np.testing.assert_array_equal(fixed[:, 0], u[:, 0])


def test_deterministic_mode_ignores_the_wall_clock():
    """With deterministic=True a step's result is the same however short the deadline (the
    solver gets none); in the default mode a deadline of 1 ns cuts the solve short."""
    from trustnav.control import SqpSolver

    peds, trusts = np.array([[19.0, 20.0], [22.0, 28.0]]), [0.3, 0.9]

    def run(deadline, deterministic):
        cfg = MpcConfig(horizon=7, dt=0.05, safety_radius=3.0, deadline=deadline, deterministic=deterministic)
        ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), cfg, SqpSolver())
        x, out = np.array([20.0, 5.0]), []
        for _ in range(30):
            sol = ctl.step(x, peds, None, trusts)
            out.append((sol.inputs, sol.status, sol.deadline_hit))
            x = x + sol.control * 0.05
        return out

    ref, fast = run(10.0, False), run(1e-9, True)
    for (u_r, s_r, _), (u_f, s_f, hit) in zip(ref, fast, strict=True):
        np.testing.assert_array_equal(u_r, u_f)
        assert s_r is s_f and not hit
    assert any(hit for *_, hit in run(1e-9, False))
    spy = _PlanSolver(np.zeros((7, 2)))
    cfg = MpcConfig(horizon=7, dt=0.05, deterministic=True)
    MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), cfg, spy).step([0, 0], [[5, 5]], None, [1])
    assert spy.deadlines == [None]
    with pytest.raises(ValueError, match="deterministic"):
        MpcConfig(deterministic=1)
