"""Campaigns: spec validation, episode records of every family, Dask runs with resume and failures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from trustnav.campaigns import RecordStore, SpecError, load_spec, run_campaign, run_episode_task, spec_from_dict
from trustnav.campaigns.episodes import OUTCOME_FIELDS
from trustnav.campaigns.summary import summarise, wilson
from trustnav.cli import main

SMALL = {
    "name": "small",
    "sweeps": [
        {
            "name": "si",
            "family": "random_si",
            "seeds": 3,
            "params": {"horizon": {"values": [4, 7]}, "max_pedestrians": 4, "max_steps": 300},
        },
        {
            "name": "paper",
            "family": "paper",
            "seeds": 1,
            "params": {"scenario": "paper-1", "trust": {"values": [0.0, 1.0]}},
        },
    ],
}


def _write(tmp: Path, doc: dict, name: str = "spec.yaml") -> Path:
    import yaml

    p = tmp / name
    p.write_text(yaml.safe_dump(doc))
    return p


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines() if line.strip()]


# ---------------------------------------------------------------------------------------------- spec


@pytest.mark.parametrize(
    ("patch", "needle"),
    [
        ({"sweeps": []}, "sweeps must be a non-empty list"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
        ({"batch": 0}, "batch must be an integer >= 1 (episodes per Dask task) or auto, got 0"),
        ({"bogus": 1}, "unknown key 'bogus' in the top level: expected one of batch, description"),
        ({"record": {"check_relaxed": "yes"}}, "record.check_relaxed must be true or false, got 'yes'"),
        ({"seeds": 3}, "unknown key 'seeds' in the top level: did you mean 'seed'?"),
        ({"record": {"step_time": True}}, "unknown key 'step_time' in record: did you mean 'step_times'?"),
    ],
)
def test_spec_top_level_errors_name_the_field(patch: dict, needle: str) -> None:
    with pytest.raises(SpecError) as exc:
        spec_from_dict({**SMALL, **patch})
    assert needle in str(exc.value)


@pytest.mark.parametrize(
    ("sweep", "needle"),
    [
        ({"family": "nope"}, "sweeps.si.family must be one of 'paper', 'random_si'"),
        ({"seeds": 0}, "sweeps.si.seeds must be an integer >= 1"),
        ({"seeds": {"start": 2}}, "sweeps.si.seeds must be an integer >= 1 (seeds 0..n-1), {start: s, count: n}"),
        ({"params": {"horizon": 0}}, "sweeps.si.params.horizon must be an integer >= 1, got 0"),
        (
            {"params": {"horizon": {"values": [4, "x"]}}},
            "sweeps.si.params.horizon.values must be an integer >= 1, got 'x'",
        ),
        ({"params": {"trust": 1.5}}, "sweeps.si.params.trust must be a number in [0, 1], got 1.5"),
        ({"params": {"gamma_ini": {"uniform": [0.1]}}}, "sweeps.si.params.gamma_ini.uniform must be [low, high]"),
        ({"params": {"delta": {"uniform": [0.1, 0.2]}}}, "sweeps.si.random_points must be an integer >= 1"),
        ({"params": {"delta": {"grid": [1]}}}, "sweeps.si.params.delta must be a value or one sweep form"),
        (
            {"params": {"wheel": 1}},
            "unknown parameter 'wheel' for family 'random_si' in sweeps.si.params: expected one of",
        ),
        ({"params": {"lam": {"linspace": [1, 2]}}}, "sweeps.si.params.lam.linspace must be [low, high, count]"),
        (
            {"params": {"horizn": 4}},
            "unknown parameter 'horizn' for family 'random_si' in sweeps.si.params: did you mean 'horizon'?",
        ),
        ({"random_point": 2}, "unknown key 'random_point' in sweeps[0]: did you mean 'random_points'?"),
    ],
)
def test_spec_sweep_errors_name_the_field_and_form(sweep: dict, needle: str) -> None:
    doc = {"name": "x", "sweeps": [{"name": "si", "family": "random_si", "seeds": 2, **sweep}]}
    with pytest.raises(SpecError) as exc:
        spec_from_dict(doc)
    assert needle in str(exc.value)


def test_spec_required_scenario_and_file_forms(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match=r"missing key 'scenario' in sweeps.p.params \(required for family 'paper'\)"):
        spec_from_dict({"name": "x", "sweeps": [{"name": "p", "family": "paper", "seeds": 1}]})
    with pytest.raises(SpecError, match=r"expected a \.yaml, \.yml or \.toml file"):
        load_spec(_write(tmp_path, SMALL, "spec.json"))
    (tmp_path / "bad.yaml").write_text("name: [unclosed\n")
    with pytest.raises(SpecError, match="cannot parse"):
        load_spec(tmp_path / "bad.yaml")
    toml = tmp_path / "spec.toml"
    toml.write_text(
        'name = "small"\n[[sweeps]]\nname = "si"\nfamily = "random_si"\nseeds = 3\n'
        "[sweeps.params]\nhorizon = {values = [4, 7]}\nmax_pedestrians = 4\nmax_steps = 300\n"
        '[[sweeps]]\nname = "paper"\nfamily = "paper"\nseeds = 1\n'
        '[sweeps.params]\nscenario = "paper-1"\ntrust = {values = [0.0, 1.0]}\n'
    )
    assert [t.key for t in load_spec(toml).tasks()] == [t.key for t in load_spec(_write(tmp_path, SMALL)).tasks()]


def test_points_grid_times_random_draws_are_reproducible() -> None:
    doc = {
        "name": "x",
        "seed": 3,
        "sweeps": [
            {
                "name": "g",
                "family": "random_si",
                "seeds": {"start": 10, "count": 2},
                "random_points": 3,
                "params": {
                    "horizon": {"values": [4, 7]},
                    "delta": {"linspace": [0.04, 0.12, 3]},
                    "gamma_ini": {"uniform": [0.01, 0.05]},
                    "trust": {"choice": [0.2, 0.8]},
                },
            }
        ],
    }
    a, b = spec_from_dict(doc).tasks(), spec_from_dict(doc).tasks()
    assert len(a) == 2 * 3 * 3 * 2
    assert [t.key for t in a] == [t.key for t in b]
    assert {t.seed for t in a} == {10, 11}
    assert all(0.01 <= t.params["gamma_ini"] <= 0.05 and t.params["trust"] in (0.2, 0.8) for t in a)
    assert len({t.point_id for t in a}) == 18
    other = spec_from_dict({**doc, "seed": 4}).tasks()
    assert {t.params["gamma_ini"] for t in other} != {t.params["gamma_ini"] for t in a}


# ---------------------------------------------------------------------------------------------- episodes


def test_every_family_gives_the_same_record_fields_and_is_pure() -> None:
    doc = {
        "name": "fam",
        "sweeps": [
            {"name": "si", "family": "random_si", "seeds": [5], "params": {"max_steps": 200, "trust": 0.3}},
            {"name": "bi", "family": "random_bicycle", "seeds": [2], "params": {"max_steps": 120}},
            {"name": "pa", "family": "paper", "seeds": [0], "params": {"scenario": "paper-2", "position_jitter": 0.2}},
            {"name": "dr", "family": "drive", "seeds": [1], "params": {"scenario": "case-2", "attentive": False}},
        ],
    }
    tasks = spec_from_dict(doc).tasks()
    for task in tasks:
        rec = run_episode_task(task)
        assert rec["status"] == "ok", rec["error"]
        assert set(OUTCOME_FIELDS) <= set(rec)
        assert rec["steps"] > 0 and rec["min_distance"] > 0 and rec["safety_radius"] > 0
        assert len(rec["ped_trust"]) == len(rec["ped_min_distance"]) == rec["n_p"]
        again = run_episode_task(task)
        timing = {"wall_s", "cpu_s", "traceback"} | {k for k in rec if k.startswith(("step_ms", "step_cpu"))}
        assert {k: v for k, v in rec.items() if k not in timing} == {k: v for k, v in again.items() if k not in timing}
    si = run_episode_task(tasks[0])
    assert set(si["ped_trust"]) == {0.3}


def test_a_raising_episode_becomes_a_failed_record() -> None:
    doc = {
        "name": "f",
        "sweeps": [{"name": "s", "family": "random_si", "seeds": 1, "params": {"gamma_ini": 0.6, "delta": 0.6}}],
    }
    rec = run_episode_task(spec_from_dict(doc).tasks()[0])
    assert rec["status"] == "failed"
    assert rec["error"].startswith("ValueError: gamma_ini + delta must be <= 1")
    assert "Traceback" in rec["traceback"]
    assert rec["min_distance"] is None


def test_record_store_drops_a_line_cut_short(tmp_path: Path) -> None:
    path = tmp_path / "records.jsonl"
    path.write_text('{"key": "a", "status": "ok"}\n{"key": "b", "sta')
    store = RecordStore(path)
    assert set(store.latest()) == {"a"}
    with store:
        store.append({"key": "c", "status": "failed"})
        store.append({"key": "c", "status": "ok"})
    assert store.latest()["c"]["status"] == "ok"
    assert path.read_text().count("\n") == 3


def test_wilson_interval() -> None:
    lo, hi = wilson(0, 100)
    assert lo == 0.0 and 0.03 < hi < 0.04
    assert wilson(0, 0) is None


# ---------------------------------------------------------------------------------------------- Dask


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    c = LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
    )
    try:
        yield c
    finally:
        c.close()


def test_sweep_cli_on_two_local_workers_then_resume_does_nothing(tmp_path: Path, capsys) -> None:
    spec = _write(tmp_path, SMALL)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "2"]) == 0
    recs = _records(out)
    assert len(recs) == 8 and len({r["key"] for r in recs}) == 8
    assert all(r["status"] == "ok" for r in recs)
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["points"]) == 4
    for p in summary["points"]:
        assert {"episodes", "violations", "infeasible_steps", "failed", "min_distance_median"} <= set(p)
        assert p["episodes"] == p["planned"] and p["failed"] == 0 and p["min_distance_median"] > 0
    by_trust = {p["params"]["trust"]: p for p in summary["points"] if p["sweep"] == "paper"}
    assert by_trust[0.0]["min_distance_by_trust"]["low"]["n"] == 1
    assert (
        by_trust[0.0]["min_distance_median"] > by_trust[1.0]["min_distance_median"]
    )  # `weight`: low trust, wider berth
    assert (out / "summary.md").read_text().startswith("# Campaign `small`")
    assert (out / "figures" / "paper_min_distance_vs_trust.png").exists()
    assert (out / "figures" / "si_rates_vs_horizon.png").exists()
    captured = capsys.readouterr()
    assert "ran 8 (0 failed) on 2 workers" in captured.out
    # stderr is not a terminal here (a log file, CI): plain progress lines, the last one complete
    assert "\r" not in captured.err
    assert "trustnav: small: done: 8/8 ep (100 %)" in captured.err.splitlines()[-1]
    before = (out / "records.jsonl").read_text()
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "2"]) == 0
    assert "8 already recorded, ran 0" in capsys.readouterr().out
    assert (out / "records.jsonl").read_text() == before


def test_interrupted_campaign_resumes_only_missing_episodes(tmp_path: Path, cluster) -> None:
    spec = spec_from_dict(SMALL)
    out = tmp_path / "out"
    first = run_campaign(spec, out, scheduler=cluster.scheduler_address, progress=False)
    assert (first.ran, first.skipped, first.workers) == (8, 0, 2)
    lines = (out / "records.jsonl").read_text().splitlines()
    dropped = {json.loads(line)["key"] for line in lines[5:]}
    (out / "records.jsonl").write_text("\n".join(lines[:5]) + "\n" + lines[5][:20])  # killed mid-write
    seen: list[str] = []
    again = run_campaign(
        spec, out, scheduler=cluster.scheduler_address, progress=False, on_record=lambda r: seen.append(r["key"])
    )
    assert (again.ran, again.skipped) == (3, 5)
    assert set(seen) == dropped
    assert len(RecordStore(out / "records.jsonl").latest()) == 8


def test_an_interrupted_campaign_logs_where_it_stopped_never_100_percent(tmp_path: Path, cluster, capsys) -> None:
    spec = spec_from_dict(SMALL)
    seen: list[str] = []

    def stop_after_three(rec: dict) -> None:
        seen.append(rec["key"])
        if len(seen) == 3:
            raise KeyboardInterrupt  # Ctrl-C while the records come in

    with pytest.raises(KeyboardInterrupt):
        run_campaign(spec, tmp_path / "out", scheduler=cluster.scheduler_address, on_record=stop_after_three)
    err = capsys.readouterr().err
    last = err.splitlines()[-1]
    assert last.startswith("trustnav: small: interrupted: ") and "/8 ep (" in last, err
    assert "100 %" not in err


def test_failing_episodes_are_recorded_and_the_rest_complete(tmp_path: Path, cluster) -> None:
    doc = {
        "name": "failing",
        "batch": 2,
        "sweeps": [
            {
                "name": "g",
                "family": "random_si",
                "seeds": 3,
                "params": {"gamma_ini": 0.5, "delta": {"values": [0.3, 0.7]}, "max_steps": 200},
            }
        ],
    }
    spec = spec_from_dict(doc)
    out = tmp_path / "out"
    rep = run_campaign(spec, out, scheduler=cluster.scheduler_address, progress=False)
    assert (rep.ran, rep.failed) == (6, 3)
    recs = _records(out)
    bad = [r for r in recs if r["status"] == "failed"]
    assert {r["params"]["delta"] for r in bad} == {0.7}
    assert all("gamma_ini + delta must be <= 1" in r["error"] for r in bad)
    assert all(r["status"] == "ok" and r["steps"] > 0 for r in recs if r["params"]["delta"] == 0.3)
    s = summarise(spec, recs)
    assert [(p["episodes"], p["failed"]) for p in s["points"]] == [(3, 0), (3, 3)]
    assert s["sweeps"]["g"]["failed"] == 3
    retry = run_campaign(spec, out, scheduler=cluster.scheduler_address, progress=False, retry_failed=True)
    assert (retry.ran, retry.failed) == (3, 3)


def test_sweep_cli_bad_spec_is_one_line_and_exit_code_2(tmp_path: Path, capsys) -> None:
    bad = _write(
        tmp_path, {"name": "x", "sweeps": [{"name": "s", "family": "random_si", "seeds": 1, "params": {"horizon": 0}}]}
    )
    assert main(["sweep", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"trustnav: error: sweeps.s.params.horizon in {bad} must be an integer >= 1, got 0"
    assert not (tmp_path / "o").exists()
