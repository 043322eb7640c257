"""The car's camera and its two sensing modes, feeding the paper's trust estimator.

Both modes end in the same trait models and estimator: LOOKING eye contact (C_eye, `eye_score`),
the pose-geometry phone classifier (C_sm, `smato_score`), pose fluctuation (C_fluc, `pose_conf`)
and `lin_comb` / `agg_trust` in :class:`trustnav.trust.TrustEstimator`.

* ``render``: the frame is rendered (``render.PyBulletRenderer``) and ``trustnav.perception`` runs
  on it (detection, landmarks, tracking, traits). Perception tracks are associated with the world's
  pedestrians by overlap (IoU) with each pedestrian's projected box; the observation of a track
  updates the trust memory of the pedestrian it is associated with.
* ``keypoints``: the 3-D joints are projected; joints outside the image or behind the camera are
  culled; the detector's error model stands in for detection and landmarks: each joint moved up
  by BlazePose's median bias (:data:`DETECTOR_V_BIAS`), all joints of a person shifted together by
  a common vertical offset and each by its own noise, with a heavy tail (a share of joints placed
  badly), all as shares of the person's image height measured on rendered frames by
  ``benchmarks/calibrate_keypoints.py``; random dropout, and
  confidences that fall for the joints the body hides (the far eye and ear of a profile, the face
  of a bowed head, the far side of the body); everything after is the same.

A pedestrian not observed in a frame gets no trust update (its last trust stays); one never
observed has trust 0 (gamma = gamma_ini, the safe default).
"""

from __future__ import annotations

import inspect
import math
import time as _time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from trustnav.geometry.camera import NEAR, CameraPose
from trustnav.perception.confidence import HeadConfidenceParams
from trustnav.perception.looking import LookingModel, normalise_keypoints
from trustnav.perception.phone import PoseGeometryPhoneClassifier, TemporalPhoneModel, phone_label
from trustnav.perception.types import Person, box_iou
from trustnav.sim.driving.body import Appearance, Skeleton
from trustnav.sim.driving.world import RoadSpec, SensingSpec, street_of

__all__ = [
    "SENSING_MODES",
    "FrameReport",
    "KeypointSensor",
    "NearField",
    "NearScan",
    "PedestrianView",
    "RenderSensor",
    "SensedPerson",
    "make_render_pipeline",
    "make_render_sensing",
    "projected_box",
    "street_clutter",
]

SENSING_MODES = ("keypoints", "render")
Mode = Literal["keypoints", "render"]

# head-frame directions of the face keypoints' surface normals (nose, eyes, ears), as in
# perception/confidence.py
_FACE_PHI = np.radians([0.0, 35.0, -35.0, 90.0, -90.0])
_HEAD = HeadConfidenceParams()
#: BlazePose's median vertical error per COCO joint on rendered people (detected - true, share of
#: the person's projected height, negative = reported higher), 334 people 8-30 m away
#: (benchmarks/data/keypoint_calibration.json).
DETECTOR_V_BIAS = np.array(
    [-0.028, -0.022, -0.022, -0.012, -0.010, -0.006, -0.005, -0.016, -0.014,
     -0.012, -0.011, 0.000, -0.001, -0.016, -0.017, -0.041, -0.040]
)  # fmt: skip
_LEFT = np.array([5, 7, 9, 11, 13, 15])
_RIGHT = np.array([6, 8, 10, 12, 14, 16])


@dataclass(frozen=True)
class SensedPerson:
    """One person perceived in a frame. ``index``: the world pedestrian it is (a label for scoring
    and for the ``true``-state mode; None for a detection of no pedestrian); ``track_id``: the
    image tracker's ID (render) or the pedestrian's index (keypoints), replaced in the frame's
    report by the world track it joined (perceived state); ``trust``: that track's trust after the
    frame (None: not known, e.g. a person not placed on the ground)."""

    index: int | None
    track_id: int
    person: Person
    eye_contact: float
    phone: float
    trust: float | None = None

    @property
    def phone_label(self) -> str:
        """'N', 'U' or 'Y': the phone-use confidence as the annotated frames label it."""
        return phone_label(self.phone)


