"""A camera frame's path to the controller, as calls: frame -> perception (people) -> perception
latency -> world tracker (tracks with covariances, trust per track) -> the controller's input.

:class:`~trustnav.sim.driving.episode.DriveEnvironment` reads as these stages (its ``observe``):

1. :meth:`FramePath.perceive`: the camera's frame through perception (the sensor: rendered frames
   and ``trustnav.perception``, or projected keypoints): a :class:`Frame` of people (boxes,
   keypoints, eye contact, phone use), stamped with the capture time;
2. :class:`PerceptionLatency`: the frame is in flight for ``SensingSpec.perception_latency``
   seconds; :meth:`PerceptionLatency.due` hands on the frames whose latency has passed, in capture
   order;
3. :meth:`FramePath.track`: the frame's people into the tracker: placed on the ground and followed
   by the world tracker, each world track's trust from its sightings (`lin_comb`, `agg_trust`);
   returns a :class:`TrackedFrame` (the people with their track and trust, the live tracks);
4. :meth:`FramePath.controller_input`: the tracks predicted to the control step, with their
   covariances and trusts: the controller's :class:`~trustnav.sim.engine.Observation`.

Two paths (``state`` of the drive): :class:`PerceivedPath` (the default: the camera only; nothing
on it sees ground truth) and :class:`TruePath` (the authors' setting: positions and velocities from
the world, optionally noisy; trust per world pedestrian, perception's people labelled by their true
boxes). Scoring against ground truth is not on the path (``frame_scoring``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from trustnav.geometry.camera import CameraPose
from trustnav.perception.pedestrians import PedestrianEstimator, SeenPerson
from trustnav.perception.world_tracking import TrackState
from trustnav.sim.driving.body import Appearance, Skeleton
from trustnav.sim.driving.sensing import KeypointSensor, NearScan, RenderSensor, SensedPerson
from trustnav.sim.driving.world import SensingSpec
from trustnav.sim.engine import Observation
from trustnav.trust import Sighting, TrustEstimator

__all__ = ["Frame", "FramePath", "PerceivedPath", "PerceptionLatency", "TrackedFrame", "TruePath", "frame_path"]

Sensor = KeypointSensor | RenderSensor
Bodies = Sequence[tuple[Skeleton, Appearance]]


@dataclass(frozen=True)
class Frame:
    """One camera frame as perception saw it: its index and capture time, the camera, the people
    (:class:`~trustnav.sim.driving.sensing.SensedPerson`), the image (render sensing or a world's
    own camera), detections of nobody, timing, and ``to_scenario``: the 2x2 map of ground points
    from the camera's frame to the scenario's (None: the same frame)."""

    index: int
    time: float
    camera: CameraPose
    people: list[SensedPerson]
    image: NDArray[np.uint8] | None = field(default=None, repr=False)
    false_positives: int = 0
    timing: dict[str, float] = field(default_factory=dict)
    to_scenario: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class TrackedFrame:
    """A frame after the tracker took it in: its people with the track each joined (``track_id``,
    -1: none) and that track's trust, and every live world track after the frame (perceived)."""

    frame: Frame
    people: list[SensedPerson]
    tracks: tuple[TrackState, ...] = ()


class PerceptionLatency:
    """The frames in flight between capture and the tracker: ``seconds`` of perception latency
    (``SensingSpec.perception_latency``); a frame is due at the first call at or after its
    capture time plus ``seconds``. A near-field sensor's scans (:class:`NearScan`) travel with
    them, so that the tracker takes everything in the order it was taken."""

    def __init__(self, seconds: float) -> None:
        self.seconds = float(seconds)
        self._queue: deque[Frame | NearScan] = deque()

    def put(self, frame: Frame | NearScan) -> None:
        self._queue.append(frame)

    def due(self, now: float) -> list[Frame | NearScan]:
        """The frames whose latency has passed at ``now``, in capture order (taken out)."""
        cut = now + 1e-9 - self.seconds
        out = []
        while self._queue and self._queue[0].time <= cut:
            out.append(self._queue.popleft())
        return out

    @property
    def in_flight(self) -> tuple[Frame | NearScan, ...]:
        """The frames captured and not yet due."""
        return tuple(self._queue)

    def __len__(self) -> int:
        return len(self._queue)


def _sighting(person: SensedPerson, key: int, time: float) -> Sighting:
    """What the trust estimator takes of one person of a frame, under the track ``key``."""
    return Sighting(
        track_id=key,
        time=time,
        c_smartphone=person.phone,
        c_eye=person.eye_contact,
        keypoints=person.person.keypoints,
        bbox=person.person.bbox,
    )


class FramePath:
    """The stages from a camera frame to the controller's input (see the module); ``trust``: the
    trust memory (a :class:`~trustnav.trust.TrustEstimator` keyed by world track, or by world
    pedestrian on the :class:`TruePath`)."""

    trust: TrustEstimator

    def __init__(self, sensor: Sensor) -> None:
        self.sensor = sensor

    def perceive(
        self,
        index: int,
        time: float,
        camera: CameraPose,
        bodies: Bodies,
        world_image: Callable[[], NDArray[np.uint8] | None] = lambda: None,
        to_scenario: NDArray[np.float64] | None = None,
    ) -> Frame:
        """Frame ``index`` captured at ``time`` by ``camera`` -> perception's people. ``bodies``:
        what is in front of the camera (the sensor renders or projects them); ``world_image``: the
        world's own camera image where the sensor makes none (CARLA)."""
        people, image, false_positives, timing = self.sensor.sense(camera, bodies, time)
        if image is None:
            image = world_image()
        return Frame(index, time, camera, people, image, false_positives, timing, to_scenario)

    def track(self, frame: Frame) -> TrackedFrame:
        """The frame's people into the tracks and their trust, at the frame's capture time."""
        raise NotImplementedError

    def fold(self, scan: NearScan) -> None:
        """A near-field sensor's scan into the tracks (positions, no traits); nothing on a path
        that does not track (the world's states)."""

    def controller_input(self, time: float, ego: NDArray[np.float64]) -> Observation:
        """What the controller gets at ``time`` (``ego``: the car's state)."""
        raise NotImplementedError


