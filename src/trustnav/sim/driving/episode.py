"""End-to-end trust-aware driving, offline (the paper's Section IV, Cases I and II):
camera frames -> perception -> trust -> bicycle MPC (`proposed` with `cbf_imp`) -> car.

Two rates: the controller runs every 1 / control.rate seconds, the camera captures a frame every
1 / camera.rate seconds (the trust-estimation rate). Rendering and perception take no simulated
time and the controller never waits for them: a frame captured at t updates the trusts used from
the control step at t on. Pedestrian positions and velocities for the controller come from the
world (as in the authors' code), optionally with noise; trust comes only from perception.

:class:`DriveSimulation` steps the world (used by :func:`run_drive` with the MPC in the loop and by
the Gymnasium environment with any controller); :func:`run_drive` is a pure function of
(scenario, parameters, seed) that returns a :class:`DriveResult` and writes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import MpcController, SolveStatus
from trustnav.sim.driving.sensing import (
    SENSING_MODES,
    FrameReport,
    KeypointSensor,
    PedestrianView,
    RenderSensor,
    TrustTracker,
    in_view,
    projected_box,
)
from trustnav.sim.driving.world import DriveScenario, VehiclePlant, pedestrian_bodies, pedestrian_states

__all__ = ["DriveResult", "DriveSimulation", "drive_metrics", "run_drive"]


class DriveSimulation:
    """The world with its camera, sensing and trust memory, advanced one control period at a time.

    ``sensor``: a :class:`KeypointSensor` (default, built from the scenario and seed) or a
    :class:`RenderSensor`. Randomness (sensing noise, controller-input noise) comes from ``seed``.
    """

    def __init__(
        self,
        scenario: DriveScenario,
        seed: int = 0,
        sensor: KeypointSensor | RenderSensor | None = None,
        capture_rate: float | None = None,
        control_rate: float | None = None,
    ) -> None:
        self.scenario = scenario
        self.seed = seed
        ss = np.random.SeedSequence(seed)
        sense_seq, input_seq = ss.spawn(2)
        self.rng_inputs = np.random.default_rng(input_seq)
        self.sensor = sensor or KeypointSensor(scenario.sensing, np.random.default_rng(sense_seq))
        self.capture_rate = float(capture_rate or scenario.camera.rate)
        self.control_rate = float(control_rate or scenario.control.rate)
        if not self.capture_rate > 0 or not self.control_rate > 0:
            raise ValueError("capture_rate and control_rate must be positive")
        self.period = 1.0 / self.control_rate
        self.plant = VehiclePlant(scenario.vehicle, scenario.initial_state())
        self.trust = TrustTracker(len(scenario.pedestrians), keep_time=scenario.sensing.keep_time)
        self.frames: list[FrameReport] = []
        self._next_capture = 0.0
        self.time = 0.0

    @property
    def state(self) -> NDArray[np.float64]:
        """Ego state (x, y, yaw, v)."""
        return self.plant.state.copy()

    def pedestrians(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """True positions and velocities (N, 2) now."""
        return pedestrian_states(self.scenario, self.time)

    def controller_inputs(self) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """(ego state, pedestrian positions, velocities, trusts) as the controller gets them."""
        pos, vel = self.pedestrians()
        s = self.scenario.sensing
        if s.position_noise > 0:
            pos = pos + self.rng_inputs.normal(0.0, s.position_noise, pos.shape)
        if s.velocity_noise > 0:
            vel = vel + self.rng_inputs.normal(0.0, s.velocity_noise, vel.shape)
        return self.state, pos, vel, self.trust.trusts()

    def capture_due(self) -> bool:
        return self.time + 1e-9 >= self._next_capture

    def capture(self) -> FrameReport:
        """Capture a frame now, perceive it and update the trusts of the pedestrians observed."""
        sc = self.scenario
        cam = sc.camera.pose(self.plant.state[:2], float(self.plant.state[2]))
        bodies = pedestrian_bodies(sc, self.time, cam.position)
        sensed, image, false_pos, timing = self.sensor.sense(cam, bodies)
        self.trust.update(sensed, self.time)
        by_index = {s.index: s for s in sensed}
        views = []
        for j, (sk, _) in enumerate(bodies):
            seen = by_index.get(j)
            views.append(
                PedestrianView(
                    index=j,
                    in_view=in_view(cam, sk, sc.sensing),
                    box=projected_box(cam, sk),
                    observed=seen is not None,
                    track_id=None if seen is None else seen.track_id,
                    eye_contact=None if seen is None else seen.eye_contact,
                    phone=None if seen is None else seen.phone,
                    trust=self.trust.trust(j),
                )
            )
        report = FrameReport(len(self.frames), self.time, views, false_pos, timing, cam, sensed, image)
        self.frames.append(report)
        self._next_capture = len(self.frames) / self.capture_rate
        return report

    def advance(self, command: ArrayLike) -> NDArray[np.float64]:
        """Send (steer, accel) to the car and run the world one control period; returns the plant's
        sub-step states."""
        self.plant.send(command)
        sub = self.plant.advance(self.period)
        self.time = self.plant.time
        return sub

    def distance_to_goal(self) -> float:
        return float(np.hypot(*(self.plant.state[:2] - np.asarray(self.scenario.goal))))

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

    @property
    def distances(self) -> NDArray[np.float64]:
        """Ego-pedestrian distance at each sample (T+1, N)."""
        return np.linalg.norm(self.ego[:, None, :2] - self.pedestrians, axis=2)

    def trust_series(self, index: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(times, trusts) of pedestrian ``index`` at the frames that observed it."""
        pts = [(f.time, f.views[index].trust) for f in self.frames if f.views[index].observed]
        arr = np.array(pts, dtype=float).reshape(-1, 2)
        return arr[:, 0], arr[:, 1]

    def metrics(self) -> dict[str, Any]:
        return drive_metrics(self)


