"""A Gymnasium environment around the driving world: put any controller in the car.

Importing this module registers ``trustnav/Drive-v0``::

    import gymnasium as gym
    import trustnav.sim.driving.gym_env  # registers the id
    env = gym.make("trustnav/Drive-v0", scenario="case-1", sensing="keypoints")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Action: (steer rad, acceleration m/s^2) within the vehicle's limits, sent to the car every control
period (1 / control.rate s; it acts after the actuation latency). Observation: ``ego`` (x, y, yaw, v)
and up to ``max_pedestrians`` (K) pedestrians, nearest first, zero-padded: ``pedestrians`` (K, 2)
positions, ``velocities`` (K, 2), ``covariances`` (K, 4, 4) of (x, y, v_x, v_y), ``trusts`` (K,),
``present`` (K,) 1 for a slot that holds a pedestrian; ``time``. With ``state="perceived"``
(default) they are the camera's world tracks (positions from the image, trust per track, 0
until a track has one); with ``state="true"`` the world's pedestrians in scenario order (with the
scenario's noise, covariances 0) and trusts from perception (0 until first observed).
Reward: progress along the lane (m) minus 10 per step with a pedestrian inside the margin R;
terminated at the goal, truncated after ``scenario.duration``.

The environment steps the same engine world as ``trustnav drive`` (:class:`DriveSimulation`, through
a :class:`~trustnav.sim.engine.Rollout`): the same capture, sensing, controller inputs and plant.
``render()`` returns the top view (``view="top"``) or the latest camera image (``view="camera"``:
the rendered frame with render sensing, else the top view), RGB; ``render_fn(result) -> RGB``
replaces it (e.g. ``trustnav.viz.drive_plots.latest_annotated_frame`` for the annotated frame).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from trustnav.sim.driving.episode import STATES, DriveResult, DriveSimulation, drive_result
from trustnav.sim.driving.sensing import RenderSensor, make_render_sensing
from trustnav.sim.driving.world import DriveScenario, load_drive_scenario
from trustnav.sim.engine import Decision, Rollout

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
        render_fn: Callable[[DriveResult], NDArray[np.uint8]] | None = None,
        state: str = "perceived",
        max_pedestrians: int = 8,
    ) -> None:
        sc = load_drive_scenario(scenario) if isinstance(scenario, str) else scenario
        if sensing not in ("keypoints", "render"):
            raise ValueError(f"sensing must be 'keypoints' or 'render', got {sensing!r}")
        if state not in STATES:
            raise ValueError(f"state must be one of {STATES}, got {state!r}")
        n_true = len(sc.pedestrians)
        if isinstance(max_pedestrians, bool) or not isinstance(max_pedestrians, int) or not 1 <= max_pedestrians <= 256:
            raise ValueError(f"max_pedestrians must be an integer in [1, 256], got {max_pedestrians!r}")
        if state == "true" and max_pedestrians < n_true:
            raise ValueError(f"max_pedestrians ({max_pedestrians}) must hold the scenario's {n_true} pedestrians")
        self.state = state
        self.max_pedestrians = max_pedestrians
        if view not in ("top", "camera"):
            raise ValueError(f"view must be 'top' or 'camera', got {view!r}")
        self.scenario = sc.with_attention(attentive)
        self.sensing = sensing
        self.capture_rate = capture_rate
        self.render_mode = render_mode
        self.view = view
        self.render_fn = render_fn
        model = self.scenario.vehicle.model()
        lo, hi = model.input_bounds()
        self.action_space = spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        n = max_pedestrians
        big = 1e4
        self.observation_space = spaces.Dict(
            {
                "ego": spaces.Box(-big, big, shape=(4,), dtype=np.float64),
                "pedestrians": spaces.Box(-big, big, shape=(n, 2), dtype=np.float64),
                "velocities": spaces.Box(-big, big, shape=(n, 2), dtype=np.float64),
                "covariances": spaces.Box(-big, big, shape=(n, 4, 4), dtype=np.float64),
                "trusts": spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float64),
                "present": spaces.MultiBinary(n),
                "time": spaces.Box(0.0, big, shape=(1,), dtype=np.float64),
            }
        )
        self._renderer: Any = None
        self._pipeline: Any = None
        self.sim: DriveSimulation | None = None
        self.rollout: Rollout | None = None

    # -- Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        sensor = None
        if self.sensing == "render":
            self._close_sensing()
            self._renderer, self._pipeline = make_render_sensing(self.scenario, self.capture_rate)
            sensor = RenderSensor(self._renderer, self._pipeline)
        run_seed = int(self.np_random.integers(2**31)) if seed is None else int(seed)
        self.sim = DriveSimulation(
            self.scenario, seed=run_seed, sensor=sensor, capture_rate=self.capture_rate, state=self.state
        )
        sc = self.scenario.control
        self.rollout = Rollout(self.sim, horizon=sc.horizon, safety_radius=sc.safety_radius)
        return self._observe(), self._info()

    def step(self, action: Any):
        if self.sim is None or self.rollout is None:
            raise RuntimeError("call reset() before step()")
        u = np.clip(np.asarray(action, dtype=float).reshape(2), self.action_space.low, self.action_space.high)
        s_before = self._progress()
        self.rollout.apply(Decision(u))
        obs = self._observe()
        d = self._distances()
        inside = bool(np.any(d < self.scenario.control.safety_radius))
        reward = self._progress() - s_before - (10.0 if inside else 0.0)
        reason = self.rollout.done()
        terminated = reason == "goal"
        truncated = reason == "time"
        return obs, float(reward), terminated, truncated, self._info()

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array" or self.sim is None:
            return None
        result = self.result()
        if self.render_fn is not None:
            return self.render_fn(result)
        if self.view == "camera" and result.frames and result.frames[-1].image is not None:
            return result.frames[-1].image
        import cv2

        return cv2.cvtColor(result.top_view_image(len(result.times) - 1), cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        self._close_sensing()

    # -- helpers
    def result(self) -> DriveResult:
        """The episode so far as a DriveResult (for the plots of trustnav.viz.drive_plots)."""
        assert self.sim is not None and self.rollout is not None
        return drive_result(self.sim, self.sensing, self.rollout.result())

    def _observe(self) -> dict[str, NDArray[np.float64]]:
        """The world's observation (captures a frame when due), as the observation space has it."""
        assert self.rollout is not None
        o = self.rollout.observe()
        k = self.max_pedestrians
        m = min(len(o.positions), k)  # the nearest k when more are known
        order = np.argsort(np.linalg.norm(o.positions - o.ego[:2], axis=1), kind="stable")[:m] if m else []
        pos, vel, cov, tr = np.zeros((k, 2)), np.zeros((k, 2)), np.zeros((k, 4, 4)), np.zeros(k)
        pos[:m], vel[:m], tr[:m] = o.positions[order], o.velocities[order], o.trusts[order]
        if o.covariances is not None:
            cov[:m] = o.covariances[order]
        present = np.zeros(k, dtype=np.int8)
        present[:m] = 1
        return {
            "ego": o.ego,
            "pedestrians": pos,
            "velocities": vel,
            "covariances": cov,
            "trusts": tr,
            "present": present,
            "time": np.array([o.time]),
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
