"""End-to-end trust-aware driving, offline (the paper's Section IV, Cases I and II):
camera frames -> perception -> trust -> bicycle MPC (`proposed` with `cbf_imp`) -> car.

Two rates: the controller runs every 1 / control.rate seconds, the camera captures a frame every
1 / camera.rate seconds (the trust-estimation rate). The controller never waits for perception: a
frame captured at t updates what the controller uses from the first control step at or after
t + ``sensing.perception_latency`` on (default 0: from the step at t on), its people stamped with
the capture time and predicted from it to each step.

Two ways the controller learns where pedestrians are (``state``):

* ``perceived`` (default): from the camera only. Each frame's people are placed on the ground
  (:class:`~trustnav.perception.localisation.GroundLocaliser`: the map's road and kerb heights, the
  ego's pose as odometry), followed by a world-frame Kalman tracker, and their trust is kept per
  world track (:class:`~trustnav.perception.pedestrians.PedestrianEstimator`); the controller gets
  every live track predicted to the control step, with its covariance, and keeps R from the true
  person with the configured confidence (:func:`~trustnav.control.barrier.uncertainty_margins`).
  Ground truth only scores (localisation error, coverage, identity switches, distances).
* ``true``: positions and velocities from the world (as in the authors' code), optionally with
  noise; trust from perception, associated with the world's pedestrians by their true boxes.

The physical world is a :class:`World` (ego state, pedestrian states, what the camera sees, apply
a command, advance time): :class:`SimWorld` is trustnav's own (bicycle plant with actuation latency,
constant-velocity or behaving pedestrians), ``trustnav.carla_bridge.CarlaWorld`` a CARLA server.
:class:`DriveEnvironment` is a World seen through the car's camera: the engine's
:class:`~trustnav.sim.engine.Environment` of every drive. Its ``observe()`` is a frame's path to the
controller as calls (:mod:`~trustnav.sim.driving.frame_path`: frame -> perception -> perception
latency -> world tracker -> the controller's input), with scoring against ground truth beside it
(:mod:`~trustnav.sim.driving.frame_scoring`). :func:`drive` runs it with the MPC on the engine's
runner; the Gymnasium environment steps the same DriveEnvironment through a
:class:`~trustnav.sim.engine.Rollout` with any controller.
:func:`run_drive` is a pure function of (scenario, parameters, seed) that returns a
:class:`DriveResult` and writes nothing.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import SolveStatus
from trustnav.geometry.camera import CameraPose
from trustnav.perception.localisation import chi2_90
from trustnav.sim.driving import topview
from trustnav.sim.driving.behaviour import PedestrianMotion
from trustnav.sim.driving.body import Appearance, Skeleton
from trustnav.sim.driving.frame_path import Frame, PerceptionLatency, frame_path
from trustnav.sim.driving.frame_scoring import FrameScoring
from trustnav.sim.driving.sensing import (
    SENSING_MODES,
    FrameReport,
    KeypointSensor,
    NearField,
    NearScan,
    RenderSensor,
    street_clutter,
)
from trustnav.sim.driving.world import (
    DriveScenario,
    VehiclePlant,
    pedestrian_bodies,
    pedestrian_states,
    street_of,
)
from trustnav.sim.engine import Decision, EpisodeResult, MpcPolicy, Observation, Sample, make_mpc, run

__all__ = [
    "STATES",
    "DriveEnvironment",
    "DriveResult",
    "SimWorld",
    "World",
    "drive",
    "drive_controller",
    "drive_metrics",
    "drive_result",
    "make_sensor",
    "prepare_scenario",
    "run_drive",
]

Bodies = list[tuple[Skeleton, Appearance]]
#: Where the controller's pedestrian states come from: the camera (default) or the world.
STATES = ("perceived", "true")


@runtime_checkable
class World(Protocol):
    """What the drive loop needs from a world, in the scenario's coordinates (metres, x/y ground,
    yaw rad counter-clockwise from +x; pedestrians in scenario order)."""

    name: str  # "sim", "carla"

    @property
    def time(self) -> float:
        """Seconds since the episode started."""
        ...

    def ego_state(self) -> NDArray[np.float64]:
        """Ego (x, y, yaw, v)."""
        ...

    def pedestrian_states(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions and velocities (N, 2) now."""
        ...

    def camera_view(self) -> tuple[CameraPose, Bodies]:
        """The camera now and each pedestrian's 3-D body, in one frame where the camera model
        projects as the real camera does (sensing projects the bodies: keypoints, or boxes to
        associate perception with pedestrians). A world whose camera frame is not the scenario's
        has ``camera_to_scenario``, the orthogonal 2x2 map of ground points from one to the other
        (perceived pedestrians are placed with it)."""
        ...

    def frame_image(self) -> NDArray[np.uint8] | None:
        """The camera's RGB image now, where the world has a camera of its own; else None."""
        ...

    def send(self, command: ArrayLike) -> None:
        """Send (steer rad, acceleration m/s^2) to the car."""
        ...

    def advance(self, duration: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Run the world ``duration`` seconds; (ego states (n, 4), pedestrian positions (n, N, 2))
        at the n sub-steps it sampled, the last at the new time."""
        ...


class SimWorld:
    """trustnav's own world: the ego :class:`VehiclePlant` (bicycle, actuation latency, fine
    sub-steps) and pedestrians posed by body.py: constant velocity, or with a ``behaviour`` (path,
    step-out, kerb wait and gap acceptance: :mod:`trustnav.sim.driving.behaviour`)."""

    name = "sim"

    def __init__(self, scenario: DriveScenario) -> None:
        self.scenario = scenario
        self.plant = VehiclePlant(scenario.vehicle, scenario.initial_state())
        self.motions: list[PedestrianMotion | None] = [
            None if p.behaviour is None else PedestrianMotion(p.position, p.velocity, p.behaviour)
            for p in scenario.pedestrians
        ]
        self._behaved = any(m is not None for m in self.motions)

    @property
    def time(self) -> float:
        return self.plant.time

    def ego_state(self) -> NDArray[np.float64]:
        return self.plant.state.copy()

    def pedestrian_states(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pos, vel = pedestrian_states(self.scenario, self.time)
        for j, m in enumerate(self.motions):
            if m is not None:
                pos[j], vel[j] = m.position, m.velocity
        return pos, vel

    def camera_view(self) -> tuple[CameraPose, Bodies]:
        cam = self.scenario.camera.pose(self.plant.state[:2], float(self.plant.state[2]))
        return cam, pedestrian_bodies(self.scenario, self.time, cam.position, self.motions if self._behaved else None)

    def frame_image(self) -> NDArray[np.uint8] | None:
        return None

    def send(self, command: ArrayLike) -> None:
        self.plant.send(command)

    def advance(self, duration: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t0 = self.plant.time
        sub = self.plant.advance(duration)
        sub_t = t0 + np.arange(1, len(sub) + 1) * (duration / len(sub))
        sc = self.scenario
        p0 = np.array([p.position for p in sc.pedestrians])
        v0 = np.array([p.velocity for p in sc.pedestrians])
        peds = p0[None] + sub_t[:, None, None] * v0[None]
        if self._behaved:  # behaving pedestrians, sub-step by sub-step with the car where it was then
            h = duration / len(sub)
            for i in range(len(sub)):
                for j, m in enumerate(self.motions):
                    if m is not None:
                        m.advance(h, sub[i])
                        peds[i, j] = m.position
        return sub, peds


class DriveEnvironment:
    """The engine's :class:`~trustnav.sim.engine.Environment` of a drive: a :class:`World` seen
    through the car's camera at its rate and the frame's path to the controller
    (:mod:`~trustnav.sim.driving.frame_path`), advanced one control period at a time.

    ``world``: a :class:`World` (default :class:`SimWorld` of the scenario). ``sensor``: a
    :class:`KeypointSensor` (default, built from the scenario and seed) or a :class:`RenderSensor`.
    ``state``: "perceived" (the controller's pedestrians from the camera) or "true" (from the
    world); see the module. Randomness (sensing noise, controller-input noise) comes from ``seed``.
    Its parts: ``path`` (perception, tracker, controller input), ``latency`` (the frames in flight),
    ``scoring`` (ground truth, for the reports only) and ``frames`` (the reports, in capture order).
    """

    def __init__(
        self,
        scenario: DriveScenario,
        seed: int = 0,
        sensor: KeypointSensor | RenderSensor | None = None,
        capture_rate: float | None = None,
        control_rate: float | None = None,
        world: World | None = None,
        max_frames: int | None = None,
        state: str = "perceived",
    ) -> None:
        if state not in STATES:
            raise ValueError(f"state must be one of {STATES}, got {state!r}")
        self.state_source = state
        self.scenario = scenario
        self.street = street_of(scenario)
        self.capture_rate = float(capture_rate or scenario.camera.rate)
        self.control_rate = float(control_rate or scenario.control.rate)
        if not self.capture_rate > 0 or not self.control_rate > 0:
            raise ValueError("capture_rate and control_rate must be positive")
        self.period = 1.0 / self.control_rate
        self.max_frames = max_frames
        self._own_sensor = sensor is None
        self.sensor: KeypointSensor | RenderSensor | None = sensor
        self._given_world = world
        self.world: World = SimWorld(scenario) if world is None else world
        self.name = self.world.name
        self.command_size = 2  # the car's (steer, acceleration)
        n, expected = len(self.world.pedestrian_states()[0]), len(scenario.pedestrians)
        if n != expected:
            raise ValueError(f"the {self.world.name} world has {n} pedestrians, the scenario {expected}")
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        """Back to t = 0 with the randomness of ``seed`` (None: the current seed): new sensing and
        input-noise generators, empty trust memory and frames, a new :class:`SimWorld` (a world
        of another kind, e.g. CARLA, cannot go back in time once it has run)."""
        if seed is not None or not hasattr(self, "seed"):
            self.seed = 0 if seed is None else int(seed)
        sc = self.scenario
        if self.world.time > 0:
            if self._given_world is not None:
                raise ValueError(f"the {self.world.name} world cannot be reset; start a new one")
            self.world = SimWorld(sc)
        sense_seq, input_seq, near_seq, clutter_seq = np.random.SeedSequence(self.seed).spawn(4)
        self.rng_inputs = np.random.default_rng(input_seq)
        self.near = NearField.of(sc.sensing)  # a near-field sensor (None: the camera alone)
        self.rng_near = np.random.default_rng(near_seq)
        self.clutter = np.zeros((0, 2))  # what else it returns: poles, bins on the sidewalks
        if self.near is not None and sc.sensing.near_clutter > 0:
            self.clutter = street_clutter(sc.road, sc.sensing.near_clutter, np.random.default_rng(clutter_seq))
        if self._own_sensor:
            self.sensor = KeypointSensor(sc.sensing, np.random.default_rng(sense_seq))
        assert self.sensor is not None
        n = len(sc.pedestrians)
        self.path = frame_path(
            self.state_source, self.sensor, sc.sensing, n, self.street.ground_height, self.pedestrians, self.rng_inputs
        )
        self.latency = PerceptionLatency(sc.sensing.perception_latency)
        self.scoring = FrameScoring(sc.sensing, n, self.path.trust, perceived=self.state_source == "perceived")
        self.frames: list[FrameReport] = []  # reported when taken in (perception_latency after capture)
        self._captured = 0
        self._next_capture = 0.0
        self._scans = 0
        self._next_scan = 0.0
        self.steps = 0
        self.max_steps = math.ceil(sc.duration * self.control_rate - 1e-9)
        self.min_distance_fine = np.full(len(sc.pedestrians), np.inf)

    @property
    def time(self) -> float:
        return self.world.time

    @property
    def plant(self) -> VehiclePlant:
        """The ego plant of a :class:`SimWorld`."""
        plant = getattr(self.world, "plant", None)
        if plant is None:
            raise AttributeError(f"the {self.world.name} world has no VehiclePlant")
        return plant

    @property
    def state(self) -> NDArray[np.float64]:
        """Ego state (x, y, yaw, v)."""
        return np.asarray(self.world.ego_state(), dtype=float).copy()

    def pedestrians(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """True positions and velocities (N, 2) now."""
        return self.world.pedestrian_states()

    def pedestrian_trusts(self) -> NDArray[np.float64]:
        """(N,) the trust in force for each world pedestrian (0 before it is seen), for records."""
        return self.scoring.trusts()

    def capture_due(self) -> bool:
        """A frame is due (the camera's rate) and ``max_frames`` not reached."""
        more = self.max_frames is None or self._captured < self.max_frames
        return more and self.time + 1e-9 >= self._next_capture

    def capture_frame(self) -> Frame:
        """The camera's frame now through perception (:meth:`FramePath.perceive`); the truth at
        this instant is kept for scoring the frame."""
        cam, bodies = self.world.camera_view()
        to_scenario = getattr(self.world, "camera_to_scenario", None)  # e.g. CARLA's left-handed map
        frame = self.path.perceive(self._captured, self.time, cam, bodies, self.world.frame_image, to_scenario)
        self.scoring.keep(frame.index, bodies, *self.pedestrians())
        self._captured += 1
        self._next_capture = self._captured / self.capture_rate
        return frame

    def scan_due(self) -> bool:
        """A near-field scan is due (the sensor's rate; never without one)."""
        return self.near is not None and self.time + 1e-9 >= self._next_scan

    def scan(self) -> NearScan | None:
        """The near-field sensor's scan now (``SensingSpec.near_range``): the returns of the world's
        pedestrians (and of the street's clutter, ``near_clutter``: indices from N on) inside its
        field around the car's front; None while the car is faster than the sensor's ``max_speed``
        (a park-assist array: no scan in that slot)."""
        if self.near is None:
            raise ValueError("this drive has no near-field sensor (SensingSpec.near_range 0)")
        self._scans += 1
        self._next_scan = self._scans / self.near.rate
        ego = self.state
        if float(ego[3]) > self.near.max_speed:
            return None
        return self.near.scan(self.time, ego, np.vstack([self.pedestrians()[0], self.clutter]), self.rng_near)

    def _put_scan(self) -> None:
        """A near-field scan, when one is due and taken, in flight with the frames."""
        if self.scan_due():
            scan = self.scan()
            if scan is not None:
                self.latency.put(scan)

    def take_in(self, frame: Frame | NearScan) -> FrameReport | None:
        """A frame whose latency has passed into the tracker (:meth:`FramePath.track`), and its
        report (scored against the truth at its capture); a near-field scan into the tracks
        (:meth:`FramePath.fold`; no report)."""
        if isinstance(frame, NearScan):
            self.path.fold(frame)
            return None
        report = self.scoring.report(self.path.track(frame), self.time)
        self.frames.append(report)
        return report

    def capture(self) -> FrameReport | None:
        """Capture a frame now (:meth:`capture_frame`) and a near-field scan if one is due, then take
        in those whose latency has passed. Returns the new frame's report if that is now (no
        latency), else None."""
        frame = self.capture_frame()
        self.latency.put(frame)
        self._put_scan()
        reports = [r for r in (self.take_in(f) for f in self.latency.due(self.time)) if r is not None]
        return reports[-1] if reports and reports[-1].index == frame.index else None

    def advance_samples(
        self, command: ArrayLike, duration: float | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Send (steer, accel) to the car and run the world ``duration`` seconds (default one
        control period); returns the world's sub-step samples (ego states (n, 4), pedestrian
        positions (n, N, 2)) and keeps the closest approach over them."""
        self.world.send(command)
        sub, ped_sub = self.world.advance(self.period if duration is None else float(duration))
        d = np.linalg.norm(sub[:, None, :2] - ped_sub, axis=2).min(axis=0)
        self.min_distance_fine = np.minimum(self.min_distance_fine, d)
        self.steps += 1
        return sub, ped_sub

    def advance(self, command: ArrayLike, duration: float | None = None) -> NDArray[np.float64]:
        """Send (steer, accel) to the car and run the world ``duration`` seconds (default one
        control period); returns the ego's sub-step states."""
        return self.advance_samples(command, duration)[0]

    # -- the engine's Environment protocol (trustnav.sim.engine)
    def observe(self) -> Observation:
        """The controller's input now, as the frame's path: a frame captured when one is due goes
        through perception and waits out the perception latency; the frames due go into the
        tracker (each scored beside the path); the tracks predicted to now are the input."""
        if self.capture_due():
            self.latency.put(self.capture_frame())  # frame -> perception: people
        self._put_scan()  # a near-field scan (optional): positions
        for frame in self.latency.due(self.time):  # the perception latency has passed
            self.take_in(frame)  # people -> world tracks with covariances, trust per track
        return self.path.controller_input(self.time, self.state)  # tracks predicted to now

    def done(self) -> str | None:
        """ "goal" within ``goal_tolerance``; "time" after the scenario's duration (in control steps)."""
        if self.reached_goal():
            return "goal"
        return "time" if self.steps >= self.max_steps else None

    def record(self) -> Sample:
        return Sample(self.time, self.state, self.pedestrians()[0], self.pedestrian_trusts())

    def outcome(self) -> dict[str, Any]:
        """Closest approach per pedestrian over the world's sub-steps (once it has advanced)."""
        if not self.steps:
            return {}
        return {"ped_min_distance": [float(v) for v in self.min_distance_fine]}

    def distance_to_goal(self) -> float:
        return float(np.hypot(*(self.state[:2] - np.asarray(self.scenario.goal))))

    def reached_goal(self) -> bool:
        return self.distance_to_goal() <= self.scenario.goal_tolerance


@dataclass
class DriveResult:
    """A closed-loop drive: per control step (T+1 samples) times, ego states, true pedestrian
    positions, the trusts the controller used; per step solver data; the captured frames."""

    scenario: DriveScenario
    sensing: str
    seed: int
    capture_rate: float
    times: NDArray[np.float64]
    ego: NDArray[np.float64]  # (T+1, 4)
    pedestrians: NDArray[np.float64]  # (T+1, N, 2)
    trusts: NDArray[np.float64]  # (T+1, N) trusts in force at each sample
    statuses: list[SolveStatus]
    fallbacks: NDArray[np.bool_]
    slack: NDArray[np.bool_]
    solve_times: NDArray[np.float64]
    plans: NDArray[np.float64]  # (T, N_h+1, 4) predicted states of each step's plan
    frames: list[FrameReport]
    reached_goal: bool
    time_to_goal: float | None
    min_distance_fine: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # over plant sub-steps
    world: str = "sim"  # which World ran it
    episode: EpisodeResult | None = None  # the engine's result it was read from
    state: str = "true"  # where the controller's pedestrian states came from ("perceived" or "true")

    @property
    def distances(self) -> NDArray[np.float64]:
        """Ego-pedestrian distance at each sample (T+1, N)."""
        return np.linalg.norm(self.ego[:, None, :2] - self.pedestrians, axis=2)

    def trust_series(self, index: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(times, trusts) of pedestrian ``index`` at the frames that observed it, each from when the
        controller used it (``FrameReport.known_at``: capture time plus perception latency)."""
        pts = [(f.known_at, f.views[index].trust) for f in self.frames if f.views[index].observed]
        arr = np.array(pts, dtype=float).reshape(-1, 2)
        return arr[:, 0], arr[:, 1]

    def metrics(self) -> dict[str, Any]:
        return drive_metrics(self)

    def road_polygons(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Road and sidewalk outlines (xy) and the road's unit direction (for plots)."""
        return topview.road_polygons(self.scenario.road)

    def estimates_at(self, i: int) -> list[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
        """(pedestrian index, estimated position (2,), covariance (2, 2)) of each pedestrian whose
        track the last frame known at or before sample ``i`` updated (perceived state; else empty)."""
        t = float(self.times[i])
        last = [f for f in self.frames if f.known_at <= t + 1e-9]
        if not last:
            return []
        return [
            (v.index, v.estimate[:2].copy(), v.estimate_cov[:2, :2].copy())
            for v in last[-1].views
            if v.estimate is not None and v.estimate_cov is not None
        ]

    def estimate_regions(self, prob: float = 0.9) -> list[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
        """(pedestrian index, estimated position (2,), outline (n, 2) of its ``prob`` region) for
        every frame's estimate of every pedestrian (perceived state; for figures)."""
        return [
            (v.index, v.estimate[:2].copy(), topview.ellipse_points(v.estimate[:2], v.estimate_cov[:2, :2], prob))
            for f in self.frames
            for v in f.views
            if v.estimate is not None and v.estimate_cov is not None
        ]

    def top_view_image(self, i: int, size: tuple[int, int] = (1280, 400)) -> NDArray[np.uint8]:
        """The top view (BGR) at sample ``i``: :func:`trustnav.sim.driving.topview.top_view_image`,
        with the latest frame's estimates and their 90 % ellipses (perceived state)."""
        return topview.top_view_image(self, i, size, estimates=self.estimates_at(i) or None)


def _yield_seconds(r: DriveResult) -> float | None:
    """Seconds the controller's yielding layer held the car back (None: no engine record)."""
    if r.episode is None:
        return None
    steps = sum(1 for s in r.episode.stats if s.route is not None and s.route.startswith("yielding"))
    return round(steps / r.scenario.control.rate, 3)


def drive_metrics(r: DriveResult) -> dict[str, Any]:
    """metrics.json: per pedestrian (scenario order) name, attentive, min_distance, final_trust,
    frames_seen, trust after the first observation and mean gain per frame; reached_goal,
    time_to_goal (s or null), margin_violations (control steps with some distance < R),
    yield_s (seconds the yielding layer held the car back for a pedestrian it could not pass on the
    road), relaxed_steps, fallback_steps, solve times, perception_latency (s, the scenario's),
    near_range (m, its near-field sensor's; 0: none); render
    mode adds detection_recall and the wall time perception took per frame
    (``per_frame[...]["perception_ms"]``, median and p95). Distances are always the true ones. With
    perceived states (``state``), per pedestrian the localisation error of its track after each
    frame that saw it (median, p95, m), the velocity error (median, m/s) and interval coverage
    (share of those frames with the truth inside the estimate's 90 % region), and ``id_switches``
    (changes of a pedestrian's world track)."""
    sc = r.scenario
    radius = sc.control.safety_radius
    d = r.distances
    mins = r.min_distance_fine if r.min_distance_fine.size else d.min(axis=0)
    peds = []
    for j, p in enumerate(sc.pedestrians):
        _, tr = r.trust_series(j)
        peds.append(
            {
                "name": p.name,
                "attentive": p.attentive,
                "min_distance": round(float(mins[j]), 4),
                "final_trust": round(float(r.trusts[-1, j]), 4),
                "frames_seen": int(tr.size),
                "first_trust": None if tr.size == 0 else round(float(tr[0]), 4),
                "trust_gain_per_frame": None if tr.size < 2 else round(float((tr[-1] - tr[0]) / (tr.size - 1)), 4),
                **(_localisation(r, j) if r.state == "perceived" else {}),
            }
        )
    gt = sum(f.ground_truth for f in r.frames)
    hits = sum(sum(v.observed and v.in_view for v in f.views) for f in r.frames)
    st = r.solve_times * 1e3
    out: dict[str, Any] = {
        "scenario": sc.name,
        "sensing": r.sensing,
        "state": r.state,
        "seed": r.seed,
        "capture_rate": r.capture_rate,
        "control_rate": sc.control.rate,
        "perception_latency": sc.sensing.perception_latency,
        "near_range": sc.sensing.near_range,
        "near_clutter": sc.sensing.near_clutter if sc.sensing.near_range > 0 else 0.0,
        "pedestrians": peds,
        "reached_goal": bool(r.reached_goal),
        "time_to_goal": None if r.time_to_goal is None else round(float(r.time_to_goal), 3),
        "margin_violations": int(np.sum(np.any(d < radius - 1e-6, axis=1))),
        "safety_radius": radius,
        "max_lateral_offset": round(float(_lateral(r).max(initial=0.0)), 4),
        "road_departure_max": round(_road_departure(r), 4),
        "min_speed": round(float(r.ego[:, 3].min()), 4) if r.ego.shape[1] > 3 else None,
        "yield_s": _yield_seconds(r),
        "relaxed_steps": int(r.slack.sum()),
        "fallback_steps": int(r.fallbacks.sum()),
        "solver_failures": int(sum(s is SolveStatus.FAILED for s in r.statuses)),
        "control_steps": len(r.statuses),
        "frames": len(r.frames),
        "solve_ms_median": round(float(np.median(st)), 3) if st.size else None,
        "solve_ms_p95": round(float(np.percentile(st, 95)), 3) if st.size else None,
    }
    if r.state == "perceived":
        out["id_switches"] = int(sum(_id_switches(r, j) for j in range(len(sc.pedestrians))))
    if r.world != "sim":
        out["world"] = r.world
    if r.sensing == "render":
        out["detection_recall"] = round(hits / gt, 4) if gt else None
        out["false_positives"] = int(sum(f.false_positives for f in r.frames))
        out["per_frame"] = [
            {"time": round(f.time, 3), "detected": f.detections, "ground_truth": f.ground_truth,
             "false_positives": f.false_positives, "perception_ms": _ms(f.timing.get("perception"))}
            for f in r.frames
        ]  # fmt: skip
        ms = [f["perception_ms"] for f in out["per_frame"] if f["perception_ms"] is not None]
        out["perception_ms_median"] = round(float(np.median(ms)), 1) if ms else None
        out["perception_ms_p95"] = round(float(np.percentile(ms, 95)), 1) if ms else None
    return out


def _road_departure(r: DriveResult) -> float:
    """Largest distance of the car's centre beyond the road's drivable edge (0: always on it)."""
    road = r.scenario.road
    lateral = _distance_from_line(r.ego[:, :2], road.start, road.end)
    return float(np.maximum(lateral - road.width / 2, 0.0).max(initial=0.0))


def _distance_from_line(points: NDArray[np.float64], a: Any, b: Any) -> NDArray[np.float64]:
    """Distance of each point from the straight line through ``a`` and ``b``."""
    a = np.asarray(a, dtype=float)
    t = np.asarray(b, dtype=float) - a
    t /= np.linalg.norm(t)
    return np.abs((points - a) @ np.array([-t[1], t[0]]))


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else round(1e3 * float(seconds), 1)


def _localisation(r: DriveResult, j: int) -> dict[str, Any]:
    """Localisation metrics of pedestrian ``j`` over the frames where its track was updated."""
    err, verr, inside = [], [], []
    for f in r.frames:
        v = f.views[j]
        if v.estimate is None or v.estimate_cov is None or v.position is None or v.velocity is None:
            continue
        d = v.estimate[:2] - v.position
        err.append(float(np.hypot(*d)))
        verr.append(float(np.hypot(*(v.estimate[2:] - v.velocity))))
        inside.append(float(d @ np.linalg.solve(v.estimate_cov[:2, :2], d)) <= chi2_90)
    if not err:
        return {"localisation_error_median": None, "localisation_error_p95": None,
                "velocity_error_median": None, "interval_coverage": None}  # fmt: skip
    return {
        "localisation_error_median": round(float(np.median(err)), 4),
        "localisation_error_p95": round(float(np.percentile(err, 95)), 4),
        "velocity_error_median": round(float(np.median(verr)), 4),
        "interval_coverage": round(float(np.mean(inside)), 4),
    }


def _id_switches(r: DriveResult, j: int) -> int:
    """Times pedestrian ``j``'s world track changed between the frames that saw it."""
    ids = [f.views[j].track_id for f in r.frames if f.views[j].observed and f.views[j].track_id is not None]
    return int(sum(a != b for a, b in itertools.pairwise(ids)))


def _lateral(r: DriveResult) -> NDArray[np.float64]:
    """Distance of the ego from its reference line (start -> goal), per sample."""
    return _distance_from_line(r.ego[:, :2], r.scenario.ego_start, r.scenario.goal)


def run_drive(
    scenario: DriveScenario,
    sensing: str = "keypoints",
    seed: int = 0,
    attentive: bool | None = None,
    capture_rate: float | None = None,
    control_rate: float | None = None,
    renderer: Any = None,
    pipeline: Any = None,
    progress: Callable[[float, float], None] | None = None,
    max_frames: int | None = None,
    state: str = "perceived",
) -> DriveResult:
    """Drive one episode in trustnav's own world with the trust-aware MPC in the loop; pure (no
    files written). ``state``: where the controller's pedestrians come from ("perceived": the
    camera, "true": the world; see the module).

    sensing: "keypoints" (fast) or "render" (needs ``renderer`` with ``.render(camera, people)`` and a
    perception ``pipeline``; see :func:`trustnav.sim.driving.make_render_sensing`). attentive:
    True/False makes every pedestrian attentive/distracted (Case II's two runs); None as given.
    capture_rate (frames/s) defaults to the scenario's camera rate, control_rate to its control
    rate. progress(t, duration) is called after each control step. max_frames stops capturing
    after that many frames (short tests).
    """
    sensor = make_sensor(sensing, renderer, pipeline)
    sc = prepare_scenario(scenario, attentive, control_rate)
    environment = DriveEnvironment(sc, seed=seed, sensor=sensor, capture_rate=capture_rate, state=state)
    return drive(environment, sensing, progress=progress, max_frames=max_frames)


def prepare_scenario(
    scenario: DriveScenario, attentive: bool | None = None, control_rate: float | None = None
) -> DriveScenario:
    """The scenario with every pedestrian attentive/distracted (None: as given) and, if given,
    another control rate."""
    sc = scenario.with_attention(attentive)
    if control_rate is not None:
        sc = replace(sc, control=replace(sc.control, rate=float(control_rate)))
    return sc


def make_sensor(sensing: str, renderer: Any = None, pipeline: Any = None) -> RenderSensor | None:
    """The sensor of a sensing mode: None for "keypoints" (DriveEnvironment builds it from its seed),
    a RenderSensor over ``renderer`` and ``pipeline`` for "render"."""
    if sensing not in SENSING_MODES:
        raise ValueError(f"sensing must be one of {SENSING_MODES}, got {sensing!r}")
    if sensing == "keypoints":
        return None
    if renderer is None or pipeline is None:
        raise ValueError("render sensing needs a renderer and a perception pipeline")
    return RenderSensor(renderer, pipeline)


def drive(
    environment: DriveEnvironment,
    sensing: str,
    progress: Callable[[float, float], None] | None = None,
    max_frames: int | None = None,
) -> DriveResult:
    """Run the trust-aware MPC on ``environment`` (on any :class:`World`) with the engine's runner
    until the goal or the scenario's duration: per control step its ``observe()`` (a frame's path to
    the controller), solve, and apply the plan's first input (index 0: the command for now; the
    controller itself plans from the state predicted ``control.latency`` ahead)."""
    sc = environment.scenario
    if max_frames is not None:
        environment.max_frames = max_frames
    policy = drive_controller(sc, environment.capture_rate)

    def report(_k: int, _obs: Observation, _d: Decision) -> None:
        if progress is not None:
            progress(environment.time, sc.duration)

    return drive_result(environment, sensing, run(environment, policy, on_step=report))


def drive_controller(scenario: DriveScenario, capture_rate: float) -> MpcPolicy:
    """The trust-aware MPC of every drive of ``scenario``, its camera at ``capture_rate`` frames/s
    (which, with the perception latency, sets the caution's reaction time): its ``[vehicle]`` model,
    its lane, its ``[control]`` (caution, yielding told what the camera sees) and its road's edges
    as barriers. ``.controller`` is the :class:`~trustnav.control.MpcController`, for a loop of
    one's own (the Gymnasium environment: ``examples/gym_mpc.py``)."""
    sc = scenario
    config = sc.control.config(capture_rate, sc.sensing.perception_latency, sc.camera)
    model, cost = sc.vehicle.model(), sc.control.cost(sc.ego_start, sc.goal)
    return make_mpc(model, cost, config, timed=True, barriers=sc.control.barriers(sc.road, sc.vehicle))


def drive_result(environment: DriveEnvironment, sensing: str, episode: EpisodeResult) -> DriveResult:
    """The :class:`DriveResult` of an engine episode on ``environment``."""
    plans = [p for p in episode.plans if p is not None]
    n = episode.steps
    return DriveResult(
        scenario=environment.scenario,
        sensing=sensing,
        seed=environment.seed,
        capture_rate=environment.capture_rate,
        times=episode.times,
        ego=episode.ego,
        pedestrians=episode.pedestrians,
        trusts=episode.trusts,
        statuses=[SolveStatus(s) for s in episode.statuses if s in _STATUS_VALUES],
        fallbacks=np.array([s.fallback for s in episode.stats], dtype=bool).reshape(n),
        slack=np.array([s.relaxed for s in episode.stats], dtype=bool).reshape(n),
        solve_times=np.array([s.solve_time for s in episode.stats if math.isfinite(s.solve_time)]),
        plans=np.array(plans) if plans else np.zeros((0, 2, 4)),
        frames=environment.frames,
        reached_goal=episode.reached_goal,
        time_to_goal=environment.time if episode.reached_goal else None,
        min_distance_fine=environment.min_distance_fine.copy() if environment.steps else np.zeros(0),
        world=environment.world.name,
        episode=episode,
        state=environment.state_source,
    )


_STATUS_VALUES = frozenset(s.value for s in SolveStatus)
