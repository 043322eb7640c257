"""Eye contact from the face (trustnav.perception.face): head pose relative to the camera ray, the
fusion with LOOKING, and the cue on the LOOKING authors' demo image."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from trustnav.perception.face import (
    CHIN,
    FOREHEAD,
    LEFT_EYE_INNER,
    LEFT_EYE_OUTER,
    LEFT_IRIS,
    RIGHT_EYE_INNER,
    RIGHT_EYE_OUTER,
    RIGHT_IRIS,
    FaceConfig,
    FaceEyeContact,
    eye_contact_probability,
    fuse_eye_contact,
    head_pose,
    iris_offset,
    ray_frame,
)
from trustnav.perception.types import Person

F, CX, CY = 900.0, 640.0, 360.0  # camera of a 1280 x 720 frame


def _template() -> np.ndarray:
    """A frontal face (head frame: x image right, y down, z away from the camera; cm): a cloud of
    points with the landmarks the pose reads placed where a face has them."""
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-7, 7, 478), rng.uniform(-10, 9, 478), rng.uniform(-3, 4, 478)])
    pts[RIGHT_EYE_OUTER], pts[RIGHT_EYE_INNER] = (-4.5, 0, 0.5), (-1.5, 0, 0.5)
    pts[LEFT_EYE_INNER], pts[LEFT_EYE_OUTER] = (1.5, 0, 0.5), (4.5, 0, 0.5)
    pts[RIGHT_IRIS], pts[LEFT_IRIS] = (-3.0, 0, 0.0), (3.0, 0, 0.0)
    pts[FOREHEAD], pts[CHIN] = (0, -9, 0.5), (0, 11, 0.5)
    return pts


def _rotation(yaw: float, pitch: float) -> np.ndarray:
    """Turns the face's outward normal (0, 0, -1) to (cos p sin y, -sin p, -cos p cos y): yaw toward
    +x (image right), pitch up."""
    y, p = math.radians(yaw), math.radians(pitch)
    ry = np.array([[math.cos(y), 0, -math.sin(y)], [0, 1, 0], [math.sin(y), 0, math.cos(y)]])
    rp = np.array([[1, 0, 0], [0, math.cos(p), math.sin(p)], [0, -math.sin(p), math.cos(p)]])
    return ry @ rp


def _project(head_cam: np.ndarray, u: float, v: float, distance: float = 800.0) -> np.ndarray:
    """Points given in camera axes around a head whose centre is seen at pixel (u, v), ``distance``
    cm along its ray -> mesh-like landmarks: pixels (perspective) and depth along the ray in pixels
    (at the head's image scale, f / Z of its centre, as the face mesh gives z in the scale of x)."""
    frame = ray_frame(u, v, F, CX, CY)
    centre = frame[2] * distance
    p = centre + head_cam
    px = np.column_stack([F * p[:, 0] / p[:, 2] + CX, F * p[:, 1] / p[:, 2] + CY])
    depth = (head_cam @ frame[2]) * F / centre[2]
    return np.column_stack([px, depth])


def _face_at(u: float, v: float, yaw: float, pitch: float) -> np.ndarray:
    """A face at pixel (u, v) turned by (yaw, pitch) relative to the ray through it."""
    frame = ray_frame(u, v, F, CX, CY)  # rows e1, e2, d: ray frame -> camera axes
    return _project(_template() @ _rotation(yaw, pitch).T @ frame, u, v)


@pytest.mark.parametrize("u,v", [(640, 360), (1200, 380), (80, 300), (900, 80)])
@pytest.mark.parametrize("yaw,pitch", [(0, 0), (20, 0), (-35, 0), (0, 15), (-10, -20), (40, 10)])
def test_head_pose_gives_back_the_angles_relative_to_the_ray(u, v, yaw, pitch):
    got_yaw, got_pitch = head_pose(_face_at(u, v, yaw, pitch), F, CX, CY)
    assert got_yaw == pytest.approx(yaw, abs=1.5)
    assert got_pitch == pytest.approx(pitch, abs=1.5)


def test_a_face_at_the_edge_facing_the_camera_reads_frontal_not_its_image_axis_turn():
    u = 1220.0  # 33 deg off the axis
    off_axis = math.degrees(math.atan((u - CX) / F))
    # facing the camera (along its ray): yaw 0
    assert head_pose(_face_at(u, CY, 0, 0), F, CX, CY)[0] == pytest.approx(0.0, abs=1.5)
    # facing straight ahead (parallel to the optical axis): turned by the ray's angle, toward image right
    parallel = _project(_template(), u, CY)
    assert head_pose(parallel, F, CX, CY)[0] == pytest.approx(off_axis, abs=1.5)


def test_iris_offset_sign_and_scale():
    lm = np.zeros((478, 3))
    lm[RIGHT_EYE_OUTER], lm[RIGHT_EYE_INNER] = (0, 0, 0), (20, 0, 0)
    lm[LEFT_EYE_INNER], lm[LEFT_EYE_OUTER] = (40, 0, 0), (60, 0, 0)
    lm[RIGHT_IRIS], lm[LEFT_IRIS] = (15, 0, 0), (55, 0, 0)  # both irises half-way to image right
    r, width = iris_offset(lm)
    assert r == pytest.approx(0.5) and width == pytest.approx(20.0)
    assert math.isnan(iris_offset(lm[:468])[0])


def test_eye_contact_probability_is_a_cone():
    cfg = FaceConfig()
    assert eye_contact_probability(0, 0, cfg) > 0.99
    assert eye_contact_probability(cfg.max_yaw_deg, 0, cfg) == pytest.approx(0.5)
    assert eye_contact_probability(0, -cfg.max_pitch_deg, cfg) == pytest.approx(0.5)
    yaws = [eye_contact_probability(y, 0, cfg) for y in range(0, 90, 5)]
    assert all(a >= b for a, b in itertools.pairwise(yaws)) and yaws[-1] < 0.01


def test_fusion_is_monotone_and_looking_dominates_small_people():
    grid = np.linspace(0, 1, 11)
    for c in grid:
        for p in grid:
            along_looking = [fuse_eye_contact(x, p, c) for x in grid]
            along_face = [fuse_eye_contact(p, x, c) for x in grid]
            assert all(a <= b + 1e-12 for a, b in itertools.pairwise(along_looking))
            assert all(a <= b + 1e-12 for a, b in itertools.pairwise(along_face))
    # no face resolved: LOOKING alone; a weak face moves it little, a clear one most of the way
    assert fuse_eye_contact(0.3, math.nan, 0.9) == 0.3 and fuse_eye_contact(0.3, 1.0, 0.0) == 0.3
    assert abs(fuse_eye_contact(0.3, 1.0, 0.1) - 0.3) < 0.1 < fuse_eye_contact(0.3, 1.0, 0.9) - 0.3
    assert fuse_eye_contact(math.nan, 0.8, 0.5) == 0.8
    # a person too small for a face is not looked at (no model loaded): LOOKING carries C_eye
    kp = np.column_stack([np.linspace(100, 120, 17), np.linspace(100, 160, 17)])
    small = Person(np.array([95.0, 95.0, 125.0, 165.0]), kp, np.ones(17), 0.9)
    face = FaceEyeContact()
    res = face.analyse(np.zeros((480, 640, 3), np.uint8), small)
    assert math.isnan(res.probability) and res.confidence == 0.0 and face._graphs is None
    assert fuse_eye_contact(0.7, res.probability, res.confidence) == 0.7


# The LOOKING authors' output on their demo image (looking_demo_predictions.png), by head position x
# (pixels) of the 8 people the MediaPipe backend finds: True = green (eye contact). Our own reading of
# the faces differs on two: the woman at x ~ 551 turns her head ~30 deg (not looking, authors: looking)
# and the woman at x ~ 965 looks past the camera (not looking, as the authors say).
AUTHORS = {243: False, 348: True, 551: True, 718: True, 828: False, 965: False, 1099: True, 1240: True}
CLEARLY_LOOKING = (348, 718, 1099, 1240)  # frontal faces, authors and our reading agree
CLEARLY_NOT = (828,)  # profile


def test_face_cue_on_the_looking_demo(street_images, looking_weights, mediapipe_backend, read_rgb):
    from trustnav.perception.cues import EyeContactCue, FaceEyeContactCue, FaceFieldCue, with_face
    from trustnav.perception.looking import LookingModel

    frame = read_rgb(street_images / "looking_demo.jpg")
    people = mediapipe_backend(frame)
    model = LookingModel.from_file(looking_weights)
    cues = with_face([EyeContactCue(model)])
    fused_cue, p_cue, c_cue = cues
    assert isinstance(fused_cue, FaceEyeContactCue) and isinstance(p_cue, FaceFieldCue)
    fused = np.asarray(fused_cue(frame, people))
    p_face, c_face = np.asarray(p_cue(frame, people)), np.asarray(c_cue(frame, people))
    looking = np.asarray(EyeContactCue(model)(frame, people))
    by_x = {}
    for i, p in enumerate(people):
        x = (p.bbox[0] + p.bbox[2]) / 2
        key = min(AUTHORS, key=lambda k: abs(k - x))
        if abs(key - x) < 40 and p.bbox[3] - p.bbox[1] >= fused_cue.face.config.min_person_px:
            by_x[key] = i
    assert set(CLEARLY_LOOKING) <= set(by_x)
    for k in CLEARLY_LOOKING:  # eye contact on, from the face, with a confident face
        i = by_x[k]
        assert fused[i] >= 0.6 and p_face[i] >= 0.8 and c_face[i] >= 0.5, (k, fused[i], p_face[i], c_face[i])
    for k in CLEARLY_NOT:
        assert fused[by_x[k]] < 0.3
    agree = lambda v: sum((v[i] >= 0.5) == AUTHORS[k] for k, i in by_x.items())  # noqa: E731
    assert agree(fused) >= agree(looking) and agree(fused) >= 6


def test_with_face_needs_looking_and_checks_field_names(looking_model):
    from trustnav.perception.cues import EyeContactCue, FaceFieldCue, PhoneUseCue, check_cues, with_face

    with pytest.raises(ValueError, match="EyeContactCue"):
        with_face([PhoneUseCue()])
    cues = check_cues(with_face([EyeContactCue(looking_model), PhoneUseCue()]))
    assert [c.name for c in cues] == ["eye_contact", "smartphone", "eye_contact_face", "face_confidence"]
    assert cues[2].face is cues[3].face is cues[0].face  # one analysis per frame, shared
    with pytest.raises(ValueError, match="face field"):
        FaceFieldCue(cues[0].face, "nose")


def test_estimate_face_option_adds_the_fields(sequences, looking_weights, tmp_path):
    import csv
    import json
    import shutil

    from trustnav.cli import main

    clip = tmp_path / "clip"
    clip.mkdir()
    for f in sorted((sequences / "walk_a").iterdir())[:2]:
        shutil.copy(f, clip / f.name)
    args = [str(clip), "--no-images", "--looking-weights", str(looking_weights)]
    assert main(["estimate", *args, "--out", str(tmp_path / "a")]) == 0
    assert "eye_contact_face" not in open(tmp_path / "a" / "tracks.csv").readline()
    assert main(["estimate", *args, "--out", str(tmp_path / "b"), "--face"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "b" / "tracks.csv")))
    assert rows and {"eye_contact", "eye_contact_face", "face_confidence"} <= set(rows[0])
    recs = json.loads((tmp_path / "b" / "tracks.json").read_text())
    near = [r for r in recs if r["bbox"][3] - r["bbox"][1] >= 105]  # boxes run head top to soles
    assert near and all(r["eye_contact_face"] is not None for r in near)  # the woman walking toward the camera
    assert all(r["eye_contact_face"] is None for r in recs if r["bbox"][3] - r["bbox"][1] < 100)


