"""`trustnav demo` tells the story: the trust-aware run beside an equal-trust (trust-blind) run of
the same world, and the headline numbers of both."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

import trustnav.cli as cli
from trustnav.cli import main
from trustnav.sim.driving import load_drive_scenario
from trustnav.sim.driving.episode import DriveSimulation, drive, prepare_scenario
from trustnav.sim.engine import Observation


def test_equal_trust_world_hands_the_controller_one_trust_and_passes_the_rest_through():
    obs = Observation(0.5, np.zeros(4), np.ones((3, 2)), np.zeros((3, 2)), np.array([0.1, 0.9, 0.4]))
    sim = SimpleNamespace(observe=lambda: obs, scenario="sc", frames=[1, 2])
    world = cli._EqualTrustWorld(sim, 1.0)
    seen = world.observe()
    assert seen.trusts.tolist() == [1.0, 1.0, 1.0]
    assert seen.positions is obs.positions and seen.time == 0.5
    assert world.scenario == "sc" and world.frames == [1, 2]


def _keypoints_drive(sc, seed, progress=None, equal_trust=None):  # type: ignore[no-untyped-def]
    """The demo's drive in keypoint sensing (fast), as cli._demo_drive is in render sensing."""
    sim = DriveSimulation(prepare_scenario(sc), seed=seed)
    world = sim if equal_trust is None else cli._EqualTrustWorld(sim, equal_trust)
    return drive(world, "keypoints", progress=progress)


def test_equal_trust_drive_goes_straight_between_the_two_pedestrians():
    sc = load_drive_scenario("case-1")
    m = _keypoints_drive(sc, 0, equal_trust=cli.DEMO_EQUAL_TRUST).metrics()
    d = [p["min_distance"] for p in m["pedestrians"]]
    # Case I is symmetric: trusted alike, both pedestrians get the same room and the car keeps its lane
    assert abs(d[0] - d[1]) < 0.3 and m["max_lateral_offset"] < 0.25


@pytest.mark.slow
def test_demo_prints_the_headline_and_draws_both_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "_demo_drive", _keypoints_drive)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "headline" in text and "equal trust 1 (trust-blind)" in text and "time to goal" in text
    assert "attentive (attentive)" not in text
    m = json.loads((out / "metrics.json").read_text())
    assert m["equal_trust"]["trust_given_to_controller"] == cli.DEMO_EQUAL_TRUST
    assert [p["name"] for p in m["equal_trust"]["pedestrians"]] == ["attentive", "distracted"]
    assert "keypoints_sensing" in m and m["pedestrians"]
    assert (out / "top_view.png").stat().st_size > 50_000
