"""Problem `proposed`: cost, horizon, barrier constraints, for one model, one MPC step at a time.

A problem object holds the data of the current step (ego state, pedestrians with their
velocities and trusts, the reference) and evaluates the problem for an input sequence U
(N_h x n_u) in two ways:

* :meth:`MpcProblem.build` fills the linearised QP of the SQP solver (compiled kernels);
* :meth:`MpcProblem.cost_np` / :meth:`MpcProblem.constraints_np` evaluate cost and
  constraints in plain numpy, as the paper's code does, for the SLSQP reference solver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import _kernels as kern
from trustnav.control.barrier import TIMINGS, Timing, cbf_rows
from trustnav.control.models import DynamicsModel, KinematicBicycle, SingleIntegrator
from trustnav.control.reference import BoundedProportionalReference
from trustnav.trust import PAPER_GAMMA_NUMERICAL, GammaParams, gamma

__all__ = [
    "BicycleProblem",
    "LaneTrackingCost",
    "MpcConfig",
    "MpcProblem",
    "SingleIntegratorProblem",
    "TrackingWeights",
    "VelocityTrackingCost",
    "make_problem",
]


@dataclass(frozen=True)
class MpcConfig:
    """Horizon N_h, step dt, margin R, gamma(trust) of `weight`, CBF timing, latency (s)."""

    horizon: int = 7
    dt: float = 0.05
    safety_radius: float = 3.0
    gamma: GammaParams = field(default_factory=lambda: PAPER_GAMMA_NUMERICAL)
    timing: Timing = "paper"
    latency: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"horizon N_h must be an integer >= 1, got {self.horizon!r}")
        if not self.dt > 0 or math.isinf(self.dt):
            raise ValueError(f"dt must be a positive finite time step, got {self.dt!r}")
        if not self.safety_radius > 0 or math.isinf(self.safety_radius):
            raise ValueError(f"safety_radius R must be positive and finite, got {self.safety_radius!r}")
        if self.timing not in TIMINGS:
            raise ValueError(f"timing must be one of {TIMINGS}, got {self.timing!r}")
        if not self.latency >= 0 or math.isinf(self.latency):
            raise ValueError(f"latency must be >= 0 seconds, got {self.latency!r}")


@dataclass(frozen=True)
class VelocityTrackingCost:
    """Section III cost: q = ||u - u_bar||^2, u_bar from a bounded proportional reference."""

    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(default_factory=BoundedProportionalReference)

    def __post_init__(self) -> None:
        object.__setattr__(self, "goal", tuple(float(g) for g in self.goal))
        if len(self.goal) != 2:
            raise ValueError(f"goal must be 2 coordinates, got {self.goal!r}")


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


@dataclass(frozen=True)
class LaneTrackingCost:
    """Bicycle cost: follow the lane start -> goal at the bounded proportional speed."""

    start: tuple[float, float]
    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(
        default_factory=lambda: BoundedProportionalReference(gain=0.5, v_max=8.0)
    )
    weights: TrackingWeights = field(default_factory=TrackingWeights)

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", tuple(float(g) for g in self.start))
        object.__setattr__(self, "goal", tuple(float(g) for g in self.goal))
        if self.start == self.goal:
            raise ValueError("lane start and goal must differ")


def _as_pedestrians(pedestrians: ArrayLike, velocities: ArrayLike | None, trusts: ArrayLike):
    peds = np.ascontiguousarray(np.asarray(pedestrians, dtype=float).reshape(-1, 2))
    n_p = peds.shape[0]
    vels = (
        np.zeros((n_p, 2))
        if velocities is None
        else np.ascontiguousarray(np.asarray(velocities, dtype=float).reshape(-1, 2))
    )
    tr = np.asarray(trusts, dtype=float).reshape(-1)
    if vels.shape[0] != n_p or tr.shape[0] != n_p:
        raise ValueError(
            f"pedestrians ({n_p}), velocities ({vels.shape[0]}) and trusts ({tr.shape[0]}) must have one entry each"
        )
    if not math.isfinite(peds.sum() + vels.sum()):
        raise ValueError("pedestrian positions and velocities must be finite")
    return peds, vels, tr


class MpcProblem:
    """Common state of a condensed MPC problem with n = N_h n_u decision variables."""

    model: DynamicsModel
    nonlinear: bool = False
    n_extra_rows: int = 0

    def __init__(self, model: DynamicsModel, config: MpcConfig) -> None:
        self.model = model
        self.config = config
        self.n_h = config.horizon
        self.n = self.n_h * model.nu
        ulo, uhi = model.input_bounds()
        self.ulo = np.ascontiguousarray(ulo, dtype=float)
        self.uhi = np.ascontiguousarray(uhi, dtype=float)
        self.lo = np.tile(self.ulo, self.n_h)
        self.hi = np.tile(self.uhi, self.n_h)
        self.timing_code = 0 if config.timing == "paper" else 1
        self.x0 = np.zeros(model.nx)
        self._resize(0)

    def _resize(self, n_p: int) -> None:
        self.n_p = n_p
        self.m_cbf = n_p * self.n_h
        self.m = self.m_cbf + self.n_extra_rows
        self.H = 2.0 * np.eye(self.n)
        self.f = np.zeros(self.n)
        self.A = np.zeros((self.m, self.n))
        self.bl = np.zeros(self.n + self.m)
        self.bu = np.zeros(self.n + self.m)
        self.g = np.zeros(self.m_cbf)

    def set_stage(
        self,
        state: ArrayLike,
        pedestrians: ArrayLike,
        velocities: ArrayLike | None,
        trusts: ArrayLike,
        u_prev: ArrayLike | None = None,
    ) -> None:
        """Data of one MPC step; gamma_j from trust_j by `weight`."""
        self.x0 = np.ascontiguousarray(self.model.check_state(state))
        self.peds, self.vels, tr = _as_pedestrians(pedestrians, velocities, trusts)
        self.one_minus_gamma = np.ascontiguousarray(1.0 - gamma(tr, self.config.gamma))
        if self.peds.shape[0] != self.n_p:
            self._resize(self.peds.shape[0])
        self.u_prev = np.zeros(self.model.nu) if u_prev is None else np.asarray(u_prev, dtype=float).copy()
        self._set_reference()

    def _set_reference(self) -> None:
        raise NotImplementedError

    def build(self, u: NDArray[np.float64]) -> float:
        """Fill H, f, A, bl, bu, g for the step dU at U (N_h, n_u); returns the cost at U."""
        raise NotImplementedError

    def initial_guess(self) -> NDArray[np.float64]:
        raise NotImplementedError

    # ---- plain numpy evaluation (reference path) ----
    def states_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        return self.model.rollout(self.x0, np.asarray(u_flat).reshape(self.n_h, -1), self.config.dt)

    def cost_np(self, u_flat: ArrayLike) -> float:
        raise NotImplementedError

    def constraints_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        """All inequality rows (>= 0): CBF rows, then model-specific rows."""
        xs = self.states_np(u_flat)
        c = self.config
        rows = cbf_rows(xs[:, :2], self.peds, self.vels, self.one_minus_gamma, c.safety_radius, c.dt, c.timing)
        return np.concatenate([rows.ravel(), self._extra_rows_np(xs)])

    def _extra_rows_np(self, xs: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.zeros(0)


class SingleIntegratorProblem(MpcProblem):
    """`proposed` with x+ = x + u dt and q = ||u - u_bar||^2 (Section III)."""

    def __init__(self, model: SingleIntegrator, cost: VelocityTrackingCost, config: MpcConfig) -> None:
        self.cost = cost
        self.goal = np.array(cost.goal)
        super().__init__(model, config)

    def _set_reference(self) -> None:
        self.ubar = np.ascontiguousarray(self.cost.reference.velocities(self.x0, self.goal, self.n_h, self.config.dt))

    def build(self, u: NDArray[np.float64]) -> float:
        c = self.config
        return kern.single_integrator_qp(
            self.x0, u, self.ubar, self.peds, self.vels, self.one_minus_gamma, c.safety_radius**2, c.dt,
            self.timing_code, self.ulo, self.uhi, self.f, self.A, self.bl, self.bu, self.g,
        )  # fmt: skip

    def initial_guess(self) -> NDArray[np.float64]:
        return np.clip(self.ubar, self.ulo, self.uhi)

    def cost_np(self, u_flat: ArrayLike) -> float:
        e = np.asarray(u_flat, dtype=float).reshape(self.n_h, 2) - self.ubar
        return float(np.sum(e * e))


class BicycleProblem(MpcProblem):
    """`proposed` with the kinematic bicycle and the Section IV lane-tracking cost."""

    nonlinear = True

    def __init__(self, model: KinematicBicycle, cost: LaneTrackingCost, config: MpcConfig) -> None:
        self.cost = cost
        self.weights = cost.weights.as_array()
        self.n_extra_rows = config.horizon  # speed bounds on v(k+1)
        super().__init__(model, config)

    def _set_reference(self) -> None:
        pts, yaw, v = self.cost.reference.lane_waypoints(
            self.x0[:2], self.cost.start, self.cost.goal, self.n_h, self.config.dt
        )
        self.ref_pts, self.ref_yaw, self.ref_v = np.ascontiguousarray(pts), yaw, v

    def build(self, u: NDArray[np.float64]) -> float:
        c = self.config
        m = self.model
        return kern.bicycle_qp(
            self.x0, u, self.u_prev, self.ref_pts, self.ref_yaw, self.ref_v, self.weights, m.wheelbase,
            m.speed_min, m.speed_max, self.peds, self.vels, self.one_minus_gamma, c.safety_radius**2, c.dt,
            self.timing_code, self.ulo, self.uhi, self.H, self.f, self.A, self.bl, self.bu, self.g,
        )  # fmt: skip

    def initial_guess(self) -> NDArray[np.float64]:
        return np.zeros((self.n_h, 2))

    def cost_np(self, u_flat: ArrayLike) -> float:
        u = np.asarray(u_flat, dtype=float).reshape(self.n_h, 2)
        xs = self.states_np(u)
        w = self.weights
        normal = np.stack([-np.sin(self.ref_yaw[1:]), np.cos(self.ref_yaw[1:])], axis=1)
        cte = np.sum(normal * (xs[1:, :2] - self.ref_pts[1:]), axis=1)
        head = (xs[1:, 2] - self.ref_yaw[1:] + np.pi) % (2 * np.pi) - np.pi
        dv = xs[1:, 3] - self.ref_v[1:]
        du = np.diff(np.vstack([self.u_prev, u]), axis=0)
        return float(
            w[0] * cte @ cte
            + w[1] * head @ head
            + w[2] * dv @ dv
            + w[3] * u[:, 0] @ u[:, 0]
            + w[4] * u[:, 1] @ u[:, 1]
            + w[5] * du[:, 0] @ du[:, 0]
            + w[6] * du[:, 1] @ du[:, 1]
        )

    def _extra_rows_np(self, xs: NDArray[np.float64]) -> NDArray[np.float64]:
        v = xs[1:, 3]
        m = self.model
        return np.concatenate([v - m.speed_min, m.speed_max - v])


def make_problem(model: DynamicsModel, cost: object, config: MpcConfig) -> MpcProblem:
    """The problem class that fits a model and its cost."""
    if isinstance(model, SingleIntegrator) and isinstance(cost, VelocityTrackingCost):
        return SingleIntegratorProblem(model, cost, config)
    if isinstance(model, KinematicBicycle) and isinstance(cost, LaneTrackingCost):
        return BicycleProblem(model, cost, config)
    raise ValueError(
        f"no MPC problem for model {type(model).__name__} with cost {type(cost).__name__}: use "
        "SingleIntegrator + VelocityTrackingCost or KinematicBicycle + LaneTrackingCost"
    )
