"""The per-step speed work of issue 22 keeps the exact problem: compiled helpers reproduce the
Python arithmetic they replace, and the SQP's full-step fast path takes the general loop's iterates."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from trustnav.control import (
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    SingleIntegrator,
    SqpSolver,
    VelocityTrackingCost,
)
from trustnav.control.models import DynamicsModel
from trustnav.control.reference import BoundedProportionalReference

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def test_compiled_rollouts_match_the_step_loop():
    rng = np.random.default_rng(3)
    bike = KinematicBicycle()
    x0 = np.array([1.0, -2.0, 0.3, 7.0])
    u = np.column_stack([rng.uniform(-0.6, 0.6, 12), rng.uniform(-6, 3, 12)])
    # DynamicsModel.rollout is the generic loop over KinematicBicycle.step
    assert np.array_equal(bike.rollout(x0, u, 0.1), DynamicsModel.rollout(bike, x0, u, 0.1))
    si = SingleIntegrator()
    us = rng.uniform(-5, 5, (9, 2))
    expected = np.vstack([[4.0, 5.0], np.cumsum(us * 0.05, axis=0) + [4.0, 5.0]])
    assert np.array_equal(si.rollout([4.0, 5.0], us, 0.05), expected)


def test_compiled_lane_waypoints_match_the_python_loop():
    ref = BoundedProportionalReference(gain=0.5, v_max=8.0)
    pts, yaw, speeds = ref.lane_waypoints([3.0, 0.7], [0.0, 0.0], [40.0, 10.0], 15, 0.1)
    a, b = np.array([0.0, 0.0]), np.array([40.0, 10.0])
    length = float(np.hypot(*(b - a)))
    t_hat = (b - a) / length
    s = float(np.clip(np.array([3.0, 0.7]) @ t_hat, 0.0, length))
    for k in range(16):
        assert speeds[k] == min(8.0, 0.5 * (length - s))
        assert np.array_equal(pts[k], a + s * t_hat)
        s = min(length, s + speeds[k] * 0.1)
    assert np.all(yaw == np.arctan2(t_hat[1], t_hat[0]))


def _closed_loop(model, cost, cfg, peds, trusts, x0, steps, solver):
    ctl = MpcController(model, cost, cfg, solver)
    x, out = np.array(x0, dtype=float), []
    for _ in range(steps):
        sol = ctl.step(x, peds, None, trusts)
        out.append((sol.inputs.copy(), sol.status, sol.recovered, sol.fallback))
        x = model.step(x, sol.control, cfg.dt)
    return out


@pytest.mark.parametrize("case", ["paper-like", "crowded", "bicycle"])
def test_compiled_sqp_loop_takes_the_general_loops_path(monkeypatch, case):
    """The compiled SQP iterations (DAQP's C API from a numba loop) against the general Python
    loop they replace: the same statuses, recoveries and fallbacks, plans within the solver's
    tolerance (crowded: pedestrians on the path, so QPs turn infeasible and the recovery runs)."""
    rng = np.random.default_rng(1)
    if case == "bicycle":
        model, x0 = KinematicBicycle(), [0.0, 0.0, 0.0, 8.0]
        peds = np.column_stack([rng.uniform(6, 40, 10), rng.choice([-1, 1], 10) * rng.uniform(2.8, 8, 10)])
        cost = LaneTrackingCost(start=(0, 0), goal=(100, 0))
        cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, deadline=10.0)
    else:
        model, x0, cost = SingleIntegrator(), [20.0, 5.0], VelocityTrackingCost(goal=(20, 45))
        if case == "crowded":
            peds, n_h = np.column_stack([rng.uniform(15, 25, 10), rng.uniform(12, 30, 10)]), 20
        else:
            peds, n_h = np.array([[19.0, 20.0], [22.0, 28.0]]), 7
        cfg = MpcConfig(horizon=n_h, dt=0.05, safety_radius=3.0, deadline=10.0)  # no wall-clock cut
    trusts = rng.uniform(0, 1, len(peds))
    compiled = _closed_loop(model, cost, cfg, peds, trusts, x0, 60, SqpSolver())
    monkeypatch.setattr(SqpSolver, "_compiled_budget", lambda self, p, until: None)  # no compiled loop at all
    general = _closed_loop(model, cost, cfg, peds, trusts, x0, 60, SqpSolver())
    for (uc, sc, rc, fc), (ug, sg, rg, fg) in zip(compiled, general, strict=True):
        assert sc is sg and rc == rg and fc == fg
        assert np.allclose(uc, ug, rtol=0, atol=1e-6), np.abs(uc - ug).max()
    if case == "crowded":
        assert any(r for _, _, r, _ in compiled), "the crowded world should exercise the recovery"


def test_compiled_loop_is_used_and_hands_infeasible_qps_over():
    """The compiled loop runs once DAQP's workspace exists, and an infeasible QP at its iterate
    reaches the general loop's recovery (a hard-feasible plan comes back)."""
    from trustnav.control import _qp

    if not _qp.AVAILABLE:
        pytest.skip("DAQP's C API layout differs: the Python path is used")
    model, cost = SingleIntegrator(), VelocityTrackingCost(goal=(0, 20))
    ctl = MpcController(model, cost, MpcConfig(horizon=7, dt=0.05, safety_radius=3.0, deadline=10.0))
    calls = []
    original = type(ctl.problem).compiled_steps

    def spy(self, *args):
        out = original(self, *args)
        calls.append(out[1])  # state: 1 converged, 0 iteration limit, -1 infeasible QP
        return out

    ctl.problem.compiled_steps = spy.__get__(ctl.problem)
    ctl.step([0.0, 0.0], [[30.0, 30.0]], None, [0.5])  # sets DAQP up through the general loop
    calls.clear()
    # a pedestrian right ahead: the straight plan's QP linearisation is infeasible at first
    sol = ctl.step([0.0, 0.0], [[0.0, 3.2]], None, [0.5])
    assert calls == [-1], "the compiled loop should meet the infeasible QP and hand it over"
    assert sol.recovered and sol.cbf_violation <= 1e-6 and not sol.fallback


def _bench():
    sys.path.insert(0, str(BENCH))
    try:
        import bench_mpc
    finally:
        sys.path.pop(0)
    return bench_mpc


def test_bench_mpc_runs_without_casadi_and_says_so():
    row = _bench().run_case("single_integrator", 2, 3, "paper-2", steps=3, baseline_steps=0, casadi=False)
    assert row["casadi_sqp_median_ms"] is None and row["ipopt_median_ms"] is None
    assert row["casadi_version"] is None
    assert row["default_p95_ms"] >= row["default_median_ms"] > 0 and row["floor_median_ms"] > 0


def test_bench_mpc_casadi_problem_agrees_with_trustnav():
    pytest.importorskip("casadi")
    bench = _bench()
    for model in ("single_integrator", "bicycle"):
        row = bench.run_case(model, 2, 5, 1, steps=4, baseline_steps=0)
        assert row["ipopt_failures"] == 0, row
        # the independently written problem has the same solution (IPOPT, to its tolerance)
        assert row["ipopt_max_input_diff"] < 1e-5, row
        assert row["casadi_sqp_median_ms"] > 0 and row["casadi_sqp_p95_ms"] >= row["casadi_sqp_median_ms"]


def test_lane_cost_bicycle_controller_still_plans_within_bounds():
    model = KinematicBicycle()
    cost = LaneTrackingCost(start=(0, 0), goal=(100, 0))
    ctl = MpcController(model, cost, MpcConfig(horizon=7, dt=0.1, safety_radius=2.5))
    sol = ctl.step([0.0, 0.0, 0.0, 8.0], [[12.0, 1.0]], None, [0.2])
    lo, hi = model.input_bounds()
    assert np.all(sol.inputs >= lo - 1e-9) and np.all(sol.inputs <= hi + 1e-9)
    assert np.allclose(sol.predicted_states, DynamicsModel.rollout(model, [0.0, 0.0, 0.0, 8.0], sol.inputs, 0.1))


def _count_whole_steps(monkeypatch) -> list[bool]:
    """Records, per call of MpcProblem.whole_step, whether it took the step (True) or handed it
    to the general path."""
    from trustnav.control.problem import MpcProblem

    taken: list[bool] = []
    original = MpcProblem.whole_step

    def spy(self, *args):
        out = original(self, *args)
        taken.append(out is not None)
        return out

    monkeypatch.setattr(MpcProblem, "whole_step", spy)
    return taken


def _whole_loop(whole: bool, worlds, cfg, x0, steps_each):
    """Closed loop of a single-integrator controller over a sequence of worlds (pedestrians,
    velocities, trusts), with the whole-step path on or off; each step's full solution."""
    model, cost = SingleIntegrator(), VelocityTrackingCost(goal=(20, 45))
    ctl = MpcController(model, cost, cfg, SqpSolver())
    ctl._whole = whole
    x, out, k = np.array(x0, dtype=float), [], 0
    for peds, vels, trusts in worlds:
        for _ in range(steps_each):
            sol = ctl.step(x, peds + k * cfg.dt * vels, vels, trusts)
            out.append(sol)
            x = model.step(x, sol.control, cfg.dt)
            k += 1
    return out


def test_whole_step_is_the_general_step_bit_for_bit(monkeypatch):
    """The whole control step in one compiled call (stage data, warm start, SQP, check, rollout)
    returns what the general path returns, to the bit, over closed loops with moving pedestrians,
    recoveries (a crowd on the path) and a pedestrian count that changes; and it is the path
    taken in most steps. Where it gives a step up (a recovery), DAQP's warm start is restored, so
    the general path's result is unchanged too."""
    from trustnav.control import _qp

    if not _qp.AVAILABLE:
        pytest.skip("DAQP's C API layout differs: the Python path is used")
    rng = np.random.default_rng(1)
    crowd = np.column_stack([rng.uniform(15, 25, 10), rng.uniform(12, 30, 10)])
    trusts = rng.uniform(0, 1, 10)
    moving = rng.normal(0.0, 0.3, crowd.shape)
    worlds = [(crowd, 0 * moving, trusts), (crowd[:6], moving[:6], trusts[:6]), (crowd[6:], moving[6:], trusts[6:])]
    cfg = MpcConfig(horizon=20, dt=0.05, safety_radius=3.0, deterministic=True)
    taken = _count_whole_steps(monkeypatch)
    fast = _whole_loop(True, worlds, cfg, [20.0, 5.0], 40)
    assert sum(taken) >= 0.8 * len(fast) and not all(taken), "most steps whole, some handed to the general path"
    asked = len(taken)
    general = _whole_loop(False, worlds, cfg, [20.0, 5.0], 40)
    assert len(taken) == asked + 1, "with the whole step off, only the warm-up loads it"
    for a, b in zip(fast, general, strict=True):
        assert np.array_equal(a.inputs, b.inputs) and np.array_equal(a.predicted_states, b.predicted_states)
        assert (a.status, a.iterations, a.cbf_violation, a.first_row_violation, a.recovered, a.detour) == (
            b.status, b.iterations, b.cbf_violation, b.first_row_violation, b.recovered, b.detour
        )  # fmt: skip
    assert any(s.recovered for s in general), "the crowd should exercise the recovery"


def test_whole_step_refuses_bad_input_and_takes_other_arrays_as_the_general_step():
    """Bad values reaching the compiled step are refused with the general path's messages;
    integers, float32, lists and non-contiguous views give the float64 step's plan, and the
    compiled call gains no new signature (nothing is compiled inside a control loop)."""
    from trustnav.control import _qp

    cfg = MpcConfig(horizon=7, dt=0.05, safety_radius=3.0, deterministic=True)
    peds, trusts = np.array([[19.0, 20.0], [22.0, 28.0]]), np.array([0.2, 0.9])

    def warm():
        ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), cfg)
        for _ in range(3):
            ctl.step(np.array([20.0, 5.0]), peds, np.zeros((2, 2)), trusts)
        return ctl

    ctl = warm()
    with pytest.raises(ValueError, match="pedestrians must be finite"):
        ctl.step(np.array([20.0, 5.0]), np.array([[19.0, np.nan], [22.0, 28.0]]), np.zeros((2, 2)), trusts)
    with pytest.raises(ValueError, match="velocities must be finite"):
        ctl.step(np.array([20.0, 5.0]), peds, np.array([[0.0, np.inf], [0.0, 0.0]]), trusts)
    with pytest.raises(ValueError, match=r"trust"):
        ctl.step(np.array([20.0, 5.0]), peds, np.zeros((2, 2)), np.array([0.2, 1.5]))
    with pytest.raises(ValueError, match="state must be 2 finite numbers"):
        ctl.step(np.array([20.0, np.nan]), peds, np.zeros((2, 2)), trusts)
    with pytest.raises(ValueError, match="beyond"):
        ctl.step(np.array([2e12, 5.0]), peds, np.zeros((2, 2)), trusts)
    signatures = len(_qp.single_integrator_step.signatures)
    reference = warm().step(np.array([20.0, 5.5]), peds, np.zeros((2, 2)), trusts).inputs
    wide = np.zeros((2, 4))
    wide[:, ::2] = peds
    for args in (
        (np.array([20, 5.5]), peds.astype(np.float32), np.zeros((2, 2), dtype=int), trusts),
        ([20.0, 5.5], peds.tolist(), None, trusts.tolist()),
        (np.array([20.0, 5.5]), wide[:, ::2], np.zeros((2, 2)), trusts),
        (np.array([20.0, 5.5]), np.asfortranarray(peds), np.zeros((2, 2)), np.repeat(trusts, 2)[::2]),
    ):
        got = warm().step(*args).inputs
        assert np.allclose(got, reference, rtol=0, atol=1e-9), args
    assert len(_qp.single_integrator_step.signatures) == signatures


