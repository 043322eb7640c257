"""A camera frame's path to the controller (sim/driving/frame_path.py): perceive -> perception
latency -> track -> controller input, with ground truth for scoring only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.sim.driving.episode import DriveEnvironment
from trustnav.sim.driving.frame_path import Frame, PerceivedPath, PerceptionLatency, TruePath
from trustnav.sim.driving.world import load_drive_scenario


def _drive(sim: DriveEnvironment, steps: int) -> list:
    out = []
    for _ in range(steps):
        obs = sim.observe()
        out.append(obs)
        sim.advance([0.05, 0.5])
    return out


def _wrong_truth(sim: DriveEnvironment) -> None:
    """The scorer is handed a world 100 m away: only the reports may notice."""
    keep = sim.scoring.keep
    sim.scoring.keep = lambda i, bodies, pos, vel: keep(i, bodies, pos + 100.0, vel + 1.0)  # type: ignore[method-assign]


def test_the_perceived_path_sees_no_ground_truth():
    sc = load_drive_scenario("case-1")
    sc = replace(sc, sensing=replace(sc.sensing, perception_latency=0.1))
    plain, fooled = DriveEnvironment(sc, seed=3, capture_rate=5.0), DriveEnvironment(sc, seed=3, capture_rate=5.0)
    assert isinstance(plain.path, PerceivedPath)
    _wrong_truth(fooled)
    a, b = _drive(plain, 30), _drive(fooled, 30)
    assert sum(len(o.positions) for o in a) > 0  # the camera saw the pedestrians
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.positions, y.positions)
        np.testing.assert_array_equal(x.velocities, y.velocities)
        np.testing.assert_array_equal(x.trusts, y.trusts)
        np.testing.assert_array_equal(x.covariances, y.covariances)
    # ... while the scoring did see the wrong truth
    err = [v.estimate[:2] - v.position for f in fooled.frames for v in f.views if v.estimate is not None]
    assert err and min(np.hypot(*e) for e in err) > 50.0


def test_the_true_path_reads_the_world_not_the_scorer():
    sc = load_drive_scenario("case-1")
    sim = DriveEnvironment(sc, seed=0, state="true")
    assert isinstance(sim.path, TruePath)
    _wrong_truth(sim)
    obs = _drive(sim, 5)[-1]
    np.testing.assert_allclose(obs.positions, sim.pedestrians()[0])  # noise-free: the world itself
    assert obs.covariances is None


def _frame(i: int, t: float) -> Frame:
    return Frame(index=i, time=t, camera=None, people=[])  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(
    gaps=st.lists(st.floats(0.0, 0.5), min_size=1, max_size=15),
    latency=st.sampled_from([0.0, 0.05, 0.1, 0.3, 1.0]),
    step=st.sampled_from([0.05, 0.1, 0.25]),
)
def test_the_latency_stage_hands_on_each_frame_once_in_order_when_due(gaps, latency, step):
    times = np.cumsum(gaps)
    stage = PerceptionLatency(latency)
    got: list[tuple[int, float]] = []  # (frame index, when handed on)
    now, k = 0.0, 0
    while len(got) < len(times):
        while k < len(times) and times[k] <= now + 1e-12:
            stage.put(_frame(k, float(times[k])))
            k += 1
        got += [(f.index, now) for f in stage.due(now)]
        assert all(f.time > now + 1e-9 - latency for f in stage.in_flight)  # none kept past its time
        now += step
    assert [i for i, _ in got] == list(range(len(times)))
    for i, when in got:
        assert times[i] + latency - 1e-9 <= when < times[i] + latency + step + 1e-9  # the first step due
    assert len(stage) == 0


def test_a_frame_path_needs_a_known_state():
    with pytest.raises(ValueError, match="state must be one of"):
        DriveEnvironment(load_drive_scenario("case-1"), state="oracle")
