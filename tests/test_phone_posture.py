"""Issue 19's phone-use and eye-contact posture cues on synthetic keypoints (no model files):
both hands held together in front of the torso, no hand evidence from a person seen from behind,
the head pitch from the face where it is judged, and the both-hands veto on eye contact."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trustnav.perception.cues import EyeContactCue, FaceEyeContactCue, PhoneUseCue, default_cues, with_face
from trustnav.perception.face import FaceConfig, FaceEyeContact, FaceResult
from trustnav.perception.phone import PoseGeometryPhoneClassifier, TemporalPhoneModel
from trustnav.perception.types import Person


def _body(nose_drop: float = 0.0) -> np.ndarray:
    """An upright person facing the camera, torso 100 px (shoulders y=100, hips y=200), arms down."""
    kp = np.zeros((17, 2))
    kp[5], kp[6] = (120, 100), (80, 100)  # left shoulder on the image right: facing the camera
    kp[11], kp[12] = (115, 200), (85, 200)
    kp[3], kp[4] = (110, 70), (90, 70)
    kp[0] = (100, 72 + nose_drop)
    kp[1], kp[2] = (105, 66), (95, 66)
    kp[7], kp[8] = (125, 150), (75, 150)
    kp[9], kp[10] = (127, 195), (73, 195)
    kp[13:15] = (115, 260), (85, 260)
    kp[15:17] = (115, 320), (85, 320)
    return kp


def both_hands(nose_drop: float = 0.0) -> np.ndarray:
    """Both wrists together in front of the chest (a phone held in both hands)."""
    kp = _body(nose_drop)
    kp[7], kp[8] = (118, 150), (82, 150)
    kp[9], kp[10] = (104, 130), (96, 131)
    return kp


def one_hand(nose_drop: float = 0.0) -> np.ndarray:
    """One wrist raised in front of the chest, the other hanging at the hip."""
    kp = _body(nose_drop)
    kp[7] = (118, 150)
    kp[9] = (104, 130)
    return kp


def _conf(face: float | tuple[float, float, float] = 1.0, wrists: float = 1.0) -> np.ndarray:
    """Confidences: ``face`` for nose and both eyes (or each of them), ``wrists`` for both wrists."""
    c = np.ones(17)
    c[:3] = face
    c[9], c[10] = wrists, wrists
    return c


BACK = 0.02  # the occlusion-aware confidences' floor: nose and both eyes of a person seen from behind
PROFILE = (0.3, 0.7, 0.02)  # nose, near eye, far eye of a profile


def _person(kp: np.ndarray, conf: np.ndarray) -> Person:
    lo, hi = kp.min(axis=0), kp.max(axis=0)
    return Person(bbox=np.r_[lo - 5, hi + 5], keypoints=kp, confidences=conf, score=0.9)


G = PoseGeometryPhoneClassifier()


def test_hands_held_together_are_a_phone_even_when_each_wrist_is_half_seen():
    # hands together in front of the body are half hidden: BlazePose gives each wrist ~0.5
    half = _conf(wrists=0.5)
    texting, calling, pair = G.parts(both_hands(nose_drop=18.0), half)
    assert G.hands_together(both_hands(nose_drop=18.0), half) == pytest.approx(pair)
    assert pair > 0.7 and texting.max() < 0.55  # each wrist alone is uncertain, the pair is not
    assert calling.max() == 0.0
    assert G.confidence(both_hands(nose_drop=18.0), half) == pytest.approx(pair)
    # hands apart (one raised, one at the hip) are no pair, and arms down no cue at all
    assert G.hands_together(one_hand(), _conf()) == 0.0
    assert G.confidence(_body(), _conf()) == 0.0
    # the pair needs the hands in the raise band: both hands together at the belt are no phone
    low = both_hands()
    low[[9, 10], 1] = 192
    assert G.hands_together(low, _conf()) == 0.0


def test_hands_together_pitch_down_raises_the_pair_but_it_holds_without():
    flat = G.hands_together(both_hands(nose_drop=0.0), _conf())
    bent = G.hands_together(both_hands(nose_drop=18.0), _conf())
    assert bent > flat > 0.5


@pytest.mark.parametrize("pose", [both_hands, one_hand])
def test_seen_from_behind_the_hands_are_no_evidence(pose):
    front = G.confidence(pose(nose_drop=18.0), _conf())
    profile = G.confidence(pose(nose_drop=18.0), _conf(PROFILE))
    dropped = G.confidence(pose(nose_drop=18.0), _conf((0.05, 0.05, 0.8)))  # nose dropped out, one eye seen
    back = G.confidence(pose(nose_drop=18.0), _conf(BACK))
    assert front > 0.7 and profile == pytest.approx(front) and dropped == pytest.approx(front)
    assert back == 0.0
    # a wrist at the ear seen from behind is a guess too
    call = _body()
    call[9] = (112, 78)
    assert G.confidence(call, _conf()) > 0.9 and G.confidence(call, _conf(BACK)) == 0.0
    # no confidences (a backend without them): no facing judgement
    assert G.confidence(pose(nose_drop=18.0)) == pytest.approx(front)
    off = PoseGeometryPhoneClassifier(facing_confidence=None)
    assert off.confidence(pose(nose_drop=18.0), _conf(BACK)) == pytest.approx(front)


def test_temporal_model_judges_facing_over_the_window():
    """A texter seen from behind for two seconds reads low however the one frame's nose reads;
    the same texter facing the camera reads high."""
    rng = np.random.default_rng(0)
    model = TemporalPhoneModel()
    back, front = [], []
    for k in range(31):  # 10 frames/s, 3 s
        t = k / 10
        kp = both_hands(nose_drop=18.0) + rng.normal(0.0, 1.0, (17, 2))
        face = 1.0 if k == 30 else BACK  # the last frame alone looks frontal
        back.append(model.add_pose(1, t, kp, _conf(face)).phone)
        front.append(model.add_pose(2, t, kp, _conf()).phone)
    assert max(back[5:]) < 0.2
    assert min(front) > 0.7


def test_face_pitch_weighs_the_texting_cue_by_the_face_confidence():
    kp, conf = one_hand(nose_drop=0.0), _conf()
    base = G.parts(kp, conf)[0].max()
    ahead = G.parts(kp, conf, face=(10.0, 0.9))[0].max()  # a confident face looking ahead
    down = G.parts(kp, conf, face=(-30.0, 0.9))[0].max()  # ... looking down at the hand
    weak = G.parts(kp, conf, face=(10.0, 0.1))[0].max()  # a small, blurred face counts little
    assert ahead < 0.2 < base < down
    assert ahead < weak < base
    assert G.parts(kp, conf, face=(math.nan, 0.9))[0].max() == pytest.approx(base)  # not judged


class _FixedFace(FaceEyeContact):
    def __init__(self, result: FaceResult) -> None:
        super().__init__(FaceConfig())
        self.result = result

    def __call__(self, frame, people):
        return [self.result for _ in people]


def test_phone_cue_reads_the_shared_face_analysis():
    frame = np.zeros((400, 300, 3), dtype=np.uint8)
    person = _person(one_hand(), _conf())
    plain = PhoneUseCue(G)(frame, [person])[0]
    ahead = PhoneUseCue(G, face=_FixedFace(FaceResult(0.9, 0.9, 0.0, 10.0)))(frame, [person])[0]
    assert ahead < 0.2 < plain
    temporal = PhoneUseCue(G, temporal=TemporalPhoneModel(G), face=_FixedFace(FaceResult(0.9, 0.9, 0.0, 10.0)))
    assert temporal(frame, [person], track_ids=[3], time=0.0)[0] == pytest.approx(ahead)


class _Looking:
    """A stand-in for the LOOKING model: every person looks at the camera (0.9)."""

    def predict(self, inputs):
        return np.full(len(inputs), 0.9)


def test_eye_contact_veto_for_hands_held_together():
    frame = np.zeros((400, 300, 3), dtype=np.uint8)
    people = [_person(both_hands(), _conf()), _person(_body(), _conf()), _person(one_hand(), _conf())]
    plain = EyeContactCue(_Looking())(frame, people)
    vetoed = EyeContactCue(_Looking(), posture=G)(frame, people)
    assert np.allclose(plain, 0.9)
    assert vetoed[0] < 0.5  # eyes on what the hands hold
    assert vetoed[1] == pytest.approx(0.9) and vetoed[2] == pytest.approx(0.9)  # arms down, one hand: no veto
    none = EyeContactCue(_Looking(), posture=G, posture_weight=0.0)(frame, people)
    assert np.allclose(none, 0.9)
    with pytest.raises(ValueError, match="posture_weight"):
        EyeContactCue(_Looking(), posture_weight=1.5)


def test_default_cues_fuse_the_face_and_keep_the_posture_veto_through_with_face():
    eye, phone = default_cues(_Looking())  # type: ignore[arg-type]
    assert isinstance(eye, FaceEyeContactCue) and isinstance(eye.posture, PoseGeometryPhoneClassifier)
    assert isinstance(phone, PhoneUseCue) and phone.temporal is not None
    assert eye.face.config.min_person_px >= 100  # the face only on people large enough
    shared = FaceEyeContact(FaceConfig(fov_deg=60.0))
    out = with_face((eye, phone), shared)
    assert isinstance(out[0], FaceEyeContactCue) and out[0].face is shared and out[0].posture is eye.posture
    assert [c.name for c in out] == ["eye_contact", "smartphone", "eye_contact_face", "face_confidence"]


def test_small_people_never_run_the_face_models():
    """People under FaceConfig.min_person_px are left to LOOKING: the face graphs are not even loaded."""
    face = FaceEyeContact(FaceConfig())
    frame = np.zeros((400, 300, 3), dtype=np.uint8)
    kp = _body() * 0.25  # ~65 px tall
    (res,) = face(frame, [_person(kp, _conf())])
    assert math.isnan(res.probability) and res.confidence == 0.0
    assert face._graphs is None
