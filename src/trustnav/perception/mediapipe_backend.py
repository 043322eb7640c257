"""Default pose backend: MediaPipe BlazePose (pinned ``mediapipe==0.10.14``), many people per frame, offline.

People are proposed by the learned person detector (issue 35, :mod:`~trustnav.perception.detector`).
Each box is fitted by BlazePose's landmark model (``PoseLandmarkByRoiCpu``, ``pose_landmark_full.tflite``,
run as a graph built from the calculators that ship in the wheel: no model download, no jax), which
confirms it and gives 33 landmarks, mapped to COCO's 17 with :data:`BLAZEPOSE_TO_COCO`. A fit is
checked (:func:`is_upright`, the hips where the region put them, a box taller than wide), which
removes boxes on non-persons; a box whose fits are all rejected gets one more fit on the region the
rejected fit suggests (a box that takes in two people). Then one box per person
(:func:`one_box_per_person`) and the geometry gate
(:mod:`~trustnav.perception.ground_gate`; rejections in ``last_rejections``). In video mode
(:meth:`MediaPipePoseBackend.reset` between videos) a box is first fitted on the region the
landmarks of the person on it gave in the previous frame, as MediaPipe follows a person. BlazePose's
own pose detector over ~25 tiles, the proposer before issue 35, was retired (docs/perception.md).
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.confidence import BLAZEPOSE_TO_COCO, occlusion_confidences
from trustnav.perception.detector import PersonDetector
from trustnav.perception.frames import quiet_stderr
from trustnav.perception.ground_gate import GateConfig, HorizonFit, Rejection, feet_in_view, gate_boxes
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


@dataclass(frozen=True)
class MediaPipeConfig:
    """Thresholds and video behaviour of :class:`MediaPipePoseBackend`.

    workers: MediaPipe graphs run in this many threads (each graph runs on one core).
    box_pad: (left, top, right, bottom) margins added to the landmarks' extent, as fractions of its
    height, so that a person's box runs from the head top to the soles and spans the clothes, as
    people are labelled (COCO, CityPersons, the project's labels): the landmarks stop at the eyes
    and the heels and lie on the joints. Medians measured on the project's labelled real sets
    (walk_a, phone_a, street): top 0.03-0.09, bottom 0.01-0.03, sides 0.01-0.04.
    detector_model, detector_min_score: the YOLOX-Nano file (:mod:`~trustnav.perception.detector`; None:
    the default places) and the score a box needs. region_scale: each box is fitted on a square of
    ``region_scale`` x its larger side. geometry_gate: the ground check of
    :mod:`~trustnav.perception.ground_gate`. duplicate_iou: two boxes overlapping by this much are one
    person (:func:`one_box_per_person`). proposal_score: with the frame's camera known
    (:attr:`MediaPipePoseBackend.camera`, a drive's), a box scoring at least this but under
    ``detector_min_score`` is a proposal too: it is fitted only if a person of human height standing
    where its feet are would fill it (the geometry gate with the camera, feet in view), and kept only
    if the landmark model then confirms a person in it, as every box, whom nobody kept has already
    (:func:`new_people_of_proposals`). The verifiers decide, not the
    detector's score alone: YOLOX-Nano scored a texting woman in profile, 135 px tall and unoccluded,
    0.17-0.21, and a car passed her at 2.37 m without once seeing her (issue 34; docs/perception.md,
    "Proposals where the camera vouches"). None: no proposals; without a camera there are none
    either (a person on a billboard stands on no ground the gate can check).
    """

    min_presence: float = 0.5
    duplicate_iou: float = 0.45
    upright_check: bool = True
    max_torso_tilt_deg: float = 35.0
    max_hip_offset: float = 0.25
    min_aspect: float = 1.3
    workers: int = 2
    box_pad: tuple[float, float, float, float] = (0.03, 0.07, 0.03, 0.02)
    detector_model: str | None = None
    detector_min_score: float = 0.25
    region_scale: float = 1.25
    geometry_gate: bool = True
    proposal_score: float | None = 0.1

    def __post_init__(self) -> None:
        if not 0.0 < self.detector_min_score < 1.0:
            raise ValueError(f"detector_min_score must be in (0, 1), got {self.detector_min_score!r}")
        if self.proposal_score is not None and (
            isinstance(self.proposal_score, bool)
            or not isinstance(self.proposal_score, (int, float))
            or not 0.0 < self.proposal_score <= self.detector_min_score
        ):
            raise ValueError(
                f"proposal_score must be None (no proposals) or in (0, detector_min_score = "
                f"{self.detector_min_score:g}], got {self.proposal_score!r}"
            )
        if not 0.8 <= self.region_scale <= 2.0:
            raise ValueError(
                f"region_scale must be in [0.8, 2] (landmark region side / box height), got {self.region_scale!r}"
            )
        if not isinstance(self.geometry_gate, bool):
            raise ValueError(f"geometry_gate must be True or False, got {self.geometry_gate!r}")
        if len(self.box_pad) != 4 or any(not 0.0 <= v <= 0.5 for v in self.box_pad):
            raise ValueError(f"box_pad must be 4 margins (left, top, right, bottom) in [0, 0.5], got {self.box_pad!r}")
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
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")


#: Shrink factor tried on a detector box's own square when no fit on it is accepted (small people).
RETRY_SCALES = (0.75,)
#: A detector box is confirmed by a landmark fit whose extent overlaps it by at least this IoU (a fit
#: that lands on a neighbour in a group overlaps less).
MIN_FIT_IOU = 0.3
#: A confirmed person's score before the body's presence: this + the rest x the detection score.
CONFIRMED_FLOOR = 0.5

#: Ankle confidence, and the share of a proposal's box above its ankle, that show its feet
#: (:meth:`MediaPipePoseBackend._proposals`).
FEET_CONFIDENCE = 0.5
FEET_SHARE = 0.8
#: The ankles among the 17 COCO keypoints.
ANKLES = (15, 16)
#: A proposal whose fit puts the nose, or the ankles' midpoint, within this share of the smaller
#: box's height of a kept person's is that person (:func:`same_fit`).
SAME_SPOT = 0.1


def _feet_at_bottom(person: Person, box: NDArray[np.float64]) -> bool:
    """Whether ``person``'s fit shows an ankle (:data:`ANKLES`) at ``box``'s bottom: confident and
    below :data:`FEET_SHARE` of the box's height from its top."""
    top, height = float(box[1]), float(box[3] - box[1])
    return any(
        person.confidences[j] >= FEET_CONFIDENCE and person.keypoints[j, 1] >= top + FEET_SHARE * height for j in ANKLES
    )


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
    """One landmark graph; it runs single-threaded, so one per worker."""

    def __init__(self) -> None:
        from google.protobuf import text_format
        from mediapipe.framework import calculator_pb2
        from mediapipe.framework.formats import rect_pb2
        from mediapipe.python import solution_base

        self.rect = rect_pb2.NormalizedRect
        with quiet_stderr(), quiet_environment(), protobuf_warning_ignored():  # start-up chatter
            config = text_format.Parse(_LANDMARK_GRAPH, calculator_pb2.CalculatorGraphConfig())
            self.landmarker = solution_base.SolutionBase(graph_config=config)
            blank = np.zeros((64, 64, 3), dtype=np.uint8)  # start the graph now, quietly
            self.landmarker.process({"image": blank, "roi": self.rect(x_center=0.5, y_center=0.5, width=1, height=1)})

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

    def close(self) -> None:
        self.landmarker.close()


class MediaPipePoseBackend:
    """Multi-person BlazePose: the person detector's boxes fitted with landmarks (see module docstring).

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
        # made now: a missing or bad model file fails here
        cfg = self.config
        floor = cfg.detector_min_score if cfg.proposal_score is None else cfg.proposal_score
        self.detector = PersonDetector(cfg.detector_model, min_score=floor)
        self.horizon = HorizonFit(GateConfig().window)
        #: what the latest frame's proposals came to: the geometry gate's rejections and the boxes the
        #: landmark model did not confirm (:class:`~trustnav.perception.ground_gate.Rejection`)
        self.last_rejections: list[Rejection] = []
        #: the frame's camera pose (trustnav.geometry CameraPose) for the geometry gate, and with it
        #: the proposals (``MediaPipeConfig.proposal_score``); None: the gate fits the horizon per frame
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

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People in ``frame`` (H x W x 3 uint8 RGB); ``last_timing`` holds the seconds spent in the
        detector and the landmark fits ("detection", "landmarks")."""
        return self._detected(check_frame(frame))

    def _detected(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People of one frame from the learned detector: each box confirmed and given keypoints by
        the landmark model (the region followed from the previous frame first, in video mode), then
        one box per person, then the geometry gate (:mod:`~trustnav.perception.ground_gate`)."""
        h, w = frame.shape[:2]
        t0 = time.perf_counter()
        boxes, scores = self.detector(frame)
        boxes, scores, vetoed = self._proposals(boxes, scores, w, h)
        t1 = time.perf_counter()
        followed = self._followed if self.video else []
        jobs = [(self._regions(box, followed), float(score), box) for box, score in zip(boxes, scores, strict=True)]
        results = self._map(lambda g, job: self._confirm(g, frame, *job, w, h, refit=True), jobs)
        t2 = time.perf_counter()
        rejected = vetoed + [
            Rejection(tuple(map(float, box)), score, "the landmark model found no upright person in the box")
            for (_, score, box), res in zip(jobs, results, strict=True)
            if res is None
        ]
        # a proposal is vouched for by where its feet stand: the fit must show them at the box's bottom
        # (a box on a texter's upper body, its "feet" at her waist, is a person of that size further
        # away to the gate)
        sure_score = self.config.detector_min_score
        for k, ((_, score, box), res) in enumerate(zip(jobs, results, strict=True)):
            if res is not None and score < sure_score and not _feet_at_bottom(res[3], box):
                reason = "a proposal whose fit shows no feet at the box's bottom"
                rejected.append(Rejection(tuple(map(float, box)), score, reason))
                results[k] = None
        kept = [(res, score) for res, (_, score, _) in zip(results, jobs, strict=True) if res is not None]
        for res, score in kept:
            if score < sure_score:  # found as a proposal: marked for the reader (rejected.json, the drives' scoring)
                res[3].extra["proposal"] = True
        people = [res[3] for res, _ in kept]
        # of two boxes on one person (a woman and her pram in one box, and she alone in another),
        # the one whose landmark fit fills it best is the person's
        keep = one_box_per_person([replace(p, score=p.extra["fit_iou"]) for p in people], self.config.duplicate_iou)
        people, kept = [people[i] for i in keep], [kept[i] for i in keep]
        # a proposal adds a person only where nobody kept has her fit: a box shifted off a person (0.4-0.5
        # of it on her box) takes the region followed from her last frame and fits her again
        keep = new_people_of_proposals(people)
        reason = "a proposal whose fit is a person kept"
        rejected += [
            Rejection(tuple(map(float, p.bbox)), k[1], reason)
            for i, (p, k) in enumerate(zip(people, kept, strict=True))
            if i not in keep
        ]
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

    def _proposals(
        self, boxes: NDArray[np.float64], scores: NDArray[np.float64], w: int, h: int
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[Rejection]]:
        """The detector's boxes to fit: those scoring ``detector_min_score``, and with the camera known
        the proposals under it (``proposal_score``) that lie mostly off the sure boxes (half or more
        of one inside a sure box is a part of that person) and that the geometry gate vouches for
        (feet in view, a person of human height standing there fills the box); the vetoed
        proposals' rejections. After the landmark fit a proposal must also show its feet at its
        box's bottom (:func:`_feet_at_bottom`) and be nobody kept (:func:`new_people_of_proposals`)."""
        sure = scores >= self.config.detector_min_score
        if sure.all():
            return boxes, scores, []
        if self.camera is None:
            return boxes[sure], scores[sure], []
        low = np.flatnonzero(~sure)
        vetoed: list[Rejection] = []
        if sure.any():  # a proposal lying mostly on a sure box is a part of that person (legs, a torso)
            on_sure = [i for i in low if any(_contains(b, boxes[i], share=0.5, min_area=0.0) for b in boxes[sure])]
            reason = "a proposal lying mostly on a box the detector is sure of"
            vetoed += [Rejection(tuple(map(float, boxes[i])), float(scores[i]), reason) for i in on_sure]
            low = np.array([i for i in low if i not in on_sure], dtype=int)
        ok, gated = gate_boxes(boxes[low], scores[low], (w, h), camera=self.camera)
        vetoed += gated
        keep = np.zeros(len(boxes), dtype=bool)
        keep[sure] = True
        for i in ok:  # the gate passes boxes cut by the frame's bottom unjudged: nothing vouches for their feet
            if feet_in_view(boxes[low[i]], h):
                keep[low[i]] = True
            else:
                vetoed.append(
                    Rejection(
                        tuple(map(float, boxes[low[i]])), float(scores[low[i]]), "a proposal cut by the frame's bottom"
                    )
                )
        return boxes[keep], scores[keep], vetoed

    def _regions(self, box: NDArray[np.float64], followed: list[tuple[NDArray[np.float64], float]]) -> NDArray:
        """Landmark regions to try for a detector box: a followed person's region that lies on it
        (video mode), then the box's own square (side ``region_scale`` x the box's height)."""
        own = box_region(box, self.config.region_scale)
        regions = [roi for roi, _ in followed if box_iou(_region_box(roi), box) >= 0.3 and _same_region(roi, own)]
        return np.vstack([*regions[:1], own])

    def _confirm(
        self,
        g: _Graphs,
        frame: NDArray[np.uint8],
        rois: NDArray,
        score: float,
        box: NDArray,
        w: int,
        h: int,
        refit: bool = False,
    ) -> tuple | None:
        """The landmark fit that confirms a detector box: the first of ``rois`` (then the box's own square shrunk by
        :data:`RETRY_SCALES`, for small people) whose landmarks :meth:`_person` accepts and whose extent
        overlaps the box by IoU >= 0.5 (else the first with :data:`MIN_FIT_IOU`: in a group the fit can take
        in a neighbour's limbs). The person keeps the detector's box (head top to soles, as people are
        labelled), stretched up or down to the fit's padded extent where a fit with IoU >= 0.5 reaches
        beyond it, and the fit's keypoints; its score is :data:`CONFIRMED_FLOOR` + the rest x the detection
        score, times the body's landmark presence (the tracker takes boxes >= 0.4 as sure). With ``refit``
        (offline), a box whose fits are all rejected gets one more fit on the region the first rejected
        fit suggests for the next frame (``extra["refit"]``; a box that takes in two people)."""

        def accept(lm: NDArray[np.float64], roi: NDArray) -> Person | None:
            return self._person(lm, CONFIRMED_FLOOR + (1.0 - CONFIRMED_FLOOR) * score, w, h, roi)

        tighter = rois[-1].copy()
        tighter[2] *= RETRY_SCALES[0]
        best, suggested = None, None
        for roi in (*rois, tighter):
            res = g.landmarks(frame, roi)
            if res is None:
                continue
            out = None if (person := accept(res[0], res[2])) is None else (*res, person)
            if out is None:
                if suggested is None:
                    suggested = res[1]  # where the rejected fit says the body is
                continue
            overlap = box_iou(out[3].bbox, box)
            if overlap >= 0.5:
                best = out
                break
            if overlap >= MIN_FIT_IOU and best is None:
                best = out
        if best is None and refit and suggested is not None:
            # the box takes in a second person and the fit reads a mix of both (shoulders narrower than
            # the head): the region the rejected fit proposes for the next frame centres on one of them
            out = g._accepted(frame, suggested, accept)
            if out is not None and box_iou(out[3].bbox, box) >= MIN_FIT_IOU:
                best = out
                best[3].extra["refit"] = True
        if best is None:
            return None
        fit_iou = box_iou(best[3].bbox, box)
        bbox = np.asarray(box, dtype=np.float64).copy()
        if best[3].extra.get("refit"):  # the box took in two people: the person is the fit's extent
            bbox = best[3].bbox.copy()
        elif fit_iou >= 0.5:  # a fit of this person: its head top and soles where the box stops short
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
    head the taller is kept, whatever the scores: it is the whole person.
    """
    order = sorted(range(len(people)), key=lambda i: -people[i].score)
    keep: list[int] = []
    for i in order:
        a = people[i]
        for n, j in enumerate(keep):
            b = people[j]
            if box_iou(a.bbox, b.bbox) >= iou or _contains(b.bbox, a.bbox):
                break
            if _share_head(a, b):
                if _height(a.bbox) > _height(b.bbox):
                    keep[n] = i
                break
        else:
            keep.append(i)
    return sorted(keep)


def _region_box(roi: NDArray[np.float64]) -> NDArray[np.float64]:
    """The person box a landmark region [cx, cy, side, ...] stands for (a body fills about 0.8 of
    the square's height and 0.4 of its width)."""
    cx, cy, side = roi[0], roi[1], roi[2]
    return np.array([cx - 0.2 * side, cy - 0.4 * side, cx + 0.2 * side, cy + 0.4 * side])


def _height(box: NDArray) -> float:
    return float(box[3] - box[1])


def _share_head(a: Person, b: Person) -> bool:
    small, large = (a, b) if _height(a.bbox) <= _height(b.bbox) else (b, a)
    return _contains(large.bbox, small.bbox, min_area=0.0) and _within(
        a.keypoints[0], b.keypoints[0], 0.25 * _height(small.bbox)
    )


def same_fit(a: Person, b: Person) -> bool:
    """Two people whose fits put the nose, or the ankles' midpoint, within :data:`SAME_SPOT` of the
    smaller box's height of each other: one body fitted twice (a head is about an eighth of a body's
    height wide). Only for a proposal: in a real group the landmark model also fits a neighbour's
    body on a second person's box, which the detector's sure box still vouches for."""
    size = min(_height(a.bbox), _height(b.bbox))
    feet_a, feet_b = a.keypoints[list(ANKLES)].mean(axis=0), b.keypoints[list(ANKLES)].mean(axis=0)
    return _within(a.keypoints[0], b.keypoints[0], SAME_SPOT * size) or _within(feet_a, feet_b, SAME_SPOT * size)


def new_people_of_proposals(people: list[Person]) -> list[int]:
    """Indices of the people to keep (sorted): every one the detector is sure of, and each proposal
    (``extra["proposal"]``, best score first) whose fit is nobody's kept before it (:func:`same_fit`)."""
    keep = [i for i, p in enumerate(people) if not p.extra.get("proposal")]
    proposals = [i for i, p in enumerate(people) if p.extra.get("proposal")]
    for i in sorted(proposals, key=lambda i: -people[i].score):
        if not any(same_fit(people[i], people[j]) for j in keep):
            keep.append(i)
    return sorted(keep)


def _within(p: NDArray[np.float64], q: NDArray[np.float64], distance: float) -> bool:
    """Two image points, both known, closer than ``distance``."""
    return bool(np.isfinite(p).all() and np.isfinite(q).all() and math.hypot(*(p - q)) < distance)


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
