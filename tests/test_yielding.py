"""Yielding (issue 21 item 1): a car on a road with its edges as barriers stops short of a
pedestrian it cannot pass on the road, passes crossers only behind, and drives on otherwise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trustnav.control.yielding import YieldConfig, Yielder

# a road along +x: its line y = 0, left (+y) and right room 2.1 m for the car's centre (6 m road,
# 0.9 m half car); the car's lane is the road's line
ROAD = {
    "lane_start": np.array([0.0, 0.0]),
    "lane_goal": np.array([100.0, 0.0]),
    "road_start": np.array([0.0, 0.0]),
    "road_normal": np.array([0.0, 1.0]),
    "room": (2.1, 2.1),
}
Y = Yielder(YieldConfig())
R = np.array([2.5])


def _decide(ped, vel, car=(0.0, 0.0), speed=8.0, radii=R, lateral=None):
    return Y.decide(np.array(car), speed, pedestrians=np.array([ped]), velocities=np.array([vel]), radii=radii,
                    covariances=None if lateral is None else _velocity_cov(lateral), **ROAD)  # fmt: skip


def _velocity_cov(sigma_across):
    """A (1, 4, 4) covariance whose velocity sigma across the road (+y here) is ``sigma_across``."""
    c = np.diag([0.01, 0.01, 0.04, sigma_across**2])
    return c[None]


def test_a_pedestrian_standing_in_the_lane_is_stopped_for_short_of_r():
    d = _decide((30.0, 0.0), (0.0, 0.0))
    assert d is not None and d.pedestrian == 0
    np.testing.assert_allclose(d.stop, [30.0 - 2.5 - 1.0, 0.0])  # R + gap short of them
    assert d.speed_cap == pytest.approx(np.sqrt(2 * 3.0 * 26.5))
    assert d.note.startswith("yielding")


def test_a_pedestrian_the_car_can_pass_at_r_on_the_road_is_not_yielded_to():
    assert _decide((30.0, 4.0), (0.0, 0.0)) is None  # on the kerb: pass at y <= 1.5
    assert _decide((30.0, -1.0), (0.0, 0.0)) is None  # pass on their left at y = 1.5 <= 2.0
    assert _decide((-10.0, 0.0), (0.0, 0.0)) is None  # behind the car
    # just passed, with a large uncertainty margin (a coasted track out of the camera's view):
    # stopping beside them helps no one
    assert _decide((-1.0, 2.5), (0.0, 0.0), radii=np.array([5.0])) is None


def test_a_crosser_is_passed_only_behind():
    # walking right (-y) from the left sidewalk: the left side (behind them) has no room yet, and
    # the right side is where they walk to, so the car yields
    d = _decide((25.0, 4.2), (0.0, -1.0))
    assert d is not None
    # the same person standing there leaves room on the right: no yield
    assert _decide((25.0, 4.2), (0.0, 0.0)) is None
    # once they are far enough across, the car passes behind them (on their left)
    assert _decide((25.0, -0.6), (0.0, -1.0)) is None


def test_the_car_goes_first_only_when_it_is_past_well_before_they_block():
    # a walker 5 m off the road's edge at 1 m/s comes within R of the car's corridor after 3.4 s;
    # at 15 m/s a car 10 m short is past them (and R) in 0.8 s: no yield; slower, it must yield
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=15.0) is None
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=4.0) is not None
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=0.0) is not None


def test_an_uncertain_crossing_speed_is_passed_in_front_only_if_its_upper_bound_allows():
    # the walker of the test above, her speed across (1 m/s, estimated from two frames) uncertain by
    # sigma 0.6 m/s (z sigma ~1 m/s): at 2 m/s she would block after 1.7 s, before the car at 15 m/s is
    # past (1.8 s)
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=15.0, lateral=0.0) is None
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=15.0, lateral=0.6) is not None
    assert _decide((10.0, -8.0), (0.0, 1.0), speed=15.0, lateral=0.6) is not None  # the other side
    assert _decide((10.0, 8.0), (0.0, -1.0), speed=15.0, lateral=0.1) is None  # known well enough
    with pytest.raises(ValueError, match=r"covariances must have shape \(1, 4, 4\)"):
        Y.decide(np.zeros(2), 8.0, pedestrians=np.array([(10.0, 8.0)]), velocities=np.zeros((1, 2)),
                 radii=R, covariances=np.zeros((1, 2, 2)), **ROAD)  # fmt: skip
    # the bound never makes someone block who does not at the estimated velocity
    assert _decide((12.0, 4.0), (0.0, 0.0), lateral=0.6) is None
    assert _decide((25.0, 4.2), (0.0, 0.0), lateral=0.6) is None


def test_a_crosser_the_car_waits_for_is_remembered_when_her_track_vanishes():
    """Her track dropped while she crosses in front of the stopped car (cut off by the image's
    edge): the car keeps waiting for her prediction until it is R from the lane's line, or for
    ``memory`` seconds; without ``time`` the layer is stateless, as before."""
    y = Yielder(YieldConfig())
    none = np.zeros((0, 2))

    def step(t, peds, vels, car=(0.0, 0.0), speed=0.0):
        return y.decide(np.array(car), speed, pedestrians=peds, velocities=vels, radii=np.full(len(peds), 3.5),
                        time=t, safety_radius=2.5, **ROAD)  # fmt: skip

    crossing = np.array([[4.0, 0.5]]), np.array([[0.0, -0.6]])  # 4 m ahead, walking right at 0.6 m/s
    assert step(0.0, *crossing) is not None and y.remembers  # (the controller skips a layer that holds nobody)
    held = step(0.5, none, none)  # gone from the inputs: still waited for
    assert held is not None and held.pedestrian == -1 and "no longer sees" in held.note and held.speed_cap < 2.0
    # at 0.6 m/s she is R from the lane's line (0.5 - 0.6 t <= -2.5) after 5 s
    assert step(4.9, none, none) is not None
    assert step(5.1, none, none) is None
    assert step(5.2, none, none) is None and not y.remembers  # forgotten
    # seen again (within rematch of her prediction): judged from the inputs as usual
    assert step(10.0, *crossing) is not None
    again = step(10.5, np.array([[4.0, 0.3]]), np.array([[0.0, -0.6]]))
    assert again is not None and again.pedestrian == 0 and "cannot pass" in again.note
    # someone standing still who vanishes is waited for at most ``memory`` s
    y.reset()
    assert step(0.0, np.array([[4.0, 0.0]]), np.zeros((1, 2))) is not None
    assert step(7.9, none, none) is not None and step(8.1, none, none) is None
    # stateless without the time
    y.reset()
    assert _decide((4.0, 0.5), (0.0, -0.6)) is not None
    assert Y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0), **ROAD) is None


def test_a_remembered_crosser_blocks_on_the_line_a_turned_car_heads_along():
    """Issue 34 (run 65): a car stopped turned toward where she walks drives that way first; she is
    waited for until she is R from the lane's line *and* from the line the car heads along."""
    none = np.zeros((0, 2))

    def walk(heading):
        y = Yielder(YieldConfig())

        def step(t, peds, vels):
            return y.decide(np.zeros(2), 0.0, pedestrians=peds, velocities=vels, radii=np.full(len(peds), 3.5),
                            time=t, safety_radius=2.5, heading=heading, **ROAD)  # fmt: skip

        assert step(0.0, np.array([[6.0, 0.5]]), np.array([[0.0, -0.6]])) is not None
        return [step(t, none, none) is not None for t in (5.5, 7.0)]

    # heading along the lane: she is R (2.5 m) from its line after 5 s
    assert walk(0.0) == [False, False]
    # turned 25 deg to the right, toward where she walks: at 5.5 s she is 2.8 m right of the lane's
    # line but on the car's heading line, 6 m ahead; at 7 s 0.8 m from it, still within R
    assert walk(math.radians(-25.0)) == [True, True]
    assert walk(math.radians(25.0)) == [False, False]  # turned away from her


