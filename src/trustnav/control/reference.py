"""Reference generators: a bounded proportional controller toward the goal.

The paper's reference generator "takes the current state and goal state as inputs to produce the
desired velocity u_bar for each timestep in the prediction horizon"; it states neither the gain
nor the bound, so both are parameters here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control._kernels import lane_march, reference_velocities

__all__ = ["BoundedProportionalReference"]


@dataclass(frozen=True)
class BoundedProportionalReference:
    """u_bar = Kp (goal - x), its norm clipped to v_max.

    mode "rollout": u_bar(k) is recomputed along the path that the reference itself would drive
    from the current position (x_bar(k+1) = x_bar(k) + u_bar(k) dt), so the horizon sees the
    slow-down near the goal; mode "hold": u_bar(t) repeated over the horizon.
    """

    gain: float = 1.5
    v_max: float = 10.0
    mode: Literal["rollout", "hold"] = "rollout"

    def __post_init__(self) -> None:
        if not self.gain > 0 or math.isinf(self.gain):
            raise ValueError(f"reference gain Kp must be a positive finite number, got {self.gain!r}")
        if not self.v_max > 0 or math.isinf(self.v_max):
            raise ValueError(f"reference speed bound v_max must be a positive finite number, got {self.v_max!r}")
        if self.mode not in ("rollout", "hold"):
            raise ValueError(f"reference mode must be 'rollout' or 'hold', got {self.mode!r}")

    def speed(self, distance: float) -> float:
        return min(self.v_max, self.gain * distance)

    def velocity(self, position: ArrayLike, goal: ArrayLike) -> NDArray[np.float64]:
        """u_bar at one position (the first step of :meth:`velocities`)."""
        return self.velocities(position, goal, 1, 0.0)[0]

    def velocities(self, position: ArrayLike, goal: ArrayLike, steps: int, dt: float) -> NDArray[np.float64]:
        """u_bar over the horizon, shape (steps, 2) (compiled loop)."""
        out = np.empty((steps, 2))
        reference_velocities(
            np.asarray(position, dtype=float), np.asarray(goal, dtype=float), self.gain, self.v_max, dt,
            self.mode == "rollout", out,
        )  # fmt: skip
        return out

    def lane_waypoints(
        self, position: ArrayLike, start: ArrayLike, goal: ArrayLike, steps: int, dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Waypoints on the straight lane start -> goal for a vehicle: the current position projected
        onto the lane, then marched along it at the bounded proportional speed.

        Returns points (steps+1, 2), headings (steps+1,) and speeds (steps+1,).
        """
        a = np.asarray(start, dtype=float)
        b = np.asarray(goal, dtype=float)
        axis = b - a
        length = float(np.hypot(*axis))
        if length <= 0:
            raise ValueError("lane start and goal must differ")
        t_hat = axis / length
        s = float(np.clip((np.asarray(position, dtype=float) - a) @ t_hat, 0.0, length))
        pts = np.empty((steps + 1, 2))
        speeds = np.empty(steps + 1)
        rollout = self.mode == "rollout"
        lane_march(a, t_hat, s, length, float(self.gain), float(self.v_max), float(dt), rollout, pts, speeds)
        if self.mode == "hold":
            speeds[:] = speeds[0]
            pts[:] = pts[0] + np.arange(steps + 1)[:, None] * speeds[0] * dt * t_hat
        return pts, np.full(steps + 1, math.atan2(t_hat[1], t_hat[0])), speeds