@dataclass
class PedestrianView:
    """Ground truth and what was perceived of one pedestrian in one frame."""

    index: int
    in_view: bool  # enough of the body inside the image to be detectable (ground truth)
    box: NDArray[np.float64] | None  # projected ground-truth box [x1, y1, x2, y2] (px), None if not in view
    observed: bool = False  # perceived and associated: its trust was updated by this frame
    track_id: int | None = None  # the world track it joined (perceived state) or its image track
    eye_contact: float | None = None
    phone: float | None = None
    trust: float | None = None  # after this frame; None: never observed yet
    position: NDArray[np.float64] | None = None  # true (x, y) at the frame (scoring)
    velocity: NDArray[np.float64] | None = None  # true (v_x, v_y)
    estimate: NDArray[np.float64] | None = None  # its track's (x, y, v_x, v_y) after this frame (perceived)
    estimate_cov: NDArray[np.float64] | None = None  # ... and its covariance (4, 4)


@dataclass
class FrameReport:
    """One captured frame: capture time, the pedestrians' views, unmatched detections, timing, image,
    and when its people reached the estimates (``known_at``)."""

    index: int
    time: float
    views: list[PedestrianView]
    false_positives: int = 0
    timing: dict[str, float] = field(default_factory=dict)
    camera: CameraPose | None = field(default=None, repr=False)
    sensed: list[SensedPerson] = field(default_factory=list, repr=False)
    image: NDArray[np.uint8] | None = field(default=None, repr=False)  # the rendered frame (RGB), render mode
    tracks: tuple[Any, ...] = field(default=(), repr=False)  # perceived: every live world track after the frame
    delivered: float | None = None  # when its people reached the estimates (perception latency); None: at ``time``

    @property
    def known_at(self) -> float:
        """The time from which the controller used this frame: capture time plus perception latency."""
        return self.time if self.delivered is None else self.delivered

    @property
    def detections(self) -> int:
        return sum(v.observed for v in self.views)

    @property
    def ground_truth(self) -> int:
        return sum(v.in_view for v in self.views)


@dataclass(frozen=True)
class NearScan:
    """One scan of a :class:`NearField` sensor (``field``) taken at ``time`` (s): the car's pose
    then (x, y, yaw), the returns' ground positions (M, 2) and covariances (M, 2, 2), and, for
    scoring only, the world pedestrian each return came from (M,)."""

    time: float
    ego: NDArray[np.float64]
    positions: NDArray[np.float64]
    covariances: NDArray[np.float64]
    indices: NDArray[np.int64]
    field: NearField

    def looked_at(self, point: NDArray[np.float64]) -> bool:
        """Whether the scan looked at ``point`` (2,): a person of half a metre's half width standing
        there wholly inside its field (where it returns nobody, nobody stands)."""
        return self.field.covers(self.ego, point, margin=0.5)