def test_whole_bicycle_step_is_the_general_step_bit_for_bit(monkeypatch):
    """The bicycle's whole step in one compiled call (lane reference, warm start, SQP with its line
    search, check, state limits, predicted states) against the general path, to the bit, over a
    closed loop on a lane with pedestrians stepping towards it (infeasible linearisations hand
    steps over); most steps take the whole call."""
    from trustnav.control import _qp

    if not _qp.AVAILABLE:
        pytest.skip("DAQP's C API layout differs: the Python path is used")
    rng = np.random.default_rng(2)
    peds = np.column_stack([rng.uniform(6, 40, 10), rng.choice([-1, 1], 10) * rng.uniform(2.8, 8, 10)])
    vels = np.column_stack([np.zeros(10), -0.3 * np.sign(peds[:, 1])])
    trusts = rng.uniform(0, 1, 10)
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, deterministic=True)
    cost = LaneTrackingCost(start=(0, 0), goal=(100, 0), reference=BoundedProportionalReference(0.5, 8.0))
    taken = _count_whole_steps(monkeypatch)
    runs = []
    for whole in (True, False):
        ctl = MpcController(KinematicBicycle(), cost, cfg, SqpSolver())
        ctl._whole = whole
        x, out = np.array([0.0, 0.0, 0.0, 8.0]), []
        for k in range(120):
            sol = ctl.step(x, peds + k * cfg.dt * vels, vels, trusts)
            out.append(sol)
            x = KinematicBicycle().step(x, sol.control, cfg.dt)
        runs.append(out)
        if whole:
            assert sum(taken) >= 0.5 * len(out) and not all(taken), (sum(taken), len(taken))
    for a, b in zip(*runs, strict=True):
        assert np.array_equal(a.inputs, b.inputs) and np.array_equal(a.predicted_states, b.predicted_states)
        assert (a.status, a.iterations, a.cbf_violation, a.first_row_violation, a.state_violation,
                a.decided_violation, a.source) == (b.status, b.iterations, b.cbf_violation, b.first_row_violation,
                                                   b.state_violation, b.decided_violation, b.source)  # fmt: skip
