"""The learned person detector (issue 35): model file resolution and errors, decoding, and the
geometry gate that keeps only people standing on the ground at a human size."""

from __future__ import annotations

import hashlib
import io
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.perception import detector as det
from trustnav.perception.ground_gate import MIN_SPREAD, GateConfig, HorizonFit, gate_boxes

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
MODEL = SHARED / "models" / "yolox" / "yolox_nano.onnx"
needs_model = pytest.mark.skipif(not MODEL.is_file(), reason="needs ../shared/models/yolox/yolox_nano.onnx")


def _no_download(*args, **kwargs):
    raise AssertionError("no download may be tried")


def test_a_missing_model_path_is_one_line_naming_it_and_never_downloaded(tmp_path, monkeypatch):
    monkeypatch.setattr(urllib.request, "urlopen", _no_download)
    with pytest.raises(FileNotFoundError) as err:
        det.resolve_model(tmp_path / "nope.onnx")
    msg = str(err.value)
    assert "\n" not in msg and str(tmp_path / "nope.onnx") in msg and "--detector-model" in msg
    with pytest.raises(FileNotFoundError, match="a folder, not a file"):
        det.resolve_model(tmp_path)


def test_a_corrupt_model_file_is_one_line_naming_it(tmp_path, monkeypatch):
    monkeypatch.setattr(urllib.request, "urlopen", _no_download)
    bad = tmp_path / "yolox_nano.onnx"
    bad.write_bytes(b"not an onnx model")
    with pytest.raises(ValueError) as err:
        det.PersonDetector(bad)
    msg = str(err.value)
    assert "\n" not in msg and str(bad) in msg and "TRUSTNAV_YOLOX_MODEL" in msg


class _Response(io.BytesIO):
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_without_a_local_file_the_model_is_downloaded_once_and_checked(tmp_path, monkeypatch, capsys):
    payload = b"model bytes"
    cache = tmp_path / "cache" / "trustnav" / det.MODEL_NAME
    monkeypatch.setattr(det, "_candidates", lambda: ([tmp_path / "none.onnx", cache], cache))
    monkeypatch.setattr(urllib.request, "urlopen", lambda url, timeout: _Response(payload))
    with pytest.raises(FileNotFoundError, match="sha256"):  # not the release's file: nothing kept
        det.resolve_model()
    assert not cache.exists() and not cache.with_suffix(".part").exists()
    monkeypatch.setattr(det, "YOLOX_SHA256", hashlib.sha256(payload).hexdigest())
    assert det.resolve_model() == cache and cache.read_bytes() == payload
    assert "downloading" in capsys.readouterr().err
    monkeypatch.setattr(urllib.request, "urlopen", _no_download)
    assert det.resolve_model() == cache  # the cached copy, no second download
    cache.unlink()
    with pytest.raises(FileNotFoundError, match="allow the download"):
        det.resolve_model(download=False)


def test_the_environment_variable_is_a_place_the_model_is_found(tmp_path, monkeypatch):
    f = tmp_path / "my.onnx"
    f.write_bytes(b"x")
    monkeypatch.setenv(det.MODEL_ENV, str(f))
    candidates, _ = det._candidates()
    assert f in candidates


def test_decode_places_boxes_and_keeps_only_people():
    grid, stride = det._anchors(416, 416)
    out = np.zeros((len(grid), 85), dtype=np.float32)
    # a person centred on cell (10, 20) of stride 8, 40 x 80 network px; a duplicate beside it
    k = 20 * 52 + 10
    out[k, :4] = [0.5, 0.5, np.log(40 / 8), np.log(80 / 8)]
    out[k, 4], out[k, 5] = 0.9, 0.9
    out[k + 1, :4] = [0.0, 0.5, np.log(40 / 8), np.log(80 / 8)]
    out[k + 1, 4], out[k + 1, 5] = 0.9, 0.6
    # a confident cell phone (class 67) is not a person
    out[k + 200, 4], out[k + 200, 5 + 67] = 0.99, 0.99
    boxes, scores = det.decode(out, grid, stride, 0.5, (832, 832), 0.25, 0.45)
    assert len(boxes) == 1 and scores[0] == pytest.approx(0.81, abs=1e-6)
    cx, cy = (10.5 * 8) / 0.5, (20.5 * 8) / 0.5
    assert boxes[0] == pytest.approx([cx - 40, cy - 80, cx + 40, cy + 80], abs=1e-3)


