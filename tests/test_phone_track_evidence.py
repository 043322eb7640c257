"""benchmarks/phone_track_evidence.py: labels carried along tracks, the replay and the forward filter,
on hand-made recordings (no pipeline run)."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load_script():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location(
        "phone_track_evidence", ROOT / "benchmarks" / "phone_track_evidence.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


pte = _load_script()


def _recording() -> dict:
    """One sequence at 10 frames/s: track 1 (labelled phone at t = 0.0 and 0.3, unlabelled between
    and after), track 2 (labelled False at 0.0, True at 0.3: no carrying between disagreeing labels)."""
    kp, conf = np.zeros((17, 2)), np.ones(17)
    calls, records = [], []
    for k in range(5):
        t = k / 10
        people = []
        for tid in (1, 2):
            box = (10.0 * tid, float(k), 10.0 * tid + 5, k + 20.0)
            people.append((tid, kp, conf, box, 0.1 * tid))
            records.append({"frame": f"f{k}.png", "track_id": tid, "bbox": [round(v, 1) for v in box]})
        calls.append((7, t, people))
    labels = {
        "frames": {
            "f0.png": {"people": [{"id": "a", "bbox": [10, 0, 15, 20], "phone": True},
                                  {"id": "b", "bbox": [20, 0, 25, 20], "phone": False}]},
            "f3.png": {"people": [{"id": "a", "bbox": [10, 3, 15, 23], "phone": True},
                                  {"id": "b", "bbox": [20, 3, 25, 23], "phone": True}]},
        }
    }  # fmt: skip
    return {"calls": calls, "records": records, "labels": labels}


def test_labels_are_carried_only_between_agreeing_labelled_frames_of_one_track():
    rows = pte.person_frames(_recording())
    by = {(r["track"], round(r["time"], 1)): r for r in rows}
    assert [by[(1, t)]["carried"] for t in (0.0, 0.1, 0.2, 0.3, 0.4)] == [True, True, True, True, None]
    assert [by[(1, t)]["label"] for t in (0.0, 0.1, 0.3)] == [True, None, True]  # hand labels as they are
    assert [by[(2, t)]["carried"] for t in (0.0, 0.1, 0.2, 0.3)] == [False, None, None, True]
    assert by[(2, 0.2)]["frame"] == "f2.png" and by[(1, 0.0)]["person"] == "a"


def test_replay_feeds_a_fresh_model_per_sequence_in_order():
    rows = pte.person_frames(_recording())
    seen = []

    class Model:
        def __init__(self):
            seen.append(self)
            self.n = 0

        def add_pose(self, track_id, time, kp, conf):
            self.n += 1

            class R:
                phone = float(self.n)

            return R()

    values = pte.replay(rows, Model)
    assert len(seen) == 1 and values == [float(i) for i in range(1, len(rows) + 1)]


def test_forward_filter_accumulates_evidence_and_forgets():
    from trustnav.perception.phone import PhoneCalibration

    flat = PhoneCalibration(-3.0, 6.0)  # geometry 0.5 -> P 0.5: no evidence either way
    f = pte.ForwardFilter(flat, persist_s=10.0, corr_s=0.1)
    kp = np.zeros((17, 2))
    one = f.add_pose(-1, None, kp, np.ones(17))  # no pose cue: geometry 0, judged alone
    assert one.phone == pytest.approx(flat(0.0))
    # repeated looks at g = 0 on a track: the posterior falls below one look's
    outs = [f.add_pose(4, t / 10, kp, np.ones(17)).phone for t in range(5)]
    assert outs[0] == pytest.approx(flat(0.0)) and all(b < a for a, b in itertools.pairwise(outs))


def test_a_missing_or_foreign_poses_file_is_one_error_naming_it(tmp_path, capsys):
    foreign = tmp_path / "notes.txt"
    foreign.write_text("# not a recording\n")
    for path in (tmp_path / "missing.pkl", foreign):
        with pytest.raises(SystemExit):
            pte.main(["--poses", str(path)])
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert f"--poses '{path}': not a file of --record" in err
