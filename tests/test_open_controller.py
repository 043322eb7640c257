"""The open controller: the problem assembled from a model, a cost and barriers (protocols).

The fused kernels of the built-in pairs and the protocol path must build the same QP; a user's
barrier and a user's model work without editing trustnav; bad parts are refused by name."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from trustnav.control import (
    FUSED_KERNELS,
    Barrier,
    DynamicsModel,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    MpcProblem,
    PedestrianBarrier,
    PositionTrackingCost,
    SingleIntegrator,
    VelocityTrackingCost,
    barrier,
    cbf_rows,
    h_quad,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _example(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


class Disk:
    """A static disk keep-out zone written against the Barrier protocol (not a trustnav class)."""

    def __init__(self, centre, radius, gamma=0.2):
        self.c, self.r, self.g = np.asarray(centre, dtype=float), radius, gamma

    def size(self):
        return 1

    def decay(self):
        return np.array([1.0 - self.g])

    def values(self, states, steps, dt):
        d = states[:, :2] - self.c
        grad = np.zeros((states.shape[0], 1, states.shape[1]))
        grad[:, 0, :2] = 2 * d
        return (np.sum(d * d, axis=1) - self.r**2)[:, None], grad


def _stage(prob, rng, bicycle):
    n_p = 3
    if bicycle:
        x0 = [5.0, 0.5, 0.1, 6.0]
        peds = rng.uniform([10, -8], [40, 8], size=(n_p, 2))
    else:
        x0 = rng.uniform(5, 45, 2)
        peds = rng.uniform(5, 45, size=(n_p, 2))
    prob.set_stage(x0, peds, rng.normal(0, 1, (n_p, 2)), rng.uniform(0, 1, n_p), [0.01, 0.2])


PAIRS = {
    "single_integrator": (SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=7)),
    "bicycle": (
        KinematicBicycle(),
        LaneTrackingCost(start=(0, 0), goal=(100, 0)),
        MpcConfig(horizon=7, dt=0.1, safety_radius=2.5),
    ),
    "bicycle_one_euler_step": (
        KinematicBicycle(integration_step=None),
        LaneTrackingCost(start=(0, 0), goal=(100, 0)),
        MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, timing="authors_code"),
    ),
}


@pytest.mark.parametrize("name", sorted(PAIRS))
@pytest.mark.parametrize("with_disk", [False, True])
def test_protocol_path_builds_the_same_qp_as_the_fused_kernel(name, with_disk):
    model, cost, cfg = PAIRS[name]
    barriers = [Disk((20.0, 2.0), 2.0)] if with_disk else []
    fused, parts = MpcProblem(model, cost, cfg, barriers), MpcProblem(model, cost, cfg, barriers)
    assert fused._fused is FUSED_KERNELS[(type(model), type(cost))]
    parts._fused = None  # force the protocol path: model.sensitivities, cost.evaluate, state_rows
    for seed in range(3):
        for prob in (fused, parts):
            _stage(prob, np.random.default_rng(seed), name != "single_integrator")
        u = np.random.default_rng(10 + seed).uniform(fused.ulo, fused.uhi, (cfg.horizon, 2))
        c1, c2 = fused.build(u), parts.build(u)
        assert c1 == pytest.approx(c2, rel=1e-10, abs=1e-10)
        for attr in ("xs", "sens", "H", "f", "A", "bl", "bu", "g"):
            np.testing.assert_allclose(getattr(fused, attr), getattr(parts, attr), rtol=1e-8, atol=1e-8, err_msg=attr)
        # and the plain numpy path (SLSQP reference) gives the same rows
        np.testing.assert_allclose(parts.constraints_np(u)[: parts.m_cbf], parts.g, rtol=1e-9, atol=1e-9)


def test_user_barrier_rows_follow_cbf_discrete_and_their_jacobian_matches_finite_differences():
    disk = Disk((20.0, 30.0), 3.0, gamma=0.25)
    prob = MpcProblem(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=5), [disk])
    prob.set_stage([18.0, 20.0], [[25.0, 25.0]], [[0.0, 1.0]], [0.5])
    u = np.random.default_rng(1).uniform(-5, 5, (5, 2))
    prob.build(u)
    xs = prob.model.rollout([18.0, 20.0], u, prob.config.dt)
    h = np.sum((xs - [20.0, 30.0]) ** 2, axis=1) - 9.0
    expected = h[1:] - 0.75 * h[:-1]  # cbf_discrete with gamma = 0.25
    rows = np.arange(5) * prob.n_obs + 1  # obstacle 1 (after the one pedestrian)
    np.testing.assert_allclose(prob.g[rows], expected, rtol=1e-12)
    a = prob.A[rows].copy()
    eps = 1e-6
    for i in range(u.size):
        du = np.zeros(u.size)
        du[i] = eps
        prob.build(u + du.reshape(u.shape))
        hi = prob.g[rows].copy()
        prob.build(u - du.reshape(u.shape))
        np.testing.assert_allclose((hi - prob.g[rows]) / (2 * eps), a[:, i], rtol=1e-5, atol=1e-6)


def test_pedestrian_barrier_is_h_quad_through_every_path():
    peds, vels = np.array([[3.0, 4.0], [-1.0, 2.0]]), np.array([[1.0, 0.0], [0.0, -1.0]])
    pb = PedestrianBarrier(peds, vels, [0.9, 0.5], radius=2.0)
    assert isinstance(pb, Barrier)
    states = np.array([[0.0, 0.0], [0.5, 0.5]])
    h, dh = pb.values(states, np.array([0, 2]), 0.1)
    q = peds[None] + np.array([0, 2])[:, None, None] * 0.1 * vels[None]
    np.testing.assert_allclose(h, [barrier(states[k], q[k], 2.0) for k in range(2)])
    np.testing.assert_allclose(h, np.sum((states[:, None] - q) ** 2, axis=2) - 4.0)
    np.testing.assert_allclose(dh[..., :2], 2 * (states[:, None] - q))
    assert h_quad(3.0, 4.0, 4.0) == 21.0
    rows = cbf_rows(np.array([[0.0, 0.0], [0.1, 0.0]]), peds, vels, [0.9, 0.5], 2.0, 0.1)
    h0, _ = pb.values(np.array([[0.0, 0.0]]), np.array([0]), 0.1)
    h1, _ = pb.values(np.array([[0.1, 0.0]]), np.array([1]), 0.1)
    np.testing.assert_allclose(rows[0], h1[0] - np.array([0.9, 0.5]) * h0[0])


def test_controller_keeps_out_of_a_user_barrier_and_reports_binding_obstacles():
    disk = Disk((20.0, 25.0), 4.0)
    ctl = MpcController(
        SingleIntegrator(), VelocityTrackingCost(goal=(20.5, 45)), MpcConfig(deadline=10.0), barriers=[disk]
    )
    x = np.array([20.0, 5.0])
    h_min = math.inf
    for _ in range(200):
        sol = ctl.step(x, np.zeros((0, 2)), None, [])
        x = x + sol.control * 0.05
        h_min = min(h_min, float(np.sum((x - disk.c) ** 2) - 16.0))
    assert h_min >= -1e-6  # the zone is never entered
    assert h_min < 1.0  # and it did bind: the path goes round it, close
    assert np.hypot(x[0] - 20.5, x[1] - 45) < 0.5  # and reaches the goal


class PlainUnicycle:
    """A model written against the Dynamics protocol only (no trustnav base class)."""

    nx, nu, name = 3, 2, "plain_unicycle"

    def step(self, x, u, dt):
        return np.array([x[0] + u[0] * math.cos(x[2]) * dt, x[1] + u[0] * math.sin(x[2]) * dt, x[2] + u[1] * dt])

    def jacobians(self, x, u, dt):
        c, s = math.cos(x[2]), math.sin(x[2])
        a = np.array([[1, 0, -u[0] * s * dt], [0, 1, u[0] * c * dt], [0, 0, 1]], dtype=float)
        b = np.array([[c * dt, 0], [s * dt, 0], [0, dt]], dtype=float)
        return a, b

    def input_bounds(self):
        return np.array([0.0, -1.0]), np.array([2.0, 1.0])


def test_a_protocol_model_without_the_base_class_is_wrapped_and_its_jacobians_are_used():
    cfg = MpcConfig(horizon=6, dt=0.1, safety_radius=1.0, deadline=10.0)
    ctl = MpcController(PlainUnicycle(), PositionTrackingCost(goal=(0.0, 10.0)), cfg)
    assert isinstance(ctl.model, DynamicsModel)
    p = ctl.problem
    p.set_stage([0.0, 0.0, math.pi / 2], [[0.0, 4.0]], None, [0.3])
    u = np.tile([1.0, 0.2], (6, 1))
    p.build(u)
    eps = 1e-6
    for i in range(u.size):  # the sensitivities (from the Jacobians) against finite differences
        du = np.zeros(u.size)
        du[i] = eps
        xp = p.states_np(u.ravel() + du)
        xm = p.states_np(u.ravel() - du)
        np.testing.assert_allclose((xp - xm) / (2 * eps), p.sens[:, :, i], atol=1e-6)
    x = np.array([0.0, 0.0, math.pi / 2])
    d_min = math.inf
    for _ in range(150):
        sol = ctl.step(x, [[0.3, 5.0]], None, [0.3])
        x = PlainUnicycle().step(x, sol.control, 0.1)
        d_min = min(d_min, float(np.hypot(x[0] - 0.3, x[1] - 5.0)))
    assert d_min >= 1.0 - 1e-3
    assert np.hypot(x[0], x[1] - 10.0) < 0.5


def test_bad_parts_are_refused_by_name():
    with pytest.raises(ValueError, match="model must follow the Dynamics protocol"):
        MpcController(object(), VelocityTrackingCost(goal=(1, 1)))
    with pytest.raises(ValueError, match="cost must follow the Cost protocol"):
        MpcController(SingleIntegrator(), object())
    with pytest.raises(ValueError, match=r"barriers\[0\] must follow the Barrier protocol"):
        MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(1, 1)), barriers=[object()])
    with pytest.raises(ValueError, match=r"barriers\[1\]\.decay\(\) must give 1 values 1 - gamma in \[0, 1\]"):
        MpcController(
            SingleIntegrator(), VelocityTrackingCost(goal=(1, 1)), barriers=[Disk((0, 0), 1), Disk((0, 0), 1, 1.5)]
        )
    with pytest.raises(ValueError, match="no MPC problem for model bicycle with cost VelocityTrackingCost"):
        MpcController(KinematicBicycle(), VelocityTrackingCost(goal=(1, 1)))
    with pytest.raises(ValueError, match="position_weight must be > 0"):
        PositionTrackingCost(goal=(1, 1), position_weight=0.0)


def test_deprecated_problem_classes_still_work_and_warn():
    from trustnav.control import BicycleProblem, SingleIntegratorProblem

    with pytest.warns(DeprecationWarning, match="use MpcProblem"):
        p = SingleIntegratorProblem(SingleIntegrator(), VelocityTrackingCost(goal=(1, 1)), MpcConfig())
    assert isinstance(p, MpcProblem)
    with pytest.warns(DeprecationWarning, match="use MpcProblem"):
        BicycleProblem(KinematicBicycle(), LaneTrackingCost(start=(0, 0), goal=(1, 0)), MpcConfig())


def test_custom_barrier_example_keeps_out_of_the_ellipse():
    out = _example("custom_barrier").main([])
    assert out["zone_barrier_min"] >= -1e-6  # the works area is never entered
    assert out["largest_lateral_offset_m"] > 1.0  # the car went round it
    assert out["pedestrian_min_distance_m"] >= out["safety_radius_m"]
    assert out["relaxed_steps"] == 0
    assert out["time_to_goal_s"] < 14.0


def test_custom_dynamics_example_keeps_r_and_trust_widens_the_pass():
    out = _example("custom_dynamics").main([])
    r = out["safety_radius_m"]
    assert out["attentive_min_distance_m"] >= r - 1e-3
    assert out["distracted_min_distance_m"] >= r - 1e-3
    # `weight`: the distracted pedestrian (low trust, small gamma) is passed wider
    assert out["distracted_min_distance_m"] > out["attentive_min_distance_m"] + 0.3
    assert out["relaxed_steps"] == 0
    assert out["time_to_goal_s"] < 25.0


@pytest.mark.parametrize("solver_name", ["sqp", "slsqp", "slsqp-authors"])
def test_every_solver_respects_a_user_barrier(solver_name):
    from trustnav.control import make_solver

    disk = Disk((20.3, 8.0), 2.0)  # a little off the straight path (dead ahead is a saddle for SLSQP)
    prob = MpcProblem(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=7), [disk])
    prob.set_stage([20.0, 5.0], [[30.0, 30.0]], None, [0.5])
    res = make_solver(solver_name).solve(prob, prob.initial_guess(), deadline=10.0)
    rows = prob.constraints_np(res.inputs)
    assert res.status.value == "optimal", res.message
    assert rows[1 :: prob.n_obs].min() >= -1e-6  # the disk's rows hold
    assert res.cbf_violation == pytest.approx(max(0.0, -rows[: prob.m_cbf].min()), abs=1e-9)
    free = MpcProblem(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=7))
    free.set_stage([20.0, 5.0], [[30.0, 30.0]], None, [0.5])
    assert free.constraints_np(free.initial_guess()).min() >= 0  # without the disk, the straight plan is fine
    assert prob.constraints_np(prob.initial_guess())[1 :: prob.n_obs].min() < 0  # with it, it is not