@needs_model
def test_the_detector_boxes_the_walkers_of_a_real_frame():
    import cv2

    frame = cv2.imread(str(SHARED / "data" / "sequences" / "walk_a" / "image_00005310_0.png"))[:, :, ::-1].copy()
    d = det.PersonDetector()
    boxes, scores = d(frame)
    # the labelled people of this frame (benchmarks/data/labels/walk_a.json)
    for label in ([527, 165, 570, 300], [437, 167, 470, 257], [485, 157, 520, 245]):
        ious = [_iou(b, label) for b in boxes]
        assert max(ious) >= 0.5
    assert np.all(np.diff(scores) <= 0) and np.all((scores >= d.min_score) & (scores <= 1))


@needs_model
def test_class_scores_find_the_phone_held_at_a_mouth_and_not_on_the_others():
    """The cell-phone score on squares around each head of crossing.jpg (mean over 9 placements 4 % of
    the person's height apart: one placement's score moves 0.1-0.6 with the crop): the older woman
    speaking into the phone at her mouth stands out from every other person of the photo, and the
    anchor that sees it lies at her mouth, in frame pixels (benchmarks/phone_detector_evidence.py)."""
    import json

    import cv2

    frame = cv2.imread(str(SHARED / "data" / "street_images" / "crossing.jpg"))[:, :, ::-1].copy()
    labels = Path(__file__).resolve().parents[1] / "benchmarks" / "data" / "labels" / "street.json"
    people = json.loads(labels.read_text())["frames"]["crossing.jpg"]["people"]
    d = det.PersonDetector()
    mean, where = {}, {}
    for p in people:
        x1, y1, x2, y2 = p["bbox"]
        h = y2 - y1
        runs = [
            d.class_scores(frame, ((x1 + x2) / 2 + i * 0.04 * h, y1 + (0.15 + j * 0.04) * h, 0.45 * h))
            for i in (-1, 0, 1)
            for j in (-1, 0, 1)
        ]
        mean[p["id"]] = float(np.mean([s.max() for _, s in runs]))
        centres, scores = max(runs, key=lambda r: r[1].max())
        where[p["id"]] = (centres[scores.argmax()], p["bbox"])
    phone = [k for k in mean if "phone held at the mouth" in k]
    assert len(phone) == 1
    others = max(v for k, v in mean.items() if k != phone[0])
    assert mean[phone[0]] > 0.25 and mean[phone[0]] > 2 * others
    (x, y), (x1, y1, x2, y2) = where[phone[0]]
    assert x1 < x < x2 and y1 < y < y1 + 0.3 * (y2 - y1)  # at the head and hand, not on the body below


@needs_model
def test_class_scores_reject_a_class_outside_coco_and_an_empty_square():
    d = det.PersonDetector()
    frame = np.zeros((64, 64, 3), np.uint8)
    for bad in (80, -1, 2.5, True):
        with pytest.raises(ValueError, match="COCO class index 0-79"):
            d.class_scores(frame, (32, 32, 32), bad)
    for region in ((32, 32, 4), (np.nan, 32, 32)):
        with pytest.raises(ValueError, match="side >= 8 px"):
            d.class_scores(frame, region)
    centres, scores = d.class_scores(frame, (0, 0, 40))  # half outside the frame: the detector's grey
    assert centres.shape == (3549, 2) and scores.shape == (3549,) and np.all((scores >= 0) & (scores <= 1))


@needs_model
def test_the_input_shaped_to_the_frame_gives_the_square_inputs_boxes():
    """The release's graph read with its input declared 416 x 416 again is the same model to the bit;
    shaped to a 640 x 480 frame (416 x 320, no grey quarter) it gives the square input's boxes."""
    import cv2

    d = det.PersonDetector(fit_aspect=True)
    assert d.input_shape(480, 640) == (320, 416) and d.input_shape(720, 720) == (416, 416)
    blob = np.random.default_rng(0).uniform(0, 255, (1, 3, 416, 416)).astype(np.float32)
    same = det.with_input_shape(MODEL.read_bytes(), 416, 416)
    square = d._session_for((416, 416))[0]
    import onnxruntime as ort

    rebuilt = ort.InferenceSession(same, providers=["CPUExecutionProvider"])
    name = square.get_inputs()[0].name
    assert np.array_equal(square.run(None, {name: blob})[0], rebuilt.run(None, {name: blob})[0])
    frame = cv2.imread(str(SHARED / "data" / "sequences" / "walk_a" / "image_00005310_0.png"))[:, :, ::-1].copy()
    fitted, _ = d(frame)
    padded, _ = det.PersonDetector()(frame)
    assert len(fitted) == len(padded)
    assert all(max(_iou(b, a) for a in fitted) >= 0.9 for b in padded)
    small = det.PersonDetector(input_size=320, fit_aspect=True)
    assert small.input_shape(480, 640) == (256, 320)
    assert len(small(frame)[0]) >= 3
    with pytest.raises(ValueError, match="input_size must be None"):
        det.PersonDetector(input_size=300)


