"""Ego dynamics models f_e (`f_e`) with their Jacobians.

Each model gives a plain numpy ``step`` (used by simulators and by the SLSQP reference) and the
input bounds (set U of `bounds`). The fast SQP path uses compiled kernels in
:mod:`trustnav.control._kernels` that implement the same equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["DynamicsModel", "KinematicBicycle", "SingleIntegrator"]


class DynamicsModel:
    """Interface: state x (nx,), input u (nu,); position = x[:2]."""

    nx: int
    nu: int
    name: str

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        raise NotImplementedError

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(A, B) = (df/dx, df/du) of one step."""
        raise NotImplementedError

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raise NotImplementedError

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        """Fallback input: the strongest braking along the current heading that brings the ego to
        rest within one step of ``dt`` (when given) and never reverses it."""
        raise NotImplementedError

    def rollout(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        """States x_0..x_N for inputs u_0..u_{N-1} (N, nu)."""
        u = np.asarray(inputs, dtype=float).reshape(-1, self.nu)
        xs = np.empty((u.shape[0] + 1, self.nx))
        xs[0] = np.asarray(x0, dtype=float)
        for k in range(u.shape[0]):
            xs[k + 1] = self.step(xs[k], u[k], dt)
        return xs

    def check_state(self, x: ArrayLike) -> NDArray[np.float64]:
        arr = np.asarray(x, dtype=float).reshape(-1)
        if arr.shape != (self.nx,) or not math.isfinite(arr.sum()):
            raise ValueError(f"{self.name} state must be {self.nx} finite numbers, got {x!r}")
        return arr


@dataclass(frozen=True)
class SingleIntegrator(DynamicsModel):
    """x(t+1) = x(t) + u(t) dt (Section III); u is a velocity bounded by |u_i| <= u_max."""

    u_max: float = 20.0

    nx = 2
    nu = 2
    name = "single_integrator"

    def __post_init__(self) -> None:
        if not self.u_max > 0 or math.isinf(self.u_max):
            raise ValueError(f"u_max must be a positive finite speed, got {self.u_max!r}")

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        return np.asarray(x, dtype=float) + np.asarray(u, dtype=float) * dt

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.eye(2), dt * np.eye(2)

    def rollout(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        u = np.asarray(inputs, dtype=float).reshape(-1, 2)
        xs = np.empty((u.shape[0] + 1, 2))
        xs[0] = x0
        np.cumsum(u * dt, axis=0, out=xs[1:])
        xs[1:] += xs[0]
        return xs

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.full(2, -self.u_max), np.full(2, self.u_max)

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        return np.zeros(2)


@dataclass(frozen=True)
class KinematicBicycle(DynamicsModel):
    """Kinematic bicycle about the rear axle: state (x, y, yaw, v), input (steer, acceleration).

    x+ = x + v cos(yaw) dt, y+ = y + v sin(yaw) dt, yaw+ = yaw + v tan(steer) / L dt, v+ = v + a dt.
    """

    wheelbase: float = 3.0
    steer_max: float = math.radians(35.0)
    accel_min: float = -6.0
    accel_max: float = 3.0
    speed_min: float = 0.0
    speed_max: float = 15.0

    nx = 4
    nu = 2
    name = "bicycle"

    def __post_init__(self) -> None:
        if not self.wheelbase > 0:
            raise ValueError(f"wheelbase must be > 0 m, got {self.wheelbase!r}")
        if not 0 < self.steer_max < math.pi / 2:
            raise ValueError(f"steer_max must be in (0, pi/2) rad, got {self.steer_max!r}")
        if not self.accel_min < 0 < self.accel_max:
            raise ValueError(f"need accel_min < 0 < accel_max, got {self.accel_min!r}, {self.accel_max!r}")
        if not 0 <= self.speed_min < self.speed_max:
            raise ValueError(f"need 0 <= speed_min < speed_max, got {self.speed_min!r}, {self.speed_max!r}")

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        px, py, yaw, v = np.asarray(x, dtype=float)
        steer, acc = np.asarray(u, dtype=float)
        return np.array(
            [
                px + v * math.cos(yaw) * dt,
                py + v * math.sin(yaw) * dt,
                yaw + v * math.tan(steer) / self.wheelbase * dt,
                v + acc * dt,
            ]
        )

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        _, _, yaw, v = np.asarray(x, dtype=float)
        steer, _ = np.asarray(u, dtype=float)
        c, s, t = math.cos(yaw), math.sin(yaw), math.tan(steer)
        a = np.array(
            [
                [1.0, 0.0, -v * s * dt, c * dt],
                [0.0, 1.0, v * c * dt, s * dt],
                [0.0, 0.0, 1.0, t / self.wheelbase * dt],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        b = np.array([[0.0, 0.0], [0.0, 0.0], [v * dt / (self.wheelbase * math.cos(steer) ** 2), 0.0], [0.0, dt]])
        return a, b

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.array([-self.steer_max, self.accel_min]), np.array([self.steer_max, self.accel_max])

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        v = float(np.asarray(x, dtype=float)[3])
        if dt is None or not dt > 0:
            a = self.accel_min if v > 0 else (self.accel_max if v < 0 else 0.0)
        else:
            a = min(self.accel_max, max(self.accel_min, -v / dt))  # to rest, not past it
        return np.array([0.0, a])