def drive_metrics(r: DriveResult) -> dict[str, Any]:
    """metrics.json: per pedestrian (scenario order) name, attentive, min_distance, final_trust,
    frames_seen, trust after the first observation and mean gain per frame; reached_goal,
    time_to_goal (s or null), margin_violations (control steps with some distance < R),
    relaxed_steps, fallback_steps, solve times; render mode adds detection_recall."""
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
            }
        )
    gt = sum(f.ground_truth for f in r.frames)
    hits = sum(sum(v.observed and v.in_view for v in f.views) for f in r.frames)
    st = r.solve_times * 1e3
    out: dict[str, Any] = {
        "scenario": sc.name,
        "sensing": r.sensing,
        "seed": r.seed,
        "capture_rate": r.capture_rate,
        "control_rate": sc.control.rate,
        "pedestrians": peds,
        "reached_goal": bool(r.reached_goal),
        "time_to_goal": None if r.time_to_goal is None else round(float(r.time_to_goal), 3),
        "margin_violations": int(np.sum(np.any(d < radius - 1e-6, axis=1))),
        "safety_radius": radius,
        "max_lateral_offset": round(float(_lateral(r).max(initial=0.0)), 4),
        "relaxed_steps": int(r.slack.sum()),
        "fallback_steps": int(r.fallbacks.sum()),
        "solver_failures": int(sum(s is SolveStatus.FAILED for s in r.statuses)),
        "control_steps": len(r.statuses),
        "frames": len(r.frames),
        "solve_ms_median": round(float(np.median(st)), 3) if st.size else None,
        "solve_ms_p95": round(float(np.percentile(st, 95)), 3) if st.size else None,
    }
    if r.sensing == "render":
        out["detection_recall"] = round(hits / gt, 4) if gt else None
        out["false_positives"] = int(sum(f.false_positives for f in r.frames))
        out["per_frame"] = [
            {"time": round(f.time, 3), "detected": f.detections, "ground_truth": f.ground_truth,
             "false_positives": f.false_positives}
            for f in r.frames
        ]  # fmt: skip
    return out


