"""A model of your own: a unicycle (a delivery robot) under the paper's trust-adaptive CBF rows.

A model is any object with ``nx``, ``nu``, ``name``, ``step(x, u, dt)``, ``jacobians(x, u, dt)``
and ``input_bounds()`` (subclass ``DynamicsModel`` to get rollouts, sensitivities and fallback
plans for free). trustnav assembles `proposed` from it, a cost (here the generic
``PositionTrackingCost``, which fits any model whose first two states are its position) and the
pedestrians' `cbf_imp` rows, and solves it with the same SQP. Nothing in trustnav is edited.

Two ways to write it: in Python (``PythonUnicycle``: ``step`` and ``jacobians`` as methods; the
SQP calls them once per horizon step and sub-step, in Python), or at compiled speed (``Unicycle``:
the same equations as two ``numba.njit`` functions of plain arrays on a ``CompiledDynamics``; the
SQP's rollouts and sensitivities run in one compiled loop that calls them).

The robot crosses a plaza past two pedestrians walking across its path, one attentive (trust 0.9)
and one distracted (trust 0.1). It prints the closest approach to each (>= R), the time to the
goal and the time per control step; ``--compare`` drives the Python model too and prints the
speed-up.

    python examples/custom_dynamics.py
    python examples/custom_dynamics.py --compare
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from trustnav.control import (
    BoundedProportionalReference,
    CompiledDynamics,
    DynamicsModel,
    MpcConfig,
    MpcController,
    PositionTrackingCost,
)

SUB_STEP = 0.05  # Euler sub-steps of at most 50 ms


@njit(cache=True)
def unicycle_step(x, u, dt, out):
    """One step of dt: Euler sub-steps of at most SUB_STEP with (v, w) held."""
    n = max(1, math.ceil(dt / SUB_STEP - 1e-9))
    h = dt / n
    px, py, th = x[0], x[1], x[2]
    for _ in range(n):
        px, py, th = px + u[0] * math.cos(th) * h, py + u[0] * math.sin(th) * h, th + u[1] * h
    out[0], out[1], out[2] = px, py, th


@njit(cache=True)
def unicycle_jacobians(x, u, dt, a, b):
    """A = df/dx, B = df/du of one step, through its sub-steps (chain rule)."""
    n = max(1, math.ceil(dt / SUB_STEP - 1e-9))
    h = dt / n
    v = u[0]
    a[:] = 0.0
    a[0, 0] = a[1, 1] = a[2, 2] = 1.0
    b[:] = 0.0
    th = x[2]
    for _ in range(n):
        c, s = math.cos(th), math.sin(th)
        # [a; b] <- A_sub [a; b] (+ B_sub for b); A_sub = I + e_0 (-v s h) e_2' + e_1 (v c h) e_2'
        for j in range(3):
            a[0, j] += -v * s * h * a[2, j]
            a[1, j] += v * c * h * a[2, j]
        for j in range(2):
            b[0, j] += -v * s * h * b[2, j]
            b[1, j] += v * c * h * b[2, j]
        b[0, 0] += c * h
        b[1, 0] += s * h
        b[2, 1] += h
        th = th + u[1] * h


@dataclass(frozen=True)
class Unicycle(CompiledDynamics):
    """State (x, y, heading), input (speed v >= 0, turn rate w), at compiled speed: the step and
    its Jacobians are the numba functions above."""

    v_max: float = 2.0
    w_max: float = 1.5

    nx = 3
    nu = 2
    name = "unicycle"
    state_names = ("x", "y", "heading")
    input_names = ("v", "w")
    step_kernel = staticmethod(unicycle_step)
    jacobian_kernel = staticmethod(unicycle_jacobians)

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.array([0.0, -self.w_max]), np.array([self.v_max, self.w_max])


@dataclass(frozen=True)
class PythonUnicycle(DynamicsModel):
    """State (x, y, heading), input (speed v >= 0, turn rate w); one step of dt in Euler sub-steps
    of at most 50 ms, with the input held."""

    v_max: float = 2.0
    w_max: float = 1.5
    sub_step: float = SUB_STEP

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


def run(seconds: float = 25.0, model: DynamicsModel | None = None) -> dict[str, float]:
    dt = 0.1
    model = model or Unicycle()
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
    step_s = []
    for k in range(int(seconds / dt)):
        t0 = time.perf_counter()
        sol = ctl.step(x, peds, vels, trusts)
        step_s.append(time.perf_counter() - t0)
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
        "step_ms_median": float(np.median(step_s) * 1e3),
    }


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=25.0, help="simulated time (s)")
    parser.add_argument("--compare", action="store_true", help="drive the Python model too; print the speed-up")
    args = parser.parse_args(argv)
    run(1.0)  # compile the model's kernels before the timed run
    out = run(args.seconds)
    if args.compare:
        slow = run(args.seconds, PythonUnicycle())
        out["python_step_ms_median"] = slow["step_ms_median"]
        out["speedup"] = slow["step_ms_median"] / out["step_ms_median"]
        out["python_max_difference_m"] = max(
            abs(slow[k] - out[k]) for k in ("attentive_min_distance_m", "distracted_min_distance_m")
        )
        out["load_1min"] = os.getloadavg()[0]
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
