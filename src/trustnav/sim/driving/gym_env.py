"""A Gymnasium environment around the driving world: put any controller in the car.

``import trustnav`` registers ``trustnav/Drive-v0`` (when gymnasium is installed; importing this
module registers it too). Configuration follows highway-env: a dictionary of the keys of
:meth:`DriveEnv.default_config`, given to ``gym.make`` or to :meth:`DriveEnv.configure`::

    import gymnasium as gym
    import trustnav
    env = gym.make("trustnav/Drive-v0", config={"scenario": "case-1", "sensing": "keypoints"})
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Action (``normalize_actions``, default true): two numbers in [-1, 1], sent to the car every control
period (1 / control.rate s; they act after the actuation latency): ``steer = a[0] * steer_max`` (rad,
> 0 left) and ``accel = a[1] * accel_max`` for ``a[1] >= 0``, ``a[1] * |accel_min|`` below (0 = hold
the speed, -1 = full braking). With ``normalize_actions`` false the action is (steer rad, accel m/s^2)
within the vehicle's limits. An action outside the action space is refused (ValueError), never
silently clipped.

Observation: ``ego`` (x, y, yaw, v) and up to ``max_pedestrians`` (K) pedestrians, nearest first,
zero-padded: ``pedestrians`` (K, 2) positions, ``velocities`` (K, 2), ``covariances`` (K, 4, 4) of
(x, y, v_x, v_y), ``trusts`` (K,), ``present`` (K,) 1 for a slot that holds a pedestrian; ``time``;
and when the camera last saw each: ``seen_times`` (K,), the (x, y, v_x, v_y) it estimated then,
``seen_states`` (K, 4), and their covariances, ``seen_covariances`` (K, 4, 4) (a track coasted out
of view keeps its last sighting; trustnav's MPC keeps an unseen pedestrian from it).
With ``state="perceived"`` (default) they are the camera's world tracks (positions from the image,
trust per track, 0 until a track has one); with ``state="true"`` the world's pedestrians in
scenario order (with the scenario's noise, covariances 0; seen now) and trusts from perception.
trustnav's own trust-aware MPC drives the environment from these (the controller of ``trustnav
drive``, :func:`~trustnav.sim.driving.episode.drive_controller`; ``examples/gym_mpc.py``).

Episode end, each reported in ``info`` (``collision``, ``off_road``, ``reached_goal``, ``time_out``
and ``reason``, one of "collision", "off_road", "goal", "time" or None), first match wins:
terminated on a **collision** (the true distance from the car's reference point to a pedestrian,
over the world's sub-steps, below ``contact_radius``), on **leaving the road** (the car's centre
beyond the drivable edge of the scenario's ``[road]`` by more than ``off_road_margin``, or past
its ends; ``terminate_off_road``), at the **goal** (within the scenario's ``goal_tolerance`` at a
speed <= ``goal_max_speed``; ``goal_max_speed`` None: the goal is a pass-through and counts at any
speed); truncated after ``scenario.duration``. A step after the episode has ended is refused
(RuntimeError) until :meth:`~DriveEnv.reset`.
Reward: ``progress_reward`` x progress along the lane (m), ``- margin_penalty`` per step with a
pedestrian inside the margin R, ``- collision_penalty``, ``- off_road_penalty`` at those ends,
``+ goal_reward`` at the goal.

The environment steps the same engine world as ``trustnav drive`` (:class:`DriveEnvironment`, through
a :class:`~trustnav.sim.engine.Rollout`): the same capture, sensing, controller inputs and plant.
``render_mode`` is None (default) or "rgb_array": ``render()`` then returns the top view
(``view="top"``) or the latest camera image (``view="camera"``: the rendered frame with render
sensing, else the top view), RGB; ``render_fn(result) -> RGB`` replaces it (e.g.
``trustnav.viz.drive_plots.latest_annotated_frame`` for the annotated frame).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Annotated, Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from trustnav.schema import Dotted, Flag, Integer, Maybe, Number, OneOf, SchemaError, check_fields, load
from trustnav.sim.driving.episode import STATES, DriveEnvironment, DriveResult, drive_result
from trustnav.sim.driving.sensing import RenderSensor, make_render_sensing
from trustnav.sim.driving.world import DriveScenario, load_drive_scenario
from trustnav.sim.engine import Decision, Rollout

__all__ = ["ENV_ID", "DriveEnv", "DriveEnvConfig"]

ENV_ID = "trustnav/Drive-v0"


_REWARD = Number(-1e6, 1e6)  # a reward or penalty per event


@dataclass(frozen=True)
class DriveEnvConfig:
    """The environment's configuration (the keys of :meth:`DriveEnv.default_config`; see the module),
    checked by :mod:`trustnav.schema` (``config contact_radius must be a number in [0, 10] m, got
    -1``; a misspelled key gets the key meant)."""

    scenario: str | DriveScenario = "case-1"
    sensing: Annotated[str, OneOf("keypoints", "render")] = "keypoints"
    attentive: Annotated[bool | None, Maybe(Flag(), none="None")] = None
    capture_rate: Annotated[float | None, Maybe(Number(1e-3, 1000.0, unit=" frames/s"), none="None")] = None
    state: Annotated[str, OneOf(*STATES)] = "perceived"
    max_pedestrians: Annotated[int, Integer(1, 256)] = 8
    view: Annotated[str, OneOf("top", "camera")] = "top"
    normalize_actions: bool = True
    contact_radius: Annotated[float, Number(0.0, 10.0, unit=" m")] = 1.0
    terminate_off_road: bool = True
    off_road_margin: Annotated[float, Number(0.0, 50.0, unit=" m")] = 0.0
    goal_max_speed: Annotated[float | None, Maybe(Number(0.0, 100.0, unit=" m/s"), none="None")] = 2.0
    progress_reward: Annotated[float, _REWARD] = 1.0
    margin_penalty: Annotated[float, _REWARD] = 10.0
    collision_penalty: Annotated[float, _REWARD] = 100.0
    off_road_penalty: Annotated[float, _REWARD] = 100.0
    goal_reward: Annotated[float, _REWARD] = 0.0

    def __post_init__(self) -> None:
        check_fields(self, Dotted("config"))
        _scenario(self.scenario, Dotted("config").sub("scenario"))

    @classmethod
    def from_dict(cls, config: dict[str, Any]) -> DriveEnvConfig:
        """From a configuration dictionary: every error at once, one line each; an unknown key
        named with the key meant (``unknown key 'contact_radus' in config: did you mean
        'contact_radius'?``)."""
        if not isinstance(config, dict):
            raise SchemaError(f"config must be a dictionary, got {config!r}")
        return load(cls, config, Dotted("config"), convert={"scenario": _scenario})  # type: ignore[no-any-return]


def _scenario(value: Any, place: Dotted) -> str | DriveScenario:
    """The scenario of a configuration: a preset's name, a .toml path or a DriveScenario."""
    if not isinstance(value, (str, DriveScenario)):
        raise SchemaError(f"{place.table} must be a name, a .toml path or a DriveScenario, got {value!r}")
    return value


