"""Phone use over time (TemporalPhoneModel, PhoneUseCue with track IDs and times) and the crop
classifier plug: synthetic COCO keypoint sequences, no model files, no video."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trustnav.perception.cues import PhoneUseCue, default_cues, run_cue
from trustnav.perception.phone import (
    LABELLED_PHONE_CALIBRATION,
    CropPhoneClassifier,
    PhoneCalibration,
    PoseGeometryPhoneClassifier,
    TemporalPhoneModel,
    fuse_crop,
)
from trustnav.perception.types import Person


def _body(x0: float, nose_drop: float = 0.0) -> np.ndarray:
    """An upright person in profile (facing +x), torso 100 px (shoulders y=100, hips y=200)."""
    kp = np.zeros((17, 2))
    kp[5], kp[6] = (x0 + 3, 100), (x0 - 3, 100)
    kp[11], kp[12] = (x0 + 2, 200), (x0 - 2, 200)
    kp[3], kp[4] = (x0 + 4, 70), (x0 - 2, 70)
    kp[0] = (x0 + 10, 72 + nose_drop)
    kp[1], kp[2] = (x0 + 8, 68), (x0 + 6, 68)
    kp[13:15] = (x0 + 5, 260), (x0 - 5, 260)
    kp[15:17] = (x0 + 5, 320), (x0 - 5, 320)
    return kp


def walker(t: float, period: float = 1.1) -> np.ndarray:
    """Arms swinging in antiphase with the stride, elbows bending on the forward swing: at the
    top of each forward swing the wrist passes through the texting band (geometry ~0.6)."""
    kp = _body(100 + 120 * t)
    for side, (wrist, elbow) in enumerate(((9, 7), (10, 8))):
        th = math.sin(2 * math.pi * t / period + side * math.pi)
        kp[elbow] = kp[5 + side] + 45 * np.array([math.sin(th), math.cos(th)])
        fore = th + 0.6 * max(th, 0.0)
        kp[wrist] = kp[elbow] + 40 * np.array([math.sin(fore), math.cos(fore)])
    return kp


def texter(t: float, rng: np.random.Generator) -> np.ndarray:
    """Both hands held together in front of the chest, head bent; 2 px keypoint noise."""
    kp = _body(100 + 60 * t, nose_drop=18)
    kp[7], kp[8] = (kp[5, 0] + 2, 150), (kp[6, 0] - 2, 150)
    kp[9], kp[10] = (kp[5, 0] + 19, 132), (kp[6, 0] + 19, 134)
    return kp + rng.normal(0.0, 2.0, kp.shape)


def _person(kp: np.ndarray) -> Person:
    lo, hi = kp.min(axis=0), kp.max(axis=0)
    return Person(bbox=np.r_[lo - 5, hi + 5], keypoints=kp, confidences=np.ones(17), score=0.9)


@pytest.mark.parametrize("fps", [1, 5, 30])
def test_walker_reads_low_after_two_seconds_at_any_rate(fps):
    model = TemporalPhoneModel()
    times = np.arange(0.0, 4.0 + 1e-9, 1.0 / fps)
    out = [model.add_pose(7, t, walker(t)) for t in times]
    geometry = max(r.geometry for r in out)
    late = [r.phone for r, t in zip(out, times, strict=True) if t >= 2.0]
    assert geometry > 0.55  # one frame's arm geometry alone fires on this walker
    assert max(late) < 0.45 and np.mean(late) < 0.35, (fps, late)
    assert all(r.weight == pytest.approx(model.max_weight) for r, t in zip(out, times, strict=True) if t >= 2.0)


@pytest.mark.parametrize("fps", [1, 5, 30])
def test_texter_reads_high(fps):
    rng = np.random.default_rng(fps)
    model = TemporalPhoneModel()
    times = np.arange(0.0, 4.0 + 1e-9, 1.0 / fps)
    out = [model.add_pose(3, t, texter(t, rng)) for t in times]
    assert out[0].weight == 0.0 and out[0].phone == out[0].geometry  # first frame: geometry only
    assert min(r.phone for r in out) > 0.8


def test_confidence_grows_with_seconds_not_frames():
    for fps in (1, 10, 30):
        model = TemporalPhoneModel(window_s=2.0, max_weight=0.8)
        rng = np.random.default_rng(0)
        res = [model.add_pose(1, t, texter(t, rng)) for t in np.arange(0.0, 1.0 + 1e-9, 1.0 / fps)]
        assert res[-1].history_s == pytest.approx(1.0)
        assert res[-1].weight == pytest.approx(0.4)


def test_history_is_per_track_and_restarts():
    rng = np.random.default_rng(1)
    model = TemporalPhoneModel(reset_after_s=3.0)
    for t in np.arange(0.0, 3.0, 0.1):
        model.add_pose(1, t, texter(t, rng))
        model.add_pose(2, t, walker(t))
    assert model.track_ids == [1, 2]
    # a new track starts with geometry only: nothing from tracks 1 or 2 leaks into it
    new = model.add_pose(3, 3.0, walker(3.0))
    assert new.weight == 0.0 and new.history_s == 0.0 and new.phone == new.geometry
    # track 1 unseen for longer than reset_after_s: dropped, and restarts from its next frame
    later = model.add_pose(2, 6.5, walker(6.5))
    assert 1 not in model.track_ids and later.history_s == 0.0
    # untracked people (-1) and frames without a time are judged alone
    assert model.add_pose(-1, 7.0, walker(7.0)).weight == 0.0
    assert model.add_pose(2, None, walker(7.0)).weight == 0.0
    model.reset()
    assert model.track_ids == []


def test_phone_use_cue_follows_tracks_through_run_cue():
    clf = PoseGeometryPhoneClassifier()
    cue = PhoneUseCue(clf, temporal=TemporalPhoneModel(clf))
    frame = np.zeros((400, 800, 3), dtype=np.uint8)
    rng = np.random.default_rng(2)
    for t in np.arange(0.0, 3.0, 0.1):
        people = [_person(walker(t)), _person(texter(t, rng))]
        values = run_cue(cue, frame, people, track_ids=[4, 5], time=float(t))
    assert values[0] < 0.45 < 0.8 < values[1]
    # without track IDs the cue is the single-frame classifier, as before
    alone = run_cue(cue, frame, people)
    assert alone == [clf(frame, p) for p in people]

    # default cues: temporal for the pose geometry, a user's own classifier as given
    class Eye:
        def predict(self, x):
            return np.zeros(len(x))

    assert default_cues(Eye(), None)[1].temporal is not None  # type: ignore[arg-type]
    mine = default_cues(Eye(), lambda frame, p: 0.3)[1]  # type: ignore[arg-type]
    assert mine.temporal is None and mine(frame, people, track_ids=[4, 5], time=9.0) == [0.3, 0.3]


def test_crop_classifier_plug_errors_and_fusion(tmp_path):
    with pytest.raises(ValueError, match="needs a model file"):
        CropPhoneClassifier()
    with pytest.raises(FileNotFoundError, match="not found"):
        CropPhoneClassifier(tmp_path / "phone.onnx")
    (tmp_path / "phone.pt").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"\.onnx or \.tflite"):
        CropPhoneClassifier(tmp_path / "phone.pt")
    # a runner stands in for the network: two class logits, phone = index 1
    seen = []
    crop = CropPhoneClassifier(runner=lambda x: seen.append(x.shape) or np.array([[0.0, 2.0]]), min_height_px=64)
    frame = np.full((400, 800, 3), 128, dtype=np.uint8)
    p = _person(texter(0.0, np.random.default_rng(3)))
    assert crop(frame, p) == pytest.approx(1 / (1 + math.exp(-2.0)))
    assert seen == [(1, 3, 224, 224)]
    small = Person(bbox=np.array([0.0, 0.0, 10.0, 30.0]), keypoints=p.keypoints, confidences=p.confidences, score=0.9)
    assert math.isnan(crop(frame, small))  # too small to judge
    # fused by confidence: weight grows with the person's height; NaN leaves the pose cue
    assert fuse_crop(0.2, math.nan, 300) == 0.2
    assert fuse_crop(0.2, 1.0, 40) == 0.2 and fuse_crop(0.2, 1.0, 300) == pytest.approx(0.2 + 0.7 * 0.8)
    cue = PhoneUseCue(PoseGeometryPhoneClassifier(), crop=crop)
    assert cue(frame, [p])[0] == pytest.approx(fuse_crop(PoseGeometryPhoneClassifier()(frame, p), crop(frame, p), 330))


def test_crop_classifier_reads_a_tflite_file_with_opencv():
    """The file path (no runner): any TFLite network of a 224 x 224 RGB input loads and runs; the
    wheel's hand-landmark model stands in for a user's classifier (its output is not a phone class)."""
    mediapipe = pytest.importorskip("mediapipe")
    from pathlib import Path

    model = Path(mediapipe.__file__).parent / "modules" / "hand_landmark" / "hand_landmark_lite.tflite"
    if not model.is_file():
        pytest.skip("no bundled TFLite model")
    crop = CropPhoneClassifier(model, probabilities=True)
    frame = np.random.default_rng(4).integers(0, 255, (400, 400, 3), dtype=np.uint8)
    p = _person(texter(0.0, np.random.default_rng(5)))
    assert 0.0 <= crop(frame, p) <= 1.0


class _Eye:
    def predict(self, x):
        return np.zeros(len(x))


def test_calibration_is_a_monotone_probability_map():
    cal = LABELLED_PHONE_CALIBRATION
    ps = np.array([cal(c) for c in np.linspace(0.0, 1.0, 201)])
    assert np.all((ps > 0.0) & (ps < 1.0)) and np.all(np.diff(ps) > 0)  # orders people as the cue does
    assert cal(cal.threshold) == pytest.approx(0.5)
    assert 0.0 < cal.threshold < 0.5  # the labelled people's cue under-reports phone use near 0.5
    assert math.isnan(cal(math.nan))  # not judged stays not judged
    assert PhoneCalibration(-800.0, 1.0)(0.0) == pytest.approx(0.0) and PhoneCalibration(800.0, 1.0)(0.0) == 1.0
    for bad in ((0.0, 0.0), (0.0, -2.0), (math.nan, 1.0), (0.0, math.inf)):
        with pytest.raises(ValueError, match="finite intercept and a positive slope"):
            PhoneCalibration(*bad)


@pytest.mark.parametrize("seed", [0, 1])
def test_calibration_fit_recovers_a_logistic_map(seed):
    rng = np.random.default_rng(seed)
    truth = PhoneCalibration(-3.0, 7.0)
    x = rng.uniform(0.0, 1.0, 5000)
    y = rng.uniform(size=x.size) < np.array([truth(v) for v in x])
    fit = PhoneCalibration.fit(x, y)
    assert fit.intercept == pytest.approx(-3.0, abs=0.4) and fit.slope == pytest.approx(7.0, abs=0.8)
    assert fit.threshold == pytest.approx(truth.threshold, abs=0.03)
    # separable labels give a finite, steep map with its 0.5 in the gap
    sep = PhoneCalibration.fit(np.r_[np.zeros(20), np.ones(20)], np.r_[np.zeros(20), np.ones(20)].astype(bool))
    assert 0.0 < sep.threshold < 1.0 and sep(1.0) > 0.95 > 0.05 > sep(0.0)
    with pytest.raises(ValueError, match="both phone users and non-users, got 0 users of 5000"):
        PhoneCalibration.fit(x, np.zeros(x.size, dtype=bool))
    with pytest.raises(ValueError, match=r"finite and of one length, got 3 values \(2 finite\) and 2 labels"):
        PhoneCalibration.fit(np.array([0.1, np.nan, 0.3]), np.array([True, False]))


def test_default_cues_give_the_calibrated_temporal_model():
    cue = default_cues(_Eye(), None)[1]  # type: ignore[arg-type]
    raw_cue = default_cues(_Eye(), None, phone_calibration=None)[1]  # type: ignore[arg-type]
    assert cue.temporal.calibration is LABELLED_PHONE_CALIBRATION and raw_cue.temporal.calibration is None
    with pytest.raises(ValueError, match="calibration must be a PhoneCalibration"):
        TemporalPhoneModel(calibration=(0.0, 1.0))  # type: ignore[arg-type]
    rng = np.random.default_rng(3)
    frame = np.zeros((400, 800, 3), dtype=np.uint8)
    for t in np.arange(0.0, 2.5, 0.1):
        people = [_person(walker(t)), _person(texter(t, rng))]
        got = run_cue(cue, frame, people, track_ids=[1, 2], time=float(t))
        raw = run_cue(raw_cue, frame, people, track_ids=[1, 2], time=float(t))
        assert got == pytest.approx([LABELLED_PHONE_CALIBRATION(v) for v in raw])
    assert got[1] > 0.95 and got[0] < got[1]  # the texter still sure, the walker below
    # the single-frame reading (no track, no time) is calibrated alike; geometry stays the model's own
    model = TemporalPhoneModel(calibration=LABELLED_PHONE_CALIBRATION)
    alone = model.add_pose(-1, None, texter(0.0, rng))
    assert alone.phone == pytest.approx(LABELLED_PHONE_CALIBRATION(alone.geometry))