def test_shifted_fits_of_a_small_face_agree_or_lose_their_weight():
    from trustnav.perception.face import FaceResult

    def fit(p: float, c: float = 0.2, pitch: float = 0.0) -> FaceResult:
        return FaceResult(p, c, 0.0, pitch, 0.0, 12.0, 0.0, 50.0)

    combine = FaceEyeContact._combine
    same = combine([fit(0.9)] * 5)
    assert same.probability == pytest.approx(0.9) and same.confidence == pytest.approx(0.2)
    # the mesh's pitch flips between -4 and -50 deg with a 1-px move (rendered frame_08): p_face is
    # their mean and c_face falls with the disagreement, to 0 when half read "looking" and half "away"
    flip = combine([fit(1.0, pitch=-4), fit(0.0, pitch=-50)] * 2)
    assert flip.probability == pytest.approx(0.5) and flip.confidence == pytest.approx(0.0)
    mixed = combine([fit(0.9), fit(0.9), fit(0.9), fit(0.9), fit(0.1, pitch=-50)])
    assert 0.0 < mixed.confidence < same.confidence and mixed.pitch == 0.0  # median angles
    # fits that found no face count against the confidence, none at all: not judged
    assert combine([fit(0.9), None, None, None, None]).confidence == pytest.approx(0.2 / 5)
    assert math.isnan(combine([None, FaceResult(face_px=11.0)]).probability)
    # the verdict fused with LOOKING no longer flips: C_eye stays near p_looking whatever the fits say
    for p_looking in (0.3, 0.48, 0.7):
        assert abs(fuse_eye_contact(p_looking, flip.probability, flip.confidence) - p_looking) < 0.01


