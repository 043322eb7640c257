"""Controller safety: feasibility recovery, checked fallbacks, braking that stops, bounded step
time, checked inputs (the cases of the safety issue, with its numbers)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from trustnav.control import (
    BoundedProportionalReference,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    SingleIntegrator,
    SolveResult,
    SolveStatus,
    SqpSolver,
    VelocityTrackingCost,
    cbf_rows,
)
from trustnav.sim.random_worlds import RandomWorldSpec, hard_feasible_exists, run_world, sample_world
from trustnav.trust import PAPER_GAMMA_CARLA

REPRO = {  # the issue's repro: single integrator, dt 0.05, R 3, N_h 7, reference (1.5, 10)
    "goal": (4.827, 40.338),
    "peds": np.array([[-0.474, 3.063], [2.426, 1.929]]),
    "vels": np.array([[-1.378, 0.165], [0.0, 0.0]]),
    "trusts": np.array([0.861, 0.747]),
}


def _si(goal=REPRO["goal"], n_h=7, solver=None, **cfg):
    """Single-integrator controller; a long step deadline (results independent of the machine's
    load) unless a test sets one."""
    cfg.setdefault("deadline", 10.0)
    cost = VelocityTrackingCost(goal=goal, reference=BoundedProportionalReference(1.5, 10.0))
    return MpcController(SingleIntegrator(), cost, MpcConfig(horizon=n_h, dt=0.05, safety_radius=3.0, **cfg), solver)


def _patient(world):
    """The world with a long step deadline (the same result on a loaded machine)."""
    return dataclasses.replace(world, config=dataclasses.replace(world.config, deadline=10.0))


def _exact_violation(ctl, sol, peds, vels, trusts):
    """Worst CBF-row violation of the returned plan, evaluated from scratch (numpy `cbf_imp`)."""
    cfg = ctl.config
    from trustnav.trust import gamma

    xs = sol.predicted_states[:, :2]
    rows = cbf_rows(xs, peds, vels, 1.0 - gamma(trusts, cfg.gamma), cfg.safety_radius, cfg.dt, cfg.timing)
    rows = rows[ctl.problem.decided_steps :]
    return max(0.0, -float(rows.min())), max(0.0, -float(rows[0].min()))


def test_issue_repro_recovers_a_hard_feasible_plan_instead_of_relaxing():
    ctl = _si()
    sol = ctl.step([0.0, 0.0], REPRO["peds"], REPRO["vels"], REPRO["trusts"])
    assert sol.status is SolveStatus.OPTIMAL, sol.message
    assert not sol.slack_used and sol.cbf_violation <= 1e-6
    assert sol.recovered and "recovered" in sol.message
    # the same problem from zero input solves directly (the recovery finds what exists)
    direct = _si(solver=SqpSolver()).problem
    direct.set_stage([0.0, 0.0], REPRO["peds"], REPRO["vels"], REPRO["trusts"])
    res = SqpSolver().solve(direct, np.zeros((7, 2)))
    assert res.status is SolveStatus.OPTIMAL


def test_issue_repro_closed_loop_keeps_the_margin():
    """Before: RELAXED at t = 0 and the ego drove to 0.48 m from a pedestrian."""
    ctl = _si()
    x, peds = np.zeros(2), REPRO["peds"].copy()
    d_min = np.inf
    for _ in range(300):
        sol = ctl.step(x, peds, REPRO["vels"], REPRO["trusts"])
        assert not sol.slack_used, sol.message
        x = x + sol.control * 0.05
        peds = peds + REPRO["vels"] * 0.05
        d_min = min(d_min, float(np.linalg.norm(peds - x, axis=1).min()))
    assert d_min >= 3.0 - 1e-6


@pytest.mark.parametrize("seed", range(12))
def test_no_relaxation_at_t0_when_an_independent_check_finds_a_safe_plan(seed):
    """Hard cases from our own generator: 1-3 pedestrians at R + 0.1 within 45 deg ahead at t = 0,
    plus walkers (some approaching). Relaxing is allowed only where SLSQP finds nothing either."""
    world = _patient(sample_world(RandomWorldSpec(close_start_share=1.0), 1000 + seed))
    ctl = MpcController(
        SingleIntegrator(),
        VelocityTrackingCost(goal=tuple(world.goal), reference=BoundedProportionalReference(1.5, world.v_max)),
        world.config,
    )
    sol = ctl.step(world.start, world.pedestrians, world.velocities, world.trusts)
    # a safe plan exists, found without the controller's answer (braking and random starts) ...
    assert hard_feasible_exists(ctl.problem, []), "no hard-feasible plan: the case does not test the claim"
    # ... so the controller must not relax, and the plan it returns must meet every hard row
    assert not sol.slack_used, sol.message
    assert ctl.problem.decision_rows_np(np.ravel(sol.inputs)).min() >= -1e-6, sol.message


def test_relaxed_steps_in_random_episodes_have_no_safe_plan():
    """A few closed-loop hard episodes: every relaxed step is one where the independent check
    finds no hard-feasible plan either, and no episode breaches R while never relaxing."""
    spec = RandomWorldSpec(close_start_share=1.0, horizons=(7,), max_steps=200)
    close_calls = 0
    for seed in range(6):
        rec = run_world(_patient(sample_world(spec, seed)), check_relaxed=True)
        assert rec["relaxed_checked"] == rec["relaxed_steps"], rec  # every relaxed step was re-checked
        assert rec["relaxed_but_feasible"] == 0, rec
        if rec["relaxed_steps"] == 0:
            assert not rec["breach"], rec
        close_calls += rec["min_distance"] <= rec["safety_radius"] + 0.05
    assert close_calls >= 3, "the episodes must press against R for the claim to be tested"


def test_reported_violation_is_that_of_the_plan_returned():
    """Solver stopped after one SQP iteration (MAX_ITER): whatever plan is applied, the reported
    violation and first-row violation are recomputed from its own predicted states."""
    peds, vels, trusts = np.array([[0.0, 3.6]]), np.array([[0.0, -2.0]]), np.array([0.2])
    ctl = _si(goal=(0.0, 40.0), solver=SqpSolver(max_iter=1))
    sol = ctl.step([0.0, 0.0], peds, vels, trusts)
    worst, first = _exact_violation(ctl, sol, peds, vels, trusts)
    assert sol.cbf_violation == pytest.approx(worst, abs=1e-9)
    assert sol.first_row_violation == pytest.approx(first, abs=1e-9)
    # braking (u = 0) lets the approaching walker break the first row: it must not be preferred
    brake_rows = cbf_rows(np.zeros((8, 2)), peds, vels, 1 - np.array([0.03 + 0.08 * 0.2**1.5]), 3.0, 0.05)
    assert brake_rows[0, 0] < 0
    assert sol.source != "braking"
    assert sol.first_row_violation <= 1e-6


class _FailingSolver(SqpSolver):
    """A solver that always fails (to exercise the fallbacks)."""

    def solve(self, problem, u0, deadline=None):
        u = np.full((problem.n_h, problem.model.nu), np.nan)
        return SolveResult(u, SolveStatus.FAILED, 1, np.nan, np.nan, True, "forced failure")


def test_fallbacks_are_checked_and_the_best_is_applied():
    peds, vels, trusts = np.array([[0.0, 3.6]]), np.array([[0.0, -2.0]]), np.array([0.2])
    ctl = _si(goal=(0.0, 40.0))
    first = ctl.step([0.0, 0.0], [[30.0, 30.0]], None, [1.0])  # a plan to shift later
    assert first.status is SolveStatus.OPTIMAL
    ctl.solver = _FailingSolver()
    sol = ctl.step([0.0, 0.0], peds, vels, trusts)
    assert sol.fallback and sol.status is SolveStatus.FALLBACK
    assert sol.source in ("previous_plan", "braking") and "forced failure" in sol.message
    worst, _ = _exact_violation(ctl, sol, peds, vels, trusts)
    assert sol.cbf_violation == pytest.approx(worst, abs=1e-9)


def test_bicycle_braking_stops_and_holds_without_reversing():
    """Before: braking was (0, -6) whatever the speed; below 0.15 m/s it reversed, the speed rows
    became infeasible and the car ran away backwards."""
    model = KinematicBicycle()
    assert model.braking_input([0, 0, 0, 0.1], dt=0.1)[1] == pytest.approx(-1.0)
    assert model.braking_input([0, 0, 0, 0.0], dt=0.1)[1] == 0.0
    cost = LaneTrackingCost(start=(0, 0), goal=(100, 0))
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)
    ctl = MpcController(model, cost, cfg, _FailingSolver())
    x = np.array([0.0, 0.0, 0.0, 7.0])
    for _ in range(400):
        sol = ctl.step(x, [[60.0, 5.0]], None, [0.5])
        assert sol.fallback and sol.source in ("braking", "previous_plan")
        x = model.step(x, sol.control, cfg.dt)
        assert x[3] >= -1e-12
    assert x[3] == pytest.approx(0.0, abs=1e-12)


def test_speed_rows_never_make_a_step_fail():
    """A car that arrives rolling backwards (v = -0.2) or over the speed bound is brought back."""
    cost = LaneTrackingCost(start=(0, 0), goal=(100, 0))
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)
    for v0 in (-0.2, 16.5):
        ctl = MpcController(KinematicBicycle(), cost, cfg)
        sol = ctl.step([0.0, 0.0, 0.0, v0], np.zeros((0, 2)), None, [])
        assert sol.status is SolveStatus.OPTIMAL, sol.message
        assert not sol.fallback
        assert (sol.control[1] > 0) == (v0 < 0)


def test_no_pedestrian_bicycle_never_runs_away():
    model = KinematicBicycle()
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)
    ctl = MpcController(model, LaneTrackingCost(start=(0, 0), goal=(30, 0)), cfg)
    x = np.array([0.0, 0.0, 0.0, -0.2])
    for _ in range(300):
        sol = ctl.step(x, np.zeros((0, 2)), None, [])
        assert sol.status is not SolveStatus.FAILED
        x = model.step(x, sol.control, cfg.dt)
        assert -0.3 <= x[3] <= 15.0 + 1e-9
    assert np.hypot(x[0] - 30, x[1]) < 1.5 and abs(x[3]) < 0.6


def test_two_hundred_pedestrians_step_is_bounded_by_the_deadline():
    """Before: 100 pedestrians at N_h 15 took 5.8 s, 200 in a ring around the ego 94 s."""
    rng = np.random.default_rng(0)
    a = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = 3.5 * np.column_stack([np.cos(a), np.sin(a)])
    ctl = _si(n_h=15, deadline=0.025)
    vels, trusts = rng.normal(0, 1, ring.shape), rng.uniform(0, 1, 200)
    ctl.step([0.0, 0.0], ring, vels, trusts)  # first step of this size: DAQP workspaces set up
    sol = ctl.step([0.0, 0.0], ring, vels, trusts)
    assert sol.solve_time < 0.25  # generous for a loaded CI machine; ~15-45 ms here
    assert sol.deadline_hit or sol.status in (SolveStatus.OPTIMAL, SolveStatus.RELAXED)
    worst, _ = _exact_violation(ctl, sol, ring, vels, trusts)
    assert sol.cbf_violation == pytest.approx(worst, abs=1e-9)


@pytest.mark.parametrize(
    ("peds", "match"),
    [
        (
            np.zeros((2, 5)),
            r"\(N, 2\) array of x, y pairs, got shape \(2, 5\) \(a \(2, N\) array\? pass its transpose\)",
        ),
        (np.zeros((3, 3)), r"got shape \(3, 3\)"),
        (np.zeros(3), r"got shape \(3,\)"),
        ([[1.0, np.nan]], "pedestrians must be finite"),
        ([["a", "b"]], "pedestrians must be an"),
    ],
)
def test_pedestrian_arrays_are_checked(peds, match):
    ctl = _si()
    with pytest.raises(ValueError, match=match):
        ctl.step([0.0, 0.0], peds, None, np.zeros(len(np.atleast_1d(peds))))


def test_velocities_are_checked_too():
    ctl = _si()
    with pytest.raises(ValueError, match=r"velocities must be an \(N, 2\) array"):
        ctl.step([0.0, 0.0], [[5.0, 5.0], [6.0, 6.0]], np.zeros((2, 3)), [0.5, 0.5])


def test_a_shared_solver_never_mixes_models():
    """Before: one SqpSolver shared by a single-integrator and a bicycle controller could solve one
    with the other's Hessian when their QP sizes collided."""
    peds, vels, trusts = [[3.0, 12.0]], [[0.0, 0.0]], [0.5]
    shared = SqpSolver()
    bike_cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)
    bike_cost = LaneTrackingCost(start=(0, 0), goal=(0, 100))
    a_si, a_bike = _si(goal=(0, 40), solver=shared), MpcController(KinematicBicycle(), bike_cost, bike_cfg, shared)
    b_si, b_bike = _si(goal=(0, 40)), MpcController(KinematicBicycle(), bike_cost, bike_cfg)
    xs, xb = [0.0, 0.0], [0.0, 0.0, np.pi / 2, 6.0]
    for _ in range(3):
        s1, b1 = a_bike.step(xb, peds, vels, trusts), a_si.step(xs, peds, vels, trusts)
        s2, b2 = b_bike.step(xb, peds, vels, trusts), b_si.step(xs, peds, vels, trusts)
        np.testing.assert_allclose(s1.inputs, s2.inputs, atol=1e-9)
        np.testing.assert_allclose(b1.inputs, b2.inputs, atol=1e-9)


