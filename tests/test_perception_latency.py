"""Perception latency in the drive (``SensingSpec.perception_latency``): a frame's people reach the
controller's estimates that long after its capture, stamped with the capture time."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from trustnav.campaigns.spec import PARAMS, SpecError, spec_from_dict
from trustnav.cli import main
from trustnav.sim.driving.episode import DriveEnvironment, run_drive
from trustnav.sim.driving.world import SensingSpec, load_drive_scenario


def _with_latency(name: str, latency: float):
    sc = load_drive_scenario(name)
    return replace(sc, sensing=replace(sc.sensing, perception_latency=latency))


def _step(sim: DriveEnvironment, command=(0.0, 0.0)):
    obs = sim.observe()
    sim.advance(list(command))
    return obs


@pytest.mark.parametrize("bad", [-0.1, math.nan, math.inf, 5.5])
def test_latency_is_validated_with_a_clear_message(bad):
    with pytest.raises(ValueError, match="perception_latency"):
        SensingSpec(perception_latency=bad)


def test_frames_reach_the_estimates_after_the_latency_stamped_with_their_capture_time():
    latency = 0.3
    sim = DriveEnvironment(_with_latency("case-1", latency), capture_rate=10.0)
    first_estimate = None
    for _ in range(30):  # 1.5 s at 20 Hz, car at rest
        obs = _step(sim)
        now = obs.time
        # delivered frames are exactly those captured at least `latency` ago, in capture order
        assert all(f.time <= now - latency + 1e-9 for f in sim.frames)
        assert all(c.time > now - latency + 1e-9 for c in sim.latency.in_flight)
        assert [f.index for f in sim.frames] == list(range(len(sim.frames)))
        assert [f.time for f in sim.frames] == pytest.approx([k / 10.0 for k in range(len(sim.frames))])
        if first_estimate is None and len(obs.positions):
            first_estimate = now
    # the pedestrians, in view from t = 0, reach the controller only once the first frame is delivered
    assert first_estimate == pytest.approx(latency)
    # each report says when the controller got it: the first control step at or after capture + latency
    lag = np.array([f.known_at - f.time for f in sim.frames])
    assert np.all(lag >= latency - 1e-9) and np.all(lag < latency + sim.period)
    assert sim._captured == len(sim.frames) + len(sim.latency)


def test_no_latency_delivers_each_frame_when_captured():
    sim = DriveEnvironment(load_drive_scenario("case-1"), capture_rate=10.0)
    obs = _step(sim)
    assert len(obs.positions) == 2 and len(sim.frames) == 1 and not len(sim.latency)
    report = DriveEnvironment(load_drive_scenario("case-1"), capture_rate=10.0).capture()
    assert report is not None and report.index == 0
    late = DriveEnvironment(_with_latency("case-1", 0.2), capture_rate=10.0)
    assert late.capture() is None and len(late.latency) == 1  # in flight, reported on delivery


def test_a_late_frame_is_predicted_to_now_for_a_walking_pedestrian():
    """Case II's walker at a brisk 1.4 m/s: the controller's estimate at each step is predicted from
    the capture time to the step, so latency does not leave it where the pedestrian was."""
    errors = {}
    for latency in (0.0, 0.5):
        sc = _with_latency("case-2", latency)
        sc = replace(sc, pedestrians=(replace(sc.pedestrians[0], velocity=(-1.4, 0.0)),))
        sim = DriveEnvironment(sc, capture_rate=10.0)
        err = []
        for _ in range(60):  # 3 s, car at rest, the walker crossing
            obs = _step(sim)
            if len(obs.positions):
                truth = sim.pedestrians()[0][0]
                err.append(float(np.min(np.linalg.norm(obs.positions - truth, axis=1))))
        errors[latency] = float(np.median(err))
    stale = 0.5 * 1.4  # where the frame saw the walker, 0.5 s ago
    assert errors[0.5] < 0.5 * stale  # not left behind by 0.5 s of walking
    assert errors[0.5] < errors[0.0] + 0.25


def test_drive_under_latency_keeps_r_and_reports_it():
    r = run_drive(_with_latency("case-1", 0.5), sensing="keypoints", seed=0, capture_rate=10.0)
    m = r.metrics()
    assert m["perception_latency"] == 0.5
    assert m["margin_violations"] == 0 and m["reached_goal"]
    near, far = (p["min_distance"] for p in m["pedestrians"])
    assert far > near  # still trust-aware: the distracted pedestrian passed wider


def test_cli_option_sets_and_checks_the_latency(tmp_path, capsys):
    out = tmp_path / "lat"
    argv = ["drive", "case-1", "--sensing", "keypoints", "--rate", "5", "--no-video", "--out", str(out)]
    assert main([*argv, "--perception-latency", "0.4"]) == 0
    assert json.loads((out / "metrics.json").read_text())["perception_latency"] == 0.4
    for bad in ("-1", "6", "nan"):
        assert main([*argv, "--overwrite", "--perception-latency", bad]) == 2
        assert "--perception-latency must be in [0, 5] s" in capsys.readouterr().err


def test_campaigns_sweep_the_latency():
    spec = {"name": "lat", "sweeps": [{"name": "d", "family": "drive", "seeds": 1,
            "params": {"scenario": "case-1", "perception_latency": {"values": [0.0, 0.3]}}}]}  # fmt: skip
    assert [p.params["perception_latency"] for p in spec_from_dict(spec).points()] == [0.0, 0.3]
    spec["sweeps"][0]["params"]["perception_latency"] = {"values": [-0.5]}
    with pytest.raises(SpecError, match="perception_latency"):
        spec_from_dict(spec)


def test_the_latency_bound_is_the_same_everywhere():
    """The CLI and campaign specs repeat MAX_PERCEPTION_LATENCY (they load without the simulator)."""
    from trustnav.cli import BOUNDS
    from trustnav.sim.driving.world import MAX_PERCEPTION_LATENCY

    assert BOUNDS["perception_latency"].hi == MAX_PERCEPTION_LATENCY
    check = PARAMS["drive"]["perception_latency"]
    assert check(MAX_PERCEPTION_LATENCY) == MAX_PERCEPTION_LATENCY
    with pytest.raises(Exception, match=r"\[0, 5\] s"):
        check(MAX_PERCEPTION_LATENCY + 0.01)
    SensingSpec(perception_latency=MAX_PERCEPTION_LATENCY)