def test_a_seen_crosser_is_waited_for_until_clear_of_the_line_a_turned_car_heads_along():
    """Issue 34 (held-out run 64): a car stopped turned toward where the crosser it waits for walks
    restarted once there was room to pass behind her, and drove toward her. A crosser it yielded to,
    still seen, now keeps it waiting while she is within her radius of the line it heads along, if
    that line is turned toward where she walks; a car along the road, or turned away, passes behind
    her as before, and one that never yielded to her is not held."""

    def walk(heading, first=True):
        y = Yielder(YieldConfig())

        def step(t, ped):
            return y.decide(np.zeros(2), 0.0, pedestrians=np.array([ped]), velocities=np.array([[0.0, -0.6]]),
                            radii=np.array([3.5]), time=t, safety_radius=2.5, heading=heading, **ROAD)  # fmt: skip

        if first:
            assert step(0.0, (6.0, 0.5)) is not None  # she walks out in front of it: it yields
        # at 4 s she is 1.9 m right of the road's line: room to pass behind her (left) at 3.5 m
        return step(4.0, (6.0, -1.9)) is not None

    assert not walk(0.0)  # along the road: released, as before
    assert not walk(math.radians(25.0))  # turned away from her side
    # turned 25 deg toward her side: she is 0.8 m from the line it heads along, 6.2 m ahead
    assert walk(math.radians(-25.0))
    assert not walk(math.radians(-25.0), first=False)  # not one it waited for: judged as usual


