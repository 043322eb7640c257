"""The road's edges in the controller (issue 21 item 1, on by default in the drive): a car that may
not swerve past the kerb brakes for a crosser, lets them cross and goes on, whatever their trust;
user barriers can be relaxed."""

from __future__ import annotations

import dataclasses
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


def test_the_front_rows_keep_the_point_ahead_on_the_road_and_their_gradient_is_exact():
    road = RoadEdgeBarrier((0.0, 0.0), (100.0, 0.0), left=3.0, right=3.0, margin=1.0, front=2.0)
    assert road.size() == 4 and road.decay().shape == (4,)
    # at y = 1.5 heading 30 deg to the left the centre has 0.5 m of room, the point 2 m ahead none
    x = np.array([[10.0, 1.5, np.radians(30.0), 5.0]])
    h, grad = road.values(x, np.zeros(1, dtype=np.int64), 0.1)
    np.testing.assert_allclose(h[0], [0.5, 3.5, -0.5, 4.5], atol=1e-12)
    eps = 1e-6
    for i in range(3):  # x, y, yaw
        dx = np.zeros_like(x)
        dx[0, i] = eps
        h2, _ = road.values(x + dx, np.zeros(1, dtype=np.int64), 0.1)
        np.testing.assert_allclose((h2[0] - h[0]) / eps, grad[0, :, i], atol=1e-5)
    with pytest.raises(ValueError, match="road front"):
        RoadEdgeBarrier((0, 0), (1, 0), left=3.0, right=3.0, front=-1.0)


TURN = 2.9 / np.tan(np.radians(35.0))  # the drive's car's smallest turning radius (m; VehicleSpec)


def _front_reach(x0, steer, metres=6.0, dt=0.002):
    """The largest lateral offset (left positive) the point 2 m ahead reaches while the default
    drive's car drives ``metres`` from ``x0`` at constant ``steer`` (fine steps of the exact bicycle)."""
    model, x, out = KinematicBicycle(wheelbase=2.9), np.array(x0, dtype=float), -np.inf
    x[3] = 1.0
    for _ in range(int(metres / dt)):
        x = model.step(x, np.array([steer, 0.0]), dt)
        out = max(out, x[1] + 2.0 * np.sin(x[2]))
    return out


def test_the_front_rows_with_a_turn_radius_keep_the_arc_back_on_the_road():
    """A car turned toward the edge by more than beta = atan(front / turn radius) (26 deg) swings its
    front further out when it turns back: the rows keep that swing on the road, so every state they
    admit can leave along the arc; the front point's rows alone admit states with no way on."""
    from trustnav.control import _kernels as kern

    plain = RoadEdgeBarrier((0.0, 0.0), (100.0, 0.0), left=3.0, right=3.0, margin=0.9, front=2.0)
    swept = RoadEdgeBarrier((0.0, 0.0), (100.0, 0.0), left=3.0, right=3.0, margin=0.9, front=2.0, turn_radius=TURN)
    k0 = np.zeros(1, dtype=np.int64)
    beta = np.degrees(np.arctan2(2.0, TURN))
    for deg in (-beta + 0.1, -10.0, 0.0, 20.0, beta - 0.1):  # turned less than beta either way: the same rows
        for x in ([10.0, 0.5, np.radians(deg), 3.0], [10.0, -0.5, np.radians(-deg), 3.0]):
            state = np.array([x])
            np.testing.assert_array_equal(swept.values(state, k0, 0.1)[0], plain.values(state, k0, 0.1)[0])
    for deg in (29.0, 45.0, 80.0):  # turned more: the outermost point of the front's circle about the turn centre
        x = np.array([[10.0, 0.3, np.radians(deg), 0.0]])
        h = swept.values(x, k0, 0.1)[0]
        swing = np.hypot(TURN, 2.0) - TURN * np.cos(np.radians(deg))
        np.testing.assert_allclose(h[0, 2], 2.1 - 0.3 - swing, atol=1e-12)
        assert h[0, 2] < plain.values(x, k0, 0.1)[0][0, 2]
        mirrored = np.array([[10.0, -0.3, -np.radians(deg), 0.0]])
        np.testing.assert_allclose(swept.values(mirrored, k0, 0.1)[0][0, 3], h[0, 2], atol=1e-12)
        road = np.array([*swept.start, *swept.normal, *swept.room, swept.front, 1.0 - swept.gamma, swept.turn_radius])
        for state in (x[0], mirrored[0]):  # the compiled rows the SQP builds are the same, gradient exact
            for i in (2, 3):
                value, *_, slope = kern._road_value(road, i, *state[:3])
                hs, gs = swept.values(state[None], k0, 0.1)
                assert value == pytest.approx(hs[0, i], abs=1e-12) and slope == pytest.approx(gs[0, i, 2], abs=1e-12)
                up = kern._road_value(road, i, state[0], state[1], state[2] + 1e-6)[0]
                assert (up - value) / 1e-6 == pytest.approx(slope, abs=1e-4)
    # on the rows' boundary, turned 29 deg toward the left edge: full steer back keeps the front on the road
    at = np.radians(29.0)
    y = 2.1 - (np.hypot(TURN, 2.0) - TURN * np.cos(at))
    assert _front_reach([10.0, y, at, 0.0], -np.radians(35.0)) <= 2.1 + 1e-3
    # the front point's boundary at the same heading: every steer takes the front past the edge
    y = 2.1 - 2.0 * np.sin(at)
    for steer in np.radians([-35.0, -20.0, 0.0, 20.0]):
        assert _front_reach([10.0, y, at, 0.0], steer) > 2.1 + 5e-3
    with pytest.raises(ValueError, match="road turn_radius"):
        RoadEdgeBarrier((0, 0), (1, 0), left=3.0, right=3.0, front=2.0, turn_radius=-1.0)


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


