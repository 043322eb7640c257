"""Default pose backend: MediaPipe BlazePose (pinned ``mediapipe==0.10.14``), many people per frame, offline.

Since issue 35 people are proposed by the learned person detector (``MediaPipeConfig.proposer =
"detector"``, :mod:`~trustnav.perception.detector`): each box is fitted by the landmark model below,
which confirms it and gives its keypoints, then one box per person and the geometry gate
(:mod:`~trustnav.perception.ground_gate`; rejections in ``last_rejections``). The proposer before it,
described next, is ``proposer="blazepose"`` (its segmentation and HOG searches were retired in issue 35).

MediaPipe's legacy Pose solution follows one person. Here its two stages run as separate graphs
built from the calculators that ship in the wheel (no model download, no jax):

1. ``PoseDetectionCpu`` (``pose_detection.tflite``) over the whole frame and over overlapping
   tiles at several scales, so small and far people are found; detections from all tiles are mapped
   back to the frame and duplicates merged;
2. ``PoseLandmarkByRoiCpu`` (``pose_landmark_full.tflite``) once per person region, giving 33
   landmarks, mapped to COCO's 17 with :data:`BLAZEPOSE_TO_COCO`.

People are then checked (:func:`is_upright`, plus the landmarks must lie where the region put the
hips and the detector saw the face, and the box must be taller than wide), which removes boxes on
non-persons, and duplicates are merged once more on their landmark boxes. In video mode
(:meth:`MediaPipePoseBackend.reset` between videos) a person found in one frame is followed in the
next from the region of its own landmarks, as MediaPipe does, while the detector searches the tiles;
``scan_frames`` shares the tiles out over consecutive frames.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.confidence import BLAZEPOSE_TO_COCO, occlusion_confidences
from trustnav.perception.detector import PersonDetector
from trustnav.perception.frames import quiet_stderr
from trustnav.perception.ground_gate import GateConfig, HorizonFit, Rejection, gate_boxes
from trustnav.perception.types import Person, box_iou, check_frame

__all__ = [
    "BLAZEPOSE_TO_COCO",
    "MEDIAPIPE_VERSION",
    "QUIET_ENV",
    "MediaPipeConfig",
    "MediaPipePoseBackend",
    "load_mediapipe",
    "protobuf_warning_ignored",
    "quiet_environment",
]

MEDIAPIPE_VERSION = "0.10.14"

INSTALL_HINT = (
    f"the default pose backend needs mediapipe=={MEDIAPIPE_VERSION}; install it with "
    f"`pip install --no-deps mediapipe=={MEDIAPIPE_VERSION}` (trustnav already depends on what it uses; "
    f"a plain `pip install mediapipe=={MEDIAPIPE_VERSION}` also works but pulls jax, ~380 MB, that is not used)"
)

_DETECTOR_GRAPH = """
input_stream: "IMAGE:image"
output_stream: "DETECTIONS:detections"
node { calculator: "PoseDetectionCpu" input_stream: "IMAGE:image" output_stream: "DETECTIONS:detections" }
"""

_LANDMARK_GRAPH = """
input_stream: "IMAGE:image"
input_stream: "ROI:roi"
output_stream: "LANDMARKS:landmarks"
output_stream: "AUXILIARY_LANDMARKS:auxiliary"
node {
  calculator: "ConstantSidePacketCalculator"
  output_side_packet: "PACKET:0:model_complexity"
  output_side_packet: "PACKET:1:enable_segmentation"
  options { [mediapipe.ConstantSidePacketCalculatorOptions.ext] {
    packet { int_value: 1 } packet { bool_value: false } } }
}
node {
  calculator: "PoseLandmarkByRoiCpu"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  output_stream: "LANDMARKS:landmarks"
  output_stream: "AUXILIARY_LANDMARKS:auxiliary"
  output_stream: "WORLD_LANDMARKS:world_landmarks"
  output_stream: "SEGMENTATION_MASK:segmentation_mask"
  input_side_packet: "MODEL_COMPLEXITY:model_complexity"
  input_side_packet: "ENABLE_SEGMENTATION:enable_segmentation"
}
"""


#: Log levels that quieten MediaPipe's glog and TFLite start-up chatter (set only while they start).
QUIET_ENV = {"GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "2"}


@contextlib.contextmanager
def quiet_environment() -> Iterator[None]:
    """:data:`QUIET_ENV` in ``os.environ`` (where not set already) for the block only, then restored.

    MediaPipe's libraries read these levels when they load and start their first graph, which is
    when trustnav enters this block (:func:`load_mediapipe`, a backend's construction); the process
    environment is never changed beyond it, and nothing happens at import of this module.
    """
    saved = {k: os.environ.get(k) for k in QUIET_ENV}
    for k, v in QUIET_ENV.items():
        os.environ.setdefault(k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def protobuf_warning_ignored() -> Iterator[None]:
    """Ignore, for the block only, the warning that mediapipe 0.10.14's protobuf call raises on every
    frame ("SymbolDatabase.GetPrototype"); the warnings filters are restored on exit. Like every
    ``warnings.catch_warnings``, the scope is the process's, for as long as the block runs."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype", category=UserWarning)
        yield


def load_mediapipe() -> Any:
    """Import mediapipe (quietly) and check its version; ImportError with the install command if absent.

    Called on first use of the backend, never at import; it leaves ``os.environ`` and the warnings
    filters as it found them (see :func:`quiet_environment`)."""
    try:
        with quiet_environment(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import mediapipe
            from mediapipe.python import solution_base  # noqa: F401
    except ImportError as exc:
        raise ImportError(INSTALL_HINT) from exc
    if mediapipe.__version__ != MEDIAPIPE_VERSION:
        raise ImportError(f"found mediapipe {mediapipe.__version__}, but {INSTALL_HINT}")
    return mediapipe


#: Who proposes people: the learned detector (YOLOX-Nano, :mod:`~trustnav.perception.detector`) or,
#: as before issue 35, BlazePose's pose detector over tiles.
PROPOSERS = ("detector", "blazepose")


@dataclass(frozen=True)
class MediaPipeConfig:
    """Tiling, thresholds and video behaviour of :class:`MediaPipePoseBackend`.

    tile_fractions: tile sides as fractions of the frame's shorter side (1.0 = square tiles as tall as
    the frame); the whole frame is always searched too. tile_overlap: overlap between neighbouring tiles.
    min_tile_px: smallest tile side searched (the detector sees 224 x 224).
    head_band: tiles of the smaller scales (fractions < 0.75) are searched only where their centre lies
    in this band of the frame's height (fractions from the top; None: everywhere). The detector finds
    a person by the face, and pedestrians' faces lie near the horizon of a camera at eye height; the
    whole frame and the largest tiles, which cover everything, find the people who are not.
    scan_frames: in video mode, the tiles are shared out over this many consecutive frames (the whole
    frame is searched every frame; people already found are followed from their landmarks meanwhile).
    workers: MediaPipe graphs run in this many threads (each graph runs on one core).
    box_pad: (left, top, right, bottom) margins added to the landmarks' extent, as fractions of its
    height, so that a person's box runs from the head top to the soles and spans the clothes, as
    people are labelled (COCO, CityPersons, the project's labels): the landmarks stop at the eyes
    and the heels and lie on the joints. Medians measured on the project's labelled real sets
    (walk_a, phone_a, street): top 0.03-0.09, bottom 0.01-0.03, sides 0.01-0.04.
    sharpen, sharpen_sigma: unsharp mask applied to the frame the detector searches (0: off, the
    default); the landmark model sees the camera's pixels. The detector loses people as soon as the
    image softens (a 3x3 blur halves what is found on walk_a) and video compression removes exactly
    that detail: an unsharp mask of 0.7 at 2 px finds 95 % of the labelled people against 92 %
    without (all four labelled sets) and keeps more of them on compressed video. It is off by
    default because the detector's regions then change the landmarks, and LOOKING's eye contact
    with them: on the street images it no longer ranks the people facing the camera above those in
    profile (``benchmarks/trust_eval.py``, docs/perception.md).
    proposer: who proposes people: "detector" (default, issue 35: YOLOX-Nano,
    :mod:`~trustnav.perception.detector`, from ``detector_model`` or the default places, boxes scored
    >= ``detector_min_score``; each box fitted on a square of ``region_scale`` x its larger side, then
    the geometry gate, ``geometry_gate``, :mod:`~trustnav.perception.ground_gate`) or "blazepose" (the
    tiles above, before issue 35; the tile, scan and sharpen settings apply to it only; it is kept
    for the people whose landmark fit needs BlazePose's own alignment region, docs/perception.md).
    """

    tile_fractions: tuple[float, ...] = (1.0, 0.5, 0.33)
    tile_overlap: float = 0.4
    min_tile_px: int = 96
    min_presence: float = 0.5
    duplicate_iou: float = 0.45
    upright_check: bool = True
    max_torso_tilt_deg: float = 35.0
    max_hip_offset: float = 0.25
    min_aspect: float = 1.3
    head_band: tuple[float, float] | None = (0.2, 0.6)
    scan_frames: int = 1
    workers: int = 2
    box_pad: tuple[float, float, float, float] = (0.03, 0.07, 0.03, 0.02)
    sharpen: float = 0.0
    sharpen_sigma: float = 2.0
    proposer: str = "detector"
    detector_model: str | None = None
    detector_min_score: float = 0.25
    region_scale: float = 1.25
    geometry_gate: bool = True

    def __post_init__(self) -> None:
        if self.proposer not in PROPOSERS:
            raise ValueError(f"proposer must be one of {PROPOSERS}, got {self.proposer!r}")
        if not 0.0 < self.detector_min_score < 1.0:
            raise ValueError(f"detector_min_score must be in (0, 1), got {self.detector_min_score!r}")
        if not 0.8 <= self.region_scale <= 2.0:
            raise ValueError(
                f"region_scale must be in [0.8, 2] (landmark region side / box height), got {self.region_scale!r}"
            )
        if not isinstance(self.geometry_gate, bool):
            raise ValueError(f"geometry_gate must be True or False, got {self.geometry_gate!r}")
        if len(self.box_pad) != 4 or any(not 0.0 <= v <= 0.5 for v in self.box_pad):
            raise ValueError(f"box_pad must be 4 margins (left, top, right, bottom) in [0, 0.5], got {self.box_pad!r}")
        if self.head_band is not None and not 0.0 <= self.head_band[0] < self.head_band[1] <= 1.0:
            raise ValueError(f"head_band must be (top, bottom) with 0 <= top < bottom <= 1, got {self.head_band!r}")
        if not self.tile_fractions or any(not 0.0 < f <= 1.0 for f in self.tile_fractions):
            raise ValueError(f"tile_fractions must be non-empty, each in (0, 1], got {self.tile_fractions!r}")
        if not 0.0 <= self.tile_overlap < 0.9:
            raise ValueError(f"tile_overlap must be in [0, 0.9), got {self.tile_overlap!r}")
        if self.min_tile_px < 16:
            raise ValueError(f"min_tile_px must be >= 16, got {self.min_tile_px!r}")
        if not 0.0 <= self.min_presence <= 1.0:
            raise ValueError(f"min_presence must be in [0, 1], got {self.min_presence!r}")
        if not 0.0 < self.duplicate_iou <= 1.0:
            raise ValueError(f"duplicate_iou must be in (0, 1], got {self.duplicate_iou!r}")
        if not 0.0 < self.max_hip_offset <= 1.0:
            raise ValueError(f"max_hip_offset must be in (0, 1], got {self.max_hip_offset!r}")
        if self.min_aspect < 0.0:
            raise ValueError(f"min_aspect must be >= 0, got {self.min_aspect!r}")
        if not 0.0 < self.max_torso_tilt_deg <= 90.0:
            raise ValueError(f"max_torso_tilt_deg must be in (0, 90], got {self.max_torso_tilt_deg!r}")
        if not 0.0 <= self.sharpen <= 3.0:
            raise ValueError(f"sharpen must be in [0, 3], got {self.sharpen!r}")
        if not 0.3 <= self.sharpen_sigma <= 10.0:
            raise ValueError(f"sharpen_sigma must be in [0.3, 10] pixels, got {self.sharpen_sigma!r}")
        if self.scan_frames < 1:
            raise ValueError(f"scan_frames must be >= 1, got {self.scan_frames!r}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")


def tiles(height: int, width: int, config: MediaPipeConfig) -> list[tuple[int, int, int, int]]:
    """Search windows (x0, y0, x1, y1): the whole frame, then overlapping square tiles per scale."""
    out = [(0, 0, width, height)]
    short = min(height, width)
    for frac in config.tile_fractions:
        side = round(frac * short)
        if side < config.min_tile_px:
            continue
        stride = side * (1.0 - config.tile_overlap)
        xs = _starts(width, side, stride)
        ys = _starts(height, side, stride)
        if config.head_band is not None and frac < 0.75:
            top, bottom = config.head_band[0] * height, config.head_band[1] * height
            ys = [y for y in ys if top <= y + side / 2 <= bottom]
        out.extend((x, y, x + side, y + side) for y in ys for x in xs)
    return list(dict.fromkeys(out))


def _starts(length: int, side: int, stride: float) -> list[int]:
    if side >= length:
        return [0]
    n = math.ceil((length - side) / stride) + 1
    return [round(v) for v in np.linspace(0, length - side, n)]


#: Shrink factors tried on a detector's region when the landmarks of its own regions are not accepted.
RETRY_SCALES = (0.75,)
#: The body's mean landmark presence a retried region needs (the first regions need
#: ``MediaPipeConfig.min_presence``): a tighter square on a car or a pole can make the model see a body.
RETRY_MIN_PRESENCE = 0.95
#: The overlap with another person's box at which a person found on a retried region is dropped.
RETRY_MAX_IOU = 0.2

#: Regions tried on a followed person whose region from the previous frame gives no accepted fit,
#: before the detector searches around it: (side as a share of that region's, shift towards the
#: feet as a share of its side). Through video compression the landmark model's person flag flips
#: with the region's placement by a few pixels (walk_a through MP4: a 77 px man fitted on a region
#: 0.1 of its side higher and 1.1 x larger, or 1.25 x larger, not on the one centred on him), and the
#: followed person was lost until the detector found them again. A person fitted
#: on one of them is marked ``refollowed``: it gives way to the detector's people and does not stop a
#: detection from being fitted (on a fast walker the tried region can still hold where she was).
FOLLOW_TRIES = ((1.1, -0.1), (1.25, 0.0))
#: Widest box (a share of its height) a fit on one of :data:`FOLLOW_TRIES` may have: a larger square
#: can fit one body on two people walking side by side (walk_a: 64 x 94 px on a couple).
REFOLLOW_MAX_WIDTH = 0.6

#: How far (a share of its region's side) a followed person's detection may lie from where the
#: person was when the landmark model lost it and the detector searches around it: beyond it, the
#: detection is a neighbour's (the follower drifted onto the next person of a group).
REDETECT_MAX_SHIFT = 0.25

#: A detector box is confirmed by a landmark fit whose extent overlaps it by at least this IoU (a fit
#: that lands on a neighbour in a group overlaps less).
MIN_FIT_IOU = 0.3
#: A confirmed person's score before the body's presence: this + the rest x the detection score.
CONFIRMED_FLOOR = 0.5

#: A landmark check: (33 landmarks, region used) -> the Person, or None if rejected.
Accept = Callable[[NDArray[np.float64], NDArray[np.float64]], "Person | None"]


def roi_from_alignment(center: NDArray, scale_point: NDArray) -> NDArray[np.float64]:
    """Person region as MediaPipe computes it from two alignment points (pixels).

    Square of side 2.5 |scale_point - center| centred on ``center``, rotated so that the
    centre -> scale-point direction is upright. Returns [cx, cy, side, rotation] (pixels, radians).
    """
    dx, dy = float(scale_point[0] - center[0]), float(scale_point[1] - center[1])
    rotation = math.pi / 2 - math.atan2(-dy, dx)
    rotation = rotation - 2 * math.pi * math.floor((rotation + math.pi) / (2 * math.pi))
    side = 2.0 * math.hypot(dx, dy) * 1.25
    return np.array([center[0], center[1], side, rotation])


class _Graphs:
    """One detector graph and one landmark graph; each runs single-threaded, so one per worker."""

    def __init__(self) -> None:
        from google.protobuf import text_format
        from mediapipe.framework import calculator_pb2
        from mediapipe.framework.formats import rect_pb2
        from mediapipe.python import solution_base

        def graph(text: str) -> Any:
            config = text_format.Parse(text, calculator_pb2.CalculatorGraphConfig())
            return solution_base.SolutionBase(graph_config=config)

        self.rect = rect_pb2.NormalizedRect
        with quiet_stderr(), quiet_environment(), protobuf_warning_ignored():  # start-up chatter
            self.detector = graph(_DETECTOR_GRAPH)
            self.landmarker = graph(_LANDMARK_GRAPH)
            blank = np.zeros((64, 64, 3), dtype=np.uint8)
            self.detector.process({"image": blank})  # start the graphs now, quietly
            self.landmarker.process({"image": blank, "roi": self.rect(x_center=0.5, y_center=0.5, width=1, height=1)})

    def detect(self, frame: NDArray[np.uint8], window: tuple[int, int, int, int]) -> list[tuple[NDArray, float]]:
        """Person regions found in one window of the frame, in frame pixels."""
        h, w = frame.shape[:2]
        x0, y0, x1, y1 = window
        tile = frame if window == (0, 0, w, h) else np.ascontiguousarray(frame[y0:y1, x0:x1])
        out = []
        for det in self.detector.process({"image": tile}).detections or []:
            kps = det.location_data.relative_keypoints
            tw, th = x1 - x0, y1 - y0
            center = np.array([x0 + kps[0].x * tw, y0 + kps[0].y * th])
            scale = np.array([x0 + kps[1].x * tw, y0 + kps[1].y * th])
            box = det.location_data.relative_bounding_box
            face = [x0 + (box.xmin + box.width / 2) * tw, y0 + (box.ymin + box.height / 2) * th]
            face_size = max(box.width * tw, box.height * th)
            out.append((np.r_[roi_from_alignment(center, scale), face, face_size], float(det.score[0])))
        return out

    def landmarks_of_group(
        self, frame: NDArray[np.uint8], rois: NDArray[np.float64], accept: Accept, tries: int = 3
    ) -> tuple | None:
        """Landmarks and person from the first of a person's candidate regions whose landmarks
        ``accept`` takes; then, for a region from the detector, the best region shrunk by
        :data:`RETRY_SCALES`. On small people the detector's region is often too large for the
        landmark model (which then sees no body or a body that fails the checks) while a tighter
        square around the same centre gives the right one."""
        for roi in rois[:tries]:
            out = self._accepted(frame, roi, accept)
            if out is not None:
                return out
        if not np.isfinite(rois[0, 4]):
            return None  # a region followed from landmarks: nothing to retry
        found = self._refit(frame, rois[0], accept, [(scale, 0.0) for scale in RETRY_SCALES])
        if found is None:
            return None
        found[0][3].extra["retried"] = True
        return found[0]

    def _refit(
        self,
        frame: NDArray[np.uint8],
        roi: NDArray[np.float64],
        accept: Accept,
        tries: Sequence[tuple[float, float]],
        max_width: float = math.inf,
    ) -> tuple[tuple, tuple[float, float]] | None:
        """The first fit, and its (scale, shift), on ``roi`` with its side times ``scale`` and moved
        toward the feet by ``shift`` x its side, for each of ``tries``, that ``accept`` takes with a mean
        body presence >= :data:`RETRY_MIN_PRESENCE` and a box no wider than ``max_width`` x its height:
        a region the first fit failed on gives a body only if the model is sure of it."""
        for scale, shift in tries:
            tried = roi.copy()
            tried[2] *= scale
            tried[:2] += shift * roi[2] * np.array([math.sin(roi[3]), math.cos(roi[3])])
            out = self._accepted(frame, tried, accept)
            if out is None:
                continue
            x0, y0, x1, y1 = out[3].bbox
            if _presence(out[0]) >= RETRY_MIN_PRESENCE and x1 - x0 <= max_width * (y1 - y0):
                return out, (scale, shift)
        return None

    def _accepted(self, frame: NDArray[np.uint8], roi: NDArray[np.float64], accept: Accept) -> tuple | None:
        res = self.landmarks(frame, roi)
        if res is None:
            return None
        person = accept(res[0], res[2])
        if person is None:
            return None
        return (*res, person)

    def landmarks(self, frame: NDArray[np.uint8], roi: NDArray[np.float64]) -> tuple[NDArray, NDArray] | None:
        """33 landmarks (x, y, z in pixels, visibility, presence) and the region to follow them next frame."""
        h, w = frame.shape[:2]
        rect = self.rect(
            x_center=float(roi[0] / w),
            y_center=float(roi[1] / h),
            width=float(roi[2] / w),
            height=float(roi[2] / h),
            rotation=float(roi[3]),
        )
        out = self.landmarker.process({"image": frame, "roi": rect})
        if out.landmarks is None:
            return None
        lm = np.array([(p.x * w, p.y * h, p.z * w, p.visibility, p.presence) for p in out.landmarks.landmark])
        aux = out.auxiliary.landmark
        nxt = roi_from_alignment(np.array([aux[0].x * w, aux[0].y * h]), np.array([aux[1].x * w, aux[1].y * h]))
        return lm, np.r_[nxt, np.nan, np.nan, np.nan], roi

    def landmarks_or_redetect(
        self,
        frame: NDArray[np.uint8],
        rois: NDArray[np.float64],
        accept: Accept,
        tries: tuple[tuple[float, float], ...] | None = None,
    ) -> tuple | None:
        """Landmarks, next region, region used and person from a person's regions (see
        :meth:`landmarks_of_group`); if none and the person was followed from the previous frame (no
        detection among its regions), first the regions of ``tries`` (default :data:`FOLLOW_TRIES`)
        around it, then a search of a window around it, for a detection near where it was and of its
        size (:data:`REDETECT_MAX_SHIFT`)."""
        res = self.landmarks_of_group(frame, rois, accept)
        if res is not None or np.isfinite(rois[:, 4]).any():
            return res
        roi = rois[0]
        # not one clear person on a larger square: it can take in a neighbour too
        found = self._refit(frame, roi, accept, FOLLOW_TRIES if tries is None else tries, REFOLLOW_MAX_WIDTH)
        if found is not None:
            found[0][3].extra["refollowed"] = found[1]
            return found[0]
        h, w = frame.shape[:2]
        half = 0.75 * roi[2]
        x0, y0 = max(0, round(roi[0] - half)), max(0, round(roi[1] - half))
        x1, y1 = min(w, round(roi[0] + half)), min(h, round(roi[1] + half))
        if x1 - x0 < 16 or y1 - y0 < 16:
            return None
        # only a detection of this person: near where it was and of its size (the window also
        # holds the neighbours of a group, whose detections are often the stronger ones)
        found = [
            (r, score) for r, score in self.detect(frame, (x0, y0, x1, y1))
            if math.hypot(*(r[:2] - roi[:2])) <= REDETECT_MAX_SHIFT * roi[2] and 0.6 < r[2] / roi[2] < 1 / 0.6
        ]  # fmt: skip
        found.sort(key=lambda r: -r[1])
        if not found:
            return None
        return self.landmarks_of_group(frame, np.vstack([r for r, _ in found]), accept, tries=2)

    def close(self) -> None:
        self.detector.close()
        self.landmarker.close()


class MediaPipePoseBackend:
    """Multi-person BlazePose: tiled detection + per-person landmarks (see module docstring).

    ``video=True`` follows people from frame to frame (call :meth:`reset` before another video);
    ``last_timing`` holds the seconds spent in detection and landmarks on the latest frame.
    """

    def __init__(self, config: MediaPipeConfig | None = None, *, video: bool = False) -> None:
        self.config = config or MediaPipeConfig()
        self.video = video
        load_mediapipe()
        self._graphs: queue.SimpleQueue[_Graphs] = queue.SimpleQueue()
        self._all_graphs = [_Graphs() for _ in range(self.config.workers)]
        for g in self._all_graphs:
            self._graphs.put(g)
        self._executor = ThreadPoolExecutor(max_workers=self.config.workers, thread_name_prefix="mediapipe")
        self._followed: list[tuple[NDArray[np.float64], float]] = []
        self._frame_index = 0
        self.last_timing: dict[str, float] = {}
        self.detector: PersonDetector | None = None
        if self.config.proposer == "detector":  # made now: a missing or bad model file fails here
            self.detector = PersonDetector(self.config.detector_model, min_score=self.config.detector_min_score)
        self.horizon = HorizonFit(GateConfig().window)
        #: what the latest frame's proposals came to: the geometry gate's rejections and the boxes the
        #: landmark model did not confirm (:class:`~trustnav.perception.ground_gate.Rejection`)
        self.last_rejections: list[Rejection] = []
        #: a camera pose (trustnav.geometry CameraPose) for the geometry gate; None: fitted per frame
        self.camera: Any = None

    def reset(self) -> None:
        """Forget the people followed from the previous frame and the fitted horizon (call between videos)."""
        self._followed = []
        self._frame_index = 0
        self.horizon.reset()

    def close(self) -> None:
        """Stop the worker threads and release the graphs."""
        self._executor.shutdown()
        for g in self._all_graphs:
            g.close()

    def __enter__(self) -> MediaPipePoseBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _submit(self, fn: Any, item: Any) -> Any:
        """``fn(graphs, item)`` on a worker, as a future (the caller goes on meanwhile)."""

        def task() -> Any:
            g = self._graphs.get()
            try:
                return fn(g, item)
            finally:
                self._graphs.put(g)

        return self._executor.submit(task)

    def _map(self, fn: Any, items: list[Any]) -> list[Any]:
        def task(item: Any) -> Any:
            g = self._graphs.get()
            try:
                return fn(g, item)
            finally:
                self._graphs.put(g)

        with protobuf_warning_ignored():  # the graphs run only inside this block
            if len(items) <= 1 or self.config.workers == 1:
                return [task(i) for i in items]
            return list(self._executor.map(task, items))

    def detect(self, frame: NDArray[np.uint8], windows: list[tuple[int, int, int, int]] | None = None) -> list:
        """Person regions [cx, cy, side, rotation, face x, face y, face size] (pixels; face NaN for a
        region followed from landmarks) as groups of candidates per person, with detection scores."""
        if windows is None:
            windows = tiles(frame.shape[0], frame.shape[1], self.config)
        found = self._map(lambda g, win: g.detect(frame, win), windows)
        return _merge_regions([r for rs in found for r in rs])

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People in ``frame`` (H x W x 3 uint8 RGB).

        In video mode the people followed from the previous frame get their landmarks while the
        detector searches the tiles (one pool of workers for both); detections of people already
        found are then dropped, and the new ones get landmarks. ``last_timing`` holds the seconds
        each stage kept the workers busy ("detection", "landmarks"), shared out over the workers.
        """
        frame = check_frame(frame)
        if self.config.proposer == "detector":
            if self.detector is None:  # a config replaced after construction
                self.detector = PersonDetector(self.config.detector_model, min_score=self.config.detector_min_score)
            return self._detected(frame)
        search = sharpened(frame, self.config.sharpen, self.config.sharpen_sigma)  # for the detector only
        h, w = frame.shape[:2]
        windows = tiles(h, w, self.config)
        if self.video and self.config.scan_frames > 1 and self._frame_index > 0:
            k = self._frame_index % self.config.scan_frames
            windows = [windows[0]] + windows[1:][k :: self.config.scan_frames]
        followed = self._followed if self.video else []
        busy = {"detection": 0.0, "landmarks": 0.0}

        def task(g: _Graphs, job: tuple[str, Any, float]) -> tuple[Any, float]:
            t = time.perf_counter()
            kind, arg, score = job
            if kind == "detection":
                out = g.detect(search, arg)
            else:
                out = g.landmarks_or_redetect(frame, arg, lambda lm, roi: self._person(lm, score, w, h, roi))
            return out, time.perf_counter() - t

        # stage 1: tiles through the detector, and the followed people through the landmark model
        jobs = [("detection", win, 0.0) for win in windows]
        jobs += [("landmarks", roi[None, :], score) for roi, score in followed]
        done = self._map(task, jobs)
        for (kind, _, _), (_, dt) in zip(jobs, done, strict=True):
            busy[kind] += dt
        found = [region for out, _ in done[: len(windows)] for region in out]
        results = [out for out, _ in done[len(jobs) - len(followed) :]]
        scores = [score for _, score in followed]
        # stage 2: landmarks for the people the detector found that are not followed already
        # (a person refitted on a tried region does not stop a detection there: the two may differ)
        known = [res[1] for res in results if res is not None and "refollowed" not in res[3].extra]
        groups = [g for g in _merge_regions(found) if not any(_same_region(g[0][0], k) for k in known)]
        for out, dt in self._map(lambda g, grp: task(g, ("landmarks", grp[0], grp[1])), groups):
            busy["landmarks"] += dt
            results.append(out)
        scores += [score for _, score in groups]
        # each result: (landmarks, region to follow next frame, region used, person)
        people = [res[3] for res in results if res is not None]
        nxt = [(res[1], score) for res, score in zip(results, scores, strict=True) if res is not None]
        keep = one_box_per_person(people, self.config.duplicate_iou)
        self._followed = [nxt[i] for i in keep]
        self._frame_index += 1
        self.last_timing = {k: v / self.config.workers for k, v in busy.items()}
        return [people[i] for i in keep]

    def _detected(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People of one frame from the learned detector: each box confirmed and given keypoints by
        the landmark model (the region followed from the previous frame first, in video mode), then
        one box per person, then the geometry gate (:mod:`~trustnav.perception.ground_gate`)."""
        assert self.detector is not None
        h, w = frame.shape[:2]
        t0 = time.perf_counter()
        boxes, scores = self.detector(frame)
        t1 = time.perf_counter()
        followed = self._followed if self.video else []
        jobs = [(self._regions(box, followed), float(score), box) for box, score in zip(boxes, scores, strict=True)]
        results = self._map(lambda g, job: self._confirm(g, frame, *job, w, h), jobs)
        t2 = time.perf_counter()
        rejected = [
            Rejection(tuple(map(float, box)), score, "the landmark model found no upright person in the box")
            for (_, score, box), res in zip(jobs, results, strict=True)
            if res is None
        ]
        kept = [(res, score) for res, (_, score, _) in zip(results, jobs, strict=True) if res is not None]
        people = [res[3] for res, _ in kept]
        # of two boxes on one person (a woman and her pram in one box, and she alone in another),
        # the one whose landmark fit fills it best is the person's
        keep = one_box_per_person([replace(p, score=p.extra["fit_iou"]) for p in people], self.config.duplicate_iou)
        people, kept = [people[i] for i in keep], [kept[i] for i in keep]
        if self.config.geometry_gate:
            ok, gated = gate_boxes(
                [p.bbox for p in people],
                [p.score for p in people],
                (w, h),
                camera=self.camera,
                fit=self.horizon if self.video else None,
            )
            rejected += gated
            people, kept = [people[i] for i in ok], [kept[i] for i in ok]
        for p in people:
            p.extra["detected"] = True
        self._followed = [(res[1], score) for res, score in kept]
        self._frame_index += 1
        self.last_rejections = rejected
        self.last_timing = {"detection": t1 - t0, "landmarks": t2 - t1}
        return people

    def _regions(self, box: NDArray[np.float64], followed: list[tuple[NDArray[np.float64], float]]) -> NDArray:
        """Landmark regions to try for a detector box: a followed person's region that lies on it
        (video mode), then the box's own square (side ``region_scale`` x the box's height)."""
        own = box_region(box, self.config.region_scale)
        regions = [roi for roi, _ in followed if box_iou(_region_box(roi), box) >= 0.3 and _same_region(roi, own)]
        return np.vstack([*regions[:1], own])

    def _confirm(
        self, g: _Graphs, frame: NDArray[np.uint8], rois: NDArray, score: float, box: NDArray, w: int, h: int
    ) -> tuple | None:
        """The landmark fit that confirms a detector box: the first of ``rois`` (then the box's own square shrunk by
        :data:`RETRY_SCALES`, for small people) whose landmarks :meth:`_person` accepts and whose extent
        overlaps the box by IoU >= 0.5 (else the first with :data:`MIN_FIT_IOU`: in a group the fit can take
        in a neighbour's limbs). The person keeps the detector's box (head top to soles, as people are
        labelled), stretched up or down to the fit's padded extent where a fit with IoU >= 0.5 reaches
        beyond it, and the fit's keypoints; its score is :data:`CONFIRMED_FLOOR` + the rest x the detection
        score, times the body's landmark presence (the tracker takes boxes >= 0.4 as sure)."""

        def accept(lm: NDArray[np.float64], roi: NDArray) -> Person | None:
            return self._person(lm, CONFIRMED_FLOOR + (1.0 - CONFIRMED_FLOOR) * score, w, h, roi)

        tighter = rois[-1].copy()
        tighter[2] *= RETRY_SCALES[0]
        best = None
        for roi in (*rois, tighter):
            out = g._accepted(frame, roi, accept)
            if out is None:
                continue
            overlap = box_iou(out[3].bbox, box)
            if overlap >= 0.5:
                best = out
                break
            if overlap >= MIN_FIT_IOU and best is None:
                best = out
        if best is None:
            return None
        fit_iou = box_iou(best[3].bbox, box)
        bbox = np.asarray(box, dtype=np.float64).copy()
        if fit_iou >= 0.5:  # a fit of this person: its head top and soles where the box stops short
            bbox[1], bbox[3] = min(bbox[1], best[3].bbox[1]), max(bbox[3], best[3].bbox[3])
        person = replace(best[3], bbox=bbox)
        person.extra["fit_iou"] = fit_iou
        return (*best[:3], person)

    def _person(self, lm: NDArray[np.float64], score: float, w: int, h: int, roi: NDArray) -> Person | None:
        presence = _presence(lm)
        if presence < self.config.min_presence:
            return None
        # the landmark model must find the body where the region put it (hips near the region's
        # centre); a fit far from it is the model hallucinating a body on the background
        hips = lm[[23, 24], :2].mean(axis=0)
        if math.hypot(*(hips - roi[:2])) > self.config.max_hip_offset * roi[2]:
            return None
        # a region from the detector also says where the face is: the nose must be there
        if np.isfinite(roi[4]) and math.hypot(*(lm[0, :2] - roi[4:6])) > roi[6]:
            return None
        if self.config.upright_check and not is_upright(lm, self.config.max_torso_tilt_deg):
            return None
        pts = lm[:, :2]
        x1, y1 = np.clip(pts.min(axis=0), 0, [w - 1, h - 1])
        x2, y2 = np.clip(pts.max(axis=0), 0, [w - 1, h - 1])
        if x2 - x1 < 2 or (y2 - y1) < self.config.min_aspect * (x2 - x1):
            return None  # pedestrians are taller than wide; a portrait on a poster is not
        span = float(np.ptp(pts[:, 1]))  # the landmarks' own height, also where the image cuts them
        left, top, right, bottom = (span * v for v in self.config.box_pad)
        x1, y1 = max(0.0, x1 - left), max(0.0, y1 - top)
        x2, y2 = min(w - 1.0, x2 + right), min(h - 1.0, y2 + bottom)
        coco = lm[list(BLAZEPOSE_TO_COCO)]
        return Person(
            bbox=np.array([x1, y1, x2, y2]),
            keypoints=coco[:, :2].copy(),
            confidences=occlusion_confidences(lm),
            score=float(min(1.0, score)) * presence,
            extra={"blazepose": lm},
        )


def box_region(box: NDArray[np.float64], scale: float = 1.25) -> NDArray[np.float64]:
    """The landmark model's region for a person box: a square of side ``scale`` x the box's larger
    side, upright, centred on the box (the hips lie near a standing person's middle), as
    [cx, cy, side, rotation, face x, face y, face size] with no face (NaN)."""
    x1, y1, x2, y2 = (float(v) for v in box[:4])
    side = scale * max(y2 - y1, x2 - x1, 1.0)
    return np.array([(x1 + x2) / 2, (y1 + y2) / 2, side, 0.0, np.nan, np.nan, np.nan])


def _presence(lm: NDArray[np.float64]) -> float:
    """Mean presence of the body's landmarks (shoulders to feet, 11-28) of a BlazePose fit."""
    return float(np.mean(lm[11:29, 4]))


def sharpened(frame: NDArray[np.uint8], amount: float, sigma: float) -> NDArray[np.uint8]:
    """Unsharp mask: ``frame + amount (frame - blur_sigma(frame))``, saturated; ``amount`` 0: the frame."""
    if amount <= 0.0:
        return frame
    import cv2

    blur = cv2.GaussianBlur(frame, (0, 0), sigma)
    return cv2.addWeighted(frame, 1.0 + amount, blur, -amount, 0.0)


def is_upright(lm: NDArray[np.float64], max_tilt_deg: float = 35.0) -> bool:
    """Pedestrian check on 33 BlazePose landmarks (pixels): head above shoulders above hips above
    knees, torso within ``max_tilt_deg`` of vertical, shoulders narrower than the torso is long and
    wider than the head."""
    nose = lm[0, :2]
    shoulders = lm[[11, 12], :2].mean(axis=0)
    hips = lm[[23, 24], :2].mean(axis=0)
    knees = lm[[25, 26], :2].mean(axis=0)
    torso = hips - shoulders
    torso_len = float(np.hypot(*torso))
    if torso_len < 1e-6 or torso[1] <= 0:
        return False
    tilt = math.degrees(math.atan2(abs(torso[0]), torso[1]))
    if tilt > max_tilt_deg:
        return False
    if nose[1] >= shoulders[1] or knees[1] <= hips[1]:
        return False
    shoulder_width = float(np.hypot(*(lm[11, :2] - lm[12, :2])))
    head_width = float(np.hypot(*(lm[7, :2] - lm[8, :2])))
    # real shoulders are about twice as wide as the head seen from the front; a pictogram or a pole
    # that the model reads as a person has them no wider than the head
    return shoulder_width < 1.5 * torso_len and shoulder_width > 1.15 * head_width


def one_box_per_person(people: list[Person], iou: float) -> list[int]:
    """Indices of the people to keep, one per person (sorted), best score first.

    Two boxes are the same person when they overlap by ``iou`` or more, when one lies inside the other
    and is not much smaller (:func:`_contains`), or when they share the head: one lies inside the
    other and their noses are within a quarter of the smaller box's height (the landmark model
    sometimes fits a second, partial body on the upper half of a person). Of two boxes sharing the
    head the taller is kept, whatever the scores: it is the whole person. People found only on a
    retried region (:data:`RETRY_SCALES`) come last and give way to any person they overlap by
    :data:`RETRY_MAX_IOU`: in a group, the tighter square can fit one body on two people.
    """
    order = sorted(range(len(people)), key=lambda i: (_secondary(people[i]), -people[i].score))
    keep: list[int] = []
    for i in order:
        a = people[i]
        limit = RETRY_MAX_IOU if _secondary(a) else iou
        for n, j in enumerate(keep):
            b = people[j]
            if box_iou(a.bbox, b.bbox) >= limit or _contains(b.bbox, a.bbox):
                break
            if _share_head(a, b):
                if _height(a.bbox) > _height(b.bbox):
                    keep[n] = i
                break
        else:
            keep.append(i)
    return sorted(keep)


def _secondary(p: Person) -> bool:
    """Found only on a retried or refollowed region: gives way to the detector's people."""
    return any(p.extra.get(key, False) for key in ("retried", "refollowed"))


def _region_box(roi: NDArray[np.float64]) -> NDArray[np.float64]:
    """The person box a landmark region [cx, cy, side, ...] stands for (a body fills about 0.8 of
    the square's height and 0.4 of its width)."""
    cx, cy, side = roi[0], roi[1], roi[2]
    return np.array([cx - 0.2 * side, cy - 0.4 * side, cx + 0.2 * side, cy + 0.4 * side])


def _height(box: NDArray) -> float:
    return float(box[3] - box[1])


def _share_head(a: Person, b: Person) -> bool:
    small, large = (a, b) if _height(a.bbox) <= _height(b.bbox) else (b, a)
    if not _contains(large.bbox, small.bbox, min_area=0.0):
        return False
    nose_a, nose_b = a.keypoints[0], b.keypoints[0]
    if not (np.isfinite(nose_a).all() and np.isfinite(nose_b).all()):
        return False
    return math.hypot(*(nose_a - nose_b)) < 0.25 * _height(small.bbox)


def _contains(outer: NDArray, inner: NDArray, share: float = 0.85, min_area: float = 0.3) -> bool:
    """Most (``share``) of ``inner`` lies inside ``outer`` and its area is at least ``min_area`` of
    the outer's (the same person seen twice)."""
    iw = min(outer[2], inner[2]) - max(outer[0], inner[0])
    ih = min(outer[3], inner[3]) - max(outer[1], inner[1])
    if iw <= 0 or ih <= 0:
        return False
    area = (inner[2] - inner[0]) * (inner[3] - inner[1])
    return iw * ih >= share * area and area >= min_area * (outer[2] - outer[0]) * (outer[3] - outer[1])


def _same_region(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    """Two person regions [cx, cy, side, ...] describe the same person: close centres, similar sizes."""
    ratio = a[2] / b[2]
    return 0.6 < ratio < 1 / 0.6 and math.hypot(*(a[:2] - b[:2])) < 0.1 * min(a[2], b[2])


def _merge_regions(found: list[tuple[NDArray[np.float64], float]]) -> list[tuple[NDArray[np.float64], float]]:
    """Group regions that describe the same person (close centres, similar sizes), best score first.

    Returns one entry per person: (regions of the group stacked as (k, 4), best score). The landmark
    stage tries the regions in order, as MediaPipe's landmark model sometimes rejects one crop of a
    person and accepts another.
    """
    order = sorted(found, key=lambda r: -r[1])
    groups: list[tuple[list[NDArray[np.float64]], float]] = []
    for roi, score in order:
        for members, _ in groups:
            if _same_region(roi, members[0]):
                members.append(roi)
                break
        else:
            groups.append(([roi], score))
    return [(np.vstack(members), score) for members, score in groups]