@dataclass(frozen=True)
class NearField:
    """A near-field sensor around the car's front (``SensingSpec.near_range``, ``near_deg``,
    ``near_sigma``, ``near_rate``): the ground within ``range`` m of the car's reference point and ``deg`` / 2
    either side of its heading, where a forward camera sees nobody's feet (nearer than its lower
    edge meets the ground) or nobody at all (beside its field of view): a bumper's short-range
    radars or ultrasonic array, which measure a position, not a pose. Each person whose ground
    position lies inside returns that position with Gaussian noise of ``sigma`` m per axis,
    ``rate`` scans a second while the car is no faster than ``max_speed`` m/s."""

    range: float
    deg: float = 180.0
    sigma: float = 0.15
    rate: float = 10.0
    max_speed: float = 3.0

    @classmethod
    def of(cls, spec: SensingSpec) -> NearField | None:
        """The scenario's near-field sensor, or None (``near_range`` 0: the camera alone)."""
        if spec.near_range <= 0:
            return None
        return cls(spec.near_range, spec.near_deg, spec.near_sigma, spec.near_rate, spec.near_max_speed)

    def covers(self, ego: NDArray[np.float64], point: NDArray[np.float64], margin: float = 0.0) -> bool:
        """Whether ``point`` (2,) lies inside the field of a car at ``ego`` (x, y, yaw), ``margin``
        m inside its edges (a person of that half width there wholly inside)."""
        rel = np.asarray(point, dtype=float)[:2] - np.asarray(ego, dtype=float)[:2]
        dist = float(np.hypot(*rel))
        if dist + margin > self.range:
            return False
        if self.deg >= 360.0 or dist < 1e-9:
            return True
        yaw = float(ego[2])
        bearing = abs(math.atan2(math.cos(yaw) * rel[1] - math.sin(yaw) * rel[0],
                                 math.cos(yaw) * rel[0] + math.sin(yaw) * rel[1]))  # fmt: skip
        return bearing + math.atan2(margin, dist) <= math.radians(0.5 * self.deg)

    def scan(
        self, time: float, ego: NDArray[np.float64], positions: NDArray[np.float64], rng: np.random.Generator
    ) -> NearScan:
        """The returns at ``time`` of the people at ``positions`` (N, 2: the world's) for a car at ``ego``."""
        pos = np.asarray(positions, dtype=float).reshape(-1, 2)
        idx = np.array([j for j, p in enumerate(pos) if self.covers(ego, p)], dtype=np.int64)
        noisy = pos[idx] + rng.normal(0.0, self.sigma, (len(idx), 2))
        cov = np.broadcast_to(self.sigma**2 * np.eye(2), (len(idx), 2, 2)).copy()
        return NearScan(float(time), np.asarray(ego, dtype=float)[:3].copy(), noisy, cov, idx, self)