def _lane_car(peds_on_road: bool = True, **config):
    cost = LaneTrackingCost(start=(0.0, 0.0), goal=(200.0, 0.0), reference=BoundedProportionalReference(1.0, 8.0))
    road = RoadEdgeBarrier((0.0, 0.0), (300.0, 0.0), left=3.0, right=3.0, margin=0.9)
    cfg = MpcConfig(horizon=7, dt=0.08, safety_radius=2.5, deterministic=True, **config)
    return MpcController(KinematicBicycle(), cost, cfg, barriers=[road] if peds_on_road else [])


def _drive_lane(ctl, ped, vel, steps=250):
    """The car at 8 m/s from x = 0 on the road y in [-3, 3]; one pedestrian; returns the car's
    path, the closest approach and the notes of the route layer."""
    x = np.array([0.0, 0.0, 0.0, 8.0])
    model, path, dmin, notes = KinematicBicycle(), [], np.inf, []
    p, v = np.array(ped, dtype=float), np.array(vel, dtype=float)
    for _ in range(steps):
        sol = ctl.step(x, p[None], v[None], np.array([0.9]))
        notes.append(sol.detour)
        x = model.step(x, sol.control, 0.08)
        p = p + v * 0.08
        path.append(x.copy())
        dmin = min(dmin, float(np.hypot(*(x[:2] - p))))
    return np.array(path), dmin, notes


def test_a_car_on_a_road_stops_short_of_someone_standing_in_its_lane_and_says_so():
    path, dmin, notes = _drive_lane(_lane_car(), (40.0, 0.2), (0.0, 0.0))
    assert np.abs(path[:, 1]).max() <= 2.1 + 1e-3  # never past the road's edge (less half the car)
    assert dmin >= 2.5 and path[-1, 3] < 0.1 and path[-1, 0] < 40.0 - 2.5  # waiting short of them
    assert any(n is not None and n.startswith("yielding") for n in notes)


def test_without_the_road_the_car_swerves_round_them_and_yielding_off_keeps_the_mpc_alone():
    path, _, notes = _drive_lane(_lane_car(peds_on_road=False), (40.0, 0.2), (0.0, 0.0))
    assert path[-1, 0] > 45.0 and np.abs(path[:, 1]).max() > 2.1  # past them, off the road
    assert all(n is None for n in notes)
    _, _, notes = _drive_lane(_lane_car(yielding=None), (40.0, 0.2), (0.0, 0.0), steps=50)
    assert all(n is None for n in notes)


def test_a_crosser_is_passed_behind_once_across():
    # walking right (-y) across the road at 1 m/s from the left kerb, 35 m ahead of the car
    path, dmin, notes = _drive_lane(_lane_car(), (35.0, 4.5), (0.0, -1.0), steps=300)
    assert np.abs(path[:, 1]).max() <= 2.1 + 1e-3 and dmin >= 2.5
    assert path[-1, 0] > 60.0  # went on once the crosser was across
    assert any(n is not None and n.startswith("yielding") for n in notes)
    crossing = path[np.argmin(np.abs(path[:, 0] - 35.0)), 1]  # where the car passed the crossing line
    assert crossing >= -0.5  # on the side the crosser came from (behind them)


