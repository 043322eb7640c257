"""Deadlock resolution (issue 21 item 2): a wedged single integrator goes around a group of
pedestrians when there is room, says so when there is none, and never enters R for it."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from trustnav.control import MpcConfig, MpcController, SingleIntegrator, VelocityTrackingCost
from trustnav.control.deadlock import DeadlockConfig, DeadlockResolver, plan_route
from trustnav.control.reference import BoundedProportionalReference

DEFAULT = DeadlockConfig()


def _drive(peds: np.ndarray, goal=(30.0, 0.0), deadlock=DEFAULT, steps=500):
    cfg = MpcConfig(horizon=7, dt=0.05, safety_radius=3.0, deterministic=True, deadlock=deadlock)
    cost = VelocityTrackingCost(goal=goal, reference=BoundedProportionalReference(1.5, 3.0))
    ctl = MpcController(SingleIntegrator(), cost, cfg)
    x = np.zeros(2)
    vels, trusts = np.zeros_like(peds), np.full(len(peds), 0.5)
    dmin, notes = np.inf, []
    for _ in range(steps):
        sol = ctl.step(x, peds, vels, trusts)
        notes.append(sol.detour)
        x = SingleIntegrator().step(x, sol.control, cfg.dt)
        dmin = min(dmin, float(np.hypot(*(peds - x).T).min()))
        if np.hypot(*(x - goal)) < 0.25:
            break
    return x, dmin, notes


# two static pedestrians 5.2 m apart (< 2R = 6 m) across the straight path to the goal
WEDGE = np.array([[10.0, 2.6], [10.0, -2.6]])


def test_the_plain_controller_stops_for_good_at_a_wedge():
    x, dmin, notes = _drive(WEDGE, deadlock=None, steps=400)
    assert np.hypot(*(x - (30.0, 0.0))) > 15.0 and dmin >= 3.0 - 1e-6
    assert all(n is None for n in notes)


def test_the_default_goes_around_the_wedge_without_entering_r():
    x, dmin, notes = _drive(WEDGE)
    assert np.hypot(*(x - (30.0, 0.0))) < 0.25  # reached the goal
    assert dmin >= 3.0 - 1e-6
    assert any(n is not None and n.startswith("wedged: going around") for n in notes)


def test_a_wall_of_pedestrians_is_reported_not_crossed():
    wall = np.array([[10.0, y] for y in np.arange(-30.0, 30.1, 5.0)])  # 5 m apart, 60 m long
    x, dmin, notes = _drive(wall, steps=200)
    assert dmin >= 3.0 - 1e-6 and x[0] < 10.0
    assert any(n is not None and "no room" in n for n in notes)


def test_the_paper_presets_keep_the_plain_controller(paper_scenario):
    for name in ("paper-1", "paper-2", "paper-3"):
        assert paper_scenario(name).config().deadlock is None


def test_deadlock_config_is_validated():
    with pytest.raises(ValueError, match="stall_time"):
        DeadlockConfig(stall_time=0.0)
    with pytest.raises(ValueError, match="deadlock must be a DeadlockConfig"):
        MpcConfig(deadlock="on")
    r = DeadlockResolver(DeadlockConfig(), 0.05)
    # moving, or nobody ahead: the goal itself
    assert r.goal(np.zeros(2), 1.0, np.array([30.0, 0.0]), WEDGE, np.full(2, 3.0)) is None
    assert r.goal(np.zeros(2), 0.0, np.array([30.0, 0.0]), -WEDGE - 20.0, np.full(2, 3.0)) is None


# a cup of static pedestrians open toward the car: no straight detour beside the group exists,
# the way around starts by backing out of the cup
CUP = np.array([[12.0, 0.0], [11.0, 5.5], [11.0, -5.5], [8.0, 9.5], [8.0, -9.5]])


def test_a_cup_open_toward_the_car_is_backed_out_of_and_gone_around():
    x, dmin, notes = _drive(CUP, steps=1200)
    assert np.hypot(*(x - (30.0, 0.0))) < 0.25
    assert dmin >= 3.0 - 1e-6
    assert any(n is not None and n.startswith("wedged: going around") for n in notes)


@settings(max_examples=60, deadline=None)
@given(
    peds=st.lists(st.tuples(st.floats(-5.0, 35.0), st.floats(-12.0, 12.0)), min_size=1, max_size=12),
    radius=st.floats(1.0, 4.0),
)
def test_every_leg_of_a_planned_route_keeps_out_of_every_r(peds, radius):
    p = np.array(peds)
    r = np.full(len(p), radius)
    start, goal = np.zeros(2), np.array([30.0, 0.0])
    assume(bool((np.hypot(*(p - start).T) >= radius).all() and (np.hypot(*(p - goal).T) >= radius + 0.5).all()))
    route = plan_route(start, goal, p, r, DEFAULT)
    if route is None:
        return
    points = [start, *route, goal]
    for a, b in itertools.pairwise(points):
        ab = b - a
        t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        closest = np.hypot(*(p - (a + t[:, None] * ab)).T)
        start_d = np.hypot(*(p - a).T)
        assert ((closest >= r - 1e-9) | (closest >= start_d - 1e-9)).all()