def _iou(a, b) -> float:
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


# -- the geometry gate ---------------------------------------------------------------------------


def _person(feet: float, v0: float, k: float, x: float = 100.0, height_m: float = 1.7) -> np.ndarray:
    h = k * (feet - v0) * height_m / 1.7
    return np.array([x, feet - h, x + 0.35 * h, feet])


@settings(max_examples=60, deadline=None)
@given(
    v0=st.floats(100, 400),
    k=st.floats(0.4, 1.6),
    feet=st.lists(st.floats(0, 1), min_size=3, max_size=8, unique=True),
    height=st.floats(1.55, 1.85),
)
def test_the_horizon_is_recovered_from_people_of_one_height(v0, k, feet, height):
    rows = np.array([v0 + 30 + f * 300 for f in feet])
    heights = k * (rows - v0) * height / 1.7
    fit = HorizonFit()
    for row, h in zip(rows, heights, strict=True):
        fit.add(row, h)
    got = fit.fit()
    if np.ptp(rows) < MIN_SPREAD * np.median(heights):
        assert got is None  # feet on nearly one row: no horizon is claimed
        return
    assert got is not None
    v0_fit, k_fit, spread = got
    assert abs(v0_fit - v0) < 1e-6 * v0 and k_fit == pytest.approx(k * height / 1.7, rel=1e-9) and spread < 1e-9


@settings(max_examples=60, deadline=None)
@given(
    v0=st.floats(100, 400),
    k=st.floats(0.4, 1.6),
    feet=st.lists(st.floats(0, 1), min_size=3, max_size=8, unique=True),
    heights_m=st.lists(st.floats(1.55, 1.85), min_size=8, max_size=8),
)
def test_a_horizon_fitted_from_people_of_varied_heights_predicts_them_within_their_spread(v0, k, feet, heights_m):
    # the horizon itself is only as sure as people's heights (+-9 % over feet spread over half a
    # person's height moves it by a third of that height or more); what the gate uses is the height
    # it predicts at a row, and that must be as good as people's own heights
    rows = np.array([v0 + 30 + f * 300 for f in feet])
    heights = np.array([k * (r - v0) * hm / 1.7 for r, hm in zip(rows, heights_m, strict=False)])
    fit = HorizonFit()
    for row, h in zip(rows, heights, strict=True):
        fit.add(row, h)
    got = fit.fit()
    if got is None:
        assert np.ptp(rows) < MIN_SPREAD * np.median(heights)  # refused only for feet on nearly one row
        return
    v0_fit, k_fit, _ = got
    assert v0_fit < rows.min()  # the horizon above every person's feet
    predicted = k_fit * (rows - v0_fit)
    assert np.median(np.abs(np.log(heights / predicted))) <= np.log(1.85 / 1.55) + 1e-9


def test_a_logo_on_the_dashboard_and_a_box_above_the_horizon_are_rejected_with_reasons():
    v0, k = 240.0, 1.1
    people = [_person(f, v0, k, x=60.0 * i) for i, f in enumerate((300.0, 340.0, 380.0, 420.0))]
    logo = np.array([300.0, 440.0, 330.0, 470.0])  # 30 px tall at row 470: a person there is ~250 px
    sky = np.array([500.0, 100.0, 520.0, 150.0])  # feet above the horizon
    boxes = [*people, logo, sky]
    keep, rejected = gate_boxes(boxes, [0.9] * len(boxes), (640, 480))
    assert keep == [0, 1, 2, 3]
    assert len(rejected) == 2 and all(r.reason for r in rejected)
    assert "above the horizon" in rejected[1].reason and "px tall" in rejected[0].reason


