"""Real-time controller (issue: QP-based SQP, bicycle, feasibility handling, latency)."""

from __future__ import annotations

import numpy as np
import pytest

from trustnav.control import (
    BoundedProportionalReference,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    SolveStatus,
)
from trustnav.sim import load_scenario, run_episode
from trustnav.trust import PAPER_GAMMA_CARLA

ROAD = LaneTrackingCost(start=(0, 0), goal=(80, 0), reference=BoundedProportionalReference(0.5, 8.0))
CARLA = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)


def _drive(ctl, peds, trusts, steps=250, appear=None, x0=(0.0, 0.0, 0.0, 8.0)):
    """Closed loop on the bicycle; ``appear`` = (step, position) adds a pedestrian mid-episode."""
    model = ctl.model
    x = np.array(x0)
    peds = np.asarray(peds, dtype=float).reshape(-1, 2)
    trusts = np.asarray(trusts, dtype=float)
    xs, sols = [x], []
    for t in range(steps):
        if appear is not None and t == appear[0]:
            peds = np.vstack([peds, appear[1]])
            trusts = np.append(trusts, 0.0)
        sol = ctl.step(x, peds, np.zeros_like(peds), trusts)
        sols.append(sol)
        x = model.step(x, sol.control, CARLA.dt)
        xs.append(x)
        if np.hypot(x[0] - 80, x[1]) < 1.0 and x[3] < 0.5:
            break
    return np.array(xs), sols, peds


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper-1", "paper-2", "paper-3"])
def test_default_and_baseline_trajectories_agree_on_paper_scenarios(name):
    sc = load_scenario(name)
    runs = [{"trusts": [t]} for t in sc.trust_sweep] or [{"horizon": h} for h in sc.horizons]
    for kw in runs:
        fast = run_episode(sc, solver="sqp", **kw)
        ref = run_episode(sc, solver="slsqp", **kw)
        assert fast.ego.shape == ref.ego.shape, kw
        assert np.max(np.abs(fast.ego - ref.ego)) < 1e-3, kw
        assert fast.slack_steps == 0 and fast.fallbacks == 0


def test_bicycle_passes_a_pedestrian_near_the_lane_and_reaches_the_goal():
    ctl = MpcController(KinematicBicycle(), ROAD, CARLA)
    ped = np.array([[35.0, 1.5]])  # 1.5 m beside the lane centre: the car must swerve or slow down
    xs, sols, _ = _drive(ctl, ped, [0.2])
    d = np.hypot(xs[:, 0] - ped[0, 0], xs[:, 1] - ped[0, 1])
    assert d.min() >= CARLA.safety_radius - 1e-6
    assert np.hypot(xs[-1, 0] - 80, xs[-1, 1]) < 1.0
    assert all(s.status is SolveStatus.OPTIMAL for s in sols)
    assert np.max(np.abs(xs[:, 1])) < 6.0  # stays near the road


def test_low_trust_pedestrian_gets_more_room_on_the_road():
    gaps = []
    for trust in (0.0, 1.0):
        ctl = MpcController(KinematicBicycle(), ROAD, CARLA)
        xs, _, _ = _drive(ctl, [[35.0, 2.0]], [trust])
        gaps.append(np.hypot(xs[:, 0] - 35.0, xs[:, 1] - 2.0).min())
    assert gaps[0] > gaps[1] + 0.1


