"""The road's edges in the controller (issue 21 item 1, opt-in): a car that may not swerve past the
kerb brakes for a distracted crosser, lets them cross and goes on; user barriers can be relaxed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trustnav.control import KinematicBicycle, LaneTrackingCost, MpcConfig, MpcController, RoadEdgeBarrier
from trustnav.control.reference import BoundedProportionalReference

ROOT = Path(__file__).resolve().parents[1]


def test_road_edge_barrier_values_and_errors():
    road = RoadEdgeBarrier((0.0, 0.0), (100.0, 0.0), left=3.0, right=3.0, margin=1.0)
    states = np.array([[10.0, 0.0, 0.0, 5.0], [10.0, 1.5, 0.0, 5.0], [10.0, -2.5, 0.0, 5.0]])
    h, grad = road.values(states, np.zeros(3, dtype=np.int64), 0.1)
    np.testing.assert_allclose(h, [[2.0, 2.0], [0.5, 3.5], [4.5, -0.5]])  # left room, right room
    np.testing.assert_allclose(grad[0, :, :2], [[0.0, -1.0], [0.0, 1.0]])
    assert road.size() == 2 and np.allclose(road.decay(), 0.5)
    with pytest.raises(ValueError, match="no room for the car"):
        RoadEdgeBarrier((0, 0), (1, 0), left=1.0, right=1.0, margin=1.0)
    with pytest.raises(ValueError, match="two different finite points"):
        RoadEdgeBarrier((0, 0), (0, 0), left=3.0, right=3.0)


def test_a_relaxed_step_with_a_user_barrier_is_solved_and_reported():
    """A pedestrian on the lane ahead and road edges too tight to pass: the QP needs its slacks,
    which cover the road rows as well as the pedestrian's (this crashed before: slacks were sized
    for pedestrians only)."""
    cost = LaneTrackingCost(start=(0.0, 0.0), goal=(60.0, 0.0), reference=BoundedProportionalReference(1.0, 8.0))
    road = RoadEdgeBarrier((0.0, 0.0), (100.0, 0.0), left=1.5, right=1.5, margin=0.9)
    ctl = MpcController(KinematicBicycle(), cost, MpcConfig(horizon=7, dt=0.08, safety_radius=2.5), barriers=[road])
    x = np.array([0.0, 0.0, 0.0, 8.0])
    sol = ctl.step(x, np.array([[6.0, 0.0]]), np.zeros((1, 2)), np.array([0.9]))
    assert np.isfinite(sol.control).all() and sol.slack_used
    assert sol.control[1] < 0  # it brakes


@pytest.mark.slow
def test_a_distracted_crosser_is_waited_for_on_the_road():
    from trustnav.sim.driving import load_drive_scenario, run_drive

    sc = load_drive_scenario(ROOT / "examples" / "scenarios" / "lane-crossing.toml")
    assert sc.control.road_edges
    m = run_drive(sc, sensing="keypoints", attentive=False).metrics()
    assert m["road_departure_max"] == 0.0 and m["margin_violations"] == 0 and m["reached_goal"]
    assert m["min_speed"] < 2.0  # it slowed down for the crosser
    assert m["pedestrians"][0]["min_distance"] >= sc.control.safety_radius
