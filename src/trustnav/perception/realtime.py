"""Real-time perception on two cores: the learned detector every frame, landmarks as the budget allows.

:class:`RealtimePoseBackend` is a drop-in pose backend (callable on a frame) built on the offline
backend's parts (:class:`~trustnav.perception.mediapipe_backend.MediaPipePoseBackend` with the
YOLOX-Nano proposer), split over time instead of run in full on every frame:

- **detection** on every frame (``RealtimeConfig.search_frames`` = k: one frame in k), one
  onnxruntime thread, its input shaped to the frame (416 x 320 for 640 x 480; ``detector_input``
  sets its longer side): every person's box is measured on that frame;
- **landmarks** (the BlazePose landmark model that confirms a box and gives the keypoints the cues
  read) on the two workers: new boxes, the largest first, in what the frame's ``max_fits`` leave (at
  least one), and each followed person again once ``landmark_every`` frames have passed since its
  last fit, the most overdue first, at most ``max_fits`` a frame (on the region of its last fit moved
  by its velocity, then its box's own square; one whose refits keep finding no body waits longer,
  :data:`REFIT_BACKOFF`); the others are **carried**: the detector's box of this
  frame with the keypoints of the last fit moved and scaled onto it (``extra["carried"]``: their cues
  are those of the last fit). A followed person the detector does not box on a frame is carried by its
  velocity for up to ``carry_frames`` frames (``extra["predicted"]``: no measurement on this frame);
- **pipelined** (``pipelined``, default): the fits chosen on frame k run on the workers while the
  caller judges frame k (cues, tracking) and this thread detects frame k + 1; frame k + 1 takes them
  in (its people fitted on frame k, reported fresh on k + 1's boxes), so the two cores work at once
  instead of the detection waiting for the fits. A new person is reported one frame after the
  detector first boxes them; a stream's first frame waits for its own fits. ``pipelined=False``: the
  fits of frame k run beside its own detection and are waited for (the schedule before);
- the **geometry gate** (:mod:`~trustnav.perception.ground_gate`) on new people, the horizon fitted
  over the stream's people; boxes the landmark model did not confirm are not tried again for
  2 x ``landmark_every`` frames where they stay, boxes under ``min_height_px`` not at all.

Every step is decided in the frame loop (a frame waits for the fits of the frame before, never for
the clock), so an episode is a pure function of its frames (no search thread, nothing
load-dependent); the latency of a frame is one detection plus what is left of the previous frame's
fits.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.detector import PersonDetector
from trustnav.perception.ground_gate import Rejection, gate_boxes
from trustnav.perception.mediapipe_backend import (
    MediaPipeConfig,
    MediaPipePoseBackend,
    box_region,
    one_box_per_person,
)
from trustnav.perception.types import Person, box_iou, check_frame

__all__ = ["REFIT_BACKOFF", "SEARCH_SECONDS", "RealtimeConfig", "RealtimePoseBackend", "modelled_search_frames"]


@dataclass(frozen=True)
class RealtimeConfig:
    """landmark_every: a followed person is fitted again once this many frames have passed since its
    last fit (4 at 15 frames/s: traits refreshed up to 3.75 times a second, 3.3 median on walk_a, inside
    the 2-core budget); max_fits: landmark fits per frame
    at most for followed people (new boxes are always fitted); carry_frames: frames a followed person
    the detector does not box is carried by its velocity; search_frames: None (default) detects on
    every frame, an integer k on one frame in k (the others carry every person by its velocity);
    min_height_px: boxes shorter than this are not fitted (a far crowd's 30-60 px people cost a landmark
    fit each, and the landmark model rarely confirms them): 60 px keeps a 15 frames/s stream inside the
    2-core budget (docs/perception.md, "Real time (issue 35)"); a slower camera can afford less (the
    drive's in-step mode, one frame a second, sets 40 px); a box the landmark model did not confirm
    is not tried again for 2 x ``landmark_every`` frames where it stays; pipelined: the fits of a frame
    run beside the next frame's detection and are reported there (module docstring); detector_input:
    the detector's input's longer side (a multiple of 32; None: the model's 416)."""

    landmark_every: int = 4
    max_fits: int = 3
    carry_frames: int = 4
    search_frames: int | None = None
    min_height_px: float = 60.0
    pipelined: bool = True
    detector_input: int | None = None

    def __post_init__(self) -> None:
        if self.search_frames is not None and (
            isinstance(self.search_frames, bool) or not isinstance(self.search_frames, int) or self.search_frames < 1
        ):
            raise ValueError(f"search_frames must be None (every frame) or an integer >= 1, got {self.search_frames!r}")
        if not isinstance(self.landmark_every, int) or not 1 <= self.landmark_every <= 10:
            raise ValueError(f"landmark_every must be an integer in [1, 10], got {self.landmark_every!r}")
        if not isinstance(self.max_fits, int) or not 0 <= self.max_fits <= 20:
            raise ValueError(f"max_fits must be an integer in [0, 20], got {self.max_fits!r}")
        if not 0.0 <= self.min_height_px <= 1000.0:
            raise ValueError(f"min_height_px must be in [0, 1000], got {self.min_height_px!r}")
        if not isinstance(self.pipelined, bool):
            raise ValueError(f"pipelined must be True or False, got {self.pipelined!r}")
        if self.detector_input is not None and (
            isinstance(self.detector_input, bool)
            or not isinstance(self.detector_input, int)
            or self.detector_input % 32
            or not 128 <= self.detector_input <= 1280
        ):
            raise ValueError(
                f"detector_input must be None (the model's 416) or a multiple of 32 in [128, 1280], "
                f"got {self.detector_input!r}"
            )
        if not isinstance(self.carry_frames, int) or not 0 <= self.carry_frames <= 100:
            raise ValueError(f"carry_frames must be an integer in [0, 100], got {self.carry_frames!r}")


#: Seconds one detection of a whole frame takes on one core of the 2-core machine (YOLOX-Nano on
#: onnxruntime, 22-31 ms at 640x480 quiet; with the landmark fits beside it), the default of
#: :func:`modelled_search_frames`.
SEARCH_SECONDS = 0.05

#: A followed person whose last k refits found no body waits ``landmark_every`` x 2^min(k, this)
#: frames for the next (pipelined schedule): the frame's fits go to people the landmark model can fit
#: (on walk_a traits refreshed 4.0 times a second, median, instead of 3.57; the same labelled recall).
REFIT_BACKOFF = 2


def modelled_search_frames(fps: float, search_seconds: float = SEARCH_SECONDS) -> int:
    """The frames a detection of ``search_seconds`` spans in a stream of ``fps`` frames/s (at least 1):
    ``RealtimeConfig.search_frames`` for a run that detects only as often as the machine could."""
    if not (math.isfinite(fps) and fps > 0 and math.isfinite(search_seconds) and search_seconds > 0):
        raise ValueError(f"fps and search_seconds must be positive, got {fps!r} and {search_seconds!r}")
    return max(1, math.ceil(search_seconds * fps - 1e-9))


@dataclass
class _Followed:
    """A person followed from frame to frame."""

    fitted: Person  # as last fitted (its box the detector's of that frame)
    fitted_at: int  # frame index of that fit
    roi: NDArray[np.float64]  # the landmark model's region for the next fit
    box: NDArray[np.float64]  # this frame's box (detected or carried)
    seen_at: int  # last frame the detector boxed it
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))  # box centre, px per frame
    person: Person | None = None
    fresh_at: int = -1  # frame on which its latest accepted fit was reported (pipelined: one frame after it)
    failed: int = 0  # refits in a row that found no body


