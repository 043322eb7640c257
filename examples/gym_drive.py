"""A user controller in the trust-aware driving world (Gymnasium), instead of trustnav's MPC.

    python examples/gym_drive.py [--scenario case-1|case-2] [--sensing keypoints|render] [--out DIR]

The controller is deliberately simple: it steers back to the lane with a proportional law and sets
its speed from the trust that perception gives each pedestrian ahead: it slows down near a
pedestrian it does not trust yet, and stops at the goal (the environment counts the goal only at <=
``goal_max_speed``, 2 m/s by default). Its (steer rad, accel m/s^2) are mapped to the environment's
normalised actions in [-1, 1] (docs/drive.md). The episode ends at the goal, on a collision, off the
road or at the time limit; ``info["reason"]`` says which. The pedestrians it sees are the camera's
(positions estimated from the image, each with a covariance; ``present`` marks the filled slots). It
prints the closest approach to each pedestrian and, with --out, saves the top view of the last step
and the figures of trustnav.viz.drive_plots.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import gymnasium as gym
import numpy as np

import trustnav  # noqa: F401  (registers "trustnav/Drive-v0")


def normalised(steer: float, accel: float, steer_max: float, accel_min: float, accel_max: float) -> np.ndarray:
    """(steer rad, accel m/s^2) as the environment's action: steer / steer_max, accel / accel_max
    when speeding up, accel / |accel_min| when braking; each clipped to [-1, 1]."""
    a = accel / accel_max if accel >= 0 else accel / -accel_min
    return np.clip(np.array([steer / steer_max, a], dtype=np.float32), -1.0, 1.0)


def user_controller(obs: dict, lane_start: np.ndarray, lane_goal: np.ndarray) -> tuple[float, float]:
    """(steer rad, accel m/s^2) from the observation: lane keeping + trust-dependent speed."""
    x, y, yaw, v = obs["ego"]
    axis = lane_goal - lane_start
    t = axis / np.linalg.norm(axis)
    n = np.array([-t[1], t[0]])
    offset = float((np.array([x, y]) - lane_start) @ n)
    heading_err = math.atan2(math.sin(yaw - math.atan2(t[1], t[0])), math.cos(yaw - math.atan2(t[1], t[0])))
    steer = -0.3 * offset - 1.2 * heading_err
    # speed: 8 m/s, less near pedestrians ahead that are not trusted (trust 0 = never seen)
    v_ref = 8.0
    for p, trust, here in zip(obs["pedestrians"], obs["trusts"], obs["present"], strict=True):
        if not here:
            continue
        ahead = float((p - np.array([x, y])) @ t)
        if 0.0 < ahead < 25.0:
            v_ref = min(v_ref, 3.0 + 5.0 * trust)
    remaining = float((lane_goal - np.array([x, y])) @ t)
    v_ref = min(v_ref, math.sqrt(2.0 * 1.5 * max(0.0, remaining)))  # brake to a stop at the goal
    accel = 1.5 * (v_ref - v)
    return steer, accel


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="case-1", help="case-1, case-2 or a scenario file (.toml)")
    ap.add_argument("--sensing", default="keypoints", choices=["keypoints", "render"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="write top view and figures here")
    args = ap.parse_args()

    env = gym.make("trustnav/Drive-v0", config={"scenario": args.scenario, "sensing": args.sensing},
                   render_mode="rgb_array" if args.out else None)  # fmt: skip
    sc = env.unwrapped.scenario
    veh = sc.vehicle
    start, goal = np.array(sc.ego_start), np.array(sc.goal)
    obs, info = env.reset(seed=args.seed)
    closest = np.full(len(sc.pedestrians), np.inf)
    total = 0.0
    terminated = truncated = False
    while not (terminated or truncated):
        steer, accel = user_controller(obs, start, goal)
        action = normalised(steer, accel, math.radians(veh.steer_max_deg), veh.accel_min, veh.accel_max)
        obs, reward, terminated, truncated, info = env.step(action)
        closest = np.minimum(closest, info["distances"])
        total += reward
    print(f"{sc.name}: episode ended ({info['reason']}) at t = {obs['time'][0]:.1f} s, speed "
          f"{info['speed']:.1f} m/s, return {total:.1f}, {info['frames']} camera frames")  # fmt: skip
    held = env.unwrapped.result().trusts[-1]  # the trust held for each pedestrian (scored against the truth)
    for p, d, tr in zip(sc.pedestrians, closest, held, strict=True):
        print(f"  {p.name:<11} closest {d:.2f} m (R = {sc.control.safety_radius}) final trust {tr:.2f}")
    if args.out:
        import cv2

        from trustnav.viz.drive_plots import plot_distance, plot_top_view, plot_trust

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / "last_step.png"), cv2.cvtColor(env.unwrapped.render(), cv2.COLOR_RGB2BGR))
        result = env.unwrapped.result()
        plot_top_view(result, out / "top_view.png")
        plot_trust(result, out / "trust.png")
        plot_distance(result, out / "distance.png")
        print(f"wrote {out}/")
    env.close()


if __name__ == "__main__":
    main()
