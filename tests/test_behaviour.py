"""Pedestrians who behave (issue 21, item 3): paths, step-out, kerb wait with gap acceptance and walking
while texting, as optional scenario data; the paper's constant-velocity pedestrians unchanged."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from trustnav.sim.driving import body, load_drive_scenario
from trustnav.sim.driving.behaviour import BehaviourSpec
from trustnav.sim.driving.episode import SimWorld
from trustnav.sim.driving.world import pedestrian_states

CROSSING = """
name = "crossing"
title = "a texting pedestrian waits at the kerb and crosses in a gap"
ego_start = [33.5, 129.0]
goal = [33.5, 80.0]
duration = 20.0

[[pedestrian]]
name = "crosser"
position = [39.0, 100.0]
attentive = false
pose = "distracted"
body_yaw_deg = 180.0
look_at_camera = false

[pedestrian.behaviour]
waypoints = [[36.6, 100.0], [27.0, 100.0]]
speed = 1.0
wait_at = 1
gap = 4.0
moving_pose = "texting_walk"
"""


def _world(tmp_path, text: str = CROSSING) -> SimWorld:  # type: ignore[no-untyped-def]
    path = tmp_path / "s.toml"
    path.write_text(text)
    return SimWorld(load_drive_scenario(path))


def _run(world: SimWorld, accel: float, seconds: float, period: float = 0.05) -> list[tuple[float, np.ndarray, float]]:
    """(time, pedestrian 0's position, the car's y) after each period, the car driven straight at ``accel``."""
    out = []
    for _ in range(round(seconds / period)):
        world.send([0.0, accel])
        world.advance(period)
        out.append((world.time, world.pedestrian_states()[0][0].copy(), float(world.ego_state()[1])))
    return out


def test_waits_at_the_kerb_while_the_car_comes_fast_and_crosses_behind_it(tmp_path):
    w = _world(tmp_path)
    trace = _run(w, 3.0, 8.0)  # full throttle: the car arrives within the 4 s gap
    xs = {round(t, 2): p[0] for t, p, _ in trace}
    assert xs[2.0] == pytest.approx(37.0, abs=0.06)  # walking to the kerb at 1 m/s
    assert xs[3.0] == pytest.approx(36.6) and xs[4.0] == pytest.approx(36.6)  # waiting
    car_past = min(t for t, _, y in trace if y < 100.0 - 1.0)  # the car's reference point 1 m past the crossing
    started = min(t for t, p, _ in trace if p[0] < 36.6 - 1e-6)
    assert car_past - 0.06 <= started <= car_past + 0.06  # it went only once the car had passed
    assert trace[-1][1][0] < 36.0 and w.pedestrian_states()[1][0][0] == pytest.approx(-1.0)  # crossing at 1 m/s


def test_a_stopped_car_gives_the_gap_and_a_pedestrian_gives_up_after_max_wait(tmp_path):
    w = _world(tmp_path)
    trace = _run(w, 0.0, 6.0)  # the car stands: the walker does not wait at the kerb
    assert trace[-1][1][0] < 36.6 - 2.5
    impatient = CROSSING.replace("gap = 4.0", "gap = 1000.0\nmax_wait = 1.0")
    w = _world(tmp_path, impatient.replace("ego_start = [33.5, 129.0]", "ego_start = [33.5, 129.0]\nego_speed = 8.0"))
    trace = _run(w, 0.0, 4.5)
    x = {round(t, 2): p[0] for t, p, _ in trace}
    assert x[3.0] == pytest.approx(36.6)  # reached the kerb at 2.4 s, waits ...
    assert x[4.5] < 36.6  # ... for 1 s at most


def test_step_out_and_paths(tmp_path):
    sc = load_drive_scenario("case-2")
    walker = sc.pedestrians[0]
    step_out = dataclasses.replace(walker, velocity=(-1.5, 0.0), behaviour=BehaviourSpec(start_time=2.0))
    w = SimWorld(dataclasses.replace(sc, pedestrians=(step_out,)))
    trace = _run(w, 0.0, 3.0)
    x = {round(t, 2): p[0] for t, p, _ in trace}
    assert x[2.0] == pytest.approx(walker.position[0]) and x[3.0] == pytest.approx(walker.position[0] - 1.5)
    path = dataclasses.replace(walker, behaviour=BehaviourSpec(waypoints=((37.5, 99.0), (35.5, 99.0)), speed=2.0))
    w = SimWorld(dataclasses.replace(sc, pedestrians=(path,)))
    trace = _run(w, 0.0, 3.0)
    pos = {round(t, 2): p for t, p, _ in trace}
    np.testing.assert_allclose(pos[0.5], (37.5, 100.0), atol=1e-6)
    np.testing.assert_allclose(pos[1.5], (36.5, 99.0), atol=1e-6)
    np.testing.assert_allclose(pos[3.0], (35.5, 99.0), atol=1e-6)  # stands at the end
    assert np.all(w.pedestrian_states()[1] == 0)


def test_without_a_behaviour_the_paper_pedestrians_move_as_before():
    sc = load_drive_scenario("case-2")
    assert all(p.behaviour is None for p in sc.pedestrians)
    w = SimWorld(sc)
    w.send([0.0, 1.0])
    _, peds = w.advance(0.5)
    p0, v0 = np.array(sc.pedestrians[0].position), np.array(sc.pedestrians[0].velocity)
    t = np.arange(1, len(peds) + 1) * (0.5 / len(peds))
    assert np.array_equal(peds[:, 0], p0[None] + t[:, None] * v0[None])
    assert np.array_equal(w.pedestrian_states()[0], pedestrian_states(sc, w.time)[0])


def test_texting_walk_pose_walks_slower_with_the_phone_and_the_head_down():
    args = ((0.0, 0.0), 0.0)
    walk = [body.pedestrian_skeleton("walking", *args, t, body.WALKER_LOOK) for t in (0.0, 0.3)]
    text = [body.pedestrian_skeleton("texting_walk", *args, t, body.DISTRACTED_LOOK) for t in (0.0, 0.3)]
    assert text[0].phone is not None and walk[0].phone is None
    assert text[0].head_pitch > math.radians(25) > walk[0].head_pitch
    ankle = slice(15, 17)
    moved = [float(np.abs(s[1].joints[ankle] - s[0].joints[ankle]).max()) for s in (walk, text)]
    assert moved[1] > 0.02  # the legs walk
    gait = body.STEPS_PER_SECOND
    assert body.TEXTING_CADENCE < 1.0 and gait * body.TEXTING_CADENCE < gait


@pytest.mark.parametrize(
    ("edit", "expected"),
    [("speed = 1.0", "speed = 0"), ("wait_at = 1", "wait_at = 5"),
     ('moving_pose = "texting_walk"', 'moving_pose = "run"'), ("gap = 4.0", "gap = 4.0\npatience = 2")],
)  # fmt: skip
def test_bad_behaviour_is_refused_naming_the_key(tmp_path, edit, expected):
    path = tmp_path / "s.toml"
    path.write_text(CROSSING.replace(edit, expected))
    key = expected.split("\n")[-1].split(" ")[0]
    with pytest.raises(ValueError, match=key) as exc:
        load_drive_scenario(path)
    assert "crosser" in str(exc.value)