@pytest.mark.slow
@pytest.mark.parametrize("attentive", [False, True], ids=["distracted", "attentive"])
def test_a_crosser_is_waited_for_on_the_road_whatever_their_trust(attentive):
    from trustnav.sim.driving import load_drive_scenario, run_drive

    sc = load_drive_scenario(ROOT / "examples" / "scenarios" / "lane-crossing.toml")
    assert sc.control.road_edges
    m = run_drive(sc, sensing="keypoints", attentive=attentive).metrics()
    assert m["road_departure_max"] == 0.0 and m["margin_violations"] == 0 and m["reached_goal"]
    assert m["yield_s"] > 1.0  # it held back for the crosser
    assert m["pedestrians"][0]["min_distance"] >= sc.control.safety_radius


def test_the_drive_has_road_edges_by_default_and_false_is_the_papers_controller():
    from trustnav.sim.driving import load_drive_scenario

    sc = load_drive_scenario("case-1")
    assert sc.control.road_edges and len(sc.control.barriers(sc.road)) == 1
    off = dataclasses.replace(sc.control, road_edges=False)
    assert off.barriers(sc.road) == ()
    # the front's rows keep the arc back at the car's smallest turning radius; road_recover = false: the point alone
    (road,) = sc.control.barriers(sc.road, sc.vehicle)
    assert road.turn_radius == pytest.approx(sc.vehicle.wheelbase / np.tan(np.radians(sc.vehicle.steer_max_deg)))
    assert dataclasses.replace(sc.control, road_recover=False).barriers(sc.road, sc.vehicle)[0].turn_radius == 0.0
    with pytest.raises(ValueError, match="road_recover must be true or false"):
        dataclasses.replace(sc.control, road_recover=1)


@pytest.mark.slow
@pytest.mark.parametrize("near_range", [0.0, 10.0], ids=["camera alone", "near-field sensor"])
def test_a_pedestrian_waiting_at_the_kerb_for_a_gap_and_a_yielding_car_do_not_wait_for_each_other(near_range):
    """kerb-gap.toml: she waits while the car would reach her within 4 s; a car that yields gives her
    the gap. Neither waits for ever: she crosses, the car goes on, on the road and outside R. With a
    near-field sensor the car, which keeps seeing her at the kerb, goes on sooner and she crosses
    behind it (she is still crossing when it reaches the goal); camera alone it waits until she has
    crossed in front of it."""
    from trustnav.sim.driving import load_drive_scenario, run_drive

    sc = load_drive_scenario(ROOT / "examples" / "scenarios" / "kerb-gap.toml")
    r = run_drive(sc.with_options(sensing={"near_range": near_range}), sensing="keypoints")
    m = r.metrics()
    assert m["reached_goal"] and m["road_departure_max"] == 0.0 and m["margin_violations"] == 0
    assert m["yield_s"] > 1.0
    x = r.pedestrians[:, 0, 0]  # she walks from x = 40.5 across the lane (31.25-37.25 m) to the far side
    last_second = round(1.0 / (r.times[1] - r.times[0]))
    assert x[-1] < 31.0 or (x[-1] < 37.25 and x[-1] < x[-1 - last_second] - 0.5)  # crossed, or crossing


@pytest.mark.slow
def test_a_relaxed_plan_gives_up_room_to_the_pedestrian_not_the_road():
    """Step-out at constant trust 1 (no caution, gamma 0.63): from some step on no plan keeps R,
    and the relaxed plans used to give up the road's rows as well, putting the car on the kerb
    (0.07 m past the room). The road's rows now stay hard in the relaxation and rank first among
    fallbacks: the car brakes on the road instead."""
    from trustnav.control import SolveStatus
    from trustnav.sim.driving import DriveEnvironment, drive, load_drive_scenario
    from trustnav.sim.driving.compare import ConstantTrustEnvironment
    from trustnav.sim.driving.episode import drive_metrics, make_sensor, prepare_scenario

    sc = load_drive_scenario(ROOT / "examples/scenarios/step-out.toml")
    sc = prepare_scenario(dataclasses.replace(sc, pedestrians=sc.pedestrians[:1]), None, None)  # the texter alone
    world = ConstantTrustEnvironment(DriveEnvironment(sc, seed=0, sensor=make_sensor("keypoints", None, None)), 1.0)
    r = drive(world, "keypoints")
    m = drive_metrics(r)
    assert any(s is SolveStatus.RELAXED for s in r.statuses)  # the situation the test is about
    assert m["road_departure_max"] == 0.0
    assert m["pedestrians"][0]["min_distance"] > 2.0  # it braked: no pass through R at speed
