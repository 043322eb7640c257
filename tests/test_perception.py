"""Perception on real frames: detection, occlusion-aware eye contact, tracking, phone use, trust.

Ground truth made by hand from the shared images, in ``tests/data/perception_truth.json`` (also
read by ``benchmarks/perception_eval.py``): "clearly visible" pedestrians have the head and most of
the body in view, not hidden behind another person; "other" people (partly hidden, far away,
seated) may be found or not, but a box must lie on some person.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.perception.confidence import BLAZEPOSE_TO_COCO, HeadConfidenceParams, head_yaw, occlusion_confidences
from trustnav.perception.frames import FrameItem, iter_frames, natural_key
from trustnav.perception.phone import PoseGeometryPhoneClassifier, phone_label
from trustnav.perception.types import Person, box_iou, check_frame
from trustnav.trust import PAPER_TRAITS, CueTrait, TrustEstimator


def _inside(point, box) -> bool:
    return box[0] <= point[0] <= box[2] and box[1] <= point[1] <= box[3]


@pytest.fixture(scope="module")
def truth(perception_truth):
    """CLEAR and OTHER boxes by image name, and the rest of the hand-made truth."""
    boxes = {k: {n: [tuple(b) for b in bs] for n, bs in perception_truth[k].items()} for k in ("clear", "other")}
    return {**perception_truth, **boxes}


@pytest.fixture(scope="module")
def street_people(mediapipe_backend, street_images, read_rgb, truth):
    return {name: mediapipe_backend(read_rgb(street_images / name)) for name in truth["clear"]}


# -- inputs and errors ---------------------------------------------------------------------------


def test_bad_frames_are_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="frame must be a numpy array"):
        check_frame([[1, 2, 3]])
    with pytest.raises(ValueError, match="shape H x W x 3"):
        check_frame(np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        check_frame(np.zeros((4, 4, 3), dtype=np.float32))


def test_person_validates_its_fields():
    kp = np.zeros((17, 2))
    with pytest.raises(ValueError, match="bbox"):
        Person(bbox=np.array([5.0, 0, 1, 1]), keypoints=kp, confidences=np.ones(17), score=0.5)
    with pytest.raises(ValueError, match="confidences"):
        Person(bbox=np.array([0.0, 0, 1, 1]), keypoints=kp, confidences=np.full(17, 2.0), score=0.5)


def test_frames_sorted_naturally_and_unreadable_frame_reported(tmp_path):
    import cv2

    img = np.full((8, 8, 3), 128, dtype=np.uint8)
    for name in ("f_10.png", "f_2.png", "f_1.png"):
        cv2.imwrite(str(tmp_path / name), img)
    (tmp_path / "f_3.png").write_bytes(b"not a png")
    items = list(iter_frames([tmp_path]))
    assert [i.name for i in items] == ["f_1.png", "f_2.png", "f_3.png", "f_10.png"]
    assert items[2].frame is None and "cannot read" in items[2].error
    assert all(i.frame is not None and i.frame.shape == (8, 8, 3) for i in items if i.name != "f_3.png")
    with pytest.raises(ValueError, match="does not exist"):
        list(iter_frames([tmp_path / "missing.png"]))
    assert natural_key(Path("a9.png")) < natural_key(Path("a10.png"))


# -- occlusion-aware confidences ------------------------------------------------------------------


def _head(yaw_deg: float) -> np.ndarray:
    """33 landmarks with the ears placed for a head turned by ``yaw_deg`` (kappa = 1)."""
    lm = np.zeros((33, 5))
    lm[:, 3:] = 1.0
    y = np.radians(yaw_deg)
    r = 10.0
    lm[7, [0, 2]] = [r * np.cos(y), r * np.sin(y)]  # left ear
    lm[8, [0, 2]] = [-r * np.cos(y), -r * np.sin(y)]  # right ear
    return lm


def test_head_yaw_and_face_confidences_follow_the_turn():
    p = HeadConfidenceParams(kappa=1.0)
    assert head_yaw(_head(0.0), 1.0) == pytest.approx(0.0)
    assert head_yaw(_head(80.0), 1.0) == pytest.approx(np.radians(80.0))
    front = occlusion_confidences(_head(0.0), p)
    profile = occlusion_confidences(_head(85.0), p)  # left ear turned away
    back = occlusion_confidences(_head(175.0), p)
    assert front[0] == pytest.approx(1.0) and front[1] == pytest.approx(front[2])
    assert profile[1] < 0.1 and profile[3] < 0.2  # far eye and far ear nearly hidden
    assert profile[4] > 0.9 and profile[2] > 0.5  # near ear and near eye seen
    assert back[:3].max() < 0.1  # no face seen from behind
    assert np.all(front[5:] == 1.0)  # body keypoints keep their visibility


@pytest.mark.slow
def test_crossing_eye_contact_ranks_facing_people_above_profiles(street_people, looking_model, truth):
    """People facing the camera: polo shirt, woman with scarf, blue sweater. In profile: the
    long-haired man (looking to his left) and the woman in the leather jacket (looking to her right)."""
    from trustnav.perception.looking import normalise_keypoints

    model = looking_model
    people = street_people["crossing.jpg"]

    def eye(box) -> float:
        match = max(people, key=lambda p: box_iou(p.bbox, box))
        assert box_iou(match.bbox, box) > 0.4, f"nobody found at {box}"
        return float(model.predict(normalise_keypoints(match.keypoints, match.confidences, 1280)[None])[0])

    facing = [eye(truth["clear"]["crossing.jpg"][i]) for i in truth["crossing_facing"]]
    profile = [eye(truth["clear"]["crossing.jpg"][i]) for i in truth["crossing_profile"]]
    assert min(facing) > max(profile), (facing, profile)
    # BlazePose's own visibility (~1 everywhere) would not separate them: the occlusion model does.
    # (Fitted from the detector's boxes since issue 35, LOOKING alone reads the facing people
    # 0.26-0.31, not 0.55-0.7 as on the tiled face detector's regions; the face cue carries them.)
    assert min(facing) > 0.2 and min(profile) < 0.1


@pytest.mark.slow
def test_people_walking_across_the_view_score_low_eye_contact(street_people, looking_model, truth):
    """street_2: the woman in grey, the man in the striped shirt and the boy cross the road in
    profile. With BlazePose's visibility as confidences LOOKING would call them attentive (> 0.9)."""
    from trustnav.perception.looking import normalise_keypoints

    model = looking_model
    people = street_people["street_2.png"]
    missed = []
    for gt in (truth["clear"]["street_2.png"][i] for i in truth["street_2_crossing"]):
        p = max(people, key=lambda q: box_iou(q.bbox, gt))
        if box_iou(p.bbox, gt) <= 0.4:
            missed.append(gt)  # the boy in front of the woman with the blue bag: one box on both
            continue
        ours = model.predict(normalise_keypoints(p.keypoints, p.confidences, 2048)[None])[0]
        vis = np.clip(p.extra["blazepose"][list(BLAZEPOSE_TO_COCO), 3], 0, 1)
        naive = model.predict(normalise_keypoints(p.keypoints, vis, 2048)[None])[0]
        assert ours < 0.2 and 0.9 < naive, (gt, ours, naive)  # 0.00-0.15 (the man in stripes 0.15)
    assert len(missed) <= 1, missed


