"""Eye contact from the face: head pose and gaze relative to the camera ray, fused with LOOKING.

For each person tall enough for a face to be resolved (``FaceConfig.min_person_px``), the head
region is cut from the pose keypoints (nose, eyes, ears; shoulders as a fallback), scaled up, and
MediaPipe's bundled models run on it (``mediapipe==0.10.14``, no download): the short-range face
detector (``FaceDetectionShortRangeCpu``) and the face mesh with attention (``FaceLandmarkCpu``,
478 landmarks with the irises). From the landmarks:

- **Head pose relative to the camera ray** (:func:`head_pose`). Image offsets around the head are
  mapped onto the plane perpendicular to the ray through the head, ``d = K^-1 (u, v, 1)``, so a
  person at the image edge who faces the camera reads yaw 0 (in image axes they look turned by the
  ray's angle). Face axes: eye line (outer corners 33 -> 263) and forehead -> chin (10 -> 152);
  n = x_face x y_face points into the head; yaw = atan2(-n_e1, n_d) (> 0: turned toward image
  right), pitch = atan2(n_e2, hypot(n_e1, n_d)) (> 0: tilted up) in the ray frame (e1 horizontal,
  e2 down, d the ray).
- **Gaze from the irises** (:func:`iris_offset`), where the eyes are at least ``min_eye_px`` wide:
  the iris centre's offset from the middle of the eye corners as a fraction of half the eye width,
  r in [-1, 1], adds ``iris_gain_deg * r`` to the yaw (eye-in-head rotation: a head turned away
  with the eyes turned back reads looking). The irises are read on a second fit of the mesh on
  the face alone, cut from the frame's own pixels and upscaled (``eye_crop_px``), not on the head
  crop's mesh (resampled twice, its irises follow the head at a few pixels per eye).
- **Eye-contact probability** p_face = 1 / (1 + exp((rho - 1) / s)) with
  rho = sqrt((yaw / max_yaw)^2 + ((pitch - pitch_offset) / max_pitch)^2): 0.5 at the edge of the
  "looking" cone (turn 25 deg, tilt 20 deg), near 1 facing the camera.
- **Face confidence** c_face = score * size * sharpness * complete: detector score; size ramps
  linearly from 0 at ``face_px_min`` to 1 at ``face_px_full`` (face box height in frame pixels);
  sharpness = v / (v + blur_ref) with v the variance of the Laplacian on the face crop; complete =
  fraction of the mesh inside the frame; with ``shift_fits`` > 1 a face under ``shift_below_px`` is
  fitted on crops moved by 1 px and its c_face also x the fits' agreement. A large person (expected
  face, height / 8, more than half way up the size ramp) with visible head keypoints on whom no face
  is found reads p_face = 0 with c_face = ``no_face_confidence`` * size (seen from the back or turned
  away).

**Fusion** (:func:`fuse_eye_contact`): C_eye = (1 - a) p_looking + a p_face, a = max_face_weight *
c_face. It is monotone in both probabilities, equals LOOKING where the face is not resolved (small
or far people: c_face = 0), and lets the face carry at most ``max_face_weight`` of the value.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.perception.types import Person

__all__ = [
    "FACE_FIELDS",
    "OFFLINE_SHIFT_FITS",
    "FaceConfig",
    "FaceEyeContact",
    "FaceResult",
    "eye_contact_probability",
    "fuse_eye_contact",
    "head_pose",
    "iris_offset",
    "ray_frame",
]

#: fits of a face under ``FaceConfig.shift_below_px`` in offline perception (``trustnav estimate``
#: without ``--realtime``): 5 fits, ~42 ms per small face instead of ~7 ms
OFFLINE_SHIFT_FITS = 5

#: record fields the face cue adds (``trustnav estimate --face``)
FACE_FIELDS = ("eye_contact_face", "face_confidence")

# face-mesh landmark indices (MediaPipe's 468-point topology, 478 with irises)
FOREHEAD, CHIN, NOSE_TIP = 10, 152, 1
RIGHT_EYE_OUTER, RIGHT_EYE_INNER, LEFT_EYE_INNER, LEFT_EYE_OUTER = 33, 133, 362, 263
RIGHT_IRIS, LEFT_IRIS = 468, 473

_DETECTOR_GRAPH = """
input_stream: "IMAGE:image"
output_stream: "DETECTIONS:detections"
node { calculator: "FaceDetectionShortRangeCpu" input_stream: "IMAGE:image" output_stream: "DETECTIONS:detections" }
"""

_MESH_GRAPH = """
input_stream: "IMAGE:image"
input_stream: "ROI:roi"
output_stream: "LANDMARKS:landmarks"
node {
  calculator: "ConstantSidePacketCalculator"
  output_side_packet: "PACKET:with_attention"
  options { [mediapipe.ConstantSidePacketCalculatorOptions.ext] { packet { bool_value: true } } }
}
node {
  calculator: "FaceLandmarkCpu"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  input_side_packet: "WITH_ATTENTION:with_attention"
  output_stream: "LANDMARKS:landmarks"
}
"""


@dataclass(frozen=True)
class FaceConfig:
    """Thresholds of the face cue (angles in degrees, sizes in frame pixels).

    min_person_px: people shorter than this (box height) are left to LOOKING alone.
    crop_px: the head crop is scaled to this side before the detector sees it.
    fov_deg: horizontal field of view for the camera ray (focal = W / 2 / tan(fov / 2)).
    max_yaw_deg, max_pitch_deg, softness, pitch_offset_deg: the "looking" cone of p_face.
    face_px_min, face_px_full: face box heights where the size confidence is 0 and 1.
    blur_ref: Laplacian variance at which the sharpness confidence is 0.5.
    min_eye_px, iris_gain_deg: gaze from the irises only on eyes this wide (frame px); degrees per
    unit offset.
    eye_crop_px: side of the face-only crop (cut from the frame around the detected face, 1.6 x its
    box, bicubic) on which the mesh is fitted again to read the irises, for faces whose eyes may be
    ``min_eye_px`` wide (face box >= 5 x ``min_eye_px``; smaller faces get no iris reading); 0: read
    them on the head crop's mesh (with ``min_eye_px`` = 10, the behaviour before issue 35's gaze
    pass). ~4 ms per such face.
    no_face_confidence: confidence of "no face found" on a large person (p_face = 0).
    max_face_weight: the largest share of C_eye the face may carry.
    shift_fits, shift_below_px: a face smaller than ``shift_below_px`` is fitted ``shift_fits`` times
    (1 = once, the default; offline ``trustnav estimate`` uses :data:`OFFLINE_SHIFT_FITS`), on its
    crop moved by 1 px each way, and read as their mean, its confidence shrunk by their disagreement
    (:meth:`FaceEyeContact._combine`). Each extra fit costs ~7 ms per small face.
    """

    min_person_px: float = 100.0
    crop_px: int = 192
    min_detection: float = 0.5
    fov_deg: float = 70.0
    max_yaw_deg: float = 25.0
    max_pitch_deg: float = 20.0
    softness: float = 0.2
    pitch_offset_deg: float = 0.0
    face_px_min: float = 8.0
    face_px_full: float = 20.0
    blur_ref: float = 20.0
    min_eye_px: float = 4.5
    iris_gain_deg: float = 40.0
    eye_crop_px: int = 256
    no_face_confidence: float = 0.4
    max_face_weight: float = 0.9
    shift_fits: int = 1
    shift_below_px: float = 20.0

    def __post_init__(self) -> None:
        if not self.min_person_px >= 0:
            raise ValueError(f"min_person_px must be >= 0, got {self.min_person_px!r}")
        if self.crop_px < 64:
            raise ValueError(f"crop_px must be >= 64, got {self.crop_px!r}")
        if not 0.0 <= self.min_detection <= 1.0:
            raise ValueError(f"min_detection must be in [0, 1], got {self.min_detection!r}")
        if not 1.0 <= self.fov_deg <= 170.0:
            raise ValueError(f"fov_deg must be in [1, 170], got {self.fov_deg!r}")
        if self.max_yaw_deg <= 0 or self.max_pitch_deg <= 0 or self.softness <= 0:
            raise ValueError("max_yaw_deg, max_pitch_deg and softness must be > 0")
        if not 0 <= self.face_px_min < self.face_px_full:
            raise ValueError("need 0 <= face_px_min < face_px_full")
        if self.blur_ref < 0 or self.min_eye_px < 0 or self.iris_gain_deg < 0:
            raise ValueError("blur_ref, min_eye_px and iris_gain_deg must be >= 0")
        if self.eye_crop_px != 0 and self.eye_crop_px < 64:
            raise ValueError(f"eye_crop_px must be 0 (off) or >= 64, got {self.eye_crop_px!r}")
        if not 0.0 <= self.no_face_confidence <= 1.0 or not 0.0 <= self.max_face_weight <= 1.0:
            raise ValueError("no_face_confidence and max_face_weight must be in [0, 1]")
        if not 1 <= self.shift_fits <= len(_SHIFTS) + 1:
            raise ValueError(f"shift_fits must be in [1, {len(_SHIFTS) + 1}], got {self.shift_fits!r}")
        if not self.shift_below_px >= 0:
            raise ValueError(f"shift_below_px must be >= 0, got {self.shift_below_px!r}")


@dataclass(frozen=True)
class FaceResult:
    """The face cue on one person: p_face (NaN: not judged), c_face, angles (degrees, NaN if none)."""

    probability: float = math.nan
    confidence: float = 0.0
    yaw: float = math.nan
    pitch: float = math.nan
    gaze_yaw: float = math.nan
    face_px: float = 0.0
    seconds: float = 0.0
    sharpness: float = math.nan  # variance of the Laplacian of the face box (frame pixels, grey 0-255)
    agreement: float = 1.0  # of the shifted fits of a small face: 1 - 2 sd(p_face); 1 for one fit


# --- geometry -------------------------------------------------------------------------------


def ray_frame(u: float, v: float, focal: float, cx: float, cy: float) -> NDArray[np.float64]:
    """Orthonormal frame (rows e1, e2, d) of the camera ray through pixel (u, v): d along the ray,
    e1 horizontal (image x for a ray on the axis), e2 = d x e1 (image y, down)."""
    d = np.array([(u - cx) / focal, (v - cy) / focal, 1.0])
    d /= np.linalg.norm(d)
    e1 = np.cross([0.0, 1.0, 0.0], d)  # horizontal, perpendicular to the ray
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    return np.vstack([e1, e2, d])


def head_pose(
    landmarks: ArrayLike, focal: float, cx: float, cy: float, centre: ArrayLike | None = None
) -> tuple[float, float]:
    """(yaw, pitch) in degrees of a face relative to the camera ray through it; 0, 0 = facing the camera.

    ``landmarks``: (N >= 468, 3) face mesh in frame pixels (x, y) and depth z in the same pixel units,
    growing away from the camera (MediaPipe's convention); ``focal``, ``cx``, ``cy``: the camera's
    focal length and principal point (pixels). A small object at ray d = K^-1 (u, v, 1) / |.| is seen
    as its parallel projection along d onto the image plane: the view along the ray, stretched by
    1 / cos(angle off the axis). Each landmark's image offset delta from the head centre (default:
    the landmarks' mean) is therefore put back on the plane across the ray, (delta . e1, delta . e2),
    with z along d (:func:`ray_frame`). Face axes: x = eye line (outer corners), y = forehead -> chin
    made orthogonal to x; n = x cross y points into the head. yaw = atan2(-n_e1, n_d) > 0: the face
    turns toward image right; pitch = atan2(n_e2, hypot(n_e1, n_d)) > 0: the face tilts up.
    """
    lm = np.asarray(landmarks, dtype=float)
    if lm.ndim != 2 or lm.shape[1] != 3 or lm.shape[0] < 468:
        raise ValueError(f"landmarks must be (N >= 468, 3), got {lm.shape}")
    c = lm[:, :2].mean(axis=0) if centre is None else np.asarray(centre, dtype=float)
    frame = ray_frame(float(c[0]), float(c[1]), focal, cx, cy)
    offsets = np.column_stack([lm[:, 0] - c[0], lm[:, 1] - c[1], np.zeros(len(lm))])
    pts = np.column_stack([offsets @ frame[0], offsets @ frame[1], lm[:, 2]])
    x = pts[LEFT_EYE_OUTER] - pts[RIGHT_EYE_OUTER]
    y = pts[CHIN] - pts[FOREHEAD]
    x /= np.linalg.norm(x)
    y -= (y @ x) * x
    y /= np.linalg.norm(y)
    n = np.cross(x, y)  # into the head: +d for a face looking at the camera
    yaw = math.degrees(math.atan2(-n[0], n[2]))
    pitch = math.degrees(math.atan2(n[1], math.hypot(n[0], n[2])))
    return yaw, pitch


def iris_offset(landmarks: ArrayLike) -> tuple[float, float]:
    """(mean horizontal iris offset r in [-1, 1], eye width in pixels): the iris centre's offset from
    the middle of its eye corners along the eye line, over half the eye width, averaged over both
    eyes; r > 0 toward image right. NaN without the 478 iris landmarks."""
    lm = np.asarray(landmarks, dtype=float)
    if lm.shape[0] < 478:
        return math.nan, 0.0
    rs, widths = [], []
    for outer, inner, iris in (
        (RIGHT_EYE_OUTER, RIGHT_EYE_INNER, RIGHT_IRIS),
        (LEFT_EYE_INNER, LEFT_EYE_OUTER, LEFT_IRIS),
    ):
        a, b = lm[outer, :2], lm[inner, :2]
        axis = b - a
        w = float(np.linalg.norm(axis))
        if w <= 0:
            continue
        mid = (a + b) / 2
        rs.append(float((lm[iris, :2] - mid) @ axis / w / (w / 2)))
        widths.append(w)
    if not rs:
        return math.nan, 0.0
    return float(np.clip(np.mean(rs), -1.0, 1.0)), float(np.mean(widths))


def eye_contact_probability(yaw: float, pitch: float, config: FaceConfig | None = None) -> float:
    """p_face = 1 / (1 + exp((rho - 1) / softness)), rho = sqrt((yaw / max_yaw)^2 + ((pitch -
    pitch_offset) / max_pitch)^2): 0.5 on the edge of the looking cone."""
    cfg = config or FaceConfig()
    rho = math.hypot(yaw / cfg.max_yaw_deg, (pitch - cfg.pitch_offset_deg) / cfg.max_pitch_deg)
    z = (rho - 1.0) / cfg.softness
    return 1.0 / (1.0 + math.exp(min(z, 60.0)))


def fuse_eye_contact(p_looking: float, p_face: float, c_face: float, max_face_weight: float = 0.9) -> float:
    """C_eye = (1 - a) p_looking + a p_face with a = max_face_weight * c_face (c_face in [0, 1]).

    Monotone non-decreasing in p_looking and p_face; LOOKING alone when the face is not resolved
    (c_face = 0 or p_face NaN); LOOKING NaN: the face alone where it was judged."""
    if math.isnan(p_face) or c_face <= 0:
        return p_looking
    if math.isnan(p_looking):
        return p_face
    a = max_face_weight * min(max(c_face, 0.0), 1.0)
    return (1.0 - a) * p_looking + a * p_face


# --- images ---------------------------------------------------------------------------------

_HEAD = (0, 1, 2, 3, 4)  # nose, eyes, ears (COCO)
#: whole-pixel moves of the head crop for the extra fits of a small face (``FaceConfig.shift_fits``)
_SHIFTS = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))


def head_box(person: Person, min_conf: float = 0.3) -> tuple[float, float, float] | None:
    """(cx, cy, side) of a square around the head, from the head keypoints (shoulders as a fallback)."""
    kp, conf, box = person.keypoints, person.confidences, person.bbox
    height = float(box[3] - box[1])
    ok = [i for i in _HEAD if conf[i] >= min_conf and np.all(np.isfinite(kp[i]))]
    side = max(0.28 * height, 1.0)
    if len(ok) >= 2:
        pts = kp[ok]
        cx, cy = float(pts[:, 0].mean()), float(pts[:, 1].mean())
        side = max(side, 2.6 * float(np.ptp(pts[:, 0])))
        return cx, cy, side
    shoulders = [i for i in (5, 6) if conf[i] >= min_conf and np.all(np.isfinite(kp[i]))]
    if shoulders:
        s = kp[shoulders]
        return float(s[:, 0].mean()), float(s[:, 1].mean()) - 0.12 * height, side
    return None


def _sharpness(gray: NDArray[np.float64]) -> float:
    """Variance of the 4-neighbour Laplacian."""
    if gray.shape[0] < 3 or gray.shape[1] < 3:
        return 0.0
    lap = gray[1:-1, :-2] + gray[1:-1, 2:] + gray[:-2, 1:-1] + gray[2:, 1:-1] - 4.0 * gray[1:-1, 1:-1]
    return float(lap.var())


def _crop(
    frame: NDArray[np.uint8], cx: float, cy: float, side: float, out: int
) -> tuple[NDArray[np.uint8], float, int, int]:
    """Square crop of ``side`` pixels around (cx, cy) (zero-padded), resized to ``out``; its scale
    (crop pixels per frame pixel) and top-left corner in the frame."""
    from PIL import Image

    h, w = frame.shape[:2]
    s = max(round(side), 2)
    x0, y0 = round(cx - s / 2), round(cy - s / 2)
    canvas = np.zeros((s, s, 3), dtype=np.uint8)
    sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x0 + s, w), min(y0 + s, h)
    if sx1 > sx0 and sy1 > sy0:
        canvas[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = frame[sy0:sy1, sx0:sx1]
    img = Image.fromarray(canvas).resize((out, out), Image.BILINEAR)
    return np.ascontiguousarray(np.asarray(img)), out / s, x0, y0


@dataclass
class _FaceGraphs:
    detector: Any
    mesh: Any
    rect: Any


def nearest_face(detections: Sequence[Any]) -> Any:
    """The face detection nearest the head crop's centre: the person's own, not a neighbour's."""

    def dist(dt: Any) -> float:
        b = dt.location_data.relative_bounding_box
        return math.hypot(b.xmin + b.width / 2 - 0.5, b.ymin + b.height / 2 - 0.5)

    return min(detections, key=dist)


class FaceEyeContact:
    """Face detection + face mesh on each near person's head -> :class:`FaceResult` per person.

    Results are cached for the latest frame, so several cues may read one analysis
    (:class:`~trustnav.perception.cues.FaceEyeContactCue` and its companion fields).
    """

    def __init__(self, config: FaceConfig | None = None) -> None:
        self.config = config or FaceConfig()
        self._graphs: _FaceGraphs | None = None
        self._cache_key: tuple | None = None
        self._cache: list[FaceResult] = []

    def _load(self) -> _FaceGraphs:
        if self._graphs is None:
            from trustnav.perception.frames import quiet_stderr
            from trustnav.perception.mediapipe_backend import (
                load_mediapipe,
                protobuf_warning_ignored,
                quiet_environment,
            )

            load_mediapipe()
            from google.protobuf import text_format
            from mediapipe.framework import calculator_pb2
            from mediapipe.framework.formats import rect_pb2
            from mediapipe.python import solution_base

            def graph(text: str) -> Any:
                return solution_base.SolutionBase(
                    graph_config=text_format.Parse(text, calculator_pb2.CalculatorGraphConfig())
                )

            with quiet_stderr(), quiet_environment(), protobuf_warning_ignored():
                g = _FaceGraphs(graph(_DETECTOR_GRAPH), graph(_MESH_GRAPH), rect_pb2.NormalizedRect)
                blank = np.zeros((64, 64, 3), dtype=np.uint8)
                g.detector.process({"image": blank})
                g.mesh.process({"image": blank, "roi": g.rect(x_center=0.5, y_center=0.5, width=1, height=1)})
            self._graphs = g
        return self._graphs

    def close(self) -> None:
        if self._graphs is not None:
            self._graphs.detector.close()
            self._graphs.mesh.close()
            self._graphs = None

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> list[FaceResult]:
        """One :class:`FaceResult` per person; the same frame and people again read the cache."""
        ref = self._cache_key  # holds the frame and people themselves: no id is reused meanwhile
        if ref is not None and ref[0] is frame and len(ref[1]) == len(people):
            if all(a is b for a, b in zip(ref[1], people, strict=True)):
                return list(self._cache)
        out = [self.analyse(frame, p) for p in people]
        self._cache_key, self._cache = (frame, tuple(people)), out
        return list(out)

    def analyse(self, frame: NDArray[np.uint8], person: Person) -> FaceResult:
        """The face cue on one person of ``frame`` (NaN probability if too small or no head).

        A face smaller than ``FaceConfig.shift_below_px`` is fitted ``shift_fits`` times, on the head
        crop moved by whole frame pixels (test-time augmentation; :meth:`_combine`): at 10-15 px the
        face mesh's angles change with a 1-pixel shift of its crop."""
        import time

        cfg = self.config
        height = float(person.bbox[3] - person.bbox[1])
        if height < cfg.min_person_px:
            return FaceResult()
        head = head_box(person)
        if head is None:
            return FaceResult()
        t0 = time.perf_counter()
        cx, cy, side = head
        # size of a face on this person, expected from the body: about 1/8 of the height
        size = float(np.clip((height / 8 - cfg.face_px_min) / (cfg.face_px_full - cfg.face_px_min), 0.0, 1.0))
        first = self._fit(frame, cx, cy, side)
        if first is None:  # no face detected
            seconds = time.perf_counter() - t0
            if size > 0.5:
                return FaceResult(0.0, cfg.no_face_confidence * size, seconds=seconds)
            return FaceResult(seconds=seconds)
        if first.face_px >= cfg.shift_below_px or cfg.shift_fits <= 1:
            return dataclasses.replace(first, seconds=time.perf_counter() - t0)
        fits = [first]
        for dx, dy in _SHIFTS[: cfg.shift_fits - 1]:
            fits.append(self._fit(frame, cx + dx, cy + dy, side))
        return dataclasses.replace(self._combine(fits), seconds=time.perf_counter() - t0)

    def _eye_fit(
        self, frame: NDArray[np.uint8], box: tuple[float, float, float, float], rotation: float
    ) -> NDArray[np.float64] | None:
        """The face mesh fitted again on the face alone: a square of 1.6 x the face box (x, y, w, h in
        frame pixels) cut from ``frame`` and upscaled to ``eye_crop_px`` (bicubic), the mesh's region
        1.5 x the box as MediaPipe places it; landmarks in frame pixels, None without a mesh."""
        import cv2

        from trustnav.perception.mediapipe_backend import protobuf_warning_ignored

        side = self.config.eye_crop_px
        s = max(round(1.6 * max(box[2], box[3])), 4)
        ax, ay = round(box[0] + box[2] / 2 - s / 2), round(box[1] + box[3] / 2 - s / 2)
        h, w = frame.shape[:2]
        sx0, sy0, sx1, sy1 = max(ax, 0), max(ay, 0), min(ax + s, w), min(ay + s, h)
        if sx1 <= sx0 or sy1 <= sy0:
            return None
        canvas = np.zeros((s, s, 3), dtype=np.uint8)
        canvas[sy0 - ay : sy1 - ay, sx0 - ax : sx1 - ax] = frame[sy0:sy1, sx0:sx1]
        big = np.ascontiguousarray(cv2.resize(canvas, (side, side), interpolation=cv2.INTER_CUBIC))
        g = self._load()
        rect = g.rect(x_center=0.5, y_center=0.5, width=1.5 / 1.6, height=1.5 / 1.6, rotation=rotation)
        with protobuf_warning_ignored():
            mesh = g.mesh.process({"image": big, "roi": rect}).landmarks
        if mesh is None:
            return None
        k = s / side
        return np.array([(p.x * side * k + ax, p.y * side * k + ay, p.z * side * k) for p in mesh.landmark])

    @staticmethod
    def _combine(fits: Sequence[FaceResult | None]) -> FaceResult:
        """One reading from fits of the same face on shifted crops (the first is the unshifted one):
        p_face = the mean over the fits that gave a mesh, the angles their medians, and c_face = the
        mean confidence x the share of fits that gave a mesh x the fits' agreement 1 - 2 sd(p_face)
        (0 when half the fits read "looking" and half "away"): a verdict that flips with the crop's
        placement carries little weight in C_eye (:func:`fuse_eye_contact`)."""
        good = [f for f in fits if f is not None and not math.isnan(f.probability)]
        if not good:
            f0 = fits[0]
            return FaceResult(face_px=f0.face_px if f0 is not None else 0.0)
        p = np.array([f.probability for f in good])
        agree = float(np.clip(1.0 - 2.0 * p.std(), 0.0, 1.0))
        conf = float(np.mean([f.confidence for f in good])) * len(good) / len(fits) * agree

        def med(name: str) -> float:
            return float(np.median([getattr(f, name) for f in good]))

        return FaceResult(
            float(p.mean()),
            conf,
            med("yaw"),
            med("pitch"),
            med("gaze_yaw"),
            med("face_px"),
            0.0,
            med("sharpness"),
            agree * len(good) / len(fits),
        )

    def _fit(self, frame: NDArray[np.uint8], cx: float, cy: float, side: float) -> FaceResult | None:
        """Face detector and mesh on the head crop of ``side`` px around (cx, cy): p_face, c_face and
        the angles (:func:`head_pose`, :func:`iris_offset`); None if no face is detected; NaN
        probability if the mesh gives no landmarks."""
        from trustnav.perception.mediapipe_backend import protobuf_warning_ignored

        cfg = self.config
        g = self._load()
        h, w = frame.shape[:2]
        focal = w / 2 / math.tan(math.radians(cfg.fov_deg) / 2)
        crop, scale, x0, y0 = _crop(frame, cx, cy, side, cfg.crop_px)
        with protobuf_warning_ignored():
            dets = g.detector.process({"image": crop}).detections or []
            dets = [dt for dt in dets if dt.score[0] >= cfg.min_detection]
            if not dets:
                return None
            det = nearest_face(dets)
            b = det.location_data.relative_bounding_box
            kps = det.location_data.relative_keypoints
            n = cfg.crop_px
            # MediaPipe's detection -> face region: square 1.5 x the box, rotated by the eye line
            rot = -math.atan2(-(kps[1].y - kps[0].y) * n, (kps[1].x - kps[0].x) * n)
            side_n = 1.5 * max(b.width, b.height)
            rect = g.rect(
                x_center=b.xmin + b.width / 2, y_center=b.ymin + b.height / 2, width=side_n, height=side_n, rotation=rot
            )
            mesh = g.mesh.process({"image": crop, "roi": rect}).landmarks
        face_px = b.height * n / scale
        if mesh is None:
            return FaceResult(face_px=face_px)
        lm = np.array([(p.x * n / scale + x0, p.y * n / scale + y0, p.z * n / scale) for p in mesh.landmark])
        yaw, pitch = head_pose(lm, focal, w / 2, h / 2)
        if not cfg.eye_crop_px:
            r, eye_w = iris_offset(lm)
        else:  # the irises only from the face refitted alone (the head crop's are not read)
            r, eye_w = math.nan, 0.0
            if face_px >= 5 * cfg.min_eye_px:
                box = (x0 + b.xmin * n / scale, y0 + b.ymin * n / scale, b.width * n / scale, b.height * n / scale)
                eyes = self._eye_fit(frame, box, rot)
                if eyes is not None:
                    r, eye_w = iris_offset(eyes)
        gaze = yaw
        if not math.isnan(r) and eye_w >= cfg.min_eye_px:
            gaze = yaw + cfg.iris_gain_deg * r
        p = eye_contact_probability(gaze, pitch, cfg)
        # confidence: detector score, face size, sharpness, share of the mesh inside the frame
        size_f = float(np.clip((face_px - cfg.face_px_min) / (cfg.face_px_full - cfg.face_px_min), 0.0, 1.0))
        # sharpness on the frame's own pixels of the face box (resampling would change it)
        fx0, fy0 = max(round(x0 + b.xmin * n / scale), 0), max(round(y0 + b.ymin * n / scale), 0)
        fx1, fy1 = round(x0 + (b.xmin + b.width) * n / scale), round(y0 + (b.ymin + b.height) * n / scale)
        patch = frame[fy0 : max(fy1, fy0), fx0 : max(fx1, fx0)]
        v = _sharpness(patch.astype(float).mean(axis=2)) if patch.size else 0.0
        sharp = v / (v + cfg.blur_ref) if cfg.blur_ref > 0 else 1.0
        inside = float(np.mean((lm[:, 0] >= 0) & (lm[:, 0] < w) & (lm[:, 1] >= 0) & (lm[:, 1] < h)))
        conf = float(det.score[0]) * size_f * sharp * inside
        return FaceResult(p, conf, yaw, pitch, gaze, face_px, 0.0, v)