def _lateral(r: DriveResult) -> NDArray[np.float64]:
    """Signed distance of the ego from its reference line (start -> goal), left positive, per sample."""
    a = np.asarray(r.scenario.ego_start)
    t = np.asarray(r.scenario.goal) - a
    t /= np.linalg.norm(t)
    n = np.array([-t[1], t[0]])
    return np.abs((r.ego[:, :2] - a) @ n)


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
) -> DriveResult:
    """Drive one episode with the trust-aware MPC in the loop; pure (no files written).

    sensing: "keypoints" (fast) or "render" (needs ``renderer`` with ``.render(camera, people)`` and a
    perception ``pipeline``; see :func:`trustnav.sim.driving.make_render_sensing`). attentive:
    True/False makes every pedestrian attentive/distracted (Case II's two runs); None as given.
    capture_rate (frames/s) defaults to the scenario's camera rate, control_rate to its control
    rate. progress(t, duration) is called after each control step. max_frames stops capturing
    after that many frames (short tests).
    """
    if sensing not in SENSING_MODES:
        raise ValueError(f"sensing must be one of {SENSING_MODES}, got {sensing!r}")
    sc = scenario.with_attention(attentive)
    if control_rate is not None:
        sc = replace(sc, control=replace(sc.control, rate=float(control_rate)))
    sensor = None
    if sensing == "render":
        if renderer is None or pipeline is None:
            raise ValueError("render sensing needs a renderer and a perception pipeline")
        sensor = RenderSensor(renderer, pipeline)
    sim = DriveSimulation(sc, seed=seed, sensor=sensor, capture_rate=capture_rate)
    model = sc.vehicle.model()
    ctl = MpcController(model, sc.control.cost(sc.ego_start, sc.goal), sc.control.config())
    radius_pts = np.array([p.position for p in sc.pedestrians])
    times, ego, peds, trusts = [sim.time], [sim.state], [sim.pedestrians()[0]], [sim.trust.trusts()]
    statuses, fallbacks, slack, solve_times, plans = [], [], [], [], []
    min_fine = np.full(len(sc.pedestrians), np.inf)
    reached = sim.reached_goal()
    steps = math.ceil(sc.duration * sim.control_rate - 1e-9)
    for _ in range(steps):
        if reached:
            break
        if sim.capture_due() and (max_frames is None or len(sim.frames) < max_frames):
            sim.capture()
        state, pos, vel, tr = sim.controller_inputs()
        sol = ctl.step(state, pos, vel, tr)
        statuses.append(sol.status)
        fallbacks.append(sol.fallback)
        slack.append(sol.slack_used)
        solve_times.append(sol.solve_time)
        plans.append(sol.predicted_states)
        t0 = sim.time
        sub = sim.advance(sol.control)
        sub_t = t0 + np.arange(1, len(sub) + 1) * (sim.period / len(sub))
        p0, v0 = radius_pts, np.array([p.velocity for p in sc.pedestrians])
        ped_sub = p0[None] + sub_t[:, None, None] * v0[None]
        min_fine = np.minimum(min_fine, np.linalg.norm(sub[:, None, :2] - ped_sub, axis=2).min(axis=0))
        times.append(sim.time)
        ego.append(sim.state)
        peds.append(sim.pedestrians()[0])
        trusts.append(sim.trust.trusts())
        reached = sim.reached_goal()
        if progress is not None:
            progress(sim.time, sc.duration)
    return DriveResult(
        scenario=sc,
        sensing=sensing,
        seed=seed,
        capture_rate=sim.capture_rate,
        times=np.array(times),
        ego=np.array(ego),
        pedestrians=np.array(peds),
        trusts=np.array(trusts),
        statuses=statuses,
        fallbacks=np.array(fallbacks, dtype=bool),
        slack=np.array(slack, dtype=bool),
        solve_times=np.array(solve_times),
        plans=np.array(plans),
        frames=sim.frames,
        reached_goal=reached,
        time_to_goal=sim.time if reached else None,
        min_distance_fine=min_fine,
    )
