"""A Gymnasium environment around the driving world: put any controller in the car.

Importing this module registers ``trustnav/Drive-v0``::

    import gymnasium as gym
    import trustnav.sim.driving.gym_env  # registers the id
    env = gym.make("trustnav/Drive-v0", scenario="case-1", sensing="keypoints")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Action: (steer rad, acceleration m/s^2) within the vehicle's limits, sent to the car every control
period (1 / control.rate s; it acts after the actuation latency). Observation: ``ego`` (x, y, yaw, v),
``pedestrians`` (N, 2) positions and ``velocities`` (N, 2) (from the world, with the scenario's
noise), ``trusts`` (N,) from perception (0 until a pedestrian is first observed), ``time``.
Reward: progress along the lane (m) minus 10 per step with a pedestrian inside the margin R;
terminated at the goal, truncated after ``scenario.duration``. ``render()`` returns the top view
(``view="top"``) or the latest annotated camera frame (``view="camera"``), RGB.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from trustnav.sim.driving.episode import DriveResult, DriveSimulation
from trustnav.sim.driving.sensing import RenderSensor, make_render_sensing
from trustnav.sim.driving.world import DriveScenario, load_drive_scenario

__all__ = ["ENV_ID", "DriveEnv"]

ENV_ID = "trustnav/Drive-v0"


class DriveEnv(gym.Env):
    """The trust-aware driving world (paper Section IV) as a Gymnasium environment."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        scenario: str | DriveScenario = "case-1",
        sensing: str = "keypoints",
        attentive: bool | None = None,
        capture_rate: float | None = None,
        render_mode: str | None = "rgb_array",
        view: str = "top",
    ) -> None:
        sc = load_drive_scenario(scenario) if isinstance(scenario, str) else scenario
        if sensing not in ("keypoints", "render"):
            raise ValueError(f"sensing must be 'keypoints' or 'render', got {sensing!r}")
        if view not in ("top", "camera"):
            raise ValueError(f"view must be 'top' or 'camera', got {view!r}")
        self.scenario = sc.with_attention(attentive)
        self.sensing = sensing
        self.capture_rate = capture_rate
        self.render_mode = render_mode
        self.view = view
        model = self.scenario.vehicle.model()
        lo, hi = model.input_bounds()
        self.action_space = spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        n = len(self.scenario.pedestrians)
        big = 1e4
        self.observation_space = spaces.Dict(
            {
                "ego": spaces.Box(-big, big, shape=(4,), dtype=np.float64),
                "pedestrians": spaces.Box(-big, big, shape=(n, 2), dtype=np.float64),
                "velocities": spaces.Box(-big, big, shape=(n, 2), dtype=np.float64),
                "trusts": spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float64),
                "time": spaces.Box(0.0, big, shape=(1,), dtype=np.float64),
            }
        )
        self._renderer: Any = None
        self._pipeline: Any = None
        self.sim: DriveSimulation | None = None

    # -- Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        sensor = None
        if self.sensing == "render":
            self._close_sensing()
            self._renderer, self._pipeline = make_render_sensing(self.scenario, self.capture_rate)
            sensor = RenderSensor(self._renderer, self._pipeline)
        run_seed = int(self.np_random.integers(2**31)) if seed is None else int(seed)
        self.sim = DriveSimulation(self.scenario, seed=run_seed, sensor=sensor, capture_rate=self.capture_rate)
        self._history: dict[str, list] = {"times": [], "ego": [], "peds": [], "trusts": [], "plans": []}
        if self.sim.capture_due():
            self.sim.capture()
        self._record()
        return self._obs(), self._info()

    def step(self, action: Any):
        if self.sim is None:
            raise RuntimeError("call reset() before step()")
        u = np.clip(np.asarray(action, dtype=float).reshape(2), self.action_space.low, self.action_space.high)
        s_before = self._progress()
        self.sim.advance(u)
        if self.sim.capture_due():
            self.sim.capture()
        self._record()
        d = self._distances()
        inside = bool(np.any(d < self.scenario.control.safety_radius))
        reward = self._progress() - s_before - (10.0 if inside else 0.0)
        terminated = self.sim.reached_goal()
        truncated = (not terminated) and self.sim.time >= self.scenario.duration - 1e-9
        return self._obs(), float(reward), terminated, truncated, self._info()

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array" or self.sim is None:
            return None
        import cv2

        from trustnav.viz import drive_plots

        result = self.result()
        if self.view == "camera" and result.frames:
            last = DriveResult(**{**result.__dict__, "frames": result.frames[-1:]})
            return cv2.cvtColor(drive_plots.annotated_frames(last)[0], cv2.COLOR_BGR2RGB)
        img = drive_plots._top_view_frame(result, len(result.times) - 1, (1280, 400), result.ego[:, :2])
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        self._close_sensing()

    # -- helpers
    def result(self) -> DriveResult:
        """The episode so far as a DriveResult (for the plots of trustnav.viz.drive_plots)."""
        assert self.sim is not None
        h = self._history
        n_steps = len(h["times"]) - 1
        return DriveResult(
            scenario=self.scenario,
            sensing=self.sensing,
            seed=self.sim.seed,
            capture_rate=self.sim.capture_rate,
            times=np.array(h["times"]),
            ego=np.array(h["ego"]),
            pedestrians=np.array(h["peds"]),
            trusts=np.array(h["trusts"]),
            statuses=[],
            fallbacks=np.zeros(n_steps, dtype=bool),
            slack=np.zeros(n_steps, dtype=bool),
            solve_times=np.zeros(0),
            plans=np.zeros((0, 2, 4)),
            frames=list(self.sim.frames),
            reached_goal=self.sim.reached_goal(),
            time_to_goal=self.sim.time if self.sim.reached_goal() else None,
        )

    def _record(self) -> None:
        assert self.sim is not None
        h = self._history
        h["times"].append(self.sim.time)
        h["ego"].append(self.sim.state)
        h["peds"].append(self.sim.pedestrians()[0])
        h["trusts"].append(self.sim.trust.trusts())

    def _obs(self) -> dict[str, NDArray[np.float64]]:
        assert self.sim is not None
        state, pos, vel, tr = self.sim.controller_inputs()
        return {
            "ego": state,
            "pedestrians": pos,
            "velocities": vel,
            "trusts": tr,
            "time": np.array([self.sim.time]),
        }

    def _info(self) -> dict[str, Any]:
        assert self.sim is not None
        return {
            "distances": self._distances(),
            "frames": len(self.sim.frames),
            "distance_to_goal": self.sim.distance_to_goal(),
        }

    def _distances(self) -> NDArray[np.float64]:
        assert self.sim is not None
        return np.linalg.norm(self.sim.pedestrians()[0] - self.sim.state[:2], axis=1)

    def _progress(self) -> float:
        assert self.sim is not None
        a = np.asarray(self.scenario.ego_start)
        t = np.asarray(self.scenario.goal) - a
        return float((self.sim.state[:2] - a) @ t / np.linalg.norm(t))

    def _close_sensing(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._pipeline is not None and hasattr(self._pipeline.backend, "close"):
            self._pipeline.backend.close()
            self._pipeline = None


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="trustnav.sim.driving.gym_env:DriveEnv")
