"""The paper's numerical scenarios (Section III): its claims, with our own numbers."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from trustnav.cli import main
from trustnav.sim import load_scenario, run_episode, run_scenario
from trustnav.sim.paper import with_overrides

R = 3.0


@pytest.fixture(scope="module")
def scenario2():
    return run_scenario("paper-2")


@pytest.fixture(scope="module")
def scenario3():
    return run_scenario("paper-3")


def test_scenario_1_distance_decreases_with_trust_and_keeps_margin():
    res = run_scenario("paper-1")
    runs = res.metrics["runs"]
    trusts = [r["trust"] for r in runs]
    d = [r["min_distance"][0] for r in runs]
    assert trusts == sorted(trusts) and len(trusts) >= 5
    assert all(a > b + 0.1 for a, b in itertools.pairwise(d)), d
    assert min(d) >= R
    assert all(r["margin_violations"] == 0 and r["solver_failures"] == 0 for r in runs)
    assert all(r["steps_to_goal"] is not None for r in runs)


def test_scenario_2_keeps_more_distance_from_the_less_trusted_pedestrian(scenario2):
    m = scenario2.metrics
    ctrl = m["control_equal_trust"]
    # pedestrian 2 has trust 0.5; the control run trusts both fully
    assert m["min_distance"][1] > ctrl["min_distance"][1] + 0.5
    assert min(m["min_distance"]) >= R and min(ctrl["min_distance"]) >= R
    assert m["margin_violations"] == ctrl["margin_violations"] == 0
    assert m["solver_failures"] == ctrl["solver_failures"] == 0
    assert m["slack_steps"] == 0
    assert m["steps_to_goal"] is not None


def test_scenario_2_no_trust_effect_at_low_reference_speed():
    """Documented in the fidelity report: at v_max = 5 no CBF row binds, trust changes nothing."""
    sc = with_overrides(load_scenario("paper-2"), reference_v_max=5.0)
    a = run_episode(sc).distances.min(axis=0)
    b = run_episode(sc, trusts=[1.0, 1.0]).distances.min(axis=0)
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_scenario_3_horizon_four_keeps_margin_and_trust_ordering(scenario3):
    for timing, runs in scenario3.metrics["timings"].items():
        r4 = next(r for r in runs if r["horizon"] == 4)
        assert r4["margin_violations"] == 0, timing
        high, low = r4["min_distance"]  # pedestrian 1 trust 1.0, pedestrian 2 trust 0.3
        assert low >= high, timing
        assert r4["solver_failures"] == 0 and r4["slack_steps"] == 0


def test_scenario_3_one_step_horizon_breaches_only_with_the_authors_timing(scenario3):
    t = scenario3.metrics["timings"]
    r1_code = next(r for r in t["authors_code"] if r["horizon"] == 1)
    r1_paper = next(r for r in t["paper"] if r["horizon"] == 1)
    assert r1_code["margin_violations"] > 0 and min(r1_code["min_distance"]) < R
    assert r1_paper["margin_violations"] == 0 and min(r1_paper["min_distance"]) >= R


def test_no_paper_scenario_uses_slack_or_fallback(scenario2, scenario3):
    for runs in scenario3.metrics["timings"].values():
        assert all(r["slack_steps"] == 0 and r["fallback_steps"] == 0 for r in runs)
    assert scenario2.metrics["control_equal_trust"]["slack_steps"] == 0


@pytest.mark.slow
def test_sqp_and_slsqp_agree_on_scenario_2_trajectory():
    sc = load_scenario("paper-2")
    fast = run_episode(sc, solver="sqp")
    ref = run_episode(sc, solver="slsqp")
    assert fast.ego.shape == ref.ego.shape
    assert np.max(np.abs(fast.ego - ref.ego)) < 1e-3


def test_cli_writes_figure_and_metrics(tmp_path, capsys):
    out = tmp_path / "s2"
    assert main(["scenario", "paper-2", "--out", str(out)]) == 0
    png = out / "paper-2.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    m = json.loads((out / "metrics.json").read_text())
    for doc in (m, m["control_equal_trust"]):
        assert {"min_distance", "steps_to_goal", "margin_violations", "solver_failures"} <= set(doc)
        assert isinstance(doc["min_distance"], list) and len(doc["min_distance"]) == 2
    assert "min distance" in capsys.readouterr().out


def test_scenario_files_are_validated(tmp_path):
    with pytest.raises(ValueError, match="unknown scenario"):
        load_scenario("paper-9")
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\ntitle = "x"\nego_start = [0, 0]\ngoal = [1, 1]\nspeed = 3\n'
                   '[[pedestrian]]\nposition = [0, 5]\n')  # fmt: skip
    with pytest.raises(ValueError, match=r"unknown key 'speed' in .*bad.toml: expected one of"):
        load_scenario(bad)
    assert main(["scenario", "paper-2", "--solver", "sqp", "--out", str(tmp_path / "ok")]) == 0