def test_a_remembered_crosser_moves_across_the_road_only():
    """Issue 34 (10 frames/s, seed 0 run 49): her dropped track's velocity along the road was the
    monocular range's drift (0.41 m/s); remembered with it, her prediction and the car's stop moved
    ahead of a creeping car while she crossed in front of it (0.89 m). Remembered, she crosses."""
    y = Yielder(YieldConfig())
    none = np.zeros((0, 2))

    def step(t, peds, vels):
        return y.decide(np.zeros(2), 0.5, pedestrians=peds, velocities=vels, radii=np.full(len(peds), 2.5),
                        time=t, safety_radius=2.5, **ROAD)  # fmt: skip

    assert step(0.0, np.array([[8.0, 1.5]]), np.array([[0.8, -0.6]])) is not None  # drifting ahead at 0.8 m/s
    first, later = step(0.5, none, none), step(3.0, none, none)
    assert first is not None and later is not None and later.pedestrian == -1
    assert later.stop[0] == pytest.approx(first.stop[0], abs=1e-6)  # the stop stays where she crosses


def test_a_remembered_crosser_is_stopped_for_short_of_her_range_error():
    """Issue 34 (10 frames/s, seed 0 run 49): her track, out of view, drifted 1.2 m along the road
    (the monocular range) before it was dropped; remembered at its mean, the stop (R + gap short)
    brought the car forward to 2.24 m from her. The stop lies z sigma of her position along the
    road further short; her uncertainty across the road does not move it, and without a covariance
    (true states) the stop is as before."""
    none = np.zeros((0, 2))
    z = 1.645

    def stop_after_drop(cov):
        y = Yielder(YieldConfig())
        peds, vels = np.array([[8.0, 1.5]]), np.array([[0.0, -0.6]])
        assert y.decide(np.zeros(2), 0.0, pedestrians=peds, velocities=vels, radii=np.array([4.0]),
                        covariances=cov, time=0.0, safety_radius=2.5, **ROAD) is not None  # fmt: skip
        held = y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0),
                        covariances=np.zeros((0, 4, 4)), time=0.5, safety_radius=2.5, **ROAD)  # fmt: skip
        assert held is not None and held.pedestrian == -1
        return float(held.stop[0])

    exact = stop_after_drop(None)
    assert exact == pytest.approx(8.0 - 2.5 - 1.0)
    along = np.diag([1.2**2, 0.05**2, 0.01, 0.01])[None]  # sigma 1.2 m along the road (x)
    assert stop_after_drop(along) == pytest.approx(exact - z * 1.2, abs=1e-6)
    across = np.diag([0.05**2, 1.2**2, 0.01, 0.01])[None]  # the same across it
    assert stop_after_drop(across) == pytest.approx(exact - z * 0.05, abs=1e-6)