def street_clutter(road: RoadSpec, per_10m: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Static objects on both sidewalks of ``road`` that a near-field sensor returns as it returns a
    person (``SensingSpec.near_clutter``: poles, bins, parked bicycles; the camera's detector finds no
    person in them): on each side a Poisson number, ``per_10m`` per 10 m of the road's length on
    average, uniform along it and across the sidewalk (at the kerb where it has no width); (K, 2)."""
    if not (math.isfinite(per_10m) and per_10m >= 0):
        raise ValueError(f"near_clutter must be a finite number >= 0 per 10 m of sidewalk, got {per_10m!r}")
    start, end = np.asarray(road.start, dtype=float), np.asarray(road.end, dtype=float)
    length = float(np.hypot(*(end - start)))
    along = (end - start) / length
    left = np.array([-along[1], along[0]])
    out = []
    for side in (1.0, -1.0):
        k = int(rng.poisson(per_10m * length / 10.0))
        s = rng.uniform(0.0, length, k)
        off = 0.5 * road.width + rng.uniform(0.0, road.sidewalk_width, k)
        out.append(start + s[:, None] * along + (side * off)[:, None] * left)
    return np.concatenate(out).reshape(-1, 2)


def projected_box(camera: CameraPose, skeleton: Skeleton, pad: float = 0.04) -> NDArray[np.float64] | None:
    """The box of a body's projected points (joints, head top, hands, feet, phone) clipped to the
    image and padded by ``pad`` of its height; None if no point is in front of the camera or the
    box misses the image."""
    uv, depth = camera.project(skeleton.points())
    ok = depth > NEAR
    if not ok.any():
        return None
    uv = uv[ok]
    x1, y1 = uv.min(axis=0)
    x2, y2 = uv.max(axis=0)
    p = pad * (y2 - y1)
    w, h = camera.spec.width, camera.spec.height
    box = np.array([max(0.0, x1 - p), max(0.0, y1 - p), min(w - 1.0, x2 + p), min(h - 1.0, y2 + p)])
    if box[2] <= box[0] or box[3] <= box[1]:
        return None
    return box


def _visible_joints(camera: CameraPose, skeleton: Skeleton) -> tuple[NDArray, NDArray]:
    uv, depth = camera.project(skeleton.joints)
    w, h = camera.spec.width, camera.spec.height
    with np.errstate(invalid="ignore"):
        inside = (depth > NEAR) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    return uv, inside


def in_view(camera: CameraPose, skeleton: Skeleton, spec: SensingSpec) -> bool:
    """Ground truth: enough joints inside the image and the body tall enough to be detected."""
    _, inside = _visible_joints(camera, skeleton)
    box = projected_box(camera, skeleton)
    return bool(inside.sum() >= spec.min_joints and box is not None and box[3] - box[1] >= spec.min_height_px)


def hidden_joint_confidences(
    camera: CameraPose, skeleton: Skeleton, head: HeadConfidenceParams = _HEAD
) -> NDArray[np.float64]:
    """(17,) confidences from how far each keypoint faces the camera (1 = fully shown).

    Face keypoints as perception/confidence.py does for BlazePose, with the head's 3-D rotation
    (so a bowed head hides its face too): c = clip(base + gain * cos(normal, to camera), floor, 1).
    Body keypoints: the far side of a body seen in profile or from behind is partly hidden,
    c = clip(0.8 + 0.2 * cos(side normal, to camera), 0.3, 1).
    """
    conf = np.ones(17)
    cam = camera.position
    if skeleton.head_rot is not None and skeleton.head_centre is not None:
        to_cam = cam - skeleton.head_centre
        to_cam /= np.linalg.norm(to_cam)
        r = skeleton.head_rot
        normals = np.cos(_FACE_PHI)[:, None] * r[:, 0] + np.sin(_FACE_PHI)[:, None] * r[:, 1]
        facing = normals @ to_cam
        base = np.array([head.face_base] * 3 + [head.ear_base] * 2)
        gain = np.array([head.face_gain] * 3 + [head.ear_gain] * 2)
        conf[:5] = np.clip(base + gain * facing, head.floor, 1.0)
    if skeleton.body_rot is not None and skeleton.pelvis is not None:
        to_cam = cam - skeleton.pelvis
        to_cam /= np.linalg.norm(to_cam)
        side = float(skeleton.body_rot[:, 1] @ to_cam)  # > 0: the left side faces the camera
        conf[_LEFT] = np.clip(0.8 + 0.2 * side, 0.3, 1.0)
        conf[_RIGHT] = np.clip(0.8 - 0.2 * side, 0.3, 1.0)
    return conf


def looking_model() -> LookingModel:
    """The LOOKING eye-contact weights found locally (../shared/models, $TRUSTNAV_LOOKING_WEIGHTS or the
    user cache); never downloaded during a drive."""
    try:
        return LookingModel.from_file(download=False)
    except FileNotFoundError as exc:
        raise ValueError(f"{exc} (`trustnav estimate` fetches them once; or set TRUSTNAV_LOOKING_WEIGHTS)") from exc


class KeypointSensor:
    """Keypoint sensing: projected joints with noise, dropout and hidden-joint confidences, then the
    same trait models as the perception pipeline (LOOKING, phone classifier). Track IDs are the
    pedestrians' indices (detection, landmarks and tracking are what this mode skips)."""

    mode: Mode = "keypoints"

    def __init__(
        self,
        spec: SensingSpec,
        rng: np.random.Generator,
        eye_model: LookingModel | None = None,
        phone: PoseGeometryPhoneClassifier | None = None,
    ) -> None:
        self.spec = spec
        self.rng = rng
        self.eye_model = eye_model or looking_model()
        self.phone = phone or PoseGeometryPhoneClassifier()
        # phone use from the posture over time, per pedestrian (the stand-in for image tracking)
        self.temporal_phone = TemporalPhoneModel(self.phone)

    def person(self, camera: CameraPose, skeleton: Skeleton) -> Person | None:
        """The synthetic detection of one body, or None when it is not detectable or missed."""
        s = self.spec
        if not in_view(camera, skeleton, s):
            return None
        if s.miss_rate > 0 and self.rng.random() < s.miss_rate:
            return None
        box = projected_box(camera, skeleton)
        assert box is not None
        uv, inside = _visible_joints(camera, skeleton)
        size = box[3] - box[1]
        sigma = s.pixel_noise * size
        # the detector's errors are shares of the person's projected stature (head top to sole)
        depth = float(camera.to_camera(skeleton.pelvis[None])[0, 2]) if skeleton.pelvis is not None else 0.0
        stature_px = camera.focal_px * skeleton.height / depth if depth > NEAR else size
        noise = self.rng.normal(0.0, 1.0, size=(17, 2)) * sigma
        if s.detector_bias:  # the detector's error model (see the module)
            noise[:, 1] += (DETECTOR_V_BIAS + self.rng.normal(0.0, s.common_noise)) * stature_px
            wild = self.rng.random((17, 2)) < s.outlier_rate  # the heavy tail: a joint placed badly
            noise += wild * self.rng.normal(0.0, s.outlier_noise, size=(17, 2)) * stature_px
        drop = self.rng.random(17) < s.dropout
        jitter = self.rng.uniform(0.9, 1.0, size=17)
        w, h = camera.spec.width, camera.spec.height
        kp = np.where(np.isfinite(uv), uv, 0.0) + noise
        kp[:, 0] = np.clip(kp[:, 0], 0.0, w - 1.0)
        kp[:, 1] = np.clip(kp[:, 1], 0.0, h - 1.0)
        conf = hidden_joint_confidences(camera, skeleton) * jitter
        conf[drop] = 0.05
        conf[~inside] = 0.0
        return Person(bbox=box, keypoints=kp, confidences=np.clip(conf, 0.0, 1.0), score=0.9)

    def sense(
        self, camera: CameraPose, bodies: Sequence[tuple[Skeleton, Appearance]], time: float | None = None
    ) -> tuple[list[SensedPerson], NDArray[np.uint8] | None, int, dict[str, float]]:
        """The frame captured at ``time`` (s; None: phone use from this frame's geometry only)."""
        t0 = _time.perf_counter()
        found = []
        for j, (sk, _) in enumerate(bodies):
            p = self.person(camera, sk)
            if p is not None:
                found.append((j, p))
        out = []
        if found:
            w = camera.spec.width
            inputs = np.stack([normalise_keypoints(p.keypoints, p.confidences, w) for _, p in found])
            eye = self.eye_model.predict(inputs)
            for (j, p), e in zip(found, eye, strict=True):
                phone = self.temporal_phone.add_pose(j, time, p.keypoints, p.confidences).phone
                out.append(SensedPerson(j, j, p, float(e), float(phone)))
        return out, None, 0, {"keypoints": _time.perf_counter() - t0}


class RenderSensor:
    """Render sensing: renderer -> perception pipeline -> association with the world by box overlap."""

    mode: Mode = "render"

    def __init__(self, renderer: Any, pipeline: Any, min_iou: float = 0.2) -> None:
        self.renderer = renderer
        self.pipeline = pipeline
        self.min_iou = min_iou
        # a pipeline that takes the frame's time follows temporal cues (phone use over time)
        try:
            self._timed = "time" in inspect.signature(pipeline).parameters
        except (TypeError, ValueError):
            self._timed = False

    def sense(
        self, camera: CameraPose, bodies: Sequence[tuple[Skeleton, Appearance]], time: float | None = None
    ) -> tuple[list[SensedPerson], NDArray[np.uint8] | None, int, dict[str, float]]:
        """Render the frame captured at ``time`` (s) and perceive it."""
        from scipy.optimize import linear_sum_assignment

        t0 = _time.perf_counter()
        frame = self.renderer.render(camera, list(bodies))
        t1 = _time.perf_counter()
        backend = getattr(self.pipeline, "backend", None)
        if hasattr(backend, "camera"):  # the car knows its camera: the geometry gate places feet with it
            backend.camera = camera
        people = self.pipeline(frame, time=time) if self._timed and time is not None else self.pipeline(frame)
        # a person the real-time backend carried by its velocity was not measured on this frame: the
        # world tracker predicts it itself, and trust gets no evidence from it
        people = [tp for tp in people if not tp.person.extra.get("predicted")]
        t2 = _time.perf_counter()
        # the true projected boxes label each detection for scoring (and for the "true"-state mode);
        # in the perceived-state mode nothing downstream uses the label
        boxes = [projected_box(camera, sk) for sk, _ in bodies]
        label: list[int | None] = [None] * len(people)
        if people:
            iou = np.array([[0.0 if b is None else box_iou(tp.person.bbox, b) for b in boxes] for tp in people])
            rows, cols = linear_sum_assignment(-iou)
            for r, c in zip(rows, cols, strict=True):
                if iou[r, c] >= self.min_iou:
                    label[r] = int(c)
        out = [
            SensedPerson(j, tp.track_id, tp.person, tp.eye_contact, tp.phone)
            for j, tp in zip(label, people, strict=True)
        ]
        timing = {"render": t1 - t0, "perception": t2 - t1}
        return out, frame, sum(j is None for j in label), timing


def make_render_sensing(
    scenario: Any, capture_rate: float | None = None, realtime: bool = False, search_seconds: float | None = None
) -> tuple[Any, Any]:
    """(renderer, perception pipeline) for render sensing: PyBullet's CPU renderer of the scenario's
    street and :func:`make_render_pipeline`. Close the renderer and the backend when done."""
    from trustnav.sim.driving.render import PyBulletRenderer

    pipeline = make_render_pipeline(scenario, capture_rate, realtime, search_seconds=search_seconds)
    return PyBulletRenderer(street_of(scenario)), pipeline


def make_render_pipeline(
    scenario: Any, capture_rate: float | None = None, realtime: bool = False, search_seconds: float | None = None
) -> Any:
    """trustnav.perception for a drive's camera frames (trustnav's renders or CARLA's images):
    the person detector (YOLOX-Nano) with BlazePose's landmarks on its boxes (issue 35; the
    localisation is calibrated on these fits, docs/perceived.md), OC-SORT tracking at the capture
    rate, LOOKING, the phone classifier.
    BlazePose's video mode (following people from their landmarks between detections) only from
    5 frames/s: at 1 frame/s a car moves metres between frames and the follower left a stray box
    where a person had been. ``realtime``: the pose backend is
    :class:`~trustnav.perception.realtime.RealtimePoseBackend` (issue 35: the person detector on every
    frame, landmarks refitted a few times a second and carried between; deterministic), with
    ``search_seconds`` detecting only on one frame in ceil(search_seconds x rate)
    (``RealtimeConfig.search_frames``). Close the backend when done."""
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker

    fps = float(capture_rate or scenario.camera.rate)
    if search_seconds is not None and not realtime:
        raise ValueError("search_seconds models the real-time backend's search: it needs realtime=True")
    if realtime:
        from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend, modelled_search_frames

        k = None if search_seconds is None else modelled_search_frames(fps, search_seconds)
        # the drive's camera (1 frame/s by default, every frame processed in step) has the budget to fit
        # people down to 40 px (Case I's distracted pedestrian is first seen at 28 m, under 60 px) and to
        # refit them every 3rd frame; a 15 frames/s stream's defaults are 60 px and every 4th frame
        cfg = RealtimeConfig(search_frames=k, min_height_px=40.0, landmark_every=3)
        backend: Any = RealtimePoseBackend(realtime=cfg)
    else:
        backend = MediaPipePoseBackend(video=fps >= 5.0)
    return PerceptionPipeline(backend, PersonTracker(fps=fps), looking_model())