@pytest.mark.parametrize("offset", [1e6, 1e9])
def test_huge_coordinates_give_the_same_plan(offset):
    """The problem is solved in ego-centred coordinates: shifting the world changes nothing.
    Before: 1e9 degraded the path by 21 m."""
    peds = REPRO["peds"] + np.array([[0.0, 8.0]])
    near = _si().step([0.0, 0.0], peds, REPRO["vels"], REPRO["trusts"])
    o = np.array([offset, -offset])
    cost = VelocityTrackingCost(goal=tuple(np.array(REPRO["goal"]) + o), reference=BoundedProportionalReference())
    far = MpcController(SingleIntegrator(), cost, MpcConfig(horizon=7, deadline=10.0)).step(
        o, peds + o, REPRO["vels"], REPRO["trusts"]
    )
    assert far.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(far.inputs, near.inputs, atol=1e-6)


def test_pedestrian_on_top_of_an_ego_at_its_goal_is_escaped():
    """Before: RELAXED with u = 0 for ever. The CBF rows (gamma > 0) allow moving out, and the
    recovery's evasive starts find that plan."""
    ctl = _si(goal=(20.0, 45.0))
    x = np.array([20.0, 45.0])
    ped = np.array([[20.0, 45.0]])
    sol = ctl.step(x, ped, None, [0.5])
    assert sol.status is SolveStatus.OPTIMAL and not sol.slack_used, sol.message
    assert np.linalg.norm(sol.control) > 0.1
    for _ in range(200):
        x = x + sol.control * 0.05
        sol = ctl.step(x, ped, None, [0.5])
        assert not sol.slack_used
    assert np.linalg.norm(x - ped[0]) >= 3.0 - 1e-3


