"""Frame -> tracked people with trait confidences -> `trustnav.trust` observations and trust.

:class:`PerceptionPipeline` runs one frame: pose backend, tracker and the trait cues, a list of
cue extractors (:mod:`~trustnav.perception.cues`; by default eye contact, LOOKING on the 17
keypoints and their occlusion-aware confidences, and smartphone use); :meth:`observations` turns
the result into :class:`~trustnav.trust.sighting.Sighting` s stamped with the frame's time,
so the trust estimator updates a track when, and only when, that person is seen. :func:`estimate`
runs a whole sequence, one bad frame never stopping it.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable, Container, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from numbers import Real
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.cues import CueExtractor, EyeContactCue, PhoneUseCue, check_cues, default_cues, run_cue
from trustnav.perception.frames import FrameItem
from trustnav.perception.looking import LookingModel
from trustnav.perception.phone import PhoneClassifier
from trustnav.perception.tracking import PersonTracker
from trustnav.perception.types import Person, PoseBackend, check_frame
from trustnav.trust.estimator import TrustEstimator
from trustnav.trust.sighting import EYE_CONTACT, SMARTPHONE, Sighting

__all__ = ["FrameResult", "PerceptionPipeline", "TrackedPerson", "estimate"]


@dataclass(frozen=True)
class TrackedPerson:
    """A person of one frame with its track ID and trait confidences: C_eye, C_sm (NaN when no cue
    extractor gives them) and ``cues``, every other cue's confidence by name."""

    track_id: int
    person: Person
    eye_contact: float
    phone: float
    cues: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))


def _given(c: float) -> float | None:
    return None if math.isnan(c) else c


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
    """Pose backend + tracker + cue extractors (eye contact, phone use, ...), one frame at a time.

    Either ``eye_model`` (and optionally ``phone``) for the paper's two cues, or ``cues``, the whole
    list of extractors, e.g. ``[*default_cues(eye_model), HeadTurnedCue()]``.
    """

    def __init__(
        self,
        backend: PoseBackend,
        tracker: PersonTracker,
        eye_model: LookingModel | None = None,
        phone: PhoneClassifier | None = None,
        *,
        cues: Sequence[CueExtractor] | None = None,
    ) -> None:
        if not callable(backend):
            raise ValueError(f"backend must be a pose backend (callable on a frame), got {type(backend).__name__}")
        if not hasattr(tracker, "add_frame"):
            raise ValueError(f"tracker must be a PersonTracker, got {type(tracker).__name__}")
        if cues is None:
            if not hasattr(eye_model, "predict"):
                raise ValueError(f"eye_model must be a LookingModel (with predict), got {type(eye_model).__name__}")
            cues = default_cues(eye_model, phone)
        elif eye_model is not None or phone is not None:
            raise ValueError("pass either eye_model/phone (the paper's cues) or cues (every extractor), not both")
        self.backend = backend
        self.tracker = tracker
        self.cues = check_cues(cues)
        self.eye_model = next((c.model for c in self.cues if isinstance(c, EyeContactCue)), None)
        self.phone = next((c.classifier for c in self.cues if isinstance(c, PhoneUseCue)), None)
        self.last_timing: dict[str, float] = {}
        self._last_values: dict[int, dict[str, float]] = {}  # per track, its latest judged cue values

    def __call__(self, frame: NDArray[np.uint8], time: float | None = None) -> list[TrackedPerson]:
        """Tracked people of ``frame``; ``time`` (seconds) lets temporal cues (phone use over time)
        follow each track; without it they judge the frame alone."""
        frame = check_frame(frame)
        t0 = _time.perf_counter()
        people = self.backend(frame)
        t1 = _time.perf_counter()
        ids = self.tracker.add_frame(people)
        t2 = _time.perf_counter()
        values = self._cue_values(frame, people, ids, time)
        t3 = _time.perf_counter()
        self.last_timing = dict(getattr(self.backend, "last_timing", {}) or {"pose": t1 - t0})
        self.last_timing.update(traits=t3 - t2, tracking=t2 - t1)
        nan = [math.nan] * len(people)
        eye, phone = values.get(EYE_CONTACT, nan), values.get(SMARTPHONE, nan)
        others = [name for name in values if name not in (EYE_CONTACT, SMARTPHONE)]
        return [
            TrackedPerson(tid, p, eye[i], phone[i], MappingProxyType({n: values[n][i] for n in others}))
            for i, (tid, p) in enumerate(zip(ids, people, strict=True))
            if tid >= 0
        ]

    def _cue_values(
        self, frame: NDArray[np.uint8], people: list[Person], ids: list[int], time: float | None
    ) -> dict[str, list[float]]:
        """Each cue's values per person. People whose keypoints the real-time backend carried from an
        earlier fit (``extra["carried"]``) are not judged again: they show their track's last values."""
        fresh = [i for i, p in enumerate(people) if not p.extra.get("carried")]
        if not fresh:
            values: dict[str, list[float]] = {c.name: [math.nan] * len(people) for c in self.cues} if people else {}
        else:
            sub = [people[i] for i in fresh]
            sub_ids = [ids[i] for i in fresh]
            judged = {c.name: run_cue(c, frame, sub, track_ids=sub_ids, time=time) for c in self.cues}
            values = {name: [math.nan] * len(people) for name in judged}
            for name, vs in judged.items():
                for i, v in zip(fresh, vs, strict=True):
                    values[name][i] = v
        for i, (p, tid) in enumerate(zip(people, ids, strict=True)):
            if tid < 0:
                continue
            if p.extra.get("carried"):
                for name, v in self._last_values.get(tid, {}).items():
                    if name in values:
                        values[name][i] = v
            else:
                self._last_values[tid] = {name: vs[i] for name, vs in values.items()}
        return values

    @staticmethod
    def sightings(people: Iterable[TrackedPerson], time: float, known: Container[int] | None = None) -> list[Sighting]:
        """One trust observation per tracked person (cues of `smato_score`, `eye_score` and any
        other trait; keypoints and box for `pose_conf`). A NaN cue is left out (missing). A person
        whose keypoints the real-time backend carried (``extra["carried"]``) was not judged on this
        frame: no observation (the same evidence is not counted twice), unless its track is not
        among ``known`` (the tracks trust already has; the tracker gave it a new ID)."""
        return [
            Sighting(
                track_id=tp.track_id,
                time=time,
                c_smartphone=_given(tp.phone),
                c_eye=_given(tp.eye_contact),
                keypoints=tp.person.keypoints,
                bbox=tp.person.bbox,
                cues={n: c for n, c in tp.cues.items() if not math.isnan(c)},
            )
            for tp in people
            if not tp.person.extra.get("carried") or (known is not None and tp.track_id not in known)
        ]