def test_without_a_fit_the_prior_rejects_only_what_no_horizon_allows():
    # one person and one logo: no fit; the logo at the image's bottom is far too small for any horizon
    person = np.array([300.0, 150.0, 360.0, 330.0])
    logo = np.array([40.0, 440.0, 90.0, 470.0])
    keep, rejected = gate_boxes([person, logo], [0.9, 0.9], (640, 480), config=GateConfig())
    assert keep == [0] and len(rejected) == 1
    cut = np.array([200.0, 300.0, 260.0, 479.0])  # cut by the frame's bottom: feet unseen, not judged
    keep, _ = gate_boxes([cut], [0.9], (640, 480))
    assert keep == [0]


def test_with_the_camera_known_heights_follow_the_feet_row():
    from trustnav.geometry.camera import CameraSpec

    cam = CameraSpec(width=640, height=480, fov_deg=70.0, up=1.4).pose([0.0, 0.0], 0.0)
    # a 1.7 m person 10 m ahead, projected; a 1.7 m "person" whose box is 3x too small; a box in the sky
    feet_w = np.array([[11.5, 0.0, 0.0], [11.5, 0.0, 1.7]])
    uv, _ = cam.project(feet_w)
    real = np.array([uv[0, 0] - 15, uv[1, 1], uv[0, 0] + 15, uv[0, 1]])
    small = real.copy()
    small[1] = real[3] - (real[3] - real[1]) / 3
    sky = np.array([100.0, 50.0, 120.0, 100.0])
    keep, rejected = gate_boxes([real, small, sky], [0.9] * 3, (640, 480), camera=cam)
    assert keep == [0] and len(rejected) == 2
    assert "camera" in rejected[0].reason and "horizon" in rejected[1].reason


def test_proposals_under_the_detector_score_count_only_where_the_camera_vouches_for_them():
    """MediaPipeConfig.proposal_score (issue 34): with the frame's camera known (a drive's), a box the
    detector scores under ``detector_min_score`` is fitted if a person standing at its feet would fill
    it; one whose size no person there has, whose feet are cut off, or that lies mostly on a sure box
    (a part of that person), is vetoed with its reason, and after the fit it must show its feet;
    without a camera nothing under the score is fitted (a person on a billboard stands on no ground
    the gate can check); a sure box passes either way."""
    pytest.importorskip("mediapipe")
    from trustnav.geometry.camera import CameraSpec
    from trustnav.perception.mediapipe_backend import MediaPipeConfig, MediaPipePoseBackend, _feet_at_bottom
    from trustnav.perception.types import Person

    cam = CameraSpec(width=640, height=480, fov_deg=70.0, up=1.4).pose([0.0, 0.0], 0.0)
    uv, _ = cam.project(np.array([[11.5, 0.0, 0.0], [11.5, 0.0, 1.7]]))
    person = np.array([uv[0, 0] - 15, uv[1, 1], uv[0, 0] + 15, uv[0, 1]])
    tall = person.copy()  # 3x a person's height at those feet: a pole, a poster
    tall[1] = person[3] - 3 * (person[3] - person[1])
    cut = np.array([400.0, 300.0, 440.0, 479.0])
    sure = person + np.array([200.0, 0.0, 200.0, 0.0])
    legs = sure.copy()  # the sure person's lower half, scored low: a part of them
    legs[1] = 0.5 * (sure[1] + sure[3])
    boxes = np.array([sure, person, tall, cut, legs])
    scores = np.array([0.6, 0.18, 0.18, 0.18, 0.2])
    with MediaPipePoseBackend(MediaPipeConfig(workers=1)) as backend:
        assert backend.detector.min_score == pytest.approx(0.1)  # proposals are asked of the detector
        kept, kept_scores, vetoed = backend._proposals(boxes, scores, 640, 480)
        assert kept.tolist() == [sure.tolist()] and kept_scores.tolist() == [0.6] and vetoed == []
        backend.camera = cam
        kept, kept_scores, vetoed = backend._proposals(boxes, scores, 640, 480)
        assert kept.tolist() == [sure.tolist(), person.tolist()] and kept_scores.tolist() == [0.6, 0.18]
        reasons = [v.reason for v in vetoed]
        assert len(reasons) == 3 and "sure" in reasons[0] and "camera" in reasons[1] and "bottom" in reasons[2]
    # after the fit a proposal must show its feet at its box's bottom (not a box ending at the waist)
    kp = np.zeros((17, 2))
    conf = np.zeros(17)
    kp[15:17] = [[10.0, 95.0], [14.0, 96.0]]
    conf[15:17] = [0.9, 0.3]
    body = Person(bbox=np.array([0.0, 0.0, 30.0, 100.0]), score=0.6, keypoints=kp, confidences=conf)
    assert _feet_at_bottom(body, body.bbox)
    assert not _feet_at_bottom(body, np.array([0.0, -100.0, 30.0, 200.0]))  # ankles mid-box
    conf[15] = 0.2  # no confident ankle
    assert not _feet_at_bottom(body, body.bbox)
    with MediaPipePoseBackend(MediaPipeConfig(workers=1, proposal_score=None)) as backend:
        backend.camera = cam
        assert backend.detector.min_score == pytest.approx(0.25)
        assert backend._proposals(boxes[scores >= 0.25], scores[scores >= 0.25], 640, 480)[0].tolist() == [
            sure.tolist()
        ]
    for bad in (0.0, 0.3, True, "0.1"):
        with pytest.raises(ValueError, match=r"proposal_score must be None .* got"):
            MediaPipeConfig(proposal_score=bad)