def test_coordinates_beyond_float_resolution_are_refused():
    """At 1e200 m, ego and a pedestrian 3 m away are the same float: refused, not collapsed."""
    cost = VelocityTrackingCost(goal=(1e200, 1e200))
    ctl = MpcController(SingleIntegrator(), cost, MpcConfig(horizon=7, deadline=10.0))
    with pytest.raises(ValueError, match=r"beyond \+-1e\+12 m.*use a local origin"):
        ctl.step([1e200, 0.0], [[1e200, 3.0]], None, [0.5])


#: World 2563 of the reliability study (single integrator, N_h 7, reference (1.5, 10)) at step 180,
#: ego-centred, rounded to mm: the ego is hemmed in by pedestrians 5 and 7 at about R, with
#: pedestrian 8 walking at it; the one way out is a dash at the input bound through the 6.35 m gap
#: between pedestrians 7 and 8, which no constant-velocity candidate start linearises into.
SQUEEZE_PEDS = np.array([[-1.685, 2.79], [-3.641, 2.703], [2.258, 3.75], [-6.437, -8.188], [-6.379, 0.746],
                         [-2.987, 0.292], [-8.512, 5.464], [2.667, 1.436], [-2.179, -2.669]])  # fmt: skip
SQUEEZE_VELS = np.array([[0.0, 0.0], [0.0, 0.0], [0.775, 0.172], [0.0, 0.0], [0.203, -0.821], [0.0, 0.0],
                         [-0.763, -0.189], [0.0, 0.0], [0.524, 0.341]])  # fmt: skip
