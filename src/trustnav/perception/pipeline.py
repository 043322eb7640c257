"""Frame -> tracked people with trait confidences -> `trustnav.trust` observations and trust.

:class:`PerceptionPipeline` runs one frame: pose backend, tracker, eye contact (LOOKING on the
17 keypoints and their occlusion-aware confidences) and smartphone use; :meth:`observations` turns
the result into :class:`~trustnav.trust.estimator.Observation` s stamped with the frame's time, so the
trust estimator updates a track when, and only when, that person is seen. :func:`estimate` runs a
whole sequence, one bad frame never stopping it.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from numbers import Real

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.frames import FrameItem
from trustnav.perception.looking import LookingModel, normalise_keypoints
from trustnav.perception.phone import PhoneClassifier, PoseGeometryPhoneClassifier
from trustnav.perception.tracking import PersonTracker
from trustnav.perception.types import Person, PoseBackend, check_frame
from trustnav.trust.estimator import Observation, TrustEstimator

__all__ = ["FrameResult", "PerceptionPipeline", "TrackedPerson", "estimate"]


@dataclass(frozen=True)
class TrackedPerson:
    """A person of one frame with its track ID and trait confidences (C_eye, C_sm)."""

    track_id: int
    person: Person
    eye_contact: float
    phone: float


@dataclass
class FrameResult:
    """Everything `trustnav estimate` reports for one frame."""

    name: str
    index: int
    time: float
    people: list[TrackedPerson] = field(default_factory=list)
    records: list[dict] = field(default_factory=list)
    error: str | None = None
    timing: dict[str, float] = field(default_factory=dict)
    rgb: NDArray[np.uint8] | None = field(default=None, repr=False)


class PerceptionPipeline:
    """Pose backend + tracker + eye-contact model + phone classifier, one frame at a time."""

    def __init__(
        self,
        backend: PoseBackend,
        tracker: PersonTracker,
        eye_model: LookingModel,
        phone: PhoneClassifier | None = None,
    ) -> None:
        if not callable(backend):
            raise ValueError(f"backend must be a pose backend (callable on a frame), got {type(backend).__name__}")
        if not hasattr(tracker, "update"):
            raise ValueError(f"tracker must be a PersonTracker, got {type(tracker).__name__}")
        if not hasattr(eye_model, "predict"):
            raise ValueError(f"eye_model must be a LookingModel (with predict), got {type(eye_model).__name__}")
        self.backend = backend
        self.tracker = tracker
        self.eye_model = eye_model
        self.phone = phone or PoseGeometryPhoneClassifier()
        self.last_timing: dict[str, float] = {}

    def __call__(self, frame: NDArray[np.uint8]) -> list[TrackedPerson]:
        frame = check_frame(frame)
        t0 = _time.perf_counter()
        people = self.backend(frame)
        t1 = _time.perf_counter()
        if people:
            inputs = np.stack([normalise_keypoints(p.keypoints, p.confidences, frame.shape[1]) for p in people])
            eye = self.eye_model.predict(inputs)
            phone = [float(self.phone(frame, p)) for p in people]
        else:
            eye, phone = np.zeros(0), []
        t2 = _time.perf_counter()
        ids = self.tracker.update(people)
        t3 = _time.perf_counter()
        self.last_timing = dict(getattr(self.backend, "last_timing", {}) or {"pose": t1 - t0})
        self.last_timing.update(traits=t2 - t1, tracking=t3 - t2)
        return [
            TrackedPerson(tid, p, float(e), ph)
            for tid, p, e, ph in zip(ids, people, eye, phone, strict=True)
            if tid >= 0
        ]

    @staticmethod
    def observations(people: Iterable[TrackedPerson], time: float) -> list[Observation]:
        """One trust observation per tracked person (traits `smato_score`, `eye_score`, `pose_conf`)."""
        return [
            Observation(
                track_id=tp.track_id,
                time=time,
                c_smartphone=tp.phone,
                c_eye=tp.eye_contact,
                keypoints=tp.person.keypoints,
                bbox=tp.person.bbox,
            )
            for tp in people
        ]


def _num(x: float | None) -> float | None:
    """Rounded number, or None for a value not available (JSON has no NaN)."""
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


def _record(name: str, tp: TrackedPerson, estimator: TrustEstimator, sequence: str | None = None) -> dict:
    st = estimator.tracks[tp.track_id]
    rec = {
        "frame": name,
        "track_id": tp.track_id,
        "bbox": [round(float(v), 1) for v in tp.person.bbox],
        "eye_contact": _num(tp.eye_contact),
        "phone": _num(tp.phone),
        "fluctuation": _num(st.fluctuation),
        "smartphone_trait": _num(st.smartphone),
        "eye_trait": _num(st.eye),
        "pose_trait": _num(st.pose),
        "score": _num(st.score),
        "trust": _num(st.trust),
    }
    if sequence is not None:
        rec["sequence"] = sequence
    return rec


def estimate(
    frames: Iterable[FrameItem],
    pipeline: PerceptionPipeline,
    estimator: TrustEstimator,
    fps: float,
    on_error: Callable[[FrameResult], None] | None = None,
    sequence: str | None = None,
) -> Iterator[FrameResult]:
    """Run perception and trust over one sequence; frame k is at time k / fps seconds.

    A frame that cannot be read, or on which perception fails, yields a FrameResult with ``error``
    set (and is passed to ``on_error``); the sequence goes on. With ``sequence`` every record
    carries it (the sequence's label).
    """
    if isinstance(fps, bool) or not isinstance(fps, Real) or not 0 < fps < math.inf:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    for item in frames:
        t = item.index / fps
        result = FrameResult(item.name, item.index, t, rgb=item.frame)
        if item.frame is None:
            result.error = item.error or "unreadable frame"
        else:
            try:
                result.people = pipeline(item.frame)
                estimator.update(pipeline.observations(result.people, t), time=t)
                result.records = [_record(item.name, tp, estimator, sequence) for tp in result.people]
                result.timing = dict(pipeline.last_timing)
            except Exception as exc:  # one bad frame never stops the sequence
                result.people, result.records = [], []
                result.error = f"perception failed on {item.name}: {type(exc).__name__}: {exc}"
        if result.error is not None and on_error is not None:
            on_error(result)
        yield result