class RealtimePoseBackend(MediaPipePoseBackend):
    """Pose backend for streams: the detector on every frame, landmarks staggered (module docstring).

    Always in video mode; call :meth:`reset` between streams and :meth:`close` at the end.
    ``stats`` gives the frames, fits per frame and the detector's mean time.
    """

    def __init__(self, config: MediaPipeConfig | None = None, realtime: RealtimeConfig | None = None) -> None:
        config = replace(config or MediaPipeConfig(), workers=2)
        super().__init__(config, video=True)
        # mediapipe 0.10.14 warns on every graph call (protobuf's GetPrototype); with two workers a
        # scoped filter is not thread-safe, so this one message is ignored for the process
        warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype", category=UserWarning)
        self.realtime = realtime or RealtimeConfig()
        # the network input shaped to the frame (416 x 320 for 640 x 480: ~0.8 of the square's time)
        self.detector = PersonDetector(
            config.detector_model,
            min_score=config.detector_min_score,
            input_size=self.realtime.detector_input,
            fit_aspect=True,
        )
        self._people: list[_Followed] = []
        self._unconfirmed: list[tuple[int, NDArray[np.float64]]] = []  # (frame, box) the landmarks refused
        self._fits: list[int] = []
        self._detect_s: list[float] = []
        # pipelined: (frame index, jobs, futures) of the fits submitted on the latest frame
        self._batch: tuple[int, list[tuple], list[Any]] | None = None

    def reset(self) -> None:
        """Forget the people followed and the fitted horizon (call between streams)."""
        self._drop_batch()
        self._people = []
        self._unconfirmed = []
        super().reset()

    def close(self) -> None:
        """Wait for the fits in flight, then stop the workers and release the graphs."""
        self._drop_batch()
        super().close()

    def _drop_batch(self) -> None:
        if self._batch is not None:
            for fut in self._batch[2]:
                fut.exception()  # waits; the graphs go back to the pool
        self._batch = None

    @property
    def stats(self) -> dict[str, float]:
        """Frames, landmark fits per frame (mean) and the detector's mean seconds per frame."""
        return {
            "frames": len(self._fits),
            "fits_per_frame": float(np.mean(self._fits)) if self._fits else math.nan,
            "detect_mean_s": float(np.mean(self._detect_s)) if self._detect_s else math.nan,
            # kept for callers of the former searching design: a detection is this design's search
            "searches": len(self._detect_s),
            "search_mean_s": float(np.mean(self._detect_s)) if self._detect_s else math.nan,
        }

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People in ``frame`` (H x W x 3 uint8 RGB): detected boxes, fitted or carried keypoints."""
        assert self.detector is not None
        frame = check_frame(frame)
        if self.realtime.pipelined:
            return self._pipelined(frame)
        h, w = frame.shape[:2]
        index = self._frame_index
        cfg = self.realtime
        t0 = time.perf_counter()
        for f in self._people:  # where each followed person should be now
            f.box = _shifted(f.box, f.velocity, w, h)
        # followed people due a fit, the most overdue first: fitted on their own region (moved by their
        # velocity) on the two workers while the detector runs on this thread
        due = sorted(
            (i for i, f in enumerate(self._people) if index - f.fitted_at >= cfg.landmark_every),
            key=lambda i: self._people[i].fitted_at,
        )[: cfg.max_fits]
        for i in due:
            f = self._people[i]
            f.roi = f.roi.copy()
            f.roi[:2] += f.velocity * (index - f.fitted_at)
        pending = [
            self._submit(
                lambda g, f: self._confirm(g, frame, f.roi[None, :], f.fitted.score, f.box, w, h), self._people[i]
            )
            for i in due
        ]
        detect = cfg.search_frames is None or index % cfg.search_frames == 0 or not self._people
        boxes, scores = self.detector(frame) if detect else (np.zeros((0, 4)), np.zeros(0))
        t1 = time.perf_counter()
        if detect:
            self._detect_s.append(t1 - t0)
        new = self._match_boxes(boxes, index)
        # new boxes, the largest (nearest) first, in what is left of the frame's fits (at least one)
        new.sort(key=lambda j: boxes[j][1] - boxes[j][3])
        new = new[: max(1, cfg.max_fits - len(due)) if cfg.max_fits else 0]
        jobs = [("new", j, self._regions(boxes[j], []), float(scores[j]), boxes[j]) for j in new]
        results = self._map(lambda g, job: self._confirm(g, frame, job[2], job[3], job[4], w, h), jobs)
        for i, fut in zip(due, pending, strict=True):
            f, res = self._people[i], fut.result()
            f.fitted_at = index  # a failed fit keeps its last keypoints; tried again in landmark_every
            if res is not None and box_iou(res[3].bbox, f.box) >= 0.3:
                # the fit's box is the predicted one; where the detector boxed the person, its box
                bbox = res[3].bbox if f.seen_at != index else f.box
                f.fitted, f.roi = replace(res[3], bbox=np.asarray(bbox, dtype=np.float64).copy()), res[1]
        t2 = time.perf_counter()
        rejected: list[Rejection] = []
        fresh: list[_Followed] = []
        for (_, _, _, score, box), res in zip(jobs, results, strict=True):
            if res is None:
                self._unconfirmed.append((index, np.asarray(box, dtype=np.float64)))
                rejected.append(Rejection(tuple(map(float, box)), score, "the landmark model found no upright person"))
                continue
            fresh.append(_Followed(res[3], index, res[1], np.asarray(box, dtype=np.float64), index))
        if fresh and self.config.geometry_gate:
            ok, gated = gate_boxes([f.box for f in fresh], [f.fitted.score for f in fresh], (w, h),
                                   camera=self.camera, fit=self.horizon)  # fmt: skip
            rejected += gated
            for r in gated:
                self._unconfirmed.append((index, np.asarray(r.bbox)))
            fresh = [fresh[i] for i in ok]
        # followed people lost for longer than carry_frames are dropped
        self._people = [f for f in self._people if index - f.seen_at <= cfg.carry_frames] + fresh
        for f in self._people:
            f.person = _carried(f, index, w, h)
        keep = one_box_per_person([f.person for f in self._people], self.config.duplicate_iou)
        self._people = [self._people[i] for i in keep]
        self._fits.append(len(jobs) + len(due))
        self.last_rejections = rejected
        self.last_timing = {"detection": t1 - t0, "landmarks": t2 - t1}
        self._frame_index += 1
        return [f.person for f in self._people]

    def _match_boxes(self, boxes: NDArray[np.float64], index: int) -> list[int]:
        """The frame's detector ``boxes`` met with the followed people (a matched person takes its box,
        its velocity smoothed); returns the new boxes worth a fit: tall enough (``min_height_px``) and not
        refused by the landmark model in the last 2 x ``landmark_every`` frames."""
        cfg = self.realtime
        matched, new = _associate([f.box for f in self._people], boxes)
        for i, j in matched.items():
            f = self._people[i]
            centre = _centre(boxes[j]) - _centre(f.box) + f.velocity
            f.velocity = 0.5 * f.velocity + 0.5 * _capped(centre, boxes[j])
            f.box, f.seen_at = boxes[j].astype(np.float64), index
        self._unconfirmed = [(k, b) for k, b in self._unconfirmed if index - k < 2 * cfg.landmark_every]
        return [
            j for j in new
            if boxes[j][3] - boxes[j][1] >= cfg.min_height_px
            and not any(box_iou(boxes[j], b) >= 0.5 for _, b in self._unconfirmed)
        ]  # fmt: skip

    def _pipelined(self, frame: NDArray[np.uint8]) -> list[Person]:
        """``RealtimeConfig.pipelined``: the landmark fits chosen on frame k run on the two workers while the
        caller judges frame k and this thread detects frame k + 1; they are taken in on frame k + 1, the
        fitted keypoints moved onto that frame's boxes (module docstring)."""
        assert self.detector is not None
        h, w = frame.shape[:2]
        index = self._frame_index
        cfg = self.realtime
        t0 = time.perf_counter()
        for f in self._people:
            f.box = _shifted(f.box, f.velocity, w, h)
        detect = cfg.search_frames is None or index % cfg.search_frames == 0 or not self._people
        boxes, scores = self.detector(frame) if detect else (np.zeros((0, 4)), np.zeros(0))
        t1 = time.perf_counter()
        if detect:
            self._detect_s.append(t1 - t0)
        rejected: list[Rejection] = []
        self._people += self._take_batch(index, w, h, rejected)  # the fits of the frame before
        t2 = time.perf_counter()
        new = self._match_boxes(boxes, index)
        self._people = [f for f in self._people if index - f.seen_at <= cfg.carry_frames]
        # this frame's fits: the most overdue followed people, then new boxes, the largest first, in what
        # is left of max_fits (at least one)
        due = sorted(
            (
                f
                for f in self._people
                if index - f.fitted_at >= cfg.landmark_every * (1 << min(f.failed, REFIT_BACKOFF))
            ),
            key=lambda f: f.fitted_at,
        )[: cfg.max_fits]
        new.sort(key=lambda j: boxes[j][1] - boxes[j][3])
        new = new[: max(1, cfg.max_fits - len(due)) if cfg.max_fits else 0]
        jobs: list[tuple] = []
        for f in due:
            roi = f.roi.copy()
            roi[:2] += f.velocity * (index - f.fitted_at)
            seen = f.seen_at == index
            # the region its last fit gives, then (where the detector boxed it now) its box's own square:
            # some people (one seen from behind) the first does not fit in most frames, the second does
            rois = np.vstack([roi, box_region(f.box, self.config.region_scale)]) if seen else roi[None, :]
            jobs.append((f, rois, f.fitted.score, f.box.copy(), seen))
        jobs += [(None, self._regions(boxes[j], []), float(scores[j]), boxes[j].astype(np.float64), True) for j in new]
        image = frame.copy()  # the caller may reuse its buffer while the workers read this one
        futures = [
            self._submit(lambda g, job: self._confirm(g, image, job[1], job[2], job[3], w, h), job) for job in jobs
        ]
        self._batch = (index, jobs, futures)
        if not self._people:  # nobody followed (a stream's first frame): this frame waits for its fits
            self._people = self._take_batch(index, w, h, rejected)
        for f in self._people:
            f.person = _carried(f, index, w, h)
        keep = one_box_per_person([f.person for f in self._people], self.config.duplicate_iou)
        self._people = [self._people[i] for i in keep]
        self._fits.append(len(jobs))
        self.last_rejections = rejected
        self.last_timing = {"detection": t1 - t0, "landmarks": t2 - t1}
        self._frame_index += 1
        return [f.person for f in self._people]

    def _take_batch(self, index: int, w: int, h: int, rejected: list[Rejection]) -> list[_Followed]:
        """Wait for the fits submitted on the frame before; refits update their person (a failed one
        keeps its last keypoints and is tried again in ``landmark_every`` frames), confirmed new boxes
        that pass the geometry gate are returned as people followed from now on."""
        if self._batch is None:
            return []
        at, jobs, futures = self._batch
        self._batch = None
        fresh: list[_Followed] = []
        for (f, _, score, box, seen), fut in zip(jobs, futures, strict=True):
            res = fut.result()
            if f is not None:  # a refit
                f.fitted_at = at
                f.failed += 1
                if res is not None and box_iou(res[3].bbox, box) >= 0.3:
                    bbox = box if seen else res[3].bbox  # where the detector boxed the person, its box
                    f.fitted, f.roi = replace(res[3], bbox=np.asarray(bbox, dtype=np.float64).copy()), res[1]
                    f.fresh_at, f.failed = index, 0
            elif res is None:
                self._unconfirmed.append((at, box))
                rejected.append(Rejection(tuple(map(float, box)), score, "the landmark model found no upright person"))
            else:
                fresh.append(_Followed(res[3], at, res[1], box.copy(), at, fresh_at=index))
        if fresh and self.config.geometry_gate:
            ok, gated = gate_boxes([f.box for f in fresh], [f.fitted.score for f in fresh], (w, h),
                                   camera=self.camera, fit=self.horizon)  # fmt: skip
            rejected += gated
            self._unconfirmed += [(at, np.asarray(r.bbox)) for r in gated]
            fresh = [fresh[i] for i in ok]
        return fresh