SQUEEZE_TRUSTS = np.array([0.69, 0.267, 0.874, 0.186, 0.198, 0.495, 0.787, 0.518, 0.626])
SQUEEZE_GOAL = (-8.623, 12.116)


def test_no_relaxation_where_only_a_bang_bang_plan_is_safe():
    """Before: every candidate start's hard QP was infeasible and the step relaxed (violation
    0.03), although multi-start SLSQP finds a hard-feasible plan (a zig-zag at the input bound).
    The feasibility SQP from bang-bang / pseudo-random starts finds one: no slack."""
    ctl = _si(goal=SQUEEZE_GOAL)
    sol = ctl.step([0.0, 0.0], SQUEEZE_PEDS, SQUEEZE_VELS, SQUEEZE_TRUSTS)
    assert not sol.slack_used, sol.message
    assert sol.status is SolveStatus.OPTIMAL and sol.recovered, sol.message
    worst, first = _exact_violation(ctl, sol, SQUEEZE_PEDS, SQUEEZE_VELS, SQUEEZE_TRUSTS)
    assert worst <= 1e-6 and first <= 1e-6
    assert np.abs(sol.control).max() > 10.0  # the dash through the gap, not a creep
    # the independent check (SLSQP on the plain numpy rows) agrees that a safe plan exists
    p = _si(goal=SQUEEZE_GOAL).problem
    p.set_stage([0.0, 0.0], SQUEEZE_PEDS, SQUEEZE_VELS, SQUEEZE_TRUSTS)
    assert hard_feasible_exists(p, [np.zeros((7, 2))], seed=2)
    # the solver alone is deterministic (fixed-seed starts): the same plan twice
    again = _si(goal=SQUEEZE_GOAL).step([0.0, 0.0], SQUEEZE_PEDS, SQUEEZE_VELS, SQUEEZE_TRUSTS)
    np.testing.assert_array_equal(again.inputs, sol.inputs)