def _num(x: float | None) -> float | None:
    """Rounded number, or None for a value not available (JSON has no NaN)."""
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


def _record(name: str, tp: TrackedPerson, estimator: TrustEstimator, sequence: str | None = None) -> dict:
    st = estimator.tracks.get(tp.track_id)
    if st is None:  # carried on from a fit but never measured under this track ID: no trust yet
        none = dict.fromkeys(("fluctuation", "smartphone_trait", "eye_trait", "pose_trait", "score", "trust"))
        rec = {"frame": name, "track_id": tp.track_id, "bbox": [round(float(v), 1) for v in tp.person.bbox],
               "eye_contact": _num(tp.eye_contact), "phone": _num(tp.phone), **none}  # fmt: skip
        return rec if sequence is None else {**rec, "sequence": sequence}
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
    # cues and traits beyond the paper's (only with a user's cue extractors or trait set)
    rec.update({name: _num(c) for name, c in tp.cues.items()})
    paper = (SMARTPHONE, EYE_CONTACT, "pose_fluctuation")
    rec.update({f"{name}_trait": _num(v) for name, v in st.values.items() if name not in paper})
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
    """Run perception and trust over one sequence; frame k is at time k / fps seconds, or at its
    own capture time when the frame carries one (live input).

    A frame that cannot be read, or on which perception fails, yields a FrameResult with ``error``
    set (and is passed to ``on_error``); the sequence goes on. With ``sequence`` every record
    carries it (the sequence's label).
    """
    if isinstance(fps, bool) or not isinstance(fps, Real) or not 0 < fps < math.inf:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    for item in frames:
        t = item.time if item.time is not None else item.index / fps
        result = FrameResult(item.name, item.index, t, rgb=item.frame)
        if item.frame is None:
            result.error = item.error or "unreadable frame"
        else:
            try:
                result.people = pipeline(item.frame, time=t)
                # a person the real-time backend only carried by its velocity was not measured on
                # this frame: reported, but no evidence for trust
                measured = [tp for tp in result.people if not tp.person.extra.get("predicted")]
                estimator.add_frame(pipeline.sightings(measured, t, known=estimator.tracks), time=t)
                result.records = [_record(item.name, tp, estimator, sequence) for tp in result.people]
                result.timing = dict(pipeline.last_timing)
            except Exception as exc:  # one bad frame never stops the sequence
                result.people, result.records = [], []
                result.error = f"perception failed on {item.name}: {type(exc).__name__}: {exc}"
        if result.error is not None and on_error is not None:
            on_error(result)
        yield result