def _associate(predicted: list[NDArray[np.float64]], boxes: NDArray[np.float64]) -> tuple[dict[int, int], list[int]]:
    """Followed person -> this frame's box (Hungarian on IoU, >= 0.3), and the boxes nobody follows."""
    if not predicted or not len(boxes):
        return {}, list(range(len(boxes)))
    from scipy.optimize import linear_sum_assignment

    iou = np.array([[box_iou(p, b) for b in boxes] for p in predicted])
    rows, cols = linear_sum_assignment(-iou)
    matched = {int(r): int(c) for r, c in zip(rows, cols, strict=True) if iou[r, c] >= 0.3}
    taken = set(matched.values())
    # a box lying mostly on a followed person's (a second box on one person) is not a new person
    new = [j for j in range(len(boxes)) if j not in taken and iou[:, j].max() < 0.5]
    return matched, new


def _centre(box: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2])


def _capped(v: NDArray[np.float64], box: NDArray[np.float64]) -> NDArray[np.float64]:
    """A velocity (px per frame) capped at a tenth of the box's height."""
    cap = 0.1 * float(box[3] - box[1])
    speed = float(np.hypot(*v))
    return v if speed <= cap else v * (cap / speed)


def _shifted(box: NDArray[np.float64], v: NDArray[np.float64], w: int, h: int) -> NDArray[np.float64]:
    out = box + np.r_[v, v]
    dx = -min(0.0, out[0]) - max(0.0, out[2] - (w - 1))
    dy = -min(0.0, out[1]) - max(0.0, out[3] - (h - 1))
    return out + np.array([dx, dy, dx, dy])


def _carried(f: _Followed, index: int, w: int, h: int) -> Person:
    """This frame's person of ``f``: its fit if fitted now, else the last fit's keypoints moved and
    scaled from that fit's box onto this frame's box (``extra["carried"]``; ``extra["predicted"]``
    when the detector did not box the person on this frame either)."""
    p = f.fitted
    fresh = f.fresh_at == index or (f.fitted_at == index and np.allclose(p.bbox, f.box))
    if fresh and np.allclose(p.bbox, f.box):
        return p
    old, new = p.bbox, f.box
    sx = (new[2] - new[0]) / max(old[2] - old[0], 1e-6)
    sy = (new[3] - new[1]) / max(old[3] - old[1], 1e-6)
    scale = np.array([sx, sy])

    def move(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        return (xy - old[:2]) * scale + new[:2]

    extra = dict(p.extra)
    if "blazepose" in extra:
        lm = extra["blazepose"].copy()
        lm[:, :2] = move(lm[:, :2])
        extra["blazepose"] = lm
    if not fresh:
        extra["carried"] = True
    if f.seen_at != index:
        extra["predicted"] = True
    return Person(bbox=new.copy(), keypoints=move(p.keypoints), confidences=p.confidences, score=p.score, extra=extra)