@pytest.mark.parametrize("seed", [18, 42])
def test_bicycle_keeps_the_margin_on_the_finer_plant_when_every_step_is_safe(seed, monkeypatch):
    """Random bicycle worlds where every step had a hard-feasible plan yet the car came 11-14 cm
    inside R: the controller predicted with one Euler step of 0.1 s while the plant integrates
    the same bicycle in 1 ms steps. With `f_e` in 10 ms sub-steps (the default) the margin holds;
    with one Euler step per dt the same world breaches."""
    import trustnav.sim.random_worlds as rw

    world = _patient(sample_world(RandomWorldSpec(family="bicycle"), seed))
    rec = run_world(world)
    assert rec["relaxed_steps"] == 0
    assert not rec["breach"] and rec["min_distance"] >= world.config.safety_radius
    monkeypatch.setattr(rw, "KinematicBicycle", lambda: KinematicBicycle(integration_step=None))
    euler = run_world(world)
    assert euler["relaxed_steps"] == 0 and euler["breach"]
    assert euler["min_distance"] < world.config.safety_radius - 0.05


def test_closest_approach_between_control_steps_is_exact_for_linear_motion():
    from trustnav.sim.random_worlds import _path_min_distance

    # ego from (-1, 3) to (1, 3) while a pedestrian stands at the origin: closest 3 m at mid-step,
    # although both ends are sqrt(10) m away; a walker moving with the ego stays 5 m away
    path = np.array([[-1.0, 3.0], [1.0, 3.0]])
    times = np.array([0.0, 0.05])
    d = _path_min_distance(path, times, np.array([[0.0, 0.0], [-1.0, -2.0]]), np.array([[0.0, 0.0], [40.0, 0.0]]))
    np.testing.assert_allclose(d, [3.0, 5.0])
    # the continuous-time radius of docs/reliability.md: a chord of length c whose ends are
    # R' = sqrt(R^2 + c^2 / 4) away touches R = 3 and no more
    c = 1.0
    end = np.sqrt(9.0 + c * c / 4)
    path = np.array([[-c / 2, np.sqrt(end**2 - c * c / 4)], [c / 2, np.sqrt(end**2 - c * c / 4)]])
    assert _path_min_distance(path, times, np.zeros((1, 2)), np.zeros((1, 2)))[0] == pytest.approx(3.0)


def test_continuous_time_radius_keeps_r_between_control_steps():
    """World 9825 skims R = 3 at its control steps and cuts 4 cm inside it along the chord between
    two of them; planned with R' = continuous_time_radius(R, top ego + pedestrian speed, dt) the
    whole path stays outside R."""
    from trustnav.control import continuous_time_radius

    world = _patient(sample_world(RandomWorldSpec(), 9825))
    plain = run_world(world)
    assert not plain["breach"] and plain["min_distance_continuous"] < 2.97
    top = float(np.hypot(*SingleIntegrator().input_bounds()[1])) + float(np.linalg.norm(world.velocities, axis=1).max())
    r_cont = continuous_time_radius(3.0, top, world.config.dt)
    assert 3.05 < r_cont < 3.1
    safe = run_world(dataclasses.replace(world, config=dataclasses.replace(world.config, safety_radius=r_cont)))
    assert safe["relaxed_steps"] == 0 and safe["min_distance_continuous"] >= 3.0
    with pytest.raises(ValueError, match="max_relative_speed"):
        continuous_time_radius(3.0, -1.0, 0.05)
    with pytest.raises(ValueError, match="dt must be a number"):
        continuous_time_radius(3.0, 1.0, "0.05")
