"""Perception and trust over planned input sequences, frame by frame (what `trustnav estimate` runs).

:func:`estimate_sequences` wires frames to trust: for each sequence planned by
:func:`trustnav.perception.frames.plan_sequences` (images, a folder, a video or one live source) a
fresh tracker, cue extractors and trust estimator (``agg_trust``: no track or trust state crosses
two sequences), the backend reset, then :func:`trustnav.perception.pipeline.estimate` frame by
frame. It yields one :class:`EstimatedFrame` per frame read (a frame that failed carries its
``error`` and the run goes on) and writes nothing: the caller writes tables and pictures.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from trustnav.perception.frames import iter_sequence, source_fps
from trustnav.perception.live import frames_due
from trustnav.perception.phone import phone_label
from trustnav.perception.pipeline import FrameResult, PerceptionPipeline, estimate
from trustnav.perception.tracking import PersonTracker
from trustnav.trust.estimator import TrustEstimator
from trustnav.trust.params import SECONDS_TRUST, TrustParams

__all__ = ["EstimatedFrame", "estimate_sequences"]


@dataclass
class EstimatedFrame:
    """One frame of :func:`estimate_sequences`: its planned ``sequence``, that sequence's rate
    ``fps``, the frame's :class:`FrameResult` (``error`` set: the frame was skipped), the label
    drawn beside each person (phone N/U/Y, the distance when placed on the ground), the detector
    boxes the backend rejected on it (dicts, with ``sequence`` and ``frame``) and how many times to
    write it into a video that plays in real time (live input: the frames due since the last one;
    else 1)."""

    sequence: Any
    fps: float
    result: FrameResult
    labels: list[str] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)
    repeat: int = 1


def estimate_sequences(
    sequences: Sequence[Any],
    backend: Any,
    eye: Any = None,
    *,
    face: Any = None,
    face_config: Any = None,
    trust: TrustParams = SECONDS_TRUST,
    fps: float = 10.0,
    ground: Any = None,
    max_frames: int | None = None,
    max_seconds: float | None = None,
    live: Any = None,
    on_stream_end: Callable[[str], None] | None = None,
    max_gap: float = 5.0,
) -> Iterator[EstimatedFrame]:
    """Perception and trust over ``sequences``, one sequence after another.

    Parameters
    ----------
    sequences : planned inputs (``kind``, ``label``, ``files``, ``has_video``).
    backend : pose backend (``reset()``, ``last_rejections`` and ``close()`` used when it has them;
        the caller closes it).
    eye : eye-contact model (LOOKING, the default cues); ``face``: a
        :class:`~trustnav.perception.face.FaceEyeContact` fused with it (shared by the sequences);
        without it, ``face_config`` (a :class:`~trustnav.perception.face.FaceConfig`) configures the
        default cues' face analysis (offline ``trustnav estimate``: the shifted fits of small faces).
    trust : the trust law (``lin_comb``, ``agg_trust``); a fresh estimator per sequence.
    fps : rate of image sequences (videos: their own; live: the source's, else this).
    ground : a :class:`~trustnav.perception.localisation.FixedCameraGround`: each record gets its
        ground fields and each label its distance.
    max_frames, max_seconds : stop each sequence after so many frames (live: seconds).
    live : the opened :class:`~trustnav.perception.live.LiveSource` of a ``live`` sequence (closed
        when its sequence ends); ``on_stream_end(message)`` when it stopped sending; ``max_gap``:
        the most seconds of video one frame fills (a jump in a stream's clock writes no more).
    """
    for seq in sequences:
        source = live if seq.kind == "live" else None
        if source is not None:
            rate = source.fps or fps
            items = source.frames(max_frames, max_seconds)
        else:
            rate = source_fps(list(seq.files), fps) if seq.has_video else fps
            items = itertools.islice(iter_sequence(seq.files), max_frames)
        if hasattr(backend, "reset"):
            backend.reset()  # nothing followed from the previous sequence
        tracker = PersonTracker(fps=rate)
        if face is None and face_config is None:
            pipeline = PerceptionPipeline(backend, tracker, eye)
        elif face is None:
            from trustnav.perception.cues import default_cues

            pipeline = PerceptionPipeline(backend, tracker, cues=default_cues(eye, face=face_config))
        else:  # eye contact from the face too, fused with LOOKING
            from trustnav.perception.cues import default_cues, with_face

            pipeline = PerceptionPipeline(backend, tracker, cues=with_face(default_cues(eye), face))
        t_first, written, most = None, 0, max(1, round(rate * max_gap))
        try:
            for res in estimate(items, pipeline, TrustEstimator(trust), rate, None, seq.label):
                if res.error is not None:
                    yield EstimatedFrame(seq, rate, res)
                    continue
                labels = [phone_label(tp.phone) for tp in res.people]
                if ground is not None:  # where each person stands, from the camera's height
                    h, w = res.rgb.shape[:2]
                    for rec, tp in zip(res.records, res.people, strict=True):
                        rec.update(ground.fields(tp.person, w, h))
                    labels = [lab if r["distance_m"] is None else f"{lab} {r['distance_m']:.1f} m"
                              for lab, r in zip(labels, res.records, strict=True)]  # fmt: skip
                rejected = [{"sequence": seq.label, "frame": res.name, **r.as_dict()}
                            for r in getattr(backend, "last_rejections", [])]  # fmt: skip
                repeat = 1
                if source is not None:  # the video plays in real time at the rate achieved
                    t_first = res.time if t_first is None else t_first
                    repeat = frames_due(res.time, t_first, rate, written, most)
                    written += repeat
                yield EstimatedFrame(seq, rate, res, labels, rejected, repeat)
        except TimeoutError as exc:  # a live stream that stopped sending: the end of that stream
            if on_stream_end is not None:
                on_stream_end(str(exc))
        finally:
            if source is not None:
                source.close()