class PerceivedPath(FramePath):
    """The car's own sensors only: each frame's people are placed on the ground, followed by the
    world tracker and given trust per world track
    (:class:`~trustnav.perception.pedestrians.PedestrianEstimator`), then the near-field sensor's
    scans, if any, folded in (:meth:`fold`: positions, no traits); the controller gets every live
    track predicted to the step, with its covariance."""

    def __init__(
        self,
        sensor: Sensor,
        spec: SensingSpec,
        ground_height: Callable[[NDArray[np.float64]], float] | None = None,
    ) -> None:
        super().__init__(sensor)
        self.trust = TrustEstimator(spec.trust_params(), keep_time=spec.keep_time)
        keypoints = isinstance(sensor, KeypointSensor)
        tracker = spec.tracker(keypoints=keypoints)
        self.pedestrians = PedestrianEstimator(spec.localiser(keypoints), tracker, self.trust)
        self.ground_height = ground_height
        # each live track's state and covariance at the last frame that observed it, and when
        self._seen: dict[int, tuple[NDArray[np.float64], NDArray[np.float64], float]] = {}

    def track(self, frame: Frame) -> TrackedFrame:
        seen = [SeenPerson(s.person, s.eye_contact, s.phone) for s in frame.people]
        ids = self.pedestrians.add_frame(frame.time, frame.camera, seen, self.ground_height, frame.to_scenario)
        tracks = self._sightings(frame.time)
        people = [
            replace(s, track_id=-1 if tid is None else tid, trust=None if tid is None else self.trust.trust(tid))
            for s, tid in zip(frame.people, ids, strict=True)
        ]
        return TrackedFrame(frame, people, tracks)

    def fold(self, scan: NearScan) -> None:
        self.pedestrians.add_returns(scan.time, scan.positions, scan.covariances, scan.looked_at)
        self._sightings(scan.time)

    def _sightings(self, time: float) -> tuple[TrackState, ...]:
        """Every live track at ``time``, keeping each one's state when last seen (for the controller)."""
        tracks = tuple(self.pedestrians.tracker.predict(time))
        self._seen = {t.track_id: (t.mean.copy(), t.covariance.copy(), float(time)) if t.last_seen >= time
                      else self._seen.get(t.track_id, (t.mean.copy(), t.covariance.copy(), float(t.last_seen)))
                      for t in tracks}  # fmt: skip
        return tracks

    def controller_input(self, time: float, ego: NDArray[np.float64]) -> Observation:
        est = self.pedestrians.estimates(time)
        n = len(est.states)
        seen = [self._seen.get(s.track_id, (s.mean, s.covariance, float(time))) for s in est.states]
        last = (np.array([a for a, _, _ in seen], dtype=float).reshape(n, 4),
                np.array([b for _, b, _ in seen], dtype=float).reshape(n, 4, 4),
                np.array([c for _, _, c in seen], dtype=float).reshape(n))  # fmt: skip
        return Observation(time, ego, est.positions, est.velocities, est.trusts, est.covariances, last)


class TruePath(FramePath):
    """The world's pedestrians (``states()``: true positions and velocities (N, 2), in scenario
    order) with the spec's noise from ``rng``; trust per pedestrian from the people perception
    labelled with it (unlabelled ones are skipped); 0 (gamma_ini) for one never seen."""

    def __init__(
        self,
        sensor: Sensor,
        spec: SensingSpec,
        n: int,
        states: Callable[[], tuple[NDArray[np.float64], NDArray[np.float64]]],
        rng: np.random.Generator,
    ) -> None:
        super().__init__(sensor)
        self.trust = TrustEstimator(spec.trust_params(), keep_time=spec.keep_time)
        self.spec, self.n, self.states, self.rng = spec, n, states, rng

    def track(self, frame: Frame) -> TrackedFrame:
        labelled = [s for s in frame.people if s.index is not None]
        self.trust.add_frame([_sighting(s, s.index, frame.time) for s in labelled], time=frame.time)  # type: ignore[arg-type]
        people = [replace(s, trust=None if s.index is None else self.trust.trust(s.index)) for s in frame.people]
        return TrackedFrame(frame, people)

    def controller_input(self, time: float, ego: NDArray[np.float64]) -> Observation:
        pos, vel = self.states()
        s = self.spec
        if s.position_noise > 0:
            pos = pos + self.rng.normal(0.0, s.position_noise, pos.shape)
        if s.velocity_noise > 0:
            vel = vel + self.rng.normal(0.0, s.velocity_noise, vel.shape)
        return Observation(time, ego, pos, vel, self.trust.trusts(np.arange(self.n), default=0.0))


def frame_path(
    state: str,
    sensor: Sensor,
    spec: SensingSpec,
    n: int,
    ground_height: Callable[[NDArray[np.float64]], float] | None,
    states: Callable[[], tuple[NDArray[np.float64], NDArray[np.float64]]],
    rng: np.random.Generator,
) -> FramePath:
    """The path of a drive's ``state`` ("perceived" or "true"; see the module)."""
    if state == "perceived":
        return PerceivedPath(sensor, spec, ground_height)
    if state == "true":
        return TruePath(sensor, spec, n, states, rng)
    raise ValueError(f"state must be 'perceived' or 'true', got {state!r}")
