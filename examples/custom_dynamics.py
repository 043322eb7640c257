"""A model of your own: a unicycle (a delivery robot) under the paper's trust-adaptive CBF rows.

A model is any object with ``nx``, ``nu``, ``name``, ``step(x, u, dt)``, ``jacobians(x, u, dt)``
and ``input_bounds()`` (subclass ``DynamicsModel`` to get rollouts, sensitivities and fallback
plans for free). trustnav assembles `proposed` from it, a cost (here the generic
``PositionTrackingCost``, which fits any model whose first two states are its position) and the
pedestrians' `cbf_imp` rows, and solves it with the same SQP. Nothing in trustnav is edited.

The robot crosses a plaza past two pedestrians walking across its path, one attentive (trust 0.9)
and one distracted (trust 0.1). It prints the closest approach to each (>= R), and the time to
the goal.

    python examples/custom_dynamics.py
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import (
    BoundedProportionalReference,
    DynamicsModel,
    MpcConfig,
    MpcController,
    PositionTrackingCost,
)


@dataclass(frozen=True)
class Unicycle(DynamicsModel):
    """State (x, y, heading), input (speed v >= 0, turn rate w); one step of dt in Euler sub-steps
    of at most 50 ms, with the input held."""

    v_max: float = 2.0
    w_max: float = 1.5
    sub_step: float = 0.05

    nx = 3
    nu = 2
    name = "unicycle"
    state_names = ("x", "y", "heading")
    input_names = ("v", "w")

    def _n(self, dt: float) -> int:
        return max(1, math.ceil(dt / self.sub_step - 1e-9))

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        px, py, th = (float(c) for c in np.asarray(x, dtype=float))
        v, w = (float(c) for c in np.asarray(u, dtype=float))
        h = dt / self._n(dt)
        for _ in range(self._n(dt)):
            px, py, th = px + v * math.cos(th) * h, py + v * math.sin(th) * h, th + w * h
        return np.array([px, py, th])

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        xs = np.asarray(x, dtype=float).copy()
        v = float(np.asarray(u, dtype=float)[0])
        h = dt / self._n(dt)
        a_tot, b_tot = np.eye(3), np.zeros((3, 2))
        for _ in range(self._n(dt)):
            c, s = math.cos(xs[2]), math.sin(xs[2])
            a = np.array([[1.0, 0.0, -v * s * h], [0.0, 1.0, v * c * h], [0.0, 0.0, 1.0]])
            b = np.array([[c * h, 0.0], [s * h, 0.0], [0.0, h]])
            a_tot, b_tot = a @ a_tot, a @ b_tot + b
            xs = self.step(xs, u, h)
        return a_tot, b_tot

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.array([0.0, -self.w_max]), np.array([self.v_max, self.w_max])


def run(seconds: float = 25.0) -> dict[str, float]:
    dt = 0.1
    model = Unicycle()
    goal = (0.0, 30.0)
    cost = PositionTrackingCost(goal=goal, reference=BoundedProportionalReference(gain=0.5, v_max=1.8))
    config = MpcConfig(horizon=12, dt=dt, safety_radius=1.0, deadline=10.0)
    ctl = MpcController(model, cost, config)
    x = np.array([0.0, 0.0, math.pi / 2])
    peds = np.array([[-6.0, 10.0], [7.0, 18.0]])
    vels = np.array([[0.6, 0.0], [-0.6, 0.0]])
    trusts = np.array([0.9, 0.1])
    d_min = np.full(2, np.inf)
    t_goal, relaxed = math.nan, 0
    for k in range(int(seconds / dt)):
        sol = ctl.step(x, peds, vels, trusts)
        relaxed += int(sol.slack_used)
        x = model.step(x, sol.control, dt)
        peds = peds + vels * dt
        d_min = np.minimum(d_min, np.linalg.norm(peds - x[:2], axis=1))
        if math.isnan(t_goal) and np.hypot(x[0] - goal[0], x[1] - goal[1]) < 0.5:
            t_goal = (k + 1) * dt
    return {
        "attentive_min_distance_m": float(d_min[0]),
        "distracted_min_distance_m": float(d_min[1]),
        "safety_radius_m": config.safety_radius,
        "time_to_goal_s": t_goal,
        "relaxed_steps": relaxed,
    }


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=25.0, help="simulated time (s)")
    args = parser.parse_args(argv)
    out = run(args.seconds)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
