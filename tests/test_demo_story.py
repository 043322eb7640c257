"""`trustnav demo` tells the story: the trust-aware run beside an equal-trust (trust-blind) run of
the same world, and the headline numbers of both (the library's :func:`run_demo`, built from the
comparison's :class:`ConstantTrustEnvironment`; the command writes its outputs once)."""

from __future__ import annotations

import functools
import json
from types import SimpleNamespace

import numpy as np
import pytest

from trustnav.cli import main
from trustnav.sim.driving import demo as story
from trustnav.sim.driving.compare import ConstantTrustEnvironment, compare_trust
from trustnav.sim.driving.demo import DEMO_EQUAL_TRUST, run_demo
from trustnav.sim.engine import Observation


def test_constant_trust_world_hands_the_controller_one_trust_and_passes_the_rest_through():
    obs = Observation(0.5, np.zeros(4), np.ones((3, 2)), np.zeros((3, 2)), np.array([0.1, 0.9, 0.4]))
    sim = SimpleNamespace(observe=lambda: obs, scenario="sc", frames=[1, 2])
    world = ConstantTrustEnvironment(sim, DEMO_EQUAL_TRUST)  # type: ignore[arg-type]
    seen = world.observe()
    assert seen.trusts.tolist() == [1.0, 1.0, 1.0]
    assert seen.positions is obs.positions and seen.time == 0.5
    assert world.scenario == "sc" and world.frames == [1, 2]


def test_compare_trust_drives_only_the_modes_asked_for_and_refuses_unknown_ones():
    from trustnav.sim.driving import load_drive_scenario

    sc = load_drive_scenario("case-1")
    with pytest.raises(ValueError, match="modes must be keys of TRUST_MODES"):
        compare_trust(sc, modes=("trust-aware", "constant trust 0.5"))


@pytest.fixture(scope="module")
def keypoints_demo():
    """The demo's story in keypoint sensing (fast), as the command runs it in render sensing."""
    return run_demo(0, sensing="keypoints")


def test_equal_trust_drive_goes_straight_between_the_two_pedestrians(keypoints_demo):
    m = keypoints_demo.runs()["equal_trust"]
    d = [p["min_distance"] for p in m["pedestrians"]]
    # Case I is symmetric: trusted alike, both pedestrians get the same room and the car keeps its lane
    assert abs(d[0] - d[1]) < 0.3 and m["max_lateral_offset"] < 0.25
    assert m["trust_given_to_controller"] == DEMO_EQUAL_TRUST


def test_trust_aware_run_passes_the_distracted_pedestrian_wider(keypoints_demo):
    m = keypoints_demo.metrics()
    aware = {p["name"]: p for p in m["pedestrians"]}
    # the paper's claim (Section IV): lower trust, larger clearance; equal trust, equal clearance
    assert aware["distracted"]["final_trust"] < aware["attentive"]["final_trust"]
    assert aware["distracted"]["min_distance"] > aware["attentive"]["min_distance"]
    assert m["equal_trust"]["pedestrians"] != m["pedestrians"] and "keypoints_sensing" in m
    # the keypoint run of the story is the same drive as `trustnav drive case-1 --sensing keypoints`
    assert m["keypoints_sensing"]["pedestrians"] == m["pedestrians"]


@pytest.mark.slow
def test_demo_prints_the_headline_and_writes_each_output_once(tmp_path, monkeypatch, capsys):
    from trustnav.viz import style

    monkeypatch.setattr(story, "run_demo", functools.partial(run_demo, sensing="keypoints"))
    written: list[str] = []
    real_save = style.save

    def save(fig, path):  # type: ignore[no-untyped-def]
        written.append(str(path).rsplit("/", 1)[-1])
        return real_save(fig, path)

    monkeypatch.setattr(style, "save", save)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "headline" in text and "equal trust 1 (trust-blind)" in text and "time to goal" in text
    assert "attentive (attentive)" not in text
    assert sorted(written) == ["distance.png", "top_view.png", "trust.png"], written  # each figure drawn once
    m = json.loads((out / "metrics.json").read_text())
    assert m["equal_trust"]["trust_given_to_controller"] == DEMO_EQUAL_TRUST
    assert [p["name"] for p in m["equal_trust"]["pedestrians"]] == ["attentive", "distracted"]
    assert "keypoints_sensing" in m and m["pedestrians"]
    assert (out / "top_view.png").stat().st_size > 50_000
