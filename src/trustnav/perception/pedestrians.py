"""Pedestrians perceived, not given: camera frames -> people on the ground with their velocities,
uncertainty and trust, for a controller.

:class:`PedestrianEstimator` is what a vehicle keeps between frames: each frame's people (boxes,
keypoints, trait confidences) are placed on the ground
(:class:`~trustnav.perception.localisation.GroundLocaliser`), followed in world coordinates
(:class:`~trustnav.perception.world_tracking.WorldTracker`), and their trust (`lin_comb`,
`agg_trust`) is kept per world track (:class:`~trustnav.trust.TrustEstimator`), so identity and
trust survive frame gaps and people leaving the view. :meth:`PedestrianEstimator.estimates` gives
the controller positions, velocities, covariances and trusts at any time (predicted at constant
velocity between frames). Nothing here sees ground truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.geometry.camera import CameraPose
from trustnav.perception.localisation import GroundLocaliser, LocaliserConfig
from trustnav.perception.types import Person
from trustnav.perception.world_tracking import TrackState, WorldTracker, WorldTrackerConfig
from trustnav.trust import PAPER_TRUST, Sighting, TrustEstimator, TrustParams

__all__ = ["PedestrianEstimates", "PedestrianEstimator", "SeenPerson"]


@dataclass(frozen=True)
class SeenPerson:
    """A person of one frame as perception reports it: detection and trait confidences (NaN when a
    cue was not computed)."""

    person: Person
    eye_contact: float = math.nan
    phone: float = math.nan


@dataclass(frozen=True)
class PedestrianEstimates:
    """What a controller gets at ``time``: per live track (M of them) its ID, position and velocity
    (M, 2), covariance of (x, y, v_x, v_y) (M, 4, 4) and trust (M,)."""

    time: float
    track_ids: NDArray[np.int64]
    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]
    covariances: NDArray[np.float64]
    trusts: NDArray[np.float64]
    states: tuple[TrackState, ...] = ()

    def __len__(self) -> int:
        return len(self.track_ids)


class PedestrianEstimator:
    """Localisation, world tracking and per-track trust in one object (one per camera/vehicle)."""

    def __init__(
        self,
        localiser: GroundLocaliser | LocaliserConfig | None = None,
        tracker: WorldTracker | WorldTrackerConfig | None = None,
        trust: TrustParams | TrustEstimator = PAPER_TRUST,
    ) -> None:
        self.localiser = localiser if isinstance(localiser, GroundLocaliser) else GroundLocaliser(localiser)
        self.tracker = tracker if isinstance(tracker, WorldTracker) else WorldTracker(tracker)
        self.trust = trust if isinstance(trust, TrustEstimator) else TrustEstimator(trust, keep_time=math.inf)

    def add_frame(
        self,
        time: float,
        camera: CameraPose,
        people: Sequence[SeenPerson],
        ground_height: Callable[[NDArray[np.float64]], float] | None = None,
        to_world: NDArray[np.float64] | None = None,
    ) -> list[int | None]:
        """Fold in one frame captured at ``time`` (s) by ``camera`` (placed with the ego's pose):
        each person is located on the ground (``ground_height(xy)``: the map's walking surface, in
        world coordinates), associated with a world track, and its trust updated with the frame's
        trait confidences. ``to_world``: a 2x2 orthogonal map from the camera's ground frame to the
        world's (e.g. CARLA's left-handed map; None: the same frame). Returns each person's world
        track ID (None for a person who could not be placed)."""
        m = None if to_world is None else np.asarray(to_world, dtype=float).reshape(2, 2)
        ground = ground_height if (m is None or ground_height is None) else (lambda xy: ground_height(m @ xy[:2]))
        estimates = [self.localiser.locate(p.person, camera, ground) for p in people]
        if m is not None:
            estimates = [None if e is None else e.mapped(m) for e in estimates]
        ids = self.tracker.add_frame(time, estimates, [p.person.bbox for p in people], camera, m)
        obs = []
        for p, tid in zip(people, ids, strict=True):
            if tid is None:
                continue
            obs.append(
                Sighting(
                    track_id=tid,
                    time=time,
                    c_smartphone=None if math.isnan(p.phone) else p.phone,
                    c_eye=None if math.isnan(p.eye_contact) else p.eye_contact,
                    keypoints=p.person.keypoints,
                    bbox=p.person.bbox,
                )
            )
        self.trust.add_frame(obs, time=time)
        self._forget_dropped()
        return ids

    def add_returns(
        self,
        time: float,
        positions: ArrayLike,
        covariances: ArrayLike,
        covers: Callable[[NDArray[np.float64]], bool],
    ) -> list[int | None]:
        """Fold in one scan of a near-field sensor (:meth:`WorldTracker.add_returns`): positions on
        the ground, no traits; it follows the people the camera found (their trust goes on), and a
        return far from all of them starts a track of its own (trust 0 until the camera sees the
        person), unless the camera has looked there and found no person (an object: a pole, a bin;
        ``WorldTrackerConfig.clear_frames``). Returns each return's world track ID (None: it joined
        none)."""
        ids = self.tracker.add_returns(time, positions, covariances, covers)
        self._forget_dropped()
        return ids

    def _forget_dropped(self) -> None:
        live = {t.track_id for t in self.tracker.tracks}
        for tid in [t for t in self.trust.tracks if t not in live]:
            self.trust.forget(tid)  # the world tracker dropped it: its trust goes with it

    def estimates(self, time: float) -> PedestrianEstimates:
        """Every live track predicted to ``time``: the controller's pedestrians; a track's trust
        is 0 (gamma_ini, the cautious default) until it has one."""
        states = self.tracker.predict(time)
        n = len(states)
        ids = np.array([s.track_id for s in states], dtype=np.int64)
        return PedestrianEstimates(
            time=float(time),
            track_ids=ids,
            positions=np.array([s.mean[:2] for s in states], dtype=float).reshape(n, 2),
            velocities=np.array([s.mean[2:] for s in states], dtype=float).reshape(n, 2),
            covariances=np.array([s.covariance for s in states], dtype=float).reshape(n, 4, 4),
            trusts=self.trust.trusts(ids, default=0.0) if n else np.zeros(0),
            states=tuple(states),
        )
