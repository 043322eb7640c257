"""The Gymnasium environment follows the conventions (issue 21, item 6): registered by `import trustnav`,
a configuration dictionary, normalised actions, termination on collision / off-road / goal with the reason
in `info`, no step after the end, `render_mode` None by default, `check_env` passes."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import trustnav  # noqa: F401  (registers trustnav/Drive-v0)
from trustnav.sim.driving import load_drive_scenario
from trustnav.sim.driving.gym_env import ENV_ID, DriveEnv

FAST = {"scenario": "case-1", "state": "true", "max_pedestrians": 2}


def _episode(env, policy, seed: int = 0):  # type: ignore[no-untyped-def]
    obs, info = env.reset(seed=seed)
    steps = 0
    while True:
        obs, _reward, terminated, truncated, info = env.step(policy(obs))
        steps += 1
        if terminated or truncated:
            return terminated, truncated, info, steps


def test_import_trustnav_registers_the_id_in_a_fresh_interpreter():
    code = (
        "import gymnasium as gym, trustnav; env = gym.make('trustnav/Drive-v0', config={'state': 'true'}); "
        "print(env.unwrapped.config['sensing'])"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "keypoints"


def test_config_dictionary_defaults_configure_and_unknown_keys():
    defaults = DriveEnv.default_config()
    assert defaults["normalize_actions"] is True and defaults["goal_max_speed"] == 2.0
    env = gym.make(ENV_ID, config={**FAST, "contact_radius": 0.8})
    u = env.unwrapped
    assert u.config["contact_radius"] == 0.8 and u.render_mode is None and u.render() is None
    assert u.action_space == gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    u.configure({"max_pedestrians": 4, "normalize_actions": False})
    assert u.observation_space["pedestrians"].shape == (4, 2)
    assert u.action_space.high[1] == pytest.approx(3.0)  # physical: accel_max m/s^2
    with pytest.raises(RuntimeError, match="reset"):
        u.step(np.zeros(2))  # a new configuration needs a reset
    with pytest.raises(ValueError, match="contact_radus"):
        u.configure({"contact_radus": 1.0})
    with pytest.raises(ValueError, match="goal_max_speed"):
        gym.make(ENV_ID, config={"goal_max_speed": -1.0})
    with pytest.raises(ValueError, match="render_mode"):
        DriveEnv(render_mode="human")
    env.close()


def test_check_env_passes_with_the_new_spaces():
    for config in (FAST, {"scenario": "case-2"}):
        env = DriveEnv(config=config)
        check_env(env, skip_render_check=True)
        env.close()
    env = gym.make(ENV_ID, config=FAST, render_mode="rgb_array").unwrapped
    check_env(env)
    env.reset(seed=0)
    img = env.render()
    assert img.ndim == 3 and img.dtype == np.uint8


def test_actions_are_normalised_and_out_of_range_actions_refused():
    env = DriveEnv(config=FAST)
    env.reset(seed=0)
    assert np.allclose(env.command([1.0, 1.0]), [np.radians(35.0), 3.0])
    assert np.allclose(env.command([-1.0, -1.0]), [-np.radians(35.0), -6.0])
    assert np.allclose(env.command([0.0, 0.0]), [0.0, 0.0])
    for bad in ([1.5, 0.0], [0.0, np.nan], [0.0]):
        with pytest.raises(ValueError, match="action"):
            env.step(np.array(bad, dtype=np.float32))


def _keep_lane_and_stop(obs):  # type: ignore[no-untyped-def]
    """Straight ahead (the car starts on its heading), speed from the distance left: stop at the goal."""
    _x, y, _yaw, v = obs["ego"]
    remaining = max(0.0, y - 75.0)
    v_ref = min(6.0, np.sqrt(2.0 * 1.5 * remaining))
    accel = np.clip(1.5 * (v_ref - v), -6.0, 3.0)
    return np.array([0.0, accel / 3.0 if accel >= 0 else accel / 6.0], dtype=np.float32)


def test_goal_only_at_a_bounded_speed_unless_a_pass_through():
    env = DriveEnv(config=FAST)
    terminated, truncated, info, _ = _episode(env, _keep_lane_and_stop)
    assert terminated and not truncated and info["reached_goal"] and info["reason"] == "goal"
    assert info["speed"] <= 2.0 and info["distance_to_goal"] <= 1.0
    with pytest.raises(RuntimeError, match=r"ended \(goal\)"):
        env.step(np.zeros(2, dtype=np.float32))
    full = lambda _obs: np.array([0.0, 1.0], dtype=np.float32)  # noqa: E731
    # full throttle through the goal: not reached at that speed, the car leaves the road past its end
    terminated, _, info, _ = _episode(env, full)
    assert terminated and info["off_road"] and not info["reached_goal"]
    env.configure({"goal_max_speed": None})  # the goal as a pass-through, stated in the config
    terminated, _, info, _ = _episode(env, full)
    assert terminated and info["reached_goal"] and info["speed"] > 5.0


def test_leaving_the_road_and_a_collision_terminate():
    env = DriveEnv(config=FAST)
    terminated, _, info, _ = _episode(env, lambda _o: np.array([1.0, 1.0], dtype=np.float32))
    assert terminated and info["off_road"] and info["reason"] == "off_road" and info["road_offset"] > 0
    sc = load_drive_scenario("case-1")
    in_lane = dataclasses.replace(sc.pedestrians[1], position=(33.5, 110.0))
    env.configure({"scenario": dataclasses.replace(sc, pedestrians=(sc.pedestrians[0], in_lane))})
    terminated, _, info, _ = _episode(env, lambda _o: np.array([0.0, 0.5], dtype=np.float32))
    assert terminated and info["collision"] and info["reason"] == "collision"
    assert info["distances"].min() < 1.5  # the true distance at the end of the step that touched


def test_a_random_policy_episode_ends_for_a_reported_reason():
    env = DriveEnv(config=FAST)
    env.action_space.seed(0)
    seen = set()
    for seed in range(3):
        terminated, truncated, info, steps = _episode(env, lambda _o: env.action_space.sample(), seed)
        flags = {k for k in ("collision", "off_road", "reached_goal", "time_out") if info[k]}
        assert len(flags) == 1 and (terminated or truncated) and terminated != truncated
        assert truncated == info["time_out"] and info["reason"] is not None
        seen.add(info["reason"])
        assert steps <= env.sim.max_steps
    assert seen <= {"collision", "off_road", "goal", "time"}


def test_config_checked_by_the_schema_every_error_one_line_and_the_key_meant():
    """The environment's configuration goes through trustnav.schema like scenario files and specs."""
    with pytest.raises(ValueError) as err:
        DriveEnv(config={"contact_radus": 1.0})
    assert str(err.value) == "unknown key 'contact_radus' in config: did you mean 'contact_radius'?"
    with pytest.raises(ValueError) as err:
        DriveEnv(config={"max_pedestrians": 0, "sensing": "lidar", "capture_rate": 0, "scenario": 3})
    assert str(err.value).splitlines() == [  # all at once, in the order of the keys
        "config.scenario must be a name, a .toml path or a DriveScenario, got 3",
        "config.sensing must be one of 'keypoints', 'render', got 'lidar'",
        "config.capture_rate must be a number in [0.001, 1000] frames/s or None, got 0",
        "config.max_pedestrians must be an integer in [1, 256], got 0",
    ]
