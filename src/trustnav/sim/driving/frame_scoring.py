"""Scoring a drive's frames against ground truth, beside the frame's path to the controller
(:mod:`~trustnav.sim.driving.frame_path`), never on it: the truth at each frame's capture (the
pedestrians' bodies, positions and velocities) meets what the tracker made of the frame in a
:class:`~trustnav.sim.driving.sensing.FrameReport` (per world pedestrian: in view, observed, the
track it joined, its trust, the track's estimate and covariance), and the trust in force for each
world pedestrian is read for the records.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from trustnav.sim.driving.frame_path import Bodies, TrackedFrame
from trustnav.sim.driving.sensing import FrameReport, PedestrianView, in_view, projected_box
from trustnav.sim.driving.world import SensingSpec
from trustnav.trust import TrustEstimator

__all__ = ["FrameScoring"]


@dataclass(frozen=True)
class _Truth:
    """The world at a frame's capture (scoring only)."""

    bodies: Bodies
    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]


class FrameScoring:
    """Ground truth for the reports and records of a drive with ``n`` pedestrians. ``trust``: the
    path's trust memory, keyed by world track (``perceived``) or by pedestrian index (true state)."""

    def __init__(self, spec: SensingSpec, n: int, trust: TrustEstimator, perceived: bool) -> None:
        self.spec, self.n, self.memory, self.perceived = spec, n, trust, perceived
        self._truth: dict[int, _Truth] = {}  # frame index -> the world at its capture
        self._track_of: dict[int, int] = {}  # pedestrian index -> world track last seen as it
        self._trust_of = np.zeros(n)  # its trust then (0 until seen)

    def keep(self, frame: int, bodies: Bodies, positions: NDArray, velocities: NDArray) -> None:
        """The truth at the capture of frame ``frame``, until its report."""
        self._truth[frame] = _Truth(bodies, positions, velocities)

    def trust(self, j: int) -> float | None:
        """The trust the controller holds for world pedestrian ``j``: its index's memory (true
        state), or that of the world track last seen as it (perceived); None before any."""
        if not self.perceived:
            return self.memory.trust(j)
        tid = self._track_of.get(j)
        if tid is None:
            return None
        t = self.memory.trust(tid)
        if t is not None:
            self._trust_of[j] = t
        return float(self._trust_of[j])

    def trusts(self) -> NDArray[np.float64]:
        """(N,) the trust in force for each world pedestrian (0 before it is seen), for records."""
        if not self.perceived:
            return self.memory.trusts(np.arange(self.n), default=0.0)
        return np.array([self.trust(j) or 0.0 for j in range(self.n)])

    def report(self, tracked: TrackedFrame, now: float) -> FrameReport:
        """The report of a frame the tracker took in at ``now``: what was perceived of each world
        pedestrian beside the truth at the frame's capture."""
        frame = tracked.frame
        truth = self._truth.pop(frame.index)
        estimate: dict[int, tuple[NDArray, NDArray]] = {}
        if self.perceived:
            by_id = {t.track_id: t for t in tracked.tracks}
            for s in tracked.people:
                if s.index is not None and s.track_id >= 0 and s.track_id in by_id:
                    self._track_of[s.index] = s.track_id
                    estimate[s.index] = (by_id[s.track_id].mean, by_id[s.track_id].covariance)
        by_index = {
            s.index: s for s in tracked.people if s.index is not None and (s.track_id >= 0 or not self.perceived)
        }
        views = []
        for j, (sk, _) in enumerate(truth.bodies):
            seen = by_index.get(j)
            est = estimate.get(j)
            views.append(
                PedestrianView(
                    index=j,
                    in_view=in_view(frame.camera, sk, self.spec),
                    box=projected_box(frame.camera, sk),
                    observed=seen is not None,
                    track_id=None if seen is None else seen.track_id,
                    eye_contact=None if seen is None else seen.eye_contact,
                    phone=None if seen is None else seen.phone,
                    trust=self.trust(j),
                    position=truth.positions[j].copy(),
                    velocity=truth.velocities[j].copy(),
                    estimate=None if est is None else est[0].copy(),
                    estimate_cov=None if est is None else est[1].copy(),
                )
            )
        return FrameReport(
            frame.index, frame.time, views, frame.false_positives, frame.timing, frame.camera, tracked.people,
            frame.image, tracked.tracks, delivered=None if now <= frame.time + 1e-9 else now,
        )  # fmt: skip