# -- detection on street images -----------------------------------------------------------------


@pytest.mark.slow
def test_street_images_find_most_clear_pedestrians_and_no_false_boxes(street_people, truth):
    CLEAR, OTHER = truth["clear"], truth["other"]
    found = total = 0
    for name, people in street_people.items():
        boxes = [p.bbox for p in people]
        for gt in CLEAR[name]:
            total += 1
            found += any(box_iou(b, gt) > 0.4 for b in boxes)
        for b in boxes:
            centre = ((b[0] + b[2]) / 2, (b[1] + b[3]) / 2)
            assert any(_inside(centre, gt) for gt in CLEAR[name] + OTHER[name]), f"false box {b} in {name}"
            for p in people:
                assert p.keypoints.shape == (17, 2) and np.all((p.confidences >= 0) & (p.confidences <= 1))
    assert found / total >= 0.8, f"found {found} of {total} clearly visible pedestrians"


def test_empty_and_degenerate_frames_have_no_people(mediapipe_backend):
    backend = mediapipe_backend
    assert backend(np.zeros((240, 320, 3), dtype=np.uint8)) == []
    for shape in ((1, 1, 3), (3, 500, 3), (2000, 16, 3)):
        assert backend(np.zeros(shape, dtype=np.uint8)) == []
    assert backend(np.full((64, 64, 3), 200, dtype=np.uint8)) == []