class DriveEnv(gym.Env):
    """The trust-aware driving world (paper Section IV) as a Gymnasium environment.

    ``config``: a dictionary of :meth:`default_config` keys (unknown keys refused by name); keyword
    arguments of the same names are merged over it (``gym.make(ENV_ID, scenario="case-2")``).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        config: dict[str, Any] | None = None,
        render_mode: str | None = None,
        render_fn: Callable[[DriveResult], NDArray[np.uint8]] | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.render_fn = render_fn
        self._renderer: Any = None
        self._pipeline: Any = None
        self.sim: DriveEnvironment | None = None
        self.rollout: Rollout | None = None
        self._ended: str | None = None
        self.settings = DriveEnvConfig()
        self.configure({**(config or {}), **overrides})

    # -- configuration (highway-env conventions)
    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """Every configuration key with its default (see the module for what each does)."""
        return asdict(DriveEnvConfig())

    @property
    def config(self) -> dict[str, Any]:
        """The configuration in force (a copy)."""
        return {f.name: getattr(self.settings, f.name) for f in fields(self.settings)}

    def configure(self, config: dict[str, Any]) -> None:
        """Update the configuration (validated at once; an unknown key or a bad value is refused by
        name). The spaces follow at once; the new settings act from the next :meth:`reset`."""
        merged = DriveEnvConfig.from_dict({**self.config, **dict(config)})
        sc = merged.scenario
        sc = load_drive_scenario(sc) if isinstance(sc, str) else sc
        n_true = len(sc.pedestrians)
        if merged.state == "true" and merged.max_pedestrians < n_true:
            raise ValueError(f"config max_pedestrians ({merged.max_pedestrians}) must hold the scenario's "
                             f"{n_true} pedestrians")  # fmt: skip
        self.settings = merged
        self.scenario = sc.with_attention(merged.attentive)
        self.metadata = {**self.metadata, "render_fps": self.scenario.control.rate}
        model = self.scenario.vehicle.model()
        lo, hi = model.input_bounds()
        self._physical = (lo.astype(float), hi.astype(float))
        if merged.normalize_actions:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        else:
            self.action_space = spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        n = merged.max_pedestrians
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
                "seen_times": spaces.Box(0.0, big, shape=(n,), dtype=np.float64),
                "seen_states": spaces.Box(-big, big, shape=(n, 4), dtype=np.float64),
                "seen_covariances": spaces.Box(-big, big, shape=(n, 4, 4), dtype=np.float64),
            }
        )
        self.sim = self.rollout = None  # a new configuration needs a reset

    # the settings as attributes, for code written against the first version
    sensing = property(lambda self: self.settings.sensing)
    state = property(lambda self: self.settings.state)
    max_pedestrians = property(lambda self: self.settings.max_pedestrians)
    capture_rate = property(lambda self: self.settings.capture_rate)
    view = property(lambda self: self.settings.view)

    # -- Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        sensor = None
        if self.sensing == "render":
            self._close_sensing()
            self._renderer, self._pipeline = make_render_sensing(self.scenario, self.capture_rate)
            sensor = RenderSensor(self._renderer, self._pipeline)
        run_seed = int(self.np_random.integers(2**31)) if seed is None else int(seed)
        self.sim = DriveEnvironment(
            self.scenario, seed=run_seed, sensor=sensor, capture_rate=self.capture_rate, state=self.state
        )
        sc = self.scenario.control
        self.rollout = Rollout(self.sim, horizon=sc.horizon, safety_radius=sc.safety_radius)
        self._ended = None
        return self._observe(), self._info(None)

    def command(self, action: Any) -> NDArray[np.float64]:
        """The car's (steer rad, accel m/s^2) for an action of the action space (ValueError outside it)."""
        try:
            a = np.asarray(action, dtype=float).reshape(2)
        except (TypeError, ValueError):
            raise ValueError(f"action must be two numbers, got {action!r}") from None
        low, high = self.action_space.low.astype(float), self.action_space.high.astype(float)
        tol = 1e-6 * np.maximum(1.0, np.abs(high - low))
        if not np.all(np.isfinite(a)) or np.any(a < low - tol) or np.any(a > high + tol):
            note = " (normalised: each in [-1, 1])" if self.settings.normalize_actions else ""
            raise ValueError(f"action {a.tolist()} outside the action space [{low.tolist()}, {high.tolist()}]{note}")
        a = np.clip(a, low, high)  # only rounding below the tolerance
        if not self.settings.normalize_actions:
            return a
        lo, hi = self._physical  # steer: symmetric; accel: 0 holds the speed, +1 accel_max, -1 accel_min
        return np.array([a[0] * hi[0], a[1] * hi[1] if a[1] >= 0 else -a[1] * lo[1]])

    def step(self, action: Any):
        if self.sim is None or self.rollout is None:
            raise RuntimeError("call reset() before step()")
        if self._ended is not None:
            raise RuntimeError(f"the episode has ended ({self._ended}); call reset() before step()")
        u = self.command(action)
        s_before = self._progress()
        self.rollout.apply(Decision(u))
        obs = self._observe()
        cfg = self.settings
        reason = self._reason()
        inside = bool(np.any(self._distances() < self.scenario.control.safety_radius))
        reward = cfg.progress_reward * (self._progress() - s_before) - (cfg.margin_penalty if inside else 0.0)
        reward -= cfg.collision_penalty if reason == "collision" else 0.0
        reward -= cfg.off_road_penalty if reason == "off_road" else 0.0
        reward += cfg.goal_reward if reason == "goal" else 0.0
        terminated = reason in ("collision", "off_road", "goal")
        truncated = reason == "time"
        self._ended = reason
        return obs, float(reward), terminated, truncated, self._info(reason)

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
        seen_t, seen_x, seen_p = np.zeros(k), np.zeros((k, 4)), np.zeros((k, 4, 4))
        if o.last_seen is not None:
            ls_x, ls_p, ls_t = (np.asarray(a, dtype=float) for a in o.last_seen)
            seen_x[:m], seen_p[:m], seen_t[:m] = ls_x[order], ls_p[order], ls_t[order]
        else:  # exact states, seen now
            seen_x[:m] = np.hstack([pos[:m], vel[:m]])
            seen_p[:m], seen_t[:m] = cov[:m], o.time
        return {
            "ego": o.ego,
            "pedestrians": pos,
            "velocities": vel,
            "covariances": cov,
            "trusts": tr,
            "present": present,
            "time": np.array([o.time]),
            "seen_times": seen_t,
            "seen_states": seen_x,
            "seen_covariances": seen_p,
        }

    def _info(self, reason: str | None) -> dict[str, Any]:
        assert self.sim is not None
        return {
            "distances": self._distances(),
            "frames": len(self.sim.frames),
            "distance_to_goal": self.sim.distance_to_goal(),
            "speed": float(self.sim.state[3]),
            "collision": reason == "collision",
            "off_road": reason == "off_road",
            "reached_goal": reason == "goal",
            "time_out": reason == "time",
            "reason": reason,
            "road_offset": self.road_offset(),
        }

    def road_offset(self) -> float:
        """How far the car's centre is beyond the drivable area of the scenario's road (m; 0 on it):
        beyond an edge sideways, or past either end along it."""
        assert self.sim is not None
        r = self.scenario.road
        a, b = np.asarray(r.start), np.asarray(r.end)
        length = float(np.linalg.norm(b - a))
        t = (b - a) / length
        d = self.sim.state[:2] - a
        along = float(d @ t)
        across = abs(float(d @ np.array([-t[1], t[0]])))
        return max(0.0, across - 0.5 * r.width, -along, along - length)

    def _reason(self) -> str | None:
        """Why the episode ends now (first match: collision, off_road, goal, time), or None."""
        assert self.sim is not None
        cfg = self.settings
        if np.any(self.sim.min_distance_fine < cfg.contact_radius):
            return "collision"
        if cfg.terminate_off_road and self.road_offset() > cfg.off_road_margin:
            return "off_road"
        if self.sim.reached_goal() and (cfg.goal_max_speed is None or self.sim.state[3] <= cfg.goal_max_speed + 1e-9):
            return "goal"
        return "time" if self.sim.steps >= self.sim.max_steps else None

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


if ENV_ID not in gym.registry:  # also registered by `import trustnav`
    gym.register(id=ENV_ID, entry_point="trustnav.sim.driving.gym_env:DriveEnv")
