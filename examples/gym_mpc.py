"""trustnav's own trust-aware MPC in the Gymnasium environment: the controller of ``trustnav drive``
(caution, yielding, road edges), driven from the environment's observations in a loop of your own.

    python examples/gym_mpc.py [--scenario examples/scenarios/step-out.toml] [--seed 0] [--caution on|off]

The controller is built from the scenario (``drive_controller``: its vehicle model, lane,
``[control]`` and road edges; the camera rate sets the caution's reaction time) and stepped as
every drive steps it (``MpcPolicy.step`` on the engine's ``Observation``). Each step it gets
the observation's pedestrians (the camera's tracks, with their covariances and trusts) and, for a
pedestrian it no longer sees, when and where the camera last saw her (``seen_times``,
``seen_states``, ``seen_covariances``). Its command (steer rad, accel m/s^2) is the action
(``normalize_actions: false``). The goal is a pass-through (``goal_max_speed: None``), as in
``trustnav drive``, so the episode is the same drive: the same seed gives the same path.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np

import trustnav  # noqa: F401  (registers "trustnav/Drive-v0")
from trustnav.sim.driving import drive_controller, load_drive_scenario
from trustnav.sim.engine import Observation


def mpc_episode(scenario: Any, seed: int = 0, **config: Any) -> tuple[dict, dict, Any]:
    """One episode of ``scenario`` (a name, a .toml path or a DriveScenario) in ``trustnav/Drive-v0``
    driven by trustnav's MPC; ``config``: more environment keys. Returns the last observation, the
    last info and the environment's :class:`~trustnav.sim.driving.DriveResult`."""
    env = gym.make("trustnav/Drive-v0", config={"scenario": scenario, "normalize_actions": False,
                                                "goal_max_speed": None, **config})  # fmt: skip
    obs, info = env.reset(seed=seed)
    policy = drive_controller(env.unwrapped.scenario, env.unwrapped.sim.capture_rate)
    low, high = env.action_space.low.astype(float), env.action_space.high.astype(float)
    done = False
    while not done:
        k = obs["present"].astype(bool)  # the filled slots
        seen = (obs["seen_states"][k], obs["seen_covariances"][k], obs["seen_times"][k])
        now = Observation(float(obs["time"][0]), obs["ego"], obs["pedestrians"][k], obs["velocities"][k],
                          obs["trusts"][k], obs["covariances"][k], seen)  # fmt: skip
        decision = policy.step(now)
        action = np.clip(decision.control, low, high)  # within the limits already; rounding only
        obs, _reward, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    result = env.unwrapped.result()
    env.close()
    return obs, info, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="examples/scenarios/step-out.toml", help="a preset or a .toml file")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--caution", choices=["on", "off"], help="override the file's [control] caution")
    args = ap.parse_args()
    try:
        sc = load_drive_scenario(args.scenario)
    except ValueError as exc:
        ap.error(f"--scenario: {exc}")
    if args.caution is not None:
        sc = dataclasses.replace(sc, control=dataclasses.replace(sc.control, caution=args.caution == "on"))
    obs, info, result = mpc_episode(sc, args.seed)
    print(f"{sc.name} (caution {'on' if sc.control.caution else 'off'}): episode ended ({info['reason']}) "
          f"at t = {obs['time'][0]:.2f} s")  # fmt: skip
    closest = result.distances.min(axis=0)
    for p, d in zip(sc.pedestrians, closest, strict=True):
        print(f"  {p.name:<11} closest {d:.2f} m (R = {sc.control.safety_radius})")


if __name__ == "__main__":
    main()