def test_uncertainty_widens_who_blocks():
    assert _decide((30.0, -1.0), (0.0, 0.0)) is None
    assert _decide((30.0, -1.0), (0.0, 0.0), radii=np.array([3.5])) is not None


def test_the_stop_is_on_the_lane_and_the_cap_brakes_there():
    d = _decide((12.0, 0.0), (0.0, 0.0), car=(10.0, 0.0))  # already closer than R + gap
    assert d.speed_cap == 0.0 and d.note.startswith("yielding: waiting")
    assert d.stop[1] == 0.0 and 0.0 < d.stop[0] <= 10.0


def test_a_stopped_car_takes_a_stop_just_ahead_as_reached():
    """A stop 0.3 m ahead (her estimate moved): a car that stands waits there (cap 0); one still
    rolling at 1 m/s, or any car with ``settle`` 0, is capped to brake in those 0.3 m."""
    ped = (3.5 + 0.3, 0.0)  # the stop R + gap = 3.5 m short of her: 0.3 m ahead of the car at 0
    stands = _decide(ped, (0.0, 0.0), speed=0.1)
    assert stands.speed_cap == 0.0 and stands.note.startswith("yielding: waiting")
    rolls = _decide(ped, (0.0, 0.0), speed=1.0)
    assert rolls.speed_cap == pytest.approx(math.sqrt(2 * 3.0 * 0.3)) and "stopping 0.3 m ahead" in rolls.note
    exact = Yielder(YieldConfig(settle=0.0)).decide(
        np.zeros(2), 0.1, pedestrians=np.array([ped]), velocities=np.zeros((1, 2)), radii=R, **ROAD
    )
    assert exact.speed_cap == pytest.approx(rolls.speed_cap)


def test_yield_config_is_validated():
    with pytest.raises(ValueError, match="lookahead"):
        YieldConfig(lookahead=0.0)
    with pytest.raises(ValueError, match="deceleration"):
        YieldConfig(deceleration=float("inf"))
    with pytest.raises(ValueError, match=r"settle must be a finite number >= 0, got -0\.5"):
        YieldConfig(settle=-0.5)
    with pytest.raises(ValueError, match="settle_speed must be a positive"):
        YieldConfig(settle_speed=0.0)


NOBODY = np.zeros((0, 2))


def _remembered(y, t, car=(0.0, 0.0), heading=0.0, peds=NOBODY):
    return y.remembered(t, np.array(car), heading, ROAD["road_start"], ROAD["road_normal"], ROAD["room"], 2.5, peds)


def test_one_the_car_waited_for_is_passed_around_after_memory_not_forgotten():
    """Issue 34 (varied Case II worlds, 1 frame/s): a texter the car stopped for beside her, turned
    away, left its camera's view; after ``memory`` s the car forgot her and drove past within R
    (1.42 m). Now, not found again, she is passed around where she would be (her last velocity
    across the road) until the car is R past her, she is found again, or her way leaves the road."""
    y = Yielder(YieldConfig())
    none = np.zeros((0, 2))

    def step(t, peds, vels):
        return y.decide(np.zeros(2), 0.0, pedestrians=peds, velocities=vels, radii=np.full(len(peds), 3.5),
                        time=t, safety_radius=2.5, heading=0.0, **ROAD)  # fmt: skip

    assert step(0.0, np.array([[6.0, 0.5]]), np.array([[0.0, -0.05]])) is not None  # sliding right at 0.05 m/s
    assert step(7.9, none, none) is not None  # waited for
    assert step(8.1, none, none) is None  # the wait is over ...
    pos, vel, sigma = _remembered(y, 8.1)  # ... but she is not forgotten: passed around where she would be
    np.testing.assert_allclose(pos, [[6.0, 0.5 - 0.05 * 8.1]])
    np.testing.assert_allclose(vel, [[0.0, -0.05]])
    assert sigma.shape == (1,)
    assert len(_remembered(y, 20.0, car=(5.0, 0.0))[0]) == 1  # beside the car: kept
    assert len(_remembered(y, 21.0, car=(8.6, 0.0))[0]) == 0  # R past her: released
    # found again (a pedestrian within ``rematch`` of her prediction): her track is the camera's
    y.reset()
    step(0.0, np.array([[6.0, 0.5]]), np.zeros((1, 2)))
    step(8.1, none, none)
    assert len(_remembered(y, 9.0, peds=np.array([[6.5, 1.0]]))[0]) == 0
    # walking off the road: released once R beyond its edge (2.1 m) the way she walks
    y.reset()
    step(0.0, np.array([[6.0, 0.5]]), np.array([[0.0, 0.2]]))  # slowly left: within R of the lane's line at 8 s
    step(8.1, none, none)
    assert len(_remembered(y, 20.0)[0]) == 1  # 0.5 + 0.2 * 20 = 4.5 < 2.1 + 2.5
    assert len(_remembered(y, 20.6)[0]) == 0  # 4.62 >= 4.6