# -- carried people in the pipeline ---------------------------------------------------------------


def test_people_carried_between_fits_are_not_judged_twice():
    """Issue 35's real-time backend carries a person's last keypoints between landmark fits
    (``extra["carried"]``): the cues run only on people fitted on the frame, a carried person shows
    its track's last values, and trust gets no observation of it unless its track is new to it."""
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker
    from trustnav.perception.types import Person

    kp = np.column_stack([np.linspace(110, 130, 17), np.linspace(110, 290, 17)])

    def person(dx: float, carried: bool) -> Person:
        extra = {"carried": True} if carried else {}
        return Person(np.array([100 + dx, 100, 140 + dx, 300]), kp + [dx, 0], np.ones(17), 0.9, extra)

    class Backend:
        def __init__(self) -> None:
            self.frames = [[person(0, False)], [person(2, True)], [person(4, True)], [person(6, False)]]

        def __call__(self, frame):
            return self.frames.pop(0)

    class Counting:
        name = "eye_contact"

        def __init__(self) -> None:
            self.judged = 0

        def __call__(self, frame, people):
            self.judged += len(people)
            return [0.1 * self.judged] * len(people)

    cue = Counting()
    pipeline = PerceptionPipeline(Backend(), PersonTracker(fps=10.0), cues=[cue])
    frame = np.zeros((400, 400, 3), dtype=np.uint8)
    outs = [pipeline(frame, time=k / 10) for k in range(4)]
    assert cue.judged == 2  # frames 0 and 3 only
    assert [round(o[0].eye_contact, 2) for o in outs] == [0.1, 0.1, 0.1, 0.2]  # carried: the last value
    tid = outs[0][0].track_id
    assert PerceptionPipeline.sightings(outs[1], 0.1) == []
    assert PerceptionPipeline.sightings(outs[1], 0.1, known={tid}) == []
    assert len(PerceptionPipeline.sightings(outs[1], 0.1, known=set())) == 1  # a track new to trust
    assert len(PerceptionPipeline.sightings(outs[3], 0.3, known={tid})) == 1


@pytest.mark.slow
@needs_model
def test_estimate_reports_the_boxes_it_turned_down(sequences, looking_weights, out_dir, capsys):
    """trustnav estimate writes rejected.json: each detector box the landmark model did not confirm
    or the geometry gate turned down, with its frame, box, score and reason, and counts them."""
    import json

    from trustnav.cli import main

    args = ["estimate", str(sequences / "phone_a"), "--out", str(out_dir), "--no-images"]
    assert main([*args, "--looking-weights", str(looking_weights)]) == 0
    rejected = json.loads((out_dir / "rejected.json").read_text())
    assert rejected and all({"sequence", "frame", "bbox", "score", "reason"} <= set(r) for r in rejected)
    assert all(r["reason"] and len(r["bbox"]) == 4 and 0 < r["score"] <= 1 for r in rejected)
    assert f"{len(rejected)} detector boxes rejected" in capsys.readouterr().out


def test_the_phone_detector_evidence_script_refuses_a_rendered_folder_without_the_sets(repo_root, tmp_path):
    """benchmarks/phone_detector_evidence.py --rendered DIR needs DIR/rendered and DIR/rendered_heldout
    (trust_eval.py --keep DIR): one parser line naming the option and what is missing."""
    import subprocess
    import sys

    (tmp_path / "rendered").mkdir()
    script = repo_root / "benchmarks" / "phone_detector_evidence.py"
    out = subprocess.run([sys.executable, str(script), "--rendered", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 2
    assert f"--rendered {tmp_path}: no rendered_heldout/ folder" in out.stderr.strip().splitlines()[-1]
