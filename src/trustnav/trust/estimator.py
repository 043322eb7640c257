"""Per-track trust state: traits, total score and aggregated trust, updated only on observation.

The estimator knows nothing of images or of the controller: it takes per-track observations
(trait confidences and, for pose fluctuation, keypoints with their box) stamped with a time in
seconds, so that perception and control can run at different rates (footnote of `proposed`).
The traits are parts (:mod:`trustnav.trust.parts`): any :class:`~trustnav.trust.parts.TraitSet`
with its weights; the paper's three (:data:`~trustnav.trust.parts.PAPER_TRAITS`) by default.

Documented choices where the paper is silent:

* A track is created on its first observation with the "(0)" formulas of `smato_score`,
  `eye_score`, `pose_score` and `agg_trust` (each trait's ``initial``); every later observation
  applies the recursive update (each trait's ``update``).
* A trait confidence missing from an observation (e.g. no face visible) leaves that trait as it
  was. A trait never observed yet is "not available" (NaN): `lin_comb` then shares its weight out
  over the available traits (see :meth:`trustnav.trust.parts.TraitSet.score`). Pose fluctuation
  is always available (its initial value nu03 does not need an observation).
* With a trait set other than the paper's, ``params`` still gives `agg_trust` (alpha, beta,
  beta0); its rho and nu constants belong to the paper's traits and are then not used.
* Pose fluctuation compares with the previous observation of the same track, however long ago.
* A track not observed for more than ``keep_time`` seconds is forgotten; if it comes back it
  starts again from the "(0)" formulas.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from numbers import Real

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.trust import traits as tr
from trustnav.trust.params import PAPER_TRUST, TrustParams, as_number
from trustnav.trust.parts import Trait, TraitSet, TraitStep, paper_traits, relax
from trustnav.trust.sighting import EYE_CONTACT, SMARTPHONE, Sighting

__all__ = ["Sighting", "TrackState", "TrustEstimator"]

_POSE = "pose_fluctuation"


@dataclass
class TrackState:
    """Memory of one tracked pedestrian (the 'Memory' block of Fig. `combined`).

    steps: each trait's latest :class:`~trustnav.trust.parts.TraitStep`, by name, in the order of
    the estimator's traits; score: S (`lin_comb`); trust: tau (`agg_trust`). The paper's traits
    read as ``smartphone`` (s_1), ``eye`` (s_2), ``pose`` (s_3) and ``fluctuation`` (last C_fluc);
    NaN for a trait not available (or not in the set).
    """

    track_id: int
    steps: dict[str, TraitStep]
    score: float
    trust: float
    last_seen: float
    observations: int = 1

    def value(self, name: str) -> float:
        """The trait ``name``'s value s_i (NaN if not available or not a trait of this estimator)."""
        step = self.steps.get(name)
        return math.nan if step is None else step.value

    @property
    def values(self) -> dict[str, float]:
        """Every trait's value by name."""
        return {name: step.value for name, step in self.steps.items()}

    @property
    def traits(self) -> NDArray[np.float64]:
        """The trait values in the estimator's order ((smartphone, eye, pose) for the paper's)."""
        return np.array([step.value for step in self.steps.values()])

    @property
    def smartphone(self) -> float:
        return self.value(SMARTPHONE)

    @property
    def eye(self) -> float:
        return self.value(EYE_CONTACT)

    @property
    def pose(self) -> float:
        return self.value(_POSE)

    @property
    def fluctuation(self) -> float:
        """Last C_fluc (`pose_conf`), NaN before the first comparison."""
        step = self.steps.get(_POSE)
        return math.nan if step is None else step.confidence

    @property
    def relative_pose(self) -> NDArray[np.float64] | None:
        step = self.steps.get(_POSE)
        return None if step is None else step.memory


def _checked(trait: Trait, step: object, when: str) -> TraitStep:
    if not isinstance(step, TraitStep):
        raise ValueError(f"trait {trait.name!r}: {when} must return a TraitStep, got {type(step).__name__}")
    v = step.value
    if isinstance(v, bool) or not isinstance(v, Real) or not (math.isnan(v) or 0.0 <= v <= 1.0):
        raise ValueError(f"trait {trait.name!r}: {when} gave {v!r}; a trait value must be a number in [0, 1] or NaN")
    return step if type(v) is float else replace(step, value=float(v))