# -- phone use ----------------------------------------------------------------------------------


def _pose(wrist_raise: float, nose_drop: float = 0.0) -> np.ndarray:
    """COCO keypoints of an upright person facing the camera, right wrist raised by a fraction."""
    kp = np.zeros((17, 2))
    kp[5], kp[6] = (60, 100), (40, 100)  # shoulders
    kp[11], kp[12] = (57, 200), (43, 200)  # hips
    kp[3], kp[4] = (56, 70), (44, 70)  # ears
    kp[0] = (50, 72 + nose_drop)
    kp[1], kp[2] = (53, 68), (47, 68)
    kp[7], kp[8] = (65, 150), (35, 150)
    kp[9] = (65, 200)  # left wrist hanging
    kp[10] = (48, 200 - wrist_raise * 100)  # right wrist in front, raised
    kp[13:15] = (55, 260), (45, 260)
    kp[15:17] = (55, 320), (45, 320)
    return kp


def test_phone_classifier_cues():
    clf = PoseGeometryPhoneClassifier()
    hanging = clf.confidence(_pose(0.0))
    texting = clf.confidence(_pose(0.75, nose_drop=20.0))
    texting_head_up = clf.confidence(_pose(0.75, nose_drop=-2.0))
    call = _pose(0.0)
    call[10] = call[4] + (2, 3)  # wrist at the right ear
    assert hanging == 0.0
    assert texting == pytest.approx(1.0)
    assert 0.4 < texting_head_up < texting
    assert clf.confidence(call) > 0.9
    hidden = clf.confidence(_pose(0.75, nose_drop=20.0), np.r_[np.ones(10), 0.1, np.ones(6)])
    assert hidden == 0.0  # an unseen wrist is no evidence
    assert [phone_label(c) for c in (0.1, 0.5, 0.9)] == ["N", "U", "Y"]
    with pytest.raises(ValueError, match="raise_band"):
        PoseGeometryPhoneClassifier(raise_band=(0.9, 0.5))


# -- sequences: tracking, traits, trust ----------------------------------------------------------


def _run_estimate(seq: Path, out: Path) -> list[dict]:
    from trustnav.cli import main

    assert main(["estimate", str(seq), "--out", str(out)]) == 0
    rows = json.loads((out / "tracks.json").read_text())
    assert (out / "tracks.csv").read_text().splitlines()[0].startswith("frame,track_id,bbox,eye_contact,phone")
    return rows


@pytest.fixture(scope="module")
def walk_rows(sequences, looking_weights, tmp_path_factory):
    return _run_estimate(sequences / "walk_a", tmp_path_factory.mktemp("walk_a"))


@pytest.fixture(scope="module")
def walk_a_frames(sequences) -> list[str]:
    return sorted(p.name for p in (sequences / "walk_a").glob("*.png"))


def _track_at(rows: list[dict], frame: str, point) -> dict | None:
    """The record of the narrowest box containing ``point`` in ``frame``."""
    hits = [r for r in rows if r["frame"] == frame and _inside(point, r["bbox"])]
    return min(hits, key=lambda r: r["bbox"][2] - r["bbox"][0]) if hits else None


def _point(keys, k):
    frames = [f for f, _, _ in keys]
    return np.interp(k, frames, [x for _, x, _ in keys]), np.interp(k, frames, [y for _, _, y in keys])


def _ids_along(rows: list[dict], frames: list[str], keys) -> list[int]:
    """Track IDs of the boxes on a hand-followed path (key frames [frame index, x, y] on the torso
    of walk_a), one per frame where it is detected."""
    return [
        hit["track_id"]
        for k in range(keys[0][0], keys[-1][0] + 1)
        if (hit := _track_at(rows, frames[k], _point(keys, k)))
    ]


