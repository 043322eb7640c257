"""Trust-aware vs trust-blind in one command (issue 21, item 5): the same scenario with constant trust at both
ends of gamma beside the trust-aware run, one figure and a table."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from trustnav.cli import main
from trustnav.sim.driving import load_drive_scenario
from trustnav.sim.driving.compare import ConstantTrustEnvironment, compare_trust, comparison_rows


@pytest.fixture(scope="module")
def case1():
    return compare_trust(load_drive_scenario("case-1"), sensing="keypoints", seed=0)


def test_only_the_trust_the_controller_gets_differs(case1):
    modes = [r.mode for r in case1.runs]
    assert modes == ["trust-aware", "constant trust 0", "constant trust 1"]
    g = case1.scenario.control.gamma
    assert [r.gamma for r in case1.runs] == [None, pytest.approx(g.gamma_ini), pytest.approx(g.gamma_ini + g.delta)]
    # perception and trust estimation run as usual in every run: the records keep the estimated trusts
    for run in case1.runs[1:]:
        assert 0.0 < run.result.trusts[-1, 1] < run.result.trusts[-1, 0] < 1.0
    with pytest.raises(ValueError, match="trust"):
        ConstantTrustEnvironment(None, 1.5)  # type: ignore[arg-type]


def test_what_trust_buys_in_case_1(case1):
    rows = {r["mode"]: r for r in comparison_rows(case1)}
    d = {mode: [p["min_distance"] for p in r["pedestrians"]] for mode, r in rows.items()}
    aware, zero, one = d["trust-aware"], d["constant trust 0"], d["constant trust 1"]
    # trust-aware: more room for the distracted pedestrian than for the attentive one, by a metre and more
    assert aware[1] > aware[0] + 1.0
    assert aware[1] > max(zero[1], one[1]) + 0.3  # more than either trust-blind run gives it
    # trust-blind: both pedestrians alike (symmetric scene)
    assert abs(zero[0] - zero[1]) < 0.2 and abs(one[0] - one[1]) < 0.2
    # caution costs time: trust 0 is the slowest, trust-aware between
    t = {mode: r["time_to_goal"] for mode, r in rows.items()}
    assert t["constant trust 1"] <= t["trust-aware"] < t["constant trust 0"]
    assert all(r["margin_violations"] == 0 for r in rows.values())


@pytest.mark.slow
def test_what_trust_buys_on_the_step_out_street():
    """Issue 34, item 3: on step-out.toml the trust-aware car meets the texter at R and passes the
    trusted watcher at speed; constant trust 0 slows past her too and arrives later."""
    from pathlib import Path

    scenario = load_drive_scenario(Path(__file__).parents[1] / "examples/scenarios/step-out.toml")
    rows = {r["mode"]: r for r in comparison_rows(compare_trust(scenario, sensing="keypoints", seed=0))}
    t = {mode: r["time_to_goal"] for mode, r in rows.items()}
    texter = {mode: r["pedestrians"][0]["min_distance"] for mode, r in rows.items()}
    assert all(v is not None for v in t.values())  # every car arrives
    assert texter["trust-aware"] >= 2.5 and rows["trust-aware"]["margin_violations"] == 0
    assert t["constant trust 0"] > t["trust-aware"] + 0.5  # slow past the trusted watcher too
    assert texter["constant trust 1"] < texter["trust-aware"] - 0.3  # trust-blind at 1: nearer the texter


def test_cli_compare_writes_one_figure_a_table_and_metrics(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", "case-2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "attentive: constant trust 0" in printed and "distracted: trust-aware" in printed
    assert (out / "compare.png").stat().st_size > 30_000
    with open(out / "table.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["variant"], r["mode"]) for r in rows] == [
        (v, m) for v in ("attentive", "distracted") for m in ("trust-aware", "constant trust 0", "constant trust 1")
    ]
    m = json.loads((out / "metrics.json").read_text())
    assert len(m["runs"]) == 6 and len(m["table"]) == 6
    by = {(r["variant"], r["mode"]): r["pedestrians"][0]["min_distance"] for r in m["table"]}
    # the distracted walker gets more room trust-aware than trusted blindly; the attentive one less than at trust 0
    assert by[("distracted", "trust-aware")] > by[("distracted", "constant trust 1")] + 1.0
    assert by[("attentive", "trust-aware")] < by[("attentive", "constant trust 0")] - 1.0
    assert np.isfinite([r["max_lateral_offset"] for r in m["table"]]).all()


def test_cli_compare_refuses_a_bad_scenario_by_name(tmp_path, capsys):
    assert main(["compare", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "nope.toml does not exist" in err and not (tmp_path / "o").exists()


def test_the_claims_campaign_spec_validates_and_its_blind_sweeps_flatten_gamma():
    from pathlib import Path

    from trustnav.campaigns.spec import load_spec

    spec = load_spec(Path(__file__).resolve().parents[1] / "examples/campaigns/trust_claims.yaml")
    names = [s.name for s in spec.sweeps]
    assert names == [f"case{c}_{m}" for c in (1, 2) for m in ("aware", "blind0", "blind1")]
    g = load_drive_scenario("case-1").control.gamma
    for sweep in spec.sweeps:
        points = sweep.points(spec.seed, spec.record)
        assert len(points) == (1 if sweep.name.startswith("case1") else 2)  # Case II: attentive and distracted
        for point in points:
            if "blind" in sweep.name:
                assert point.params["delta"] < 1e-5  # one gamma for everybody: trust-blind
                low = sweep.name.endswith("0")
                want = g.gamma_ini if low else g.gamma_ini + g.delta
                assert point.params["gamma_ini"] == pytest.approx(want, abs=1e-5)
            else:
                assert "delta" not in point.params
