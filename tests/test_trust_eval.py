"""The project's labelled set (benchmarks/data/labels) and the metrics of benchmarks/trust_eval.py.

Fast: reads the label files (image sizes from the PNG/JPEG headers when ../shared is present) and
checks the matching and metric functions on a tiny hand-made example; the pipeline is not run.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
LABELS = ROOT / "benchmarks" / "data" / "labels"


def _load_script():
    spec = importlib.util.spec_from_file_location("trust_eval", ROOT / "benchmarks" / "trust_eval.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


te = _load_script()


@pytest.mark.parametrize("name", te.SETS)
def test_label_files_load_and_are_self_consistent(name):
    labels = json.loads((LABELS / f"{name}.json").read_text())
    assert labels["set"] == name and labels["_doc"] and labels["tuned_on"] and labels["frames"]
    held_out = name in ("rendered_heldout", "rendered_sequence")
    assert ("not tuned on" in labels["tuned_on"]) == held_out
    assert bool(labels.get("held_out")) == held_out
    people = 0
    for frame, entry in labels["frames"].items():
        w, h = entry.get("image_size", labels.get("image_size"))
        ids = [p["id"] for p in entry["people"]]
        assert len(ids) == len(set(ids)), (name, frame, "ids not unique")
        for p in entry["people"]:
            x1, y1, x2, y2 = p["bbox"]
            assert 0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h, (name, frame, p["id"], p["bbox"])
            assert p["phone"] in (True, False, None) and p["eye_contact"] in (True, False, None), (name, frame, p)
            vis = p["visible"]
            assert vis["in_view"] is True and vis["occluded"] in (True, False), (name, frame, p["id"])
            assert vis["height_px"] == pytest.approx(y2 - y1, abs=1.0)
            assert vis["height_px"] >= labels.get("min_height_px", 60), (name, frame, p["id"])
        for r in entry.get("ignore", []):
            assert len(r) == 4 and r[0] < r[2] and r[1] < r[3], (name, frame, r)
        people += len(entry["people"])
    assert people >= 10


def test_label_frames_exist_in_the_shared_data():
    for name in ("walk_a", "phone_a", "street"):
        labels = json.loads((LABELS / f"{name}.json").read_text())
        base = (ROOT / labels["source"]).resolve()
        if not base.is_dir():
            pytest.skip("needs ../shared")
        from PIL import Image

        for frame, entry in labels["frames"].items():
            with Image.open(base / frame) as im:
                assert list(im.size) == list(entry.get("image_size", labels.get("image_size"))), (name, frame)


def test_iou_and_hungarian_matching():
    assert te.iou([0, 0, 10, 10], [0, 0, 10, 10]) == 1.0
    assert te.iou([0, 0, 10, 10], [5, 0, 15, 10]) == pytest.approx(50 / 150)
    assert te.iou([0, 0, 10, 10], [20, 20, 30, 30]) == 0.0
    labels = [[10, 0, 20, 10], [13, 0, 23, 10]]
    dets = [[11, 0, 21, 10], [8, 0, 18, 10]]  # det 0 fits label 0 best (0.82), but only det 0 reaches label 1
    assert te.iou(dets[0], labels[0]) > te.iou(dets[0], labels[1]) > 0.5 > te.iou(dets[1], labels[1])
    assert te.match(dets, labels) == [(0, 1), (1, 0)]  # greedy would match det 0 -> label 0 and lose one
    assert te.match([[50, 50, 60, 60]], labels) == []
    assert te.match([], labels) == [] and te.match(dets, []) == []


def test_frame_classification_counts_duplicates_false_and_ignored():
    people = [{"id": "a", "bbox": [0, 0, 10, 20]}, {"id": "b", "bbox": [100, 0, 110, 20]}]
    dets = [
        [0, 0, 10, 20],  # a
        [1, 1, 9, 12],  # inside a: duplicate
        [200, 0, 210, 20],  # in the ignore region
        [300, 0, 310, 20],  # false
    ]
    res = te.classify_frame(dets, people, ignore=[[190, 0, 230, 30]])
    assert res["matched"] == {0: 0}
    assert res["duplicate"] == [1] and res["ignored"] == [2] and res["false"] == [3]


def test_id_switches_and_binary_scores():
    assert te.id_switches([1, 1, None, 1, 2, 2, 1]) == 2
    assert te.id_switches([None, None]) == 0
    s = te.binary_scores([(True, 0.9), (True, 0.2), (False, 0.7), (False, 0.1), (None, 0.9), (True, None)])
    assert (s["tp"], s["fp"], s["fn"], s["tn"]) == (1, 1, 2, 1)
    assert s["precision"] == pytest.approx(0.5) and s["recall"] == pytest.approx(1 / 3)
    assert s["f1"] == pytest.approx(0.4)
    empty = te.binary_scores([(False, 0.1)])
    assert empty["precision"] is None and empty["recall"] is None and empty["f1"] is None


def test_evaluate_on_a_tiny_sequence():
    labels = {
        "frames": {
            "f0": {"people": [{"id": "p", "bbox": [0, 0, 10, 20], "phone": True, "eye_contact": None},
                              {"id": "q", "bbox": [50, 0, 60, 20], "phone": False, "eye_contact": True}],
                   "ignore": []},
            "f1": {"people": [{"id": "p", "bbox": [2, 0, 12, 20], "phone": True, "eye_contact": False}], "ignore": []},
        }
    }  # fmt: skip
    records = [
        {"frame": "f0", "track_id": 1, "bbox": [0, 0, 10, 20], "phone": 0.8, "eye_contact": 0.1},
        {"frame": "f0", "track_id": 2, "bbox": [50, 0, 60, 20], "phone": 0.6, "eye_contact": 0.9},
        {"frame": "f0", "track_id": 3, "bbox": [400, 0, 410, 20], "phone": 0.0, "eye_contact": 0.0},
        {"frame": "f1", "track_id": 4, "bbox": [2, 0, 12, 20], "phone": 0.3, "eye_contact": 0.6},
    ]
    r = te.evaluate(labels, records)
    assert (r["people"], r["found"], r["false_boxes"], r["duplicates"], r["id_switches"]) == (3, 3, 1, 0, 1)
    assert (r["phone"]["tp"], r["phone"]["fp"], r["phone"]["fn"], r["phone"]["tn"]) == (1, 1, 1, 0)
    assert (r["eye_contact"]["tp"], r["eye_contact"]["fp"], r["eye_contact"]["fn"]) == (1, 1, 0)
    assert te.total({"a": r, "b": r})["people"] == 6


def test_cues_per_person_height_split_the_counts_by_the_labelled_box():
    people = [{"id": f"p{h}", "bbox": [10 * i, 0, 10 * i + 8, h], "phone": h >= 150, "eye_contact": h < 150}
              for i, h in enumerate((60, 120, 200, 300))]  # fmt: skip
    labels = {"frames": {"f0": {"people": people, "ignore": []}}}
    records = [{"frame": "f0", "track_id": i, "bbox": p["bbox"], "phone": 0.9, "eye_contact": 0.9}
               for i, p in enumerate(people)]  # fmt: skip
    r = te.evaluate(labels, records)
    bands = r["by_height"]
    assert list(bands) == ["< 100 px", "100-150 px", "150-250 px", ">= 250 px"]
    assert [(b["phone"]["tp"], b["phone"]["fp"]) for b in bands.values()] == [(0, 1), (0, 1), (1, 0), (1, 0)]
    assert [(b["eye_contact"]["tp"], b["eye_contact"]["fp"]) for b in bands.values()] == [
        (1, 0),
        (1, 0),
        (0, 1),
        (0, 1),
    ]
    both = te.total({"a": r, "b": r})["by_height"]
    assert both["150-250 px"]["phone"]["tp"] == 2 and both["< 100 px"]["eye_contact"]["tp"] == 2


def test_help_runs():
    with pytest.raises(SystemExit) as exc:
        te.parse_args(["--help"])
    assert exc.value.code == 0


def test_mp4_round_trip_reports_psnr_and_maps_frames_back(tmp_path):
    import cv2

    folder = tmp_path / "seq"
    folder.mkdir()
    rng = np.random.default_rng(1)
    base = cv2.GaussianBlur(rng.integers(0, 255, (96, 128, 3), dtype=np.uint8), (0, 0), 3)
    for i in range(4):
        cv2.imwrite(str(folder / f"f_{i:03d}.png"), np.roll(base, 3 * i, axis=1))
    video, psnr = te.mp4_of(folder, tmp_path / "seq.mp4")
    assert video.is_file() and 25.0 < psnr < 99.0
    recs = [{"frame": "seq.mp4#2", "track_id": 0, "bbox": [1, 2, 3, 4]}, {"frame": "seq.mp4#0", "track_id": 1}]
    mapped = te.video_records(recs, folder)
    assert [r["frame"] for r in mapped] == ["f_002.png", "f_000.png"] and mapped[0]["bbox"] == [1, 2, 3, 4]


def test_records_matched_counts_the_same_person_not_the_record_count():
    base = [{"frame": "a", "bbox": [0, 0, 10, 20]}, {"frame": "a", "bbox": [50, 0, 60, 20]},
            {"frame": "b", "bbox": [0, 0, 10, 20]}]  # fmt: skip
    # the coded run finds as many records, but one is another person (far away) on frame a
    coded = [{"frame": "a", "bbox": [1, 0, 11, 20]}, {"frame": "a", "bbox": [100, 0, 110, 20]},
             {"frame": "b", "bbox": [0, 1, 10, 21]}]  # fmt: skip
    assert te.records_matched(base, coded) == 2
    assert te.records_matched(base, []) == 0
    assert te.records_matched(base, base) == 3


def test_shifted_frames_and_labels_move_together(tmp_path):
    import cv2

    img = np.zeros((40, 60, 3), np.uint8)
    img[10:20, 5:15] = 255  # a white square at x 5-14, y 10-19
    cv2.imwrite(str(tmp_path / "f.png"), img)
    folder = tmp_path / "seq"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), img)
    moved = te.shifted_inputs([tmp_path / "f.png", folder], tmp_path / "out", 2, 1)
    assert moved == [tmp_path / "out" / "f.png", tmp_path / "out" / "seq"]
    for path in (moved[0], moved[1] / "a.png"):
        out = cv2.imread(str(path))
        ys, xs = np.nonzero(out[:, :, 0] > 128)
        assert (xs.min(), xs.max(), ys.min(), ys.max()) == (7, 16, 11, 20)  # moved by (2, 1), size kept
        assert out.shape == img.shape
    labels = {"set": "x", "frames": {"a.png": {"people": [{"id": "p", "bbox": [5, 10, 15, 20], "phone": True}],
                                               "ignore": [[0, 0, 4, 4]]}}}  # fmt: skip
    shifted = te.shifted_labels(labels, 2, 1)
    assert shifted["frames"]["a.png"]["people"][0]["bbox"] == [7, 11, 17, 21]
    assert shifted["frames"]["a.png"]["people"][0]["phone"] is True
    assert shifted["frames"]["a.png"]["ignore"] == [[2, 1, 6, 5]]
    assert labels["frames"]["a.png"]["people"][0]["bbox"] == [5, 10, 15, 20]  # the original is left alone


def test_jitter_is_checked_before_anything_runs():
    with pytest.raises(SystemExit, match="--jitter must be 0-6"):
        te.main(["--jitter", "7", "--set", "street"])


def test_held_out_sets_are_reported_apart_from_all():
    r = {"frames": 1, "people": 2, "found": 2, "detections": 2, "duplicates": 0, "false_boxes": 0,
         "ignored_boxes": 0, "id_switches": 0, "persons": 2,
         "phone": te.binary_scores([(True, 0.9), (False, 0.1)]),
         "eye_contact": te.binary_scores([(True, 0.9), (False, 0.7)])}  # fmt: skip
    both = te.total({"tuned": r, "held": {**r, "held_out": True}})
    assert both["people"] == 2 and both["eye_contact"]["fp"] == 1  # the held-out set is not summed


def test_held_out_recipe_differs_from_the_labelled_rendered_set():
    """The held-out rendered set is a different recipe (seed, poses, distances) of the same
    generator, and the labelled set's recipe is unchanged by the variant option."""
    spec = importlib.util.spec_from_file_location("make_rendered", LABELS / "rendered" / "make_rendered.py")
    assert spec is not None and spec.loader is not None
    pytest.importorskip("pybullet")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    base, held = (json.loads((LABELS / f"{n}.json").read_text()) for n in ("rendered", "rendered_heldout"))
    assert held["held_out"] is True and held["recipe"]["variant"] == "heldout"
    assert held["recipe"]["seed"] != base["recipe"]["seed"] and "variant" not in base["recipe"]
    default = mod.VARIANTS["default"]["roles"]
    assert [(r[0], r[2], r[3], r[4], r[5]) for r in default] == [r[:5] for r in mod.ROLES]
    assert {r[1] for r in mod.VARIANTS["heldout"]["roles"]} != {r[1] for r in default}  # other poses
    ids = {p["id"] for f in held["frames"].values() for p in f["people"]}
    assert ids == {r[0] for r in mod.HELDOUT_ROLES}
    for f in held["frames"].values():
        for p in f["people"]:
            role = next(r for r in mod.HELDOUT_ROLES if r[0] == p["id"])
            assert (p["phone"], p["eye_contact"]) == (role[3], role[4])  # truth from the scenario