@pytest.mark.slow
def test_walk_a_pedestrians_keep_one_id(walk_rows, walk_a_frames, truth):
    """Measure: for each hand-followed pedestrian, the share of the frames where it is detected that
    carry its most frequent track ID (1.0 = never switched). Most pedestrians must keep >= 0.8."""
    assert len(walk_a_frames) == 45
    kept = {}
    for name, keys in truth["walk_a"].items():
        ids = _ids_along(walk_rows, walk_a_frames, keys)
        assert len(ids) >= 0.5 * (keys[-1][0] - keys[0][0] + 1), f"{name}: detected in only {len(ids)} frames"
        kept[name] = max(ids.count(i) for i in set(ids)) / len(ids)
    assert sum(v >= 0.8 for v in kept.values()) >= 2, kept


@pytest.mark.slow
def test_phone_user_ends_with_lower_phone_trait_and_trust_than_walkers(
    walk_rows, walk_a_frames, truth, sequences, tmp_path
):
    phone_rows = _run_estimate(sequences / "phone_a", tmp_path / "phone_a")
    frames = sorted({r["frame"] for r in phone_rows})
    # the woman in the light padded jacket: left of the woman in black, x ~ 280 in the last frame
    point = truth["phone_a_user_last_frame_point"]
    last = [r for r in phone_rows if r["frame"] == frames[-1] and _inside(point, r["bbox"])]
    assert last, "phone user not found in the last frame"
    woman = last[0]
    assert len([r for r in phone_rows if r["track_id"] == woman["track_id"]]) >= 3  # one track
    walkers = []
    for name in truth["walk_a_no_phone"]:  # the standing old man and the man walking away
        ids = _ids_along(walk_rows, walk_a_frames, truth["walk_a"][name])
        assert ids, f"{name} not found"
        track = max(set(ids), key=ids.count)
        walkers.append([r for r in walk_rows if r["track_id"] == track][-1])  # its final state
    for w in walkers:
        assert woman["smartphone_trait"] < w["smartphone_trait"], (woman, w)
        assert woman["trust"] < w["trust"], (woman, w)


# -- the command line: videos, bad frames, optional backends ----------------------------------------


