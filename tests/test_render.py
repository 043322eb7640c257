"""Driving-world camera, pedestrian bodies and the PyBullet renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trustnav.geometry.camera import CameraPose, CameraSpec
from trustnav.sim.driving.body import (
    ATTENTIVE_LOOK,
    COCO_NAMES,
    DISTRACTED_LOOK,
    POSES,
    WALKER_LOOK,
    Appearance,
    pedestrian_skeleton,
)

EGO_YAW = -math.pi / 2  # Case I: the ego drives toward -y
ATTENTIVE_AT, DISTRACTED_AT = (29.5, 101.0), (37.5, 101.0)
ATTENTIVE_YAW, DISTRACTED_YAW = math.radians(60.0), 0.0


def idx(name: str) -> int:
    return COCO_NAMES.index(name)


def case_one(y: float, t: float = 0.0):
    cam = CameraSpec().pose((33.5, y), EGO_YAW)
    att = pedestrian_skeleton(
        "attentive", ATTENTIVE_AT, ATTENTIVE_YAW, t, ATTENTIVE_LOOK, look_at=cam.position, phase=0.1
    )
    dis = pedestrian_skeleton("distracted", DISTRACTED_AT, DISTRACTED_YAW, t, DISTRACTED_LOOK, phase=0.6)
    return cam, att, dis


# ----------------------------------------------------------------------------- camera


def test_camera_mount_and_axis_projects_to_centre() -> None:
    spec = CameraSpec()
    cam = spec.pose((33.5, 129.0), EGO_YAW)
    np.testing.assert_allclose(cam.position, [33.5, 127.5, 1.7])
    uv, depth = cam.project([[33.5, 100.0, 1.7]])
    np.testing.assert_allclose(uv[0], [640.0, 360.0], atol=1e-9)
    assert depth[0] == pytest.approx(27.5)
    assert cam.focal_px == pytest.approx(640.0 / math.tan(math.radians(35.0)))


def test_camera_behind_and_fov_edges() -> None:
    spec = CameraSpec(width=800, height=400, fov_deg=90.0)
    cam = spec.pose((0.0, 0.0), 0.0)  # looks along +x from (1.5, 0, 1.7)
    _, depth = cam.project([[-5.0, 0.0, 1.7]])
    assert depth[0] < 0.0
    # 45 deg to the left/right lands on the image's left/right edge
    uv, _ = cam.project([[11.5, 10.0, 1.7], [11.5, -10.0, 1.7]])
    np.testing.assert_allclose(uv[:, 0], [0.0, 800.0], atol=1e-9)
    np.testing.assert_allclose(uv[:, 1], [200.0, 200.0], atol=1e-9)
    # up is up in the image
    uv, _ = cam.project([[11.5, 0.0, 3.0]])
    assert uv[0, 1] < 200.0
    inside = cam.in_view([[11.5, 9.9, 1.7], [11.5, -10.1, 1.7], [-5.0, 0.0, 1.7], [11.5, 0.0, 1.7]])
    assert inside.tolist() == [True, False, False, True]


def test_camera_pitch_moves_horizon_up() -> None:
    cam = CameraSpec(pitch_deg=10.0).pose((0.0, 0.0), 0.3)
    far = cam.position + 1000.0 * np.array([math.cos(0.3), math.sin(0.3), 0.0])
    uv, _ = cam.project(far[None])
    assert uv[0, 1] == pytest.approx(360.0 - cam.focal_px * math.tan(math.radians(10.0)), abs=0.5)
    assert isinstance(cam, CameraPose)


@pytest.mark.parametrize(
    "kwargs", [{"width": 0}, {"fov_deg": 0.0}, {"up": -1.0}, {"rate": 0.0}, {"pitch_deg": 95.0}, {"width": 12.5}]
)
def test_camera_spec_validates(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        CameraSpec(**kwargs)


# ----------------------------------------------------------------------------- bodies


@pytest.mark.parametrize("pose", POSES)
def test_skeleton_is_upright(pose: str) -> None:
    for t in (0.0, 0.4, 1.3):
        sk = pedestrian_skeleton(pose, (3.0, 4.0), 0.7, t, WALKER_LOOK, look_at=(10.0, 4.0, 1.7))
        j = sk.joints
        assert j.shape == (17, 3) and len(COCO_NAMES) == 17
        head = j[:5, 2].min()
        shoulders = j[[idx("left_shoulder"), idx("right_shoulder")], 2]
        hips = j[[idx("left_hip"), idx("right_hip")], 2]
        ankles = j[[idx("left_ankle"), idx("right_ankle")], 2]
        assert head > shoulders.max() > hips.max() > ankles.max() >= 0.0
        assert 1.55 < sk.head_centre[2] + 0.11 < 1.8
        np.testing.assert_allclose(sk.pelvis[:2], [3.0, 4.0], atol=0.1)


def test_distracted_holds_phone_between_raised_hands() -> None:
    sk = pedestrian_skeleton("distracted", (0.0, 0.0), 0.0, 0.0, DISTRACTED_LOOK)
    j = sk.joints
    wrists = j[[idx("left_wrist"), idx("right_wrist")]]
    hips_z = j[[idx("left_hip"), idx("right_hip")], 2].mean()
    shoulders_z = j[[idx("left_shoulder"), idx("right_shoulder")], 2].mean()
    raised = (wrists[:, 2] - hips_z) / (shoulders_z - hips_z)
    assert np.all((raised > 0.55) & (raised < 0.95))  # the phone classifier's band
    assert np.all(wrists[:, 0] > 0.15)  # in front of the body (faces +x)
    assert sk.phone is not None
    assert wrists[:, 1].min() < sk.phone[1] < wrists[:, 1].max()
    assert sk.phone[0] > wrists[:, 0].min()
    assert sk.head_pitch == pytest.approx(math.radians(35.0), abs=math.radians(4.0))
    for rot in (sk.phone_rot, sk.head_rot, sk.body_rot):
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
        assert np.linalg.det(rot) == pytest.approx(1.0)
    att = pedestrian_skeleton("attentive", (0.0, 0.0), 0.0, 0.0, ATTENTIVE_LOOK)
    assert att.phone is None
    assert np.all(att.joints[[idx("left_wrist"), idx("right_wrist")], 2] < hips_z + 0.05)


def test_attentive_head_turns_toward_look_at_within_limits() -> None:
    sk = pedestrian_skeleton("attentive", (0.0, 0.0), 0.0, 0.0, ATTENTIVE_LOOK, look_at=(5.0, 5.0, 1.7), sway=0.0)
    assert sk.head_yaw == pytest.approx(math.pi / 4, abs=0.03)
    behind = pedestrian_skeleton("attentive", (0.0, 0.0), 0.0, 0.0, ATTENTIVE_LOOK, look_at=(-5.0, 0.1, 1.7), sway=0)
    assert abs(behind.head_yaw) <= math.radians(100.0)  # neck 75 deg + chest 20 deg (+ sway)
    chest = math.atan2(sk.body_rot[1, 0], sk.body_rot[0, 0])
    assert 0.0 < chest < sk.head_yaw  # the chest turns a little with the head, the hips do not
    hips = sk.joint("left_hip") - sk.joint("right_hip")
    assert math.atan2(hips[1], hips[0]) == pytest.approx(math.pi / 2, abs=1e-9)
    nose, ears = sk.joint("nose"), (sk.joint("left_ear") + sk.joint("right_ear")) / 2
    assert math.atan2(*(nose - ears)[1::-1]) == pytest.approx(math.pi / 4, abs=0.05)


def test_sway_is_small_deterministic_and_varies() -> None:
    args = ("attentive", (1.0, 2.0), 0.3, 2.0, ATTENTIVE_LOOK)
    a = pedestrian_skeleton(*args, phase=0.2)
    b = pedestrian_skeleton(*args, phase=0.2)
    np.testing.assert_array_equal(a.joints, b.joints)
    c = pedestrian_skeleton("attentive", (1.0, 2.0), 0.3, 3.0, ATTENTIVE_LOOK, phase=0.2)
    still = pedestrian_skeleton(*args, phase=0.2, sway=0.0)
    moved = np.linalg.norm(c.joints - a.joints, axis=1)
    assert 0.002 < moved.max() < 0.08
    assert np.linalg.norm(still.joints - a.joints, axis=1).max() < 0.08


def test_walking_legs_swing_with_time() -> None:
    frames = [pedestrian_skeleton("walking", (0.0, 0.0), 0.0, t, WALKER_LOOK, sway=0.0) for t in np.arange(0, 1.2, 0.1)]
    ankle_x = np.array([f.joint("left_ankle")[0] - f.joint("right_ankle")[0] for f in frames])
    assert ankle_x.max() > 0.3 and ankle_x.min() < -0.3
    assert min(f.joints[15:17, 2].min() for f in frames) == pytest.approx(0.085 * WALKER_LOOK.height / 1.75, abs=1e-6)


def test_body_validation() -> None:
    with pytest.raises(ValueError):
        pedestrian_skeleton("running", (0, 0), 0.0, 0.0, ATTENTIVE_LOOK)
    with pytest.raises(ValueError):
        Appearance(skin=(1.2, 0, 0), hair=(0, 0, 0), shirt=(0, 0, 0), trousers=(0, 0, 0), shoes=(0, 0, 0))
    with pytest.raises(ValueError):
        Appearance(skin=(1, 0, 0), hair=(0, 0, 0), shirt=(0, 0, 0), trousers=(0, 0, 0), shoes=(0, 0, 0), height=3.0)


# ----------------------------------------------------------------------------- renderer


@pytest.fixture(scope="module")
def renderer():
    pytest.importorskip("pybullet")
    from trustnav.sim.driving.render import PyBulletRenderer, StreetSpec

    with PyBulletRenderer(StreetSpec()) as r:
        yield r


def _box(cam: CameraPose, sk, pad: float = 0.0) -> tuple[int, int, int, int]:
    uv, _ = cam.project(sk.points())
    x1, y1 = np.floor(uv.min(axis=0) - pad).astype(int)
    x2, y2 = np.ceil(uv.max(axis=0) + pad).astype(int)
    return x1, y1, x2, y2


def test_renderer_draws_people_where_the_camera_projects_them(renderer) -> None:
    spec = CameraSpec(width=640, height=360)
    cam = spec.pose((33.5, 113.0), EGO_YAW)
    street = renderer.street
    att_at, dis_at = ((*xy, street.ground_height(xy)) for xy in (ATTENTIVE_AT, DISTRACTED_AT))
    assert att_at[2] == dis_at[2] == street.kerb_height > 0  # both on the sidewalks
    att = pedestrian_skeleton("attentive", att_at, ATTENTIVE_YAW, 0.0, ATTENTIVE_LOOK, look_at=cam.position)
    dis = pedestrian_skeleton("distracted", dis_at, DISTRACTED_YAW, 0.0, DISTRACTED_LOOK)
    empty = renderer.render(cam, [])
    frame = renderer.render(cam, [(att, ATTENTIVE_LOOK), (dis, DISTRACTED_LOOK)])
    assert frame.shape == (360, 640, 3) and frame.dtype == np.uint8
    changed = np.any(frame != empty, axis=2)
    for sk in (att, dis):
        x1, y1, x2, y2 = _box(cam, sk)
        assert changed[y1:y2, x1:x2].mean() > 0.25, "the person should cover a good part of its projected box"
        x1, y1, x2, y2 = _box(cam, sk, pad=0.12 * cam.focal_px / 12.0)  # body surface ~0.12 m beyond joints
        inner = changed[y1:y2, x1:x2].sum()
        ring = changed[max(0, y1 - 40) : y2 + 40, max(0, x1 - 40) : x2 + 40].sum() - inner
        assert ring < 0.02 * inner, "the person should be drawn where the camera projects it"
    # the attentive person's shirt colour appears inside its box
    x1, y1, x2, y2 = _box(cam, att)
    shirt = np.array(ATTENTIVE_LOOK.shirt) * 255
    patch = frame[y1:y2, x1:x2].reshape(-1, 3).astype(float)
    assert np.min(np.linalg.norm(patch / patch.sum(1, keepdims=True).clip(1) - shirt / shirt.sum(), axis=1)) < 0.05
    # people removed again: back to the empty street; sky on top, road at the bottom centre
    again = renderer.render(cam, [])
    np.testing.assert_array_equal(again, empty)
    assert again[5, 320, 2] > again[5, 320, 0]
    assert abs(int(again[350, 320, 0]) - int(again[350, 320, 2])) < 20


def test_renderer_people_may_change_order_count_and_ground(renderer) -> None:
    spec = CameraSpec(width=320, height=180)
    cam, att, dis = case_one(115.0)
    cam = spec.pose((33.5, 115.0), EGO_YAW)
    both = renderer.render(cam, [(att, ATTENTIVE_LOOK), (dis, DISTRACTED_LOOK)])
    swapped = renderer.render(cam, [(dis, DISTRACTED_LOOK), (att, ATTENTIVE_LOOK)])
    np.testing.assert_array_equal(both, swapped)
    only = renderer.render(cam, [(att, ATTENTIVE_LOOK)])
    x1, y1, x2, y2 = _box(cam, dis, pad=4.0)
    assert np.any(only[y1:y2, x1:x2] != both[y1:y2, x1:x2])  # the distracted one is gone
    # a body built at the sidewalk's height is drawn where the one built at z = 0 is lifted to
    z = renderer.street.ground_height(ATTENTIVE_AT)
    lifted = pedestrian_skeleton(
        "attentive", (*ATTENTIVE_AT, z), ATTENTIVE_YAW, 0.0, ATTENTIVE_LOOK, look_at=cam.position, phase=0.1
    )
    np.testing.assert_allclose(lifted.joints[:, 2] - att.joints[:, 2], z, atol=0.01)
    a = renderer.render(cam, [(att, ATTENTIVE_LOOK)])
    b = renderer.render(cam, [(lifted, ATTENTIVE_LOOK)])
    assert np.mean(np.any(a != b, axis=2)) < 0.002


def test_renderer_closes() -> None:
    pytest.importorskip("pybullet")
    import pybullet

    from trustnav.sim.driving.render import PyBulletRenderer, StreetSpec

    r = PyBulletRenderer(StreetSpec(buildings=False, poles=False))
    cid = r.client
    r.close()
    r.close()
    assert not pybullet.isConnected(physicsClientId=cid)
    with pytest.raises(RuntimeError):
        r.render(CameraSpec(width=64, height=36).pose((33.5, 120.0), EGO_YAW), [])
    with pytest.raises(ValueError):
        StreetSpec(road_width=0.5)


def _covers(bbox, point) -> bool:
    x1, y1, x2, y2 = bbox
    return bool(x1 <= point[0] <= x2 and y1 <= point[1] <= y2)


@pytest.mark.slow
def test_case_one_frames_through_real_perception(renderer) -> None:
    pytest.importorskip("mediapipe")
    from trustnav.perception.looking import LookingModel
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker

    try:
        eye_model = LookingModel.from_file(download=False)
    except (FileNotFoundError, OSError) as exc:
        pytest.skip(f"LOOKING weights not available: {exc}")
    with MediaPipePoseBackend(video=True) as backend:
        perceive = PerceptionPipeline(backend, PersonTracker(fps=1), eye_model)
        eye = {"att": [], "dis": []}
        phone = {"att": [], "dis": []}
        for t, y in enumerate((117.5, 113.0)):  # ~15 m and ~10 m
            cam, att, dis = case_one(y, float(t))
            frame = renderer.render(cam, [(att, ATTENTIVE_LOOK), (dis, DISTRACTED_LOOK)])
            people = perceive(frame)
            for name, sk in (("att", att), ("dis", dis)):
                uv, _ = cam.project(sk.pelvis[None])
                hits = [p for p in people if _covers(p.person.bbox, uv[0])]
                assert len(hits) == 1, f"{name} not found once at y={y}"
                eye[name].append(hits[0].eye_contact)
                phone[name].append(hits[0].phone)
    assert np.mean(eye["att"]) > np.mean(eye["dis"]) + 0.15
    assert np.mean(phone["dis"]) > 0.6 > 0.2 > np.mean(phone["att"])