def test_shift_fits_are_validated():
    with pytest.raises(ValueError, match="shift_fits must be in"):
        FaceConfig(shift_fits=0)
    with pytest.raises(ValueError, match="shift_below_px"):
        FaceConfig(shift_below_px=-1.0)
    assert FaceConfig(shift_fits=1).shift_fits == 1


def test_looking_face_confidences_move_from_the_ears_to_the_mesh_with_the_face_size(looking_model):
    from trustnav.perception.confidence import face_confidences, head_yaw
    from trustnav.perception.cues import FACE_YAW_MIN_PX, FaceEyeContactCue
    from trustnav.perception.face import FaceResult

    # BlazePose's ears read the body turned -80 deg; the face mesh reads the face turned -10 deg
    lm = np.zeros((33, 5))
    lm[:, 3:] = 1.0
    lm[7, 0], lm[8, 0] = 100.0 + 2.0 * math.cos(math.radians(-80)), 100.0
    lm[7, 2], lm[8, 2] = 2.0 * math.sin(math.radians(-80)) / 0.5, 0.0
    assert math.degrees(head_yaw(lm)) == pytest.approx(-80.0)
    kp = np.column_stack([np.linspace(100, 120, 17), np.linspace(100, 260, 17)])
    person = Person(np.array([90.0, 90.0, 130.0, 270.0]), kp, np.full(17, 0.9), 0.9, extra={"blazepose": lm})
    cue = FaceEyeContactCue(looking_model)
    ears = face_confidences(np.ones(5), math.radians(-80))
    mesh = face_confidences(np.ones(5), math.radians(-10))

    def nose(face_px: float, agreement: float = 1.0) -> float:
        face = FaceResult(0.9, 0.5, -10.0, 0.0, -10.0, face_px, 0.0, 100.0, agreement)
        return float(cue._face_yawed(person, face).confidences[0])

    lo = cue.face.config.face_px_min
    assert nose(lo) == 0.9 and nose(0.0) == 0.9  # too small a face: BlazePose's own confidences
    assert nose(FACE_YAW_MIN_PX) == pytest.approx(mesh[0]) == pytest.approx(nose(40.0))
    sizes = np.linspace(lo, FACE_YAW_MIN_PX, 7)[1:]
    noses = [nose(s) for s in sizes]
    assert ears[0] < noses[0] and all(a < b for a, b in itertools.pairwise(noses))  # no switch: a ramp
    # a small face whose shifted fits disagree keeps the body's reading
    assert nose(14.0, agreement=0.0) == 0.9 and nose(14.0, 0.5) < nose(14.0, 1.0)