@pytest.mark.slow
def test_estimate_on_a_video_writes_an_annotated_mp4(sequences, looking_weights, tmp_path, out_dir):
    import cv2

    from trustnav.cli import main

    video = tmp_path / "clip.mp4"
    frames = sorted((sequences / "phone_a").glob("*.png"))
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, (640, 480))
    for f in frames:
        writer.write(cv2.imread(str(f)))
    writer.release()
    assert main(["estimate", str(video), "--out", str(out_dir)]) == 0
    cap = cv2.VideoCapture(str(out_dir / "annotated.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(frames)
    cap.release()
    rows = json.loads((out_dir / "tracks.json").read_text())
    assert rows and all(r["frame"].startswith("clip.mp4#") for r in rows)
    for r in rows:
        assert 0.0 <= r["eye_contact"] <= 1.0 and 0.0 <= r["phone"] <= 1.0 and 0.0 <= r["trust"] <= 1.0
        x1, y1, x2, y2 = r["bbox"]
        assert 0 <= x1 < x2 <= 640 and 0 <= y1 < y2 <= 480


def test_one_unreadable_frame_is_skipped_not_fatal(sequences, looking_weights, tmp_path, out_dir, capsys):
    import shutil

    from trustnav.cli import main

    seq = tmp_path / "seq"
    seq.mkdir()
    good = sorted((sequences / "phone_a").glob("*.png"))[3:5]
    shutil.copy(good[0], seq / "f1.png")
    (seq / "f2.png").write_bytes(b"\x89PNG broken")
    shutil.copy(good[1], seq / "f3.png")
    assert main(["estimate", str(seq), "--out", str(out_dir)]) == 0
    assert "skipped frame f2.png" in capsys.readouterr().err
    rows = json.loads((out_dir / "tracks.json").read_text())
    assert {r["frame"] for r in rows} == {"f1.png", "f3.png"}
    assert sorted(p.name for p in (out_dir / "frames").iterdir()) == ["f1.png", "f3.png"]


def test_missing_optional_backend_says_what_to_install(monkeypatch):
    import builtins

    from trustnav.perception.optional_backends import make_backend

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name in ("ultralytics", "openpifpaf"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(ImportError, match="pip install ultralytics"):
        make_backend("yolo")
    with pytest.raises(ImportError, match="pip install openpifpaf"):
        make_backend("openpifpaf")
    with pytest.raises(ValueError, match="unknown pose backend"):
        make_backend("nope")


# -- configuration ----------------------------------------------------------------------------


def test_configs_refuse_bad_values_by_name():
    from trustnav.perception.mediapipe_backend import MediaPipeConfig
    from trustnav.perception.tracking import TrackerConfig

    with pytest.raises(ValueError, match="region_scale"):
        MediaPipeConfig(region_scale=3.0)
    with pytest.raises(ValueError, match="workers"):
        MediaPipeConfig(workers=0)
    with pytest.raises(ValueError, match="algorithm"):
        TrackerConfig(algorithm="deepsort")
    with pytest.raises(ValueError, match="lost_seconds"):
        TrackerConfig(lost_seconds=-1.0)


# -- pipeline without a camera: observations reach the trust estimator only when seen --------------


class _ScriptedBackend:
    """Returns the people scripted for each call (no model)."""

    def __init__(self, script):
        self.script = list(script)

    def __call__(self, frame):
        return self.script.pop(0)


def _walker(x: float) -> Person:
    kp = np.column_stack([np.full(17, x + 10.0), np.linspace(10, 90, 17)])
    return Person(bbox=np.array([x, 0.0, x + 20, 100]), keypoints=kp, confidences=np.full(17, 0.9), score=0.9)


def test_pipeline_updates_trust_only_for_people_seen(make_pipeline):
    from trustnav.perception.pipeline import estimate

    script = [[_walker(10)], [_walker(12)], [], [_walker(16)]]
    pipe = make_pipeline(_ScriptedBackend(script), fps=10)
    frames = [FrameItem(f"f{i}", i, np.zeros((120, 160, 3), dtype=np.uint8)) for i in range(4)]
    est = TrustEstimator()
    results = list(estimate(frames, pipe, est, fps=10.0))
    assert [len(r.records) for r in results] == [1, 1, 0, 1]
    ids = {r.records[0]["track_id"] for r in results if r.records}
    assert len(ids) == 1  # one walker, one ID across the gap
    (tid,) = ids
    assert est.tracks[tid].observations == 3 and est.tracks[tid].last_seen == pytest.approx(0.3)
    assert results[1].records[0]["fluctuation"] is not None  # second sighting compares poses
    assert all(0.0 <= r.records[0]["trust"] <= 1.0 for r in results if r.records)


def test_trust_colours_follow_the_bands():
    from trustnav.viz.annotate import GREEN, ORANGE, RED, annotate, trust_colour

    assert [trust_colour(t) for t in (0.95, 0.71, 0.7, 0.41, 0.4, 0.0)] == [GREEN, GREEN, ORANGE, ORANGE, RED, RED]
    frame = np.zeros((100, 100, 3), dtype=np.uint8)
    rec = {"bbox": [10, 10, 50, 90], "trust": 0.9, "track_id": 3, "eye_contact": 0.5}
    img = annotate(frame, [rec], [_walker(10).keypoints], ["N"])
    assert img.shape == (100, 100, 3) and tuple(img[50, 10]) == GREEN  # box edge drawn in trust colour


@settings(max_examples=100, deadline=None)
@given(st.floats(-179.0, 179.0))
def test_mirrored_head_swaps_left_and_right_confidences(yaw):
    p = HeadConfidenceParams(kappa=1.0)
    c = occlusion_confidences(_head(yaw), p)
    m = occlusion_confidences(_head(-yaw), p)
    assert np.all((c >= 0) & (c <= 1))
    assert c[0] == pytest.approx(m[0])  # the nose sees the same
    assert c[1] == pytest.approx(m[2]) and c[3] == pytest.approx(m[4])  # left <-> right


@pytest.mark.skipif(not os.environ.get("TRUSTNAV_YOLO_WEIGHTS"), reason="set TRUSTNAV_YOLO_WEIGHTS to a YOLO-pose .pt")
def test_yolo_pose_backend_finds_the_crossing_pedestrians(street_images, read_rgb, truth):
    pytest.importorskip("ultralytics")
    from trustnav.perception.optional_backends import make_backend

    people = make_backend("yolo", weights=os.environ["TRUSTNAV_YOLO_WEIGHTS"])(read_rgb(street_images / "crossing.jpg"))
    clear = truth["clear"]["crossing.jpg"]
    found = sum(any(box_iou(p.bbox, gt) > 0.4 for p in people) for gt in clear)
    assert found >= 0.8 * len(clear)


@pytest.mark.skipif(not os.environ.get("TRUSTNAV_OPENPIFPAF"), reason="set TRUSTNAV_OPENPIFPAF=1 with openpifpaf")
def test_openpifpaf_backend_finds_the_crossing_pedestrians(street_images, read_rgb, truth):
    pytest.importorskip("openpifpaf")
    from trustnav.perception.optional_backends import make_backend

    people = make_backend("openpifpaf")(read_rgb(street_images / "crossing.jpg"))
    clear = truth["clear"]["crossing.jpg"]
    found = sum(any(box_iou(p.bbox, gt) > 0.4 for p in people) for gt in clear)
    assert found >= 0.8 * len(clear)


@pytest.mark.parametrize("fps", ["x", None, 0, -1.0, float("nan"), float("inf"), True])
def test_tracker_refuses_a_bad_frame_rate_with_a_clear_error(fps):
    from trustnav.perception.tracking import PersonTracker

    with pytest.raises(ValueError, match="fps must be a positive finite number"):
        PersonTracker(fps=fps)


# -- traits as parts: a new cue and its trait plug in from outside trustnav ------------------------


@dataclass(frozen=True)
class HeadTurnedCue:
    """A user's cue: how far the face is turned away from the camera (1 - mean face confidence)."""

    name: str = "head_turned"

    def __call__(self, frame, people):
        return [float(1.0 - np.mean(p.confidences[:5])) for p in people]


@dataclass(frozen=True)
class FacesTraffic(CueTrait):
    """A user's trait: s(0) = 1 - c; s(t) = 0.5 s(t-1) + 0.5 (1 - c(t))."""

    name: str = "faces_traffic"
    weight: float = 0.25
    cue: str = "head_turned"

    def start(self, c):
        return 1.0 - c

    def step(self, prev, c):
        return 0.5 * prev + 0.5 * (1.0 - c)


def _turned(x: float, face: float) -> Person:
    p = _walker(x)
    return Person(p.bbox, p.keypoints, np.r_[np.full(5, face), np.full(12, 0.9)], 0.9)


def test_a_users_cue_and_trait_plug_into_pipeline_and_estimator(make_pipeline, looking_model):
    from trustnav.perception.cues import default_cues
    from trustnav.perception.pipeline import estimate

    script = [[_turned(10, 0.8)], [_turned(12, 0.2)], [_turned(14, 0.2)]]
    frames = [FrameItem(f"f{i}", i, np.zeros((120, 160, 3), dtype=np.uint8)) for i in range(3)]
    pipe = make_pipeline(_ScriptedBackend(script), cues=[*default_cues(looking_model), HeadTurnedCue()])
    est = TrustEstimator(traits=[*PAPER_TRAITS, FacesTraffic()])
    results = list(estimate(frames, pipe, est, fps=10.0))
    recs = [r.records[0] for r in results]
    assert [r["head_turned"] for r in recs] == pytest.approx([0.2, 0.8, 0.8])
    # the user's trait follows its own formulas: 1 - 0.2; then 0.5 s + 0.5 (1 - 0.8), twice
    assert [r["faces_traffic_trait"] for r in recs] == pytest.approx([0.8, 0.5, 0.35], abs=1e-4)
    st = est.tracks[recs[0]["track_id"]]
    assert st.value("faces_traffic") == pytest.approx(0.35)
    # lin_comb over four traits: weights 0.4, 0.5, 0.1, 0.25 shared out over their sum
    s = np.array([st.smartphone, st.eye, st.pose, st.value("faces_traffic")])
    assert st.score == pytest.approx(float(s @ [0.4, 0.5, 0.1, 0.25]) / 1.25)
    # the paper's cues are what the default pipeline computes on the same people
    plain = make_pipeline(_ScriptedBackend(list(script)))
    again = list(estimate(frames, plain, TrustEstimator(), fps=10.0))
    for mine, paper in zip(recs, (r.records[0] for r in again), strict=True):
        assert (mine["eye_contact"], mine["phone"]) == (paper["eye_contact"], paper["phone"])
        assert "head_turned" not in paper and "faces_traffic_trait" not in paper


def test_pipeline_cues_default_to_the_papers_and_are_checked(make_pipeline, looking_model):
    from trustnav.perception.cues import FaceEyeContactCue, PhoneUseCue
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker

    pipe = make_pipeline(_ScriptedBackend([[_walker(10)]]))
    # eye contact: LOOKING fused with the face (near people only), with the both-hands posture veto
    assert [type(c) for c in pipe.cues] == [FaceEyeContactCue, PhoneUseCue]
    assert isinstance(pipe.cues[0].posture, PoseGeometryPhoneClassifier)
    assert [c.name for c in pipe.cues] == ["eye_contact", "smartphone"]
    assert pipe.eye_model is looking_model and isinstance(pipe.phone, PoseGeometryPhoneClassifier)
    frame = np.zeros((120, 160, 3), dtype=np.uint8)

    class Bad:
        name = "bad"

        def __init__(self, values):
            self.values = values

        def __call__(self, frame, people):
            return self.values

    for values, message in (([0.5, 0.5], "gave 2 confidences for 1 people"), ([1.5], r"must lie in \[0, 1\]")):
        bad = make_pipeline(_ScriptedBackend([[_walker(10)]]), cues=[Bad(values)])
        with pytest.raises(ValueError, match=message):
            bad(frame)
    with pytest.raises(ValueError, match="cue names must be unique, 'bad' appears twice"):
        make_pipeline(_ScriptedBackend([]), cues=[Bad([]), Bad([])])
    with pytest.raises(ValueError, match="either eye_model/phone"):
        PerceptionPipeline(_ScriptedBackend([]), PersonTracker(fps=10), looking_model, cues=[Bad([])])
    with pytest.raises(ValueError, match="eye_model must be a LookingModel"):
        PerceptionPipeline(_ScriptedBackend([]), PersonTracker(fps=10))
    # a cue that cannot judge a person (NaN) leaves that trait input missing
    only = make_pipeline(_ScriptedBackend([[_walker(10)]]), cues=[Bad([float("nan")])])
    (tp,) = only(frame)
    assert math.isnan(tp.eye_contact) and math.isnan(tp.phone) and math.isnan(tp.cues["bad"])
    (obs,) = only.sightings([tp], 0.0)
    assert obs.c_eye is None and obs.c_smartphone is None and obs.cue("bad") is None


# -- no global state changed by perception -------------------------------------------------------------


def test_mediapipe_backend_leaves_environment_and_warnings_filters_as_it_found_them(monkeypatch):
    pytest.importorskip("mediapipe")
    from trustnav.perception.mediapipe_backend import (
        QUIET_ENV,
        MediaPipeConfig,
        MediaPipePoseBackend,
        quiet_environment,
    )

    for key in QUIET_ENV:
        monkeypatch.delenv(key, raising=False)
    with quiet_environment():  # the levels are set while MediaPipe starts ...
        assert all(os.environ[k] == v for k, v in QUIET_ENV.items())
    assert not any(k in os.environ for k in QUIET_ENV)  # ... and only then
    filters = list(warnings.filters)
    with MediaPipePoseBackend(MediaPipeConfig(workers=1)) as backend:
        assert backend(np.zeros((96, 128, 3), dtype=np.uint8)) == []
    assert not any(k in os.environ for k in QUIET_ENV)
    assert list(warnings.filters) == filters
