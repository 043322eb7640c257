"""The control step's fast paths give what the general code gives."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.control import (
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    SingleIntegrator,
    VelocityTrackingCost,
)
from trustnav.control.problem import MpcProblem
from trustnav.control.reference import BoundedProportionalReference


@pytest.mark.parametrize("mode", ["rollout", "hold"])
def test_compiled_stage_matches_the_general_code(mode):
    cost = VelocityTrackingCost(goal=(20, 45), reference=BoundedProportionalReference(1.5, 10.0, mode))
    x = np.array([1e6 + 20.0, -3e5 + 5.0])
    peds = np.array([[1e6 + 19.0, -3e5 + 20.0], [1e6 + 22.0, -3e5 + 28.0]])
    vels = np.array([[0.5, -0.1], [0.0, 0.3]])
    tr = np.array([0.2, 0.9])
    out = []
    for fast in (True, False):
        p = MpcProblem(SingleIntegrator(), cost, MpcConfig(horizon=7))
        p._velocity_stage = fast
        p.set_checked_stage(x, peds, vels, tr, np.array([1.0, 2.0]), np.array([0.1, 0.0]))
        out.append((p.x0, p.origin, p.peds, p.one_minus_gamma, p.stage, p.radii, p.r2, p.u_prev))
    for a, b in zip(*out, strict=True):
        assert np.array_equal(a, b)


def test_compiled_stage_refuses_bad_data_with_the_same_messages():
    p = MpcProblem(SingleIntegrator(), VelocityTrackingCost(goal=(0, 20)), MpcConfig(horizon=7))
    peds, vels = np.array([[1.0, 2.0]]), np.zeros((1, 2))
    with pytest.raises(ValueError, match="beyond"):
        p.set_checked_stage(np.array([2e12, 0.0]), peds, vels, np.array([0.5]))
    with pytest.raises(ValueError, match="trust"):
        p.set_checked_stage(np.array([0.0, 0.0]), peds, vels, np.array([1.5]))
    ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(0, 20)), MpcConfig(horizon=7))
    with pytest.raises(ValueError, match="pedestrians must be finite"):
        ctl.step([0.0, 0.0], [[1.0, np.nan]], None, [0.5])
    with pytest.raises(ValueError, match="state must be 2 finite numbers"):
        ctl.step([0.0, np.inf], [[1.0, 2.0]], None, [0.5])


def test_converged_step_reports_the_exact_check():
    ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=7))
    x = np.array([20.0, 5.0])
    peds, tr = np.array([[19.0, 20.0], [22.0, 28.0]]), np.array([0.3, 0.8])
    for _ in range(30):
        sol = ctl.step(x, peds, None, tr)
        chk = ctl.problem.evaluate(sol.inputs)
        assert sol.cbf_violation == pytest.approx(chk.worst, abs=1e-12)
        assert sol.first_row_violation == pytest.approx(chk.first_row, abs=1e-12)
        assert np.allclose(sol.predicted_states, SingleIntegrator().rollout(x, sol.inputs, 0.05))
        x = SingleIntegrator().step(x, sol.control, 0.05)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), horizon=st.integers(1, 12))
def test_the_bicycles_compiled_qp_is_the_lane_costs_gauss_newton_model(seed, horizon):
    """The fused bicycle kernel sums its gradient and Hessian over the rows that can be nonzero
    only; they are the lane cost's Gauss-Newton model in numpy (every row, J' W J)."""
    rng = np.random.default_rng(seed)
    cost = LaneTrackingCost(start=(0.0, 0.0), goal=(0.0, 80.0))
    p = MpcProblem(KinematicBicycle(), cost, MpcConfig(horizon=horizon))
    state = [rng.uniform(-2.0, 2.0), rng.uniform(0.0, 20.0), rng.uniform(1.2, 1.9), rng.uniform(0.0, 10.0)]
    p.set_stage(state, np.zeros((0, 2)), None, [], u_prev=rng.uniform([-0.5, -3.0], [0.5, 3.0]))
    u = rng.uniform([-0.5, -5.0], [0.5, 2.0], (horizon, 2))
    value = p.build(u)
    h, g = np.empty_like(p.H), np.empty_like(p.f)
    want = cost.evaluate(p.stage, p.xs, p.sens, u, p.u_prev, h, g)
    assert value == pytest.approx(want, rel=1e-12)
    np.testing.assert_allclose(p.f, g, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p.H, h, rtol=1e-9, atol=1e-9)