def test_rendered_sequence_is_one_scene_whose_truth_comes_from_its_roles():
    """The held-out rendered video: one sequence (run as a folder), every person's phone and eye
    contact from the role that drew them, the walker moving right and the texter left across the
    view, the attentive man standing; hidden people are ignore regions, not labels."""
    spec = importlib.util.spec_from_file_location("make_rendered", LABELS / "rendered" / "make_rendered.py")
    assert spec is not None and spec.loader is not None
    pytest.importorskip("pybullet")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    seq = json.loads((LABELS / "rendered_sequence.json").read_text())
    assert seq["input"] == "folder" and not seq.get("independent_frames") and seq["recipe"]["variant"] == "sequence"
    assert len(seq["frames"]) == seq["recipe"]["frames"] == 40
    roles = {r[0]: r for r in mod.SEQUENCE_ROLES}
    centre: dict[str, list[float]] = {}
    for name in sorted(seq["frames"]):
        for p in seq["frames"][name]["people"]:
            assert (p["phone"], p["eye_contact"]) == (roles[p["id"]][3], roles[p["id"]][4])
            centre.setdefault(p["id"], []).append((p["bbox"][0] + p["bbox"][2]) / 2)
    assert centre["walker"][-1] - centre["walker"][0] > 200 and centre["texter"][-1] - centre["texter"][0] < -100
    assert max(centre["attentive"]) - min(centre["attentive"]) < 5
    hidden = [n for n, f in seq["frames"].items() if f["ignore"]]
    assert hidden and all("texter" not in {p["id"] for p in seq["frames"][n]["people"]} for n in hidden)
