"""Per-track trust state: traits, total score and aggregated trust, updated only on observation.

The estimator knows nothing of images or of the controller: it takes per-track observations
(trait confidences and, for pose fluctuation, keypoints with their box) stamped with a time in
seconds, so that perception and control can run at different rates (footnote of `proposed`).

Documented choices where the paper is silent:

* A track is created on its first observation with the "(0)" formulas of `smato_score`,
  `eye_score`, `pose_score` and `agg_trust`; every later observation applies the recursive update.
* A trait confidence missing from an observation (e.g. no face visible) leaves that trait as it
  was. A trait never observed yet is "not available": `lin_comb` then shares its weight out over
  the available traits (see :func:`trustnav.trust.traits.total_score`). Pose fluctuation is always
  available (its initial value nu03 does not need an observation).
* Pose fluctuation compares with the previous observation of the same track, however long ago.
* A track not observed for more than ``keep_time`` seconds is forgotten; if it comes back it
  starts again from the "(0)" formulas.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from numbers import Integral

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.trust import traits as tr
from trustnav.trust.params import PAPER_TRUST, TrustParams, as_number

__all__ = ["Observation", "TrackState", "TrustEstimator"]


@dataclass(frozen=True)
class Observation:
    """What perception saw of one track at one instant. Any trait input may be missing (None)."""

    track_id: int
    time: float
    c_smartphone: float | None = None
    c_eye: float | None = None
    keypoints: NDArray[np.float64] | None = None
    bbox: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.track_id, bool) or not isinstance(self.track_id, Integral):
            raise ValueError(f"observation track_id must be an integer, got {self.track_id!r}")
        object.__setattr__(self, "track_id", int(self.track_id))
        t = as_number("observation time", self.time)
        if not math.isfinite(t):
            raise ValueError(f"observation time must be finite seconds, got {self.time!r}")
        object.__setattr__(self, "time", t)
        for name in ("c_smartphone", "c_eye"):
            c = getattr(self, name)
            if c is not None:
                c = as_number(name, c)
                if not 0.0 <= c <= 1.0:
                    raise ValueError(f"{name} must be a confidence in [0, 1] (or None), got {getattr(self, name)!r}")
                object.__setattr__(self, name, c)
        if (self.keypoints is None) != (self.bbox is None):
            raise ValueError("keypoints and bbox must be given together (pose fluctuation needs both)")
        if self.keypoints is not None:
            kp = np.asarray(self.keypoints, dtype=float)
            box = np.asarray(self.bbox, dtype=float)
            if kp.ndim != 2 or kp.shape[1] != 2 or box.shape != (4,):
                raise ValueError(
                    f"keypoints must be (K, 2) and bbox [x1, y1, x2, y2], got shapes {kp.shape} and {box.shape}"
                )
            object.__setattr__(self, "keypoints", kp)
            object.__setattr__(self, "bbox", box)


@dataclass
class TrackState:
    """Memory of one tracked pedestrian (the 'Memory' block of Fig. `combined`)."""

    track_id: int
    smartphone: float  # s_1, NaN until first observed
    eye: float  # s_2, NaN until first observed
    pose: float  # s_3
    score: float  # S, `lin_comb`
    trust: float  # tau, `agg_trust`
    first_seen: float
    last_seen: float
    observations: int = 1
    fluctuation: float = math.nan  # last C_fluc
    relative_pose: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def traits(self) -> NDArray[np.float64]:
        return np.array([self.smartphone, self.eye, self.pose])


class TrustEstimator:
    """Aggregates per-track trust over time (`lin_comb`, `agg_trust`, trait updates)."""

    def __init__(self, params: TrustParams = PAPER_TRUST, keep_time: float = 2.0) -> None:
        if not isinstance(params, TrustParams):
            raise ValueError(f"params must be a TrustParams (e.g. PAPER_TRUST), got {type(params).__name__}")
        if not as_number("keep_time", keep_time) >= 0:
            raise ValueError(f"keep_time must be >= 0 seconds, got {keep_time!r}")
        self.params = params
        self.keep_time = float(keep_time)
        self._tracks: dict[int, TrackState] = {}

    @property
    def tracks(self) -> dict[int, TrackState]:
        """Live tracks by id (read-only use)."""
        return self._tracks

    def observe(self, obs: Observation) -> TrackState:
        """Apply one observation; returns the track's updated state."""
        p = self.params
        rel = None if obs.keypoints is None else tr.relative_pose(obs.keypoints, obs.bbox)
        st = self._tracks.get(obs.track_id)
        if st is not None and obs.time < st.last_seen:
            raise ValueError(
                f"observation of track {obs.track_id} at t={obs.time} is older than its last one ({st.last_seen})"
            )
        if st is None:
            s1 = math.nan if obs.c_smartphone is None else float(tr.smartphone_trait_init(obs.c_smartphone, p))
            s2 = math.nan if obs.c_eye is None else float(tr.eye_trait_init(obs.c_eye, p))
            s3 = tr.pose_trait_init(p)
            score = float(tr.total_score([s1, s2, s3], p))
            st = TrackState(
                track_id=obs.track_id,
                smartphone=s1,
                eye=s2,
                pose=s3,
                score=score,
                trust=float(tr.trust_init(score, p)),
                first_seen=obs.time,
                last_seen=obs.time,
                relative_pose=rel,
            )
            self._tracks[obs.track_id] = st
            return st
        if obs.c_smartphone is not None:
            st.smartphone = float(
                tr.smartphone_trait_init(obs.c_smartphone, p)
                if math.isnan(st.smartphone)
                else tr.smartphone_trait_update(st.smartphone, obs.c_smartphone, p)
            )
        if obs.c_eye is not None:
            st.eye = float(
                tr.eye_trait_init(obs.c_eye, p) if math.isnan(st.eye) else tr.eye_trait_update(st.eye, obs.c_eye, p)
            )
        if rel is not None:
            if st.relative_pose is not None and np.any(np.isfinite(rel - st.relative_pose).all(axis=1)):
                st.fluctuation = tr.fluctuation_confidence(rel, st.relative_pose, p)
                st.pose = float(tr.pose_trait_update(st.pose, st.fluctuation, p))
            st.relative_pose = rel
        st.score = float(tr.total_score(st.traits, p))
        st.trust = float(tr.trust_update(st.trust, st.score, p))
        st.last_seen = obs.time
        st.observations += 1
        return st

    def update(self, observations: Iterable[Observation], time: float | None = None) -> dict[int, TrackState]:
        """Apply a frame's observations, then forget tracks unseen for longer than keep_time."""
        if time is not None:
            time = as_number("time", time)
        latest = -math.inf
        for obs in observations:
            self.observe(obs)
            latest = max(latest, obs.time)
        now = time if time is not None else latest
        if math.isfinite(now):
            self.prune(now)
        return self._tracks

    def prune(self, now: float) -> list[int]:
        """Forget tracks last seen more than keep_time before ``now``; returns their ids."""
        now = as_number("now", now)
        gone = [tid for tid, st in self._tracks.items() if now - st.last_seen > self.keep_time]
        for tid in gone:
            del self._tracks[tid]
        return gone

    def trust(self, track_id: int, default: float | None = None) -> float | None:
        st = self._tracks.get(track_id)
        return default if st is None else st.trust

    def trusts(self, track_ids: ArrayLike, default: float = 0.0) -> NDArray[np.float64]:
        """Trust of each id as an array for the controller; ``default`` for unknown ids
        (0 = least trusted, the safe choice: gamma falls back to gamma_ini)."""
        return np.array(
            [self._tracks[t].trust if t in self._tracks else default for t in np.asarray(track_ids).ravel()]
        )
