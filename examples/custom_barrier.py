"""A barrier of your own: an elliptical keep-out zone (a road works area) for the car.

trustnav's controller takes any number of extra barriers next to the paper's pedestrian barrier:
an object with ``size()``, ``decay()`` (1 - gamma per function) and ``values(states, steps, dt)``
(h and dh/dx over the horizon) is turned into the rows of `cbf_discrete`,
h(x(k+1)) - (1 - gamma) h(x(k)) >= 0. Nothing in trustnav is edited.

Here the kinematic bicycle follows its lane (Section IV cost) toward a works area that covers the
lane, modelled as an ellipse, with a distracted pedestrian (trust 0.1) beyond it. It prints the
smallest barrier value of the ellipse (>= 0: never entered), the closest approach to the
pedestrian and the time to the goal.

    python examples/custom_barrier.py
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from trustnav.control import KinematicBicycle, LaneTrackingCost, MpcConfig, MpcController
from trustnav.trust import PAPER_GAMMA_CARLA


@dataclass(frozen=True)
class EllipseKeepOut:
    """h(x) = ((x - c) R(theta))_1^2 / a^2 + (...)_2^2 / b^2 - 1 >= 0: outside an ellipse with
    centre c, semi-axes (a, b) rotated by theta; one barrier function with a fixed gamma."""

    centre: tuple[float, float]
    semi_axes: tuple[float, float]
    angle: float = 0.0
    gamma: float = 0.3

    def __post_init__(self) -> None:
        if min(self.semi_axes) <= 0:
            raise ValueError(f"semi_axes must be positive, got {self.semi_axes!r}")
        if not 0 < self.gamma <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma!r}")

    def size(self) -> int:
        return 1

    def decay(self) -> NDArray[np.float64]:
        return np.array([1.0 - self.gamma])

    def values(self, states: NDArray[np.float64], steps: NDArray[np.int64], dt: float):
        c, s = math.cos(self.angle), math.sin(self.angle)
        rot = np.array([[c, -s], [s, c]])  # body axes of the ellipse in world coordinates
        local = (states[:, :2] - np.asarray(self.centre)) @ rot  # (K, 2)
        inv2 = 1.0 / np.asarray(self.semi_axes) ** 2
        h = np.sum(local * local * inv2, axis=1) - 1.0
        grad = np.zeros((states.shape[0], 1, states.shape[1]))
        grad[:, 0, :2] = (2.0 * local * inv2) @ rot.T
        return h[:, None], grad


def run(seconds: float = 14.0) -> dict[str, float]:
    dt = 0.1
    model = KinematicBicycle()
    zone = EllipseKeepOut(centre=(30.0, -0.5), semi_axes=(6.0, 2.0), angle=0.1)
    config = MpcConfig(horizon=10, dt=dt, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, deadline=10.0)
    cost = LaneTrackingCost(start=(0.0, 0.0), goal=(80.0, 0.0))
    ctl = MpcController(model, cost, config, barriers=[zone])
    x = np.array([0.0, 0.0, 0.0, 6.0])
    ped, ped_v, trust = np.array([[52.0, 4.0]]), np.array([[0.0, -0.3]]), np.array([0.1])
    h_min, d_min, t_goal, relaxed, lateral = math.inf, math.inf, math.nan, 0, 0.0
    for k in range(int(seconds / dt)):
        sol = ctl.step(x, ped, ped_v, trust)
        relaxed += int(sol.slack_used)
        x = model.step(x, sol.control, dt)
        ped = ped + ped_v * dt
        h_min = min(h_min, float(zone.values(x[None], np.zeros(1, dtype=np.int64), dt)[0][0, 0]))
        d_min = min(d_min, float(np.linalg.norm(x[:2] - ped[0])))
        lateral = max(lateral, float(x[1]))
        if math.isnan(t_goal) and np.hypot(x[0] - 80.0, x[1]) < 2.0:
            t_goal = (k + 1) * dt
    return {
        "zone_barrier_min": h_min,
        "pedestrian_min_distance_m": d_min,
        "safety_radius_m": config.safety_radius,
        "largest_lateral_offset_m": lateral,
        "time_to_goal_s": t_goal,
        "relaxed_steps": relaxed,
    }


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=14.0, help="simulated time (s)")
    args = parser.parse_args(argv)
    out = run(args.seconds)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