def test_one_remembered_is_released_when_the_camera_looks_where_she_would_be_and_finds_nobody():
    """Released by looking, not by a clock: with the camera's view known (``view_deg``), one the
    car remembers is released once her predicted place has been whole in the image for
    ``view_confirm`` s (the tracker's confirmation) with nobody found there; out of view (beside
    the car, nearer than the image's lower edge reaches) she is kept."""
    cfg = YieldConfig(view_deg=70.0, view_forward=1.5, view_near=4.3, view_confirm=2.0)
    none = np.zeros((0, 2))

    def run(ped, heading, times):
        y = Yielder(cfg)
        y.decide(np.zeros(2), 0.0, pedestrians=np.array([ped]), velocities=np.zeros((1, 2)), radii=np.array([3.5]),
                 time=0.0, safety_radius=2.5, heading=heading, **ROAD)  # fmt: skip
        out = []
        for t in times:
            d = y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0), time=t,
                         safety_radius=2.5, heading=heading, **ROAD)  # fmt: skip
            out.append(d is not None)
        return out, y

    # 10 m ahead on the lane, in the middle of the image: released after 2 s of looking
    held, y = run((10.0, 0.0), 0.0, (0.5, 1.0, 2.4, 2.6))
    assert held == [True, True, True, False] and not y.remembers and len(_remembered(y, 3.0)[0]) == 0
    # the car stopped turned 35 deg away: she is 41 deg off the camera's axis (half its view 35), out of view
    held, y = run((10.0, 0.0), math.radians(-35.0), (0.5, 2.6, 7.9, 8.1))
    assert held == [True, True, True, False] and len(_remembered(y, 8.1, heading=math.radians(-35.0))[0]) == 1
    # 3 m ahead: below the image's lower edge (her feet nearer than 4.3 m from the camera): kept
    held, _ = run((4.0, 0.0), 0.0, (0.5, 2.6, 7.9))
    assert held == [True, True, True]
    # without the view the camera's looking releases no one
    y = Yielder(YieldConfig())
    y.decide(np.zeros(2), 0.0, pedestrians=np.array([[10.0, 0.0]]), velocities=np.zeros((1, 2)),
             radii=np.array([3.5]), time=0.0, safety_radius=2.5, heading=0.0, **ROAD)  # fmt: skip
    assert y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0), time=5.0,
                    safety_radius=2.5, heading=0.0, **ROAD) is not None  # fmt: skip