class TrustEstimator:
    """Aggregates per-track trust over time (`lin_comb`, `agg_trust`, trait updates).

    params: `agg_trust` constants (and the paper's trait constants when ``traits`` is None);
    keep_time: seconds after which an unseen track is forgotten; traits: the trait set (a
    TraitSet or a sequence of Trait), by default the paper's three built from ``params``.
    """

    def __init__(
        self,
        params: TrustParams = PAPER_TRUST,
        keep_time: float = 2.0,
        *,
        traits: TraitSet | Sequence[Trait] | None = None,
    ) -> None:
        if not isinstance(params, TrustParams):
            raise ValueError(f"params must be a TrustParams (e.g. PAPER_TRUST), got {type(params).__name__}")
        if not as_number("keep_time", keep_time) >= 0:
            raise ValueError(f"keep_time must be >= 0 seconds, got {keep_time!r}")
        self.params = params
        self.keep_time = float(keep_time)
        self.traits = paper_traits(params) if traits is None else TraitSet.of(traits)
        self._tracks: dict[int, TrackState] = {}

    @property
    def tracks(self) -> dict[int, TrackState]:
        """Live tracks by id (read-only use)."""
        return self._tracks

    def add_sighting(self, obs: Sighting) -> TrackState:
        """Apply one observation; returns the track's updated state."""
        if not isinstance(obs, Sighting):
            raise ValueError(f"add_sighting needs a Sighting, got {type(obs).__name__}")
        p = self.params
        st = self._tracks.get(obs.track_id)
        if st is not None and obs.time < st.last_seen:
            raise ValueError(
                f"observation of track {obs.track_id} at t={obs.time} is older than its last one ({st.last_seen})"
            )
        if st is None:
            steps = {t.name: _checked(t, t.initial(obs), "initial") for t in self.traits}
            score = float(self.traits.score([s.value for s in steps.values()]))
            st = TrackState(
                track_id=obs.track_id,
                steps=steps,
                score=score,
                trust=float(tr.trust_init(score, p)),
                last_seen=obs.time,
            )
            self._tracks[obs.track_id] = st
            return st
        # every trait steps before anything is stored: a trait that fails leaves the track as it was
        steps = {t.name: _checked(t, t.update(st.steps[t.name], obs), "update") for t in self.traits}
        st.steps = steps
        st.score = float(self.traits.score([s.value for s in steps.values()]))
        if p.time_constants is None:
            st.trust = float(tr.trust_update(st.trust, st.score, p))
        else:  # the rate-invariant law: relax toward the score over the time since the last observation
            st.trust = float(tr.sat01(relax(st.trust, st.score, obs.time - st.last_seen, p.time_constants[3])))
        st.last_seen = obs.time
        st.observations += 1
        return st

    def add_frame(self, sightings: Iterable[Sighting], time: float | None = None) -> dict[int, TrackState]:
        """Apply a frame's observations, then forget tracks unseen for longer than keep_time."""
        if time is not None:
            time = as_number("time", time)
        latest = -math.inf
        for obs in sightings:
            self.add_sighting(obs)
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

    def forget(self, track_id: int) -> None:
        """Forget a track now (e.g. one its tracker has dropped); unknown ids are ignored."""
        self._tracks.pop(track_id, None)

    def trust(self, track_id: int, default: float | None = None) -> float | None:
        st = self._tracks.get(track_id)
        return default if st is None else st.trust

    def trusts(self, track_ids: ArrayLike, default: float = 0.0) -> NDArray[np.float64]:
        """Trust of each id as an array for the controller; ``default`` for unknown ids
        (0 = least trusted, the safe choice: gamma falls back to gamma_ini)."""
        return np.array(
            [self._tracks[t].trust if t in self._tracks else default for t in np.asarray(track_ids).ravel()]
        )
