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

    The continuous model dx = v cos(yaw), dy = v sin(yaw), dyaw = v tan(steer) / L, dv = a,
    integrated over one step ``dt`` of `f_e` (input held) with explicit Euler sub-steps of at most
    ``integration_step`` seconds (10 ms by default). A single Euler step per dt
    (``integration_step=None``) is centimetres off the continuous car on a curve at 8 m/s and
    dt = 0.1 s: enough to breach R while every predicted CBF row holds.
    """

    wheelbase: float = 3.0
    steer_max: float = math.radians(35.0)
    accel_min: float = -6.0
    accel_max: float = 3.0
    speed_min: float = 0.0
    speed_max: float = 15.0
    integration_step: float | None = 0.01

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
        if self.integration_step is not None and (not self.integration_step > 0 or math.isinf(self.integration_step)):
            raise ValueError(
                f"integration_step must be a positive finite time in seconds (or None), got {self.integration_step!r}"
            )

    def substeps(self, dt: float) -> int:
        """Euler sub-steps in one step of ``dt`` (1 with ``integration_step=None``)."""
        if self.integration_step is None:
            return 1
        return max(1, math.ceil(dt / self.integration_step - 1e-9))

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        px, py, yaw, v = (float(c) for c in np.asarray(x, dtype=float))
        steer, acc = (float(c) for c in np.asarray(u, dtype=float))
        n = self.substeps(dt)
        h = dt / n
        turn = math.tan(steer) / self.wheelbase
        for _ in range(n):
            px, py, yaw, v = px + v * math.cos(yaw) * h, py + v * math.sin(yaw) * h, yaw + v * turn * h, v + acc * h
        return np.array([px, py, yaw, v])

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        xs = np.asarray(x, dtype=float).copy()
        steer, _ = np.asarray(u, dtype=float)
        n = self.substeps(dt)
        h = dt / n
        t = math.tan(steer)
        a_tot, b_tot = np.eye(4), np.zeros((4, 2))
        for _ in range(n):
            _, _, yaw, v = xs
            c, s = math.cos(yaw), math.sin(yaw)
            a = np.array(
                [
                    [1.0, 0.0, -v * s * h, c * h],
                    [0.0, 1.0, v * c * h, s * h],
                    [0.0, 0.0, 1.0, t / self.wheelbase * h],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            )
            b = np.array([[0.0, 0.0], [0.0, 0.0], [v * h / (self.wheelbase * math.cos(steer) ** 2), 0.0], [0.0, h]])
            a_tot, b_tot = a @ a_tot, a @ b_tot + b
            xs = self.step(xs, u, h)
        return a_tot, b_tot

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.array([-self.steer_max, self.accel_min]), np.array([self.steer_max, self.accel_max])

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        v = float(np.asarray(x, dtype=float)[3])
        if dt is None or not dt > 0:
            a = self.accel_min if v > 0 else (self.accel_max if v < 0 else 0.0)
        else:
            a = min(self.accel_max, max(self.accel_min, -v / dt))  # to rest, not past it
        return np.array([0.0, a])