@pytest.mark.parametrize(("flags", "fits"), [((), 5), (("--realtime",), 1), (("--face",), 5)])
def test_estimate_fits_small_faces_on_shifted_crops_offline_only(
    sequences, looking_weights, tmp_path, monkeypatch, flags, fits
):
    import trustnav.perception.estimate as est
    from trustnav.cli import main
    from trustnav.perception.face import OFFLINE_SHIFT_FITS

    seen = {}

    class Captured(Exception):
        pass

    def capture(*args, face=None, face_config=None, **kwargs):
        seen["config"] = face.config if face is not None else face_config
        raise Captured  # the face configuration is all this test needs

    monkeypatch.setattr(est, "estimate_sequences", capture)
    frame = sorted((sequences / "walk_a").iterdir())[0]
    args = [str(frame), "--no-images", "--looking-weights", str(looking_weights), "--out", str(tmp_path / "o")]
    with pytest.raises(Captured):
        main(["estimate", *args, *flags])
    assert OFFLINE_SHIFT_FITS == 5 and seen["config"].shift_fits == fits  # real time has no time for them


def test_eye_crop_px_is_validated():
    with pytest.raises(ValueError, match="eye_crop_px"):
        FaceConfig(eye_crop_px=32)
    assert FaceConfig(eye_crop_px=0).eye_crop_px == 0


