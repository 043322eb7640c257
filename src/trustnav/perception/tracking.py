"""Multi-person tracking: stable integer IDs from the ``trackers`` package (pinned 2.6.1).

Default OC-SORT: on the shared walking sequence it kept one ID for a pedestrian passing in front of
another where ByteTrack (also available) swapped them, because OC-SORT also weighs the direction of
motion. Both give a new track its ID only from its second frame; trustnav needs one from the first
(a single still image must report its people, and the trust estimator counts every observation), so
a track spawned by this frame's detection gets its ID at once. This touches the tracker's tracklet
list, hence the exact pin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from trustnav.perception.types import Person
from trustnav.trust.params import as_number

__all__ = ["PersonTracker", "TrackerConfig"]

ALGORITHMS = ("ocsort", "bytetrack")


@dataclass(frozen=True)
class TrackerConfig:
    """algorithm: 'ocsort' or 'bytetrack'. lost_seconds: how long a track that disappeared keeps its
    ID for a return. min_iou: association threshold (low: at a few frames per second a walker's box
    moves by much of its width between frames). high_confidence: detections at or above it are
    'high' in the trackers' two-stage association."""

    algorithm: str = "ocsort"
    lost_seconds: float = 2.0
    min_iou: float = 0.02
    high_confidence: float = 0.4

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {self.algorithm!r}")
        if self.lost_seconds < 0:
            raise ValueError(f"lost_seconds must be >= 0, got {self.lost_seconds!r}")
        for name in ("min_iou", "high_confidence"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {v!r}")


class PersonTracker:
    """Assigns a track ID to every person of each frame (call :meth:`update` once per frame, in order)."""

    def __init__(self, config: TrackerConfig | None = None, fps: float = 10.0) -> None:
        try:
            ok = 0 < as_number("fps", fps) < math.inf
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"fps must be a positive finite number of frames per second, got {fps!r}")
        self.config = config or TrackerConfig()
        self.fps = fps
        try:
            import supervision as sv
            from trackers import ByteTrackTracker, OCSORTTracker
        except ImportError as exc:  # pragma: no cover - exercised only without the dependency
            raise ImportError(
                "tracking needs the `trackers` package: pip install --no-deps trackers==2.6.1 "
                "(its other requirements come with trustnav)"
            ) from exc
        self._sv = sv
        c = self.config
        common = {
            "lost_track_buffer": max(0, round(c.lost_seconds * 30.0)),  # counted in 30 fps frames
            "frame_rate": fps,
            "minimum_consecutive_frames": 1,
            "minimum_iou_threshold": c.min_iou,
            "high_conf_det_threshold": c.high_confidence,
        }
        if c.algorithm == "ocsort":
            self._tracker = OCSORTTracker(**common)
        else:
            self._tracker = ByteTrackTracker(track_activation_threshold=c.high_confidence, **common)

    def add_frame(self, people: list[Person]) -> list[int]:
        """Track ID per person (same order); -1 for a person the tracker did not take on."""
        if not people:
            self._tracker.update(self._sv.Detections.empty())
            return []
        dets = self._sv.Detections(
            xyxy=np.array([p.bbox for p in people], dtype=np.float32),
            confidence=np.array([p.score for p in people], dtype=np.float32),
            class_id=np.zeros(len(people), dtype=int),
            data={"index": np.arange(len(people))},
        )
        out = self._tracker.update(dets)
        ids = [-1] * len(people)
        for idx, tid in zip(out.data["index"], out.tracker_id, strict=True):
            ids[int(idx)] = int(tid)
        # tracks spawned just now: give them their ID on this first frame
        for track in self._tracker.tracks:
            if track.tracker_id != -1:
                continue
            box = np.asarray(track.get_state_bbox(), dtype=float).reshape(-1)
            for i, person in enumerate(people):
                if ids[i] == -1 and np.allclose(box, person.bbox, atol=0.5):
                    track.tracker_id = self._tracker._allocate_tracker_id()
                    ids[i] = int(track.tracker_id)
                    break
        return ids
