"""Costs of problem `proposed` and the :class:`Cost` protocol.

A cost is configuration (a frozen dataclass) plus three functions of the stage:
``prepare`` computes the step's reference from the ego state, ``evaluate`` gives the cost at a
plan with its gradient and Gauss-Newton Hessian (from the state sensitivities the model gives),
and ``value`` the cost alone (the SLSQP reference path). Coordinates are ego-centred: the
problem passes the ego's world position as ``origin`` and states with the ego at (0, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from trustnav.control import _kernels as kern
from trustnav.control.models import Dynamics
from trustnav.control.reference import BoundedProportionalReference

__all__ = [
    "Cost",
    "LaneTrackingCost",
    "PositionTrackingCost",
    "TrackingWeights",
    "VelocityTrackingCost",
    "finite_pair",
]


@runtime_checkable
class Cost(Protocol):
    """The cost q of `proposed`, evaluated for the SQP."""

    #: the Hessian does not depend on the plan or the stage (the QP solver keeps it in place)
    constant_hessian: bool

    def check(self, model: Dynamics) -> None:
        """Raise ValueError when the cost does not fit the model (names both)."""
        ...

    def prepare(self, x0: NDArray[np.float64], origin: NDArray[np.float64], n_h: int, dt: float) -> Any:
        """The stage data of one step (a reference), from the ego-centred state x0."""
        ...

    def evaluate(
        self,
        stage: Any,
        xs: NDArray[np.float64],
        sens: NDArray[np.float64],
        u: NDArray[np.float64],
        u_prev: NDArray[np.float64],
        hessian: NDArray[np.float64],
        gradient: NDArray[np.float64],
    ) -> float:
        """Cost at plan u (N_h, nu) with states xs (N_h+1, nx) and sensitivities sens (N_h+1, nx,
        N_h nu); fills the Gauss-Newton ``hessian`` (n, n) and ``gradient`` (n,) in place."""
        ...

    def value(self, stage: Any, xs: NDArray[np.float64], u: NDArray[np.float64], u_prev: NDArray[np.float64]) -> float:
        """Cost alone (plain numpy, for the SLSQP reference)."""
        ...

    def initial_guess(
        self, stage: Any, n_h: int, lower: NDArray[np.float64], upper: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """First plan (N_h, nu) of a solve without a previous one, within the input bounds."""
        ...


def finite_pair(value: object, name: str) -> tuple[float, float]:
    """Two finite coordinates, or a ValueError naming ``name``."""
    try:
        pair = tuple(float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be 2 finite coordinates, got {value!r}") from exc
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair):
        raise ValueError(f"{name} must be 2 finite coordinates, got {value!r}")
    return pair  # type: ignore[return-value]


def _gauss_newton(r: NDArray[np.float64], jac: NDArray[np.float64], w: NDArray[np.float64], hessian, gradient) -> float:
    """sum w r^2 with H = 2 J' W J (+ 1e-9 I) and gradient 2 J' W r, filled in place."""
    wj = jac * w[:, None]
    hessian[:] = 2.0 * (jac.T @ wj)
    hessian[np.diag_indices_from(hessian)] += 1e-9
    gradient[:] = 2.0 * (wj.T @ r)
    return float(np.sum(w * r * r))


@dataclass(frozen=True)
class VelocityTrackingCost:
    """Section III cost: q = ||u - u_bar||^2, u_bar from a bounded proportional reference (for
    models whose two inputs are a planar velocity)."""

    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(default_factory=BoundedProportionalReference)

    constant_hessian = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "goal", finite_pair(self.goal, "goal"))

    def check(self, model: Dynamics) -> None:
        if tuple(getattr(model, "input_names", ())) != ("vx", "vy"):
            raise ValueError(
                f"no MPC problem for model {model.name} with cost VelocityTrackingCost: it needs a model whose "
                "inputs are a planar velocity (e.g. SingleIntegrator)"
            )

    def prepare(self, x0, origin, n_h, dt):
        goal = np.asarray(self.goal) - origin
        return np.ascontiguousarray(self.reference.velocities(x0[:2], goal, n_h, dt))

    def evaluate(self, stage, xs, sens, u, u_prev, hessian, gradient) -> float:
        e = u - stage
        hessian[:] = 0.0
        hessian[np.diag_indices_from(hessian)] = 2.0
        gradient[:] = 2.0 * e.ravel()
        return float(np.sum(e * e))

    def value(self, stage, xs, u, u_prev) -> float:
        e = u - stage
        return float(np.sum(e * e))

    def initial_guess(self, stage, n_h, lower, upper):
        return np.clip(stage, lower, upper)


@dataclass(frozen=True)
class TrackingWeights:
    """Section IV tracking cost weights: cross-track, heading and speed errors, steer,
    acceleration and their rates."""

    cte: float = 2.0
    heading: float = 5.0
    speed: float = 1.0
    steer: float = 1.0
    accel: float = 0.05
    steer_rate: float = 20.0
    accel_rate: float = 0.1

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if not v >= 0 or math.isinf(v):
                raise ValueError(f"tracking weight {k} must be a finite number >= 0, got {v!r}")

    def as_array(self) -> NDArray[np.float64]:
        return np.array(
            [self.cte, self.heading, self.speed, self.steer, self.accel, self.steer_rate, self.accel_rate], dtype=float
        )


@dataclass
class LaneStage:
    """Reference of one step of :class:`LaneTrackingCost`: waypoints, headings, speeds (N_h+1)."""

    points: NDArray[np.float64]
    yaw: NDArray[np.float64]
    speed: NDArray[np.float64]


@dataclass(frozen=True)
class LaneTrackingCost:
    """Section IV cost for a car (states x, y, yaw, v; inputs steer, acceleration): follow the
    lane start -> goal at the bounded proportional speed (cross-track, heading and speed errors,
    input effort and input rates, weighted by :class:`TrackingWeights`)."""

    start: tuple[float, float]
    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(
        default_factory=lambda: BoundedProportionalReference(gain=0.5, v_max=8.0)
    )
    weights: TrackingWeights = field(default_factory=TrackingWeights)

    constant_hessian = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", finite_pair(self.start, "lane start"))
        object.__setattr__(self, "goal", finite_pair(self.goal, "lane goal"))
        if self.start == self.goal:
            raise ValueError("lane start and goal must differ")

    def check(self, model: Dynamics) -> None:
        states, inputs = tuple(getattr(model, "state_names", ()))[:4], tuple(getattr(model, "input_names", ()))
        if states != ("x", "y", "yaw", "v") or inputs != ("steer", "accel"):
            raise ValueError(
                f"no MPC problem for model {model.name} with cost LaneTrackingCost: it needs states "
                "(x, y, yaw, v) and inputs (steer, acceleration), e.g. KinematicBicycle"
            )

    def prepare(self, x0, origin, n_h, dt) -> LaneStage:
        start = np.asarray(self.start) - origin
        goal = np.asarray(self.goal) - origin
        pts, yaw, v = self.reference.lane_waypoints(x0[:2], start, goal, n_h, dt)
        return LaneStage(np.ascontiguousarray(pts), yaw, v)

    def _residuals(self, stage: LaneStage, xs, u, u_prev):
        n_h = u.shape[0]
        w = self.weights.as_array()
        normal = np.stack([-np.sin(stage.yaw[1:]), np.cos(stage.yaw[1:])], axis=1)
        cte = np.sum(normal * (xs[1:, :2] - stage.points[1:]), axis=1)
        head = (xs[1:, 2] - stage.yaw[1:] + np.pi) % (2 * np.pi) - np.pi
        dv = xs[1:, 3] - stage.speed[1:]
        du = np.diff(np.vstack([u_prev, u]), axis=0)
        r = np.concatenate([cte, head, dv, u[:, 0], u[:, 1], du[:, 0], du[:, 1]])
        return r, np.repeat(w, n_h), normal

    def evaluate(self, stage, xs, sens, u, u_prev, hessian, gradient) -> float:
        n_h = u.shape[0]
        n = 2 * n_h
        r, w, normal = self._residuals(stage, xs, u, u_prev)
        jac = np.zeros((7 * n_h, n))
        jac[:n_h] = np.einsum("kd,kdn->kn", normal, sens[1:, :2])
        jac[n_h : 2 * n_h] = sens[1:, 2]
        jac[2 * n_h : 3 * n_h] = sens[1:, 3]
        k = np.arange(n_h)
        for d in range(2):
            jac[(3 + d) * n_h + k, 2 * k + d] = 1.0
            jac[(5 + d) * n_h + k, 2 * k + d] = 1.0
            jac[(5 + d) * n_h + k[1:], 2 * k[:-1] + d] = -1.0
        return _gauss_newton(r, jac, w, hessian, gradient)

    def value(self, stage, xs, u, u_prev) -> float:
        r, w, _ = self._residuals(stage, xs, u, u_prev)
        return float(np.sum(w * r * r))

    def initial_guess(self, stage, n_h, lower, upper):
        return np.zeros((n_h, lower.size))


@dataclass(frozen=True)
class PositionTrackingCost:
    """A cost for any model whose first two states are its position: follow the bounded
    proportional reference toward ``goal`` (positions x_bar(k+1) = x_bar(k) + u_bar(k) dt from the
    current position), with input effort and input-rate terms,

        q = w_p sum ||p(k+1) - x_bar(k+1)||^2 + w_u sum ||u(k)||^2 + w_r sum ||u(k) - u(k-1)||^2.
    """

    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(default_factory=BoundedProportionalReference)
    position_weight: float = 1.0
    input_weight: float = 0.01
    rate_weight: float = 0.1

    constant_hessian = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "goal", finite_pair(self.goal, "goal"))
        for name in ("position_weight", "input_weight", "rate_weight"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not v >= 0 or math.isinf(v):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if not self.position_weight > 0:
            raise ValueError(f"position_weight must be > 0, got {self.position_weight!r}")

    def check(self, model: Dynamics) -> None:
        if model.nx < 2:
            raise ValueError(
                f"no MPC problem for model {model.name} with cost PositionTrackingCost: needs x[:2] = position"
            )

    def prepare(self, x0, origin, n_h, dt):
        goal = np.asarray(self.goal) - origin
        ubar = self.reference.velocities(x0[:2], goal, n_h, dt)
        return x0[:2] + np.cumsum(ubar * dt, axis=0)  # x_bar(1..N_h)

    def _residuals(self, stage, xs, u, u_prev):
        n_h, nu = u.shape
        du = np.diff(np.vstack([u_prev, u]), axis=0)
        r = np.concatenate([(xs[1:, :2] - stage).ravel(), u.ravel(), du.ravel()])
        w = np.concatenate(
            [
                np.full(2 * n_h, self.position_weight),
                np.full(n_h * nu, self.input_weight),
                np.full(n_h * nu, self.rate_weight),
            ]
        )
        return r, w

    def evaluate(self, stage, xs, sens, u, u_prev, hessian, gradient) -> float:
        n_h, nu = u.shape
        n = n_h * nu
        if hessian.flags.c_contiguous and gradient.flags.c_contiguous:  # one compiled pass (the same model)
            f64 = np.float64
            return float(kern.position_tracking(
                np.ascontiguousarray(stage, dtype=f64), np.ascontiguousarray(xs, dtype=f64),
                np.ascontiguousarray(sens, dtype=f64), np.ascontiguousarray(u, dtype=f64),
                np.ascontiguousarray(u_prev, dtype=f64), float(self.position_weight), float(self.input_weight),
                float(self.rate_weight), hessian, gradient,
            ))  # fmt: skip
        r, w = self._residuals(stage, xs, u, u_prev)
        jac = np.zeros((r.size, n))
        jac[: 2 * n_h] = sens[1:, :2].reshape(2 * n_h, n)
        jac[2 * n_h : 2 * n_h + n] = np.eye(n)
        rate = np.eye(n) - np.eye(n, k=-nu)
        jac[2 * n_h + n :] = rate
        return _gauss_newton(r, jac, w, hessian, gradient)

    def value(self, stage, xs, u, u_prev) -> float:
        r, w = self._residuals(stage, xs, u, u_prev)
        return float(np.sum(w * r * r))

    def initial_guess(self, stage, n_h, lower, upper):
        return np.tile(np.minimum(np.maximum(0.0, lower), upper), (n_h, 1))