def test_eyes_turned_back_to_the_camera_count_and_eyes_turned_away_do_not(
    street_images, repo_root, mediapipe_backend, read_rgb
):
    """Gaze = head yaw + the eyes' turn in the head, the irises read on the face refitted alone
    (``FaceConfig.eye_crop_px``): street_2's woman in white turns her head ~30 deg away and her eyes
    back to the camera (labelled looking); crossing.jpg's man behind the polo shirt turns his head
    ~20 deg and his eyes further away (labelled not looking). On the head crop's mesh the irises of
    these 5-7 px eyes are not read (``eye_crop_px=0``, the iris threshold of 10 px there) and both
    read the head alone, the wrong way."""
    import json

    from trustnav.perception.types import box_iou

    labels = json.loads((repo_root / "benchmarks" / "data" / "labels" / "street.json").read_text())["frames"]
    cases = (("street_2.png", "woman in white", True), ("crossing.jpg", "man in dark jacket", False))
    refit, head_crop = FaceEyeContact(), FaceEyeContact(FaceConfig(eye_crop_px=0, min_eye_px=10.0))
    for image, who, looking in cases:
        frame = read_rgb(street_images / image)
        box = next(p["bbox"] for p in labels[image]["people"] if p["id"].startswith(who))
        person = max(mediapipe_backend(frame), key=lambda q: box_iou(q.bbox, box))
        assert box_iou(person.bbox, box) >= 0.5, (image, who)
        new, old = refit.analyse(frame, person), head_crop.analyse(frame, person)
        assert new.face_px >= 25 and old.gaze_yaw == old.yaw  # no iris on the head crop's mesh
        turn = new.gaze_yaw - new.yaw  # the eyes' turn in the head, the head's turn: opposite when looking
        assert (turn * new.yaw < 0) == looking and abs(turn) >= 5, (who, new.yaw, turn)
        assert (new.probability >= 0.5) == looking and (old.probability >= 0.5) != looking, (who, new, old)


@pytest.mark.parametrize(
    ("args", "named"),
    [(["--rendered", "/nonexistent"], "--rendered '/nonexistent': expected the folder trust_eval.py --keep wrote"),
     (["--side", "0"], "--side 0: expected the upscaled face crop's side in px, >= 64")],
)  # fmt: skip
def test_the_gaze_evidence_script_refuses_a_bad_folder_or_crop_side_by_name(repo_root, args, named):
    """benchmarks/gaze_evidence.py: a missing rendered folder (was an OpenCV warning and 'cannot
    read' a frame) or a crop too small is one parser line naming the option."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(repo_root / "benchmarks" / "gaze_evidence.py"), *args],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 2
    assert named in out.stderr.strip().splitlines()[-1]