def test_pedestrian_appearing_inside_margin_relaxes_brakes_and_episode_continues():
    ctl = MpcController(KinematicBicycle(), ROAD, CARLA)
    # cruising at 8 m/s on an empty road; at step 20 (x ~ 16 m) a pedestrian steps out ~1.8 m ahead,
    # inside R = 2.5: the bicycle's first CBF row cannot be met by any input
    xs, sols, _ = _drive(ctl, np.empty((0, 2)), [], steps=60, appear=(20, [[17.8, 0.2]]))
    assert len(sols) == 60  # the episode goes on to its end
    assert 15.0 < xs[20, 0] < 17.0
    hit = sols[20]
    assert hit.status is SolveStatus.RELAXED and hit.slack_used and hit.cbf_violation > 0
    assert not hit.fallback
    assert hit.control[1] < 0  # braking
    assert xs[21, 3] < xs[20, 3]  # the braking is applied
    # never a failed step; a checked fallback (a better plan than the solver's) only once the
    # pedestrian is there
    assert all(s.status is not SolveStatus.FAILED for s in sols)
    assert not any(s.fallback for s in sols[:20])
    # slack only while the hard problem is infeasible: the pedestrian inside (or entering) the margin
    d = np.hypot(xs[:-1, 0] - 17.8, xs[:-1, 1] - 0.2)
    used = np.flatnonzero([s.slack_used for s in sols])
    assert used.size and used.min() == 20 and np.all(d[used] < CARLA.safety_radius + 1.0)
    assert xs[-1, 0] > 30.0  # it does not stall: the drive goes on past the pedestrian


def test_latency_compensation_plans_from_the_predicted_state():
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, latency=0.1, deadline=10.0)
    ctl = MpcController(KinematicBicycle(), ROAD, cfg)
    x0 = np.array([0.0, 0.0, 0.0, 8.0])
    # before any input is applied the vehicle coasts: 8 m/s * 0.1 s along its heading
    x_pred, peds = ctl.compensate_latency(x0, [[40.0, 4.0]], [[0.0, -1.0]])
    np.testing.assert_allclose(x_pred, [0.8, 0.0, 0.0, 8.0], atol=1e-12)
    np.testing.assert_allclose(peds, [[40.0, 3.9]])  # pedestrians advanced by v * latency
    sol = ctl.step(x0, [[40.0, 4.0]], [[0.0, -1.0]], [0.5])
    np.testing.assert_allclose(sol.predicted_states[0], [0.8, 0.0, 0.0, 8.0], atol=1e-12)
    # the next prediction applies the input now being executed
    x_next, _ = ctl.compensate_latency(x0, [[40.0, 4.0]], None)
    assert x_next[3] == pytest.approx(8.0 + sol.control[1] * 0.1)
    # without latency the plan starts at the measured state
    ctl0 = MpcController(KinematicBicycle(), ROAD, CARLA)
    np.testing.assert_allclose(ctl0.step(x0, [[40.0, 4.0]], [[0.0, -1.0]], [0.5]).predicted_states[0], x0)


def test_latency_compensation_with_several_commands_in_flight():
    """Control at 20 Hz with 100 ms actuation latency: two commands are in flight at every step.
    The compensated state is where the car (each command acting from its send time + latency)
    will be when the new command acts, and no step relaxes on a plain road."""
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, latency=0.1, deadline=10.0)
    model = KinematicBicycle()
    ctl = MpcController(model, ROAD, cfg)
    x = np.array([0.0, 0.0, 0.0, 6.0])
    sent = []  # (time acting from, command)
    applied = np.zeros(2)
    period, fine = 0.05, 0.001
    peds = [[30.0, 1.8]]
    for i in range(60):
        t = i * period
        predicted, _ = ctl.compensate_latency(x, peds, None, time=t)
        # the truth: integrate a copy of the plant over the latency with the commands in flight
        y, act, queue = x.copy(), applied, list(sent)
        for j in range(round(cfg.latency / fine)):
            while queue and queue[0][0] <= t + j * fine + 1e-9:
                act = queue.pop(0)[1]
            y = model.step(y, act, fine)
        assert np.linalg.norm(predicted[:2] - y[:2]) < 0.01, i
        sol = ctl.step(x, peds, None, [0.3], time=t)
        assert not sol.slack_used, (i, sol.message)
        sent.append((t + cfg.latency, sol.control))
        for j in range(round(period / fine)):
            while sent and sent[0][0] <= t + j * fine + 1e-9:
                applied = sent.pop(0)[1]
            x = model.step(x, applied, fine)
    assert x[0] > 15.0
    with pytest.raises(ValueError, match="time must not go back"):
        ctl.step(x, peds, None, [0.3], time=1.0)
    with pytest.raises(ValueError, match="time must be a finite number"):
        ctl.step(x, peds, None, [0.3], time="soon")
