"""Ego dynamics models f_e (`f_e`) with their Jacobians, and the :class:`Dynamics` protocol.

A model gives ``step`` (one step of `f_e`), its Jacobians and the input bounds (set U of
`bounds`); the problem rolls it out over the horizon with the sensitivities dx(k)/dU that the
Jacobians give (:meth:`DynamicsModel.sensitivities`). Subclass :class:`DynamicsModel` to add a
model (see ``examples/custom_dynamics.py``); the built-in models also have compiled kernels in
:mod:`trustnav.control._kernels` that fuse the same equations with their cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import _kernels as kern

__all__ = ["CompiledDynamics", "Dynamics", "DynamicsModel", "KinematicBicycle", "SingleIntegrator", "StateRow"]


@runtime_checkable
class Dynamics(Protocol):
    """What a model must give: state size nx (position = x[:2]), input size nu, a name, one step
    of `f_e`, its Jacobians (A, B) = (df/dx, df/du), and the input bounds. Subclass
    :class:`DynamicsModel` to get the rest (rollout, sensitivities, fallback plans) for free."""

    nx: int
    nu: int
    name: str

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]: ...

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...


#: Bounds lo[k] <= x(k+1)[index] <= hi[k] on one state component over the horizon (k = 0..N_h-1).
StateRow = tuple[int, NDArray[np.float64], NDArray[np.float64]]


class DynamicsModel:
    """Base of the models: the :class:`Dynamics` protocol plus generic defaults a model may
    override (state x (nx,), input u (nu,), position = x[:2])."""

    nx: int
    nu: int
    name: str
    #: names of the state and input components (costs check that a model fits them)
    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    #: f_e is linear in (x, u) (the SQP takes full steps; no line search needed)
    linear: bool = False
    #: the SQP may run its feasibility (phase-1) search from varied starts when the recovery's
    #: candidate starts fail (validated on the single integrator; off elsewhere)
    feasibility_search: bool = False

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        raise NotImplementedError

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(A, B) = (df/dx, df/du) of one step."""
        raise NotImplementedError

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        raise NotImplementedError

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        """Fallback input: the strongest braking along the current heading that brings the ego to
        rest within one step of ``dt`` (when given) and never reverses it. Default: zero input
        (within the bounds), right for models whose inputs are velocities."""
        lo, hi = self.input_bounds()
        return np.minimum(np.maximum(np.zeros(self.nu), lo), hi)

    def braking_plan(self, x0: ArrayLike, n_h: int, dt: float) -> NDArray[np.float64]:
        """Plan that brings the ego to rest as fast as the input bounds allow, then holds it."""
        return np.tile(self.braking_input(x0, dt), (n_h, 1))

    def sensitivities(
        self, x0: ArrayLike, inputs: ArrayLike, dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """States x_0..x_N (N+1, nx) and their sensitivities dx_k/dU (N+1, nx, N nu) to the
        stacked inputs U, from the one-step Jacobians: S_{k+1} = A_k S_k + B_k E_k."""
        u = np.asarray(inputs, dtype=float).reshape(-1, self.nu)
        n_h = u.shape[0]
        xs = np.empty((n_h + 1, self.nx))
        sens = np.zeros((n_h + 1, self.nx, n_h * self.nu))
        xs[0] = np.asarray(x0, dtype=float)
        for k in range(n_h):
            a, b = self.jacobians(xs[k], u[k], dt)
            cols = (k + 1) * self.nu  # inputs after u_k do not move x(k+1)
            sens[k + 1, :, :cols] = a @ sens[k, :, :cols]
            sens[k + 1, :, k * self.nu : cols] += b
            xs[k + 1] = self.step(xs[k], u[k], dt)
        return xs, sens

    def state_limit_violation(self, states: NDArray[np.float64]) -> float:
        """Worst violation of the model's hard state limits (e.g. the bicycle's v >= speed_min)
        over the predicted states x_1..x_N of ``states`` (N+1, nx); 0 when every one holds
        (default: the model has none)."""
        return 0.0

    def repair_plan(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64] | None:
        """The plan nearest ``inputs`` (N, nu) that keeps the hard state limits from ``x0``, or
        None when the model has no such repair (default)."""
        return None

    def decided_steps(self, dt: float) -> int:
        """Leading horizon steps whose positions no input can change (their CBF rows are reported
        but left out of the QP): 0 unless the position responds to inputs only with a delay."""
        return 0

    def state_rows(self, x0: NDArray[np.float64], n_h: int, dt: float) -> list[StateRow]:
        """Bounds on state components over the horizon (e.g. speed), as linearised QP rows."""
        return []

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
        if arr.shape != (self.nx,) or not math.isfinite(sum(arr.tolist())):
            raise ValueError(f"{self.name} state must be {self.nx} finite numbers, got {x!r}")
        return arr


class CompiledDynamics(DynamicsModel):
    """A model of the user's at compiled speed: its one step and Jacobians are numba functions
    (``@numba.njit``) of plain arrays, given as the class attributes

    * ``step_kernel(x, u, dt, out)``: write x(k+1) of one step of ``dt`` from x = x(k), u into ``out``;
    * ``jacobian_kernel(x, u, dt, a, b)``: write A = df/dx (nx, nx) and B = df/du (nx, nu) of that step.

    (wrap each in ``staticmethod``). The rollout and the sensitivities dx(k)/dU the SQP linearises
    with run in one compiled loop that calls them (:func:`~trustnav.control._kernels.user_sensitivities`)
    instead of a Python call per step and sub-step; ``step`` and ``jacobians`` call them too. Everything
    else is :class:`DynamicsModel`'s (bounds, fallbacks, hooks). See ``examples/custom_dynamics.py``."""

    step_kernel: Any = None
    jacobian_kernel: Any = None

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        out = np.empty(self.nx)
        self.step_kernel(_f64(x), _f64(u), float(dt), out)
        return out

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        a, b = np.empty((self.nx, self.nx)), np.empty((self.nx, self.nu))
        self.jacobian_kernel(_f64(x), _f64(u), float(dt), a, b)
        return a, b

    def sensitivities(
        self, x0: ArrayLike, inputs: ArrayLike, dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        u = _f64(inputs).reshape(-1, self.nu)
        xs = np.empty((u.shape[0] + 1, self.nx))
        sens = np.empty((u.shape[0] + 1, self.nx, u.size))
        kern.user_sensitivities(self.step_kernel, self.jacobian_kernel, _f64(x0), u, float(dt), xs, sens)
        return xs, sens

    def rollout(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        u = _f64(inputs).reshape(-1, self.nu)
        xs = np.empty((u.shape[0] + 1, self.nx))
        kern.user_rollout(self.step_kernel, _f64(x0), u, float(dt), xs)
        return xs


def _f64(a: ArrayLike) -> NDArray[np.float64]:
    return np.ascontiguousarray(a, dtype=np.float64)


@dataclass(frozen=True)
class SingleIntegrator(DynamicsModel):
    """x(t+1) = x(t) + u(t) dt (Section III); u is a velocity bounded by |u_i| <= u_max."""

    u_max: float = 20.0

    nx = 2
    nu = 2
    name = "single_integrator"
    state_names = ("x", "y")
    input_names = ("vx", "vy")
    linear = True
    feasibility_search = True

    def __post_init__(self) -> None:
        if not self.u_max > 0 or math.isinf(self.u_max):
            raise ValueError(f"u_max must be a positive finite speed, got {self.u_max!r}")

    def step(self, x: ArrayLike, u: ArrayLike, dt: float) -> NDArray[np.float64]:
        return np.asarray(x, dtype=float) + np.asarray(u, dtype=float) * dt

    def jacobians(self, x: ArrayLike, u: ArrayLike, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.eye(2), dt * np.eye(2)

    def rollout(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        u = np.ascontiguousarray(inputs, dtype=float).reshape(-1, 2)
        xs = np.empty((u.shape[0] + 1, 2))
        kern.single_integrator_rollout(np.ascontiguousarray(x0, dtype=float).reshape(2), u, float(dt), xs)
        return xs

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.full(2, -self.u_max), np.full(2, self.u_max)

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        return np.zeros(2)

    def sensitivities(
        self, x0: ArrayLike, inputs: ArrayLike, dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        u = np.asarray(inputs, dtype=float).reshape(-1, 2)
        n_h = u.shape[0]
        sens = np.zeros((n_h + 1, 2, 2 * n_h))
        for k in range(n_h):
            sens[k + 1 :, 0, 2 * k] = dt
            sens[k + 1 :, 1, 2 * k + 1] = dt
        return self.rollout(x0, u, dt), sens


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
    state_names = ("x", "y", "yaw", "v")
    input_names = ("steer", "accel")

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
        px, py, yaw, v = np.asarray(x, dtype=float).tolist()
        steer, acc = np.asarray(u, dtype=float).tolist()
        n = self.substeps(dt)
        out = np.empty(4)
        kern.bicycle_advance(px, py, yaw, v, math.tan(steer) / self.wheelbase, acc, dt / n, n, out)  # compiled
        return out

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

    def rollout(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        """States x_0..x_N (compiled; the arithmetic of :meth:`step`)."""
        u = np.ascontiguousarray(inputs, dtype=float).reshape(-1, 2)
        xs = np.empty((u.shape[0] + 1, 4))
        x = np.ascontiguousarray(x0, dtype=float).reshape(4)
        kern.bicycle_rollout(x, u, float(dt), self.substeps(dt), float(self.wheelbase), xs)
        return xs

    def input_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return np.array([-self.steer_max, self.accel_min]), np.array([self.steer_max, self.accel_max])

    def braking_input(self, x: ArrayLike, dt: float | None = None) -> NDArray[np.float64]:
        v = float(np.asarray(x, dtype=float)[3])
        if dt is None or not dt > 0:
            a = self.accel_min if v > 0 else (self.accel_max if v < 0 else 0.0)
        else:
            a = min(self.accel_max, max(self.accel_min, -v / dt))  # to rest, not past it
        return np.array([0.0, a])

    def state_limit_violation(self, states: NDArray[np.float64]) -> float:
        """How far the predicted speed v(1..N) drops below ``speed_min`` (m/s; 0 when it never does):
        the speed rows keep it only to the QP's tolerance, and a fallback plan (the shifted previous
        plan holds its last input one step longer) can brake past rest."""
        v = np.asarray(states, dtype=float)[1:, 3]
        return float(max(0.0, self.speed_min - v.min())) if v.size else 0.0

    def repair_plan(self, x0: ArrayLike, inputs: ArrayLike, dt: float) -> NDArray[np.float64]:
        """``inputs`` with each acceleration raised just enough that v(k+1) = v(k) + a(k) dt stays
        >= ``speed_min`` (within the acceleration bounds): braking stops at rest instead of reversing."""
        u = np.array(inputs, dtype=float).reshape(-1, 2)
        a_lo, a_hi = self.accel_min, self.accel_max
        v = float(np.asarray(x0, dtype=float)[3])
        for k in range(u.shape[0]):
            if v + u[k, 1] * dt < self.speed_min:
                u[k, 1] = min(a_hi, max(a_lo, (self.speed_min - v) / dt))
            v = v + u[k, 1] * dt
        return u

    def decided_steps(self, dt: float) -> int:
        """With one Euler step per dt the position at k = 1 depends on the state only; with
        sub-steps u_0 moves it (a little), so those rows stay in the QP."""
        return 1 if self.substeps(dt) == 1 else 0

    def speed_bounds(self, v0: float, n_h: int, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bounds on v(1..N_h): [speed_min, speed_max], widened to the speeds the acceleration
        bounds can reach from v(0), so that the speed rows are always feasible (a car rolling
        back or over speed is brought back without an infeasible QP)."""
        k = np.arange(1, n_h + 1) * dt
        return np.minimum(self.speed_min, v0 + k * self.accel_max), np.maximum(self.speed_max, v0 + k * self.accel_min)

    def state_rows(self, x0: NDArray[np.float64], n_h: int, dt: float) -> list[StateRow]:
        lo, hi = self.speed_bounds(float(x0[3]), n_h, dt)
        return [(3, lo, hi)]

    def plan(self, x0: ArrayLike, n_h: int, dt: float, steer: float, accel: str) -> NDArray[np.float64]:
        """Constant steer with acceleration 'hold' (0), 'brake' (to rest at the strongest
        deceleration, never reversing) or 'ease' (half of it)."""
        u = np.zeros((n_h, 2))
        u[:, 0] = steer
        v = float(np.asarray(x0, dtype=float)[3])
        for k in range(n_h):
            if accel == "hold":
                a = 0.0
            else:
                a_min = self.accel_min if accel == "brake" else 0.5 * self.accel_min
                a = min(self.accel_max, max(a_min, -v / dt))  # reach v = 0 exactly, never below
            u[k, 1] = a
            v += a * dt
        return u

    def braking_plan(self, x0: ArrayLike, n_h: int, dt: float) -> NDArray[np.float64]:
        return self.plan(x0, n_h, dt, 0.0, "brake")