def test_looking_for_her_covers_where_her_uncertain_speed_across_the_road_may_have_taken_her():
    """Her prediction walks at her estimated speed across the road; a speed estimated from a frame or
    two is uncertain, so where she could be spreads across the road with time (z sigma of that
    speed times the time since). The camera must see all of that, not only her mean, before she is
    released by looking: a region that has spread beyond the image keeps her."""
    cfg = YieldConfig(view_deg=70.0, view_forward=1.5, view_near=4.3, view_confirm=2.0)
    none = np.zeros((0, 2))

    def held(speed_sigma):
        y = Yielder(cfg)
        cov = np.diag([0.01, 0.01, 0.01, speed_sigma**2])[None]  # (x, y, v_x, v_y); the road along x
        y.decide(np.zeros(2), 0.0, pedestrians=np.array([[10.0, 0.0]]), velocities=np.zeros((1, 2)),
                 radii=np.array([3.5]), covariances=cov, time=0.0, safety_radius=2.5, heading=0.0, **ROAD)  # fmt: skip
        return [y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0),
                         covariances=np.zeros((0, 4, 4)), time=t, safety_radius=2.5, heading=0.0, **ROAD) is not None
                for t in (0.5, 2.6, 4.0)]  # fmt: skip

    assert held(0.05) == [True, False, False]  # a speed known well: her place stays in view, released
    # 1.5 m/s of doubt: by 2.6 s she may be 6.4 m to either side, beyond the image's edge (5.95 m there)
    assert held(1.5) == [True, True, True]


def test_the_yielding_view_refuses_an_angle_outside_its_range_by_name():
    with pytest.raises(ValueError, match=r"yielding view_deg must be in \[0, 180\) degrees .* got 200"):
        YieldConfig(view_deg=200.0)
    with pytest.raises(ValueError, match="yielding view_confirm must be a finite number >= 0, got -1"):
        YieldConfig(view_confirm=-1.0)


def test_one_passed_around_is_where_her_last_sighting_says_not_where_her_coasted_track_drifted():
    """A track coasted out of view loses her speed (its walking model fades) and grows uncertain:
    given the sightings, one the car waited for is passed around where her last sighting, carried at
    its velocity across the road, puts her, as uncertain as that sighting carried so far; and only a
    pedestrian seen after that sighting finds her again (a track coasted near her prediction is no
    sighting)."""
    y = Yielder(YieldConfig())
    none = np.zeros((0, 2))
    # the input: her coasted track (standing, 3 m uncertain); the sighting 2 s before: sliding right at 0.1 m/s
    sightings = (np.array([[6.0, 0.7, 0.0, -0.1]]), np.diag([0.04, 0.04, 0.01, 0.01])[None], np.array([-2.0]))
    y.decide(np.zeros(2), 0.0, pedestrians=np.array([[6.0, 0.5]]), velocities=np.zeros((1, 2)),
             radii=np.array([3.5]), covariances=np.diag([9.0, 9.0, 0.01, 0.01])[None], time=0.0, safety_radius=2.5,
             heading=0.0, sightings=sightings, **ROAD)  # fmt: skip
    assert y.decide(np.zeros(2), 0.0, pedestrians=none, velocities=none, radii=np.zeros(0), time=8.1,
                    safety_radius=2.5, heading=0.0, **ROAD) is None  # fmt: skip
    pos, vel, sigma = _remembered(y, 10.0)
    np.testing.assert_allclose(pos, [[6.0, 0.7 - 0.1 * 12.0]])  # her sighting, 12 s on
    np.testing.assert_allclose(vel, [[0.0, -0.1]])
    # her sighting's uncertainty, carried: her range's sigma (0.2 m) and her speed's across the road (0.1 m/s, 12 s)
    np.testing.assert_allclose(sigma, [math.hypot(0.2, 0.1 * 12.0)])
    # a track there, last seen before her sighting (coasted), does not find her; one seen since does
    assert len(y.remembered(10.0, np.zeros(2), 0.0, ROAD["road_start"], ROAD["road_normal"], ROAD["room"], 2.5,
                            np.array([[6.0, -0.3]]), np.array([-3.0]))[0]) == 1  # fmt: skip
    assert len(y.remembered(10.1, np.zeros(2), 0.0, ROAD["road_start"], ROAD["road_normal"], ROAD["room"], 2.5,
                            np.array([[6.0, -0.3]]), np.array([10.0]))[0]) == 0  # fmt: skip
