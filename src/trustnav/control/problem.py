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
from typing import NamedTuple

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
    "PlanCheck",
    "SingleIntegratorProblem",
    "TrackingWeights",
    "VelocityTrackingCost",
    "as_pedestrians",
    "make_problem",
]


@dataclass(frozen=True)
class MpcConfig:
    """Horizon N_h, step dt, margin R, gamma(trust) of `weight`, CBF timing, latency (s), and the
    wall-clock deadline of one controller step (s; None = half of dt)."""

    horizon: int = 7
    dt: float = 0.05
    safety_radius: float = 3.0
    gamma: GammaParams = field(default_factory=lambda: PAPER_GAMMA_NUMERICAL)
    timing: Timing = "paper"
    latency: float = 0.0
    deadline: float | None = None

    @property
    def step_deadline(self) -> float:
        return 0.5 * self.dt if self.deadline is None else self.deadline

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
        if self.deadline is not None and (not self.deadline > 0 or math.isinf(self.deadline)):
            raise ValueError(f"deadline must be a positive finite time in seconds (or None), got {self.deadline!r}")


def _finite_pair(value: object, name: str) -> tuple[float, float]:
    try:
        pair = tuple(float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be 2 finite coordinates, got {value!r}") from exc
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair):
        raise ValueError(f"{name} must be 2 finite coordinates, got {value!r}")
    return pair  # type: ignore[return-value]


@dataclass(frozen=True)
class VelocityTrackingCost:
    """Section III cost: q = ||u - u_bar||^2, u_bar from a bounded proportional reference."""

    goal: tuple[float, float]
    reference: BoundedProportionalReference = field(default_factory=BoundedProportionalReference)

    def __post_init__(self) -> None:
        object.__setattr__(self, "goal", _finite_pair(self.goal, "goal"))


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
        object.__setattr__(self, "start", _finite_pair(self.start, "lane start"))
        object.__setattr__(self, "goal", _finite_pair(self.goal, "lane goal"))
        if self.start == self.goal:
            raise ValueError("lane start and goal must differ")


MAX_COORDINATE = 1e12  # m; beyond it float64 spacing exceeds 0.1 mm


class PlanCheck(NamedTuple):
    """Exact check of one plan: violations of the CBF rows (m^2) and cost."""

    first_row: float  # worst violation of the k = 0 rows (those that decide the next state)
    worst: float  # worst violation over the horizon
    total: float  # sum of violations over the horizon
    cost: float


def _points(value: ArrayLike, name: str) -> NDArray[np.float64]:
    """An (N, 2) array of finite points (N may be 0); anything else is refused by name and shape."""
    if (
        type(value) is np.ndarray
        and value.dtype == np.float64
        and value.ndim == 2
        and value.shape[1] == 2
        and value.flags.c_contiguous
        and math.isfinite(float(value.sum()))
    ):
        return value  # the common case, checked cheaply (NaN and inf make the sum non-finite)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an (N, 2) array of numbers, got {value!r}") from exc
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        hint = " (a (2, N) array? pass its transpose)" if arr.ndim == 2 and arr.shape[0] == 2 else ""
        raise ValueError(f"{name} must be an (N, 2) array of x, y pairs, got shape {arr.shape}{hint}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()!r}")
    return np.ascontiguousarray(arr)


def as_pedestrians(pedestrians: ArrayLike, velocities: ArrayLike | None, trusts: ArrayLike):
    """Validated pedestrians (N, 2), velocities (N, 2) (zeros when None) and trusts (N,)."""
    peds = _points(pedestrians, "pedestrians")
    n_p = peds.shape[0]
    vels = np.zeros((n_p, 2)) if velocities is None else _points(velocities, "velocities")
    try:
        tr = np.asarray(trusts, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"trusts must be N numbers in [0, 1], got {trusts!r}") from exc
    if vels.shape[0] != n_p or tr.shape[0] != n_p:
        raise ValueError(
            f"pedestrians ({n_p}), velocities ({vels.shape[0]}) and trusts ({tr.shape[0]}) must have one entry each"
        )
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
        self.origin = np.zeros(2)
        self._resize(0)

    #: leading horizon steps whose CBF rows no input can change (a bicycle integrated with one
    #: Euler step per dt: its position at k = 1 depends on the state only): they are reported,
    #: but left out of the QP and of feasibility
    decided_steps: int = 0

    #: the SQP solver may run its feasibility (phase-1) SQP from varied starts when the recovery's
    #: candidate starts fail (on for the single integrator; off for the bicycle, where phase-1
    #: points led to worse closed loops)
    feasibility_search: bool = False

    def first_step_infeasible(self, tol: float) -> bool:
        """True when the k = 0 rows admit no first input (a certificate that no plan is
        hard-feasible); False when unknown."""
        return False

    def _resize(self, n_p: int) -> None:
        self.n_p = n_p
        self.n_decided = n_p * self.decided_steps  # rows fixed by the current state
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
        """Data of one MPC step; gamma_j from trust_j by `weight` (inputs validated)."""
        peds, vels, tr = as_pedestrians(pedestrians, velocities, trusts)
        self.set_checked_stage(self.model.check_state(state), peds, vels, tr, u_prev)

    def set_checked_stage(
        self,
        x0: NDArray[np.float64],
        peds: NDArray[np.float64],
        vels: NDArray[np.float64],
        tr: NDArray[np.float64],
        u_prev: ArrayLike | None = None,
    ) -> None:
        """:meth:`set_stage` for inputs already validated by :func:`as_pedestrians` and the model."""
        x0 = x0.copy()
        self.vels = vels
        # ego-centred coordinates: the problem is solved relative to the ego's position, so large
        # map coordinates (1e9 m) lose no precision; inputs are translation invariant
        if abs(x0[0]) > MAX_COORDINATE or abs(x0[1]) > MAX_COORDINATE:
            raise ValueError(
                f"ego position {x0[:2].tolist()} is beyond +-{MAX_COORDINATE:g} m, where float64 cannot hold "
                "millimetre offsets between ego and pedestrians: use a local origin"
            )
        self.origin = x0[:2].copy()
        x0[:2] = 0.0
        self.x0 = np.ascontiguousarray(x0)
        self.peds = np.ascontiguousarray(peds - self.origin)
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

    def evaluate(self, u: NDArray[np.float64]) -> PlanCheck:
        """Exact check of a plan U against the CBF rows of `cbf_imp` (violations max(0, -row) in
        m^2) and its cost. Fills the QP buffers at U as a side effect (like :meth:`build`)."""
        cost = self.build(u)
        return self.check_built(cost)

    def check_built(self, cost: float) -> PlanCheck:
        """:class:`PlanCheck` of the point of the last :meth:`build` (which returned ``cost``)."""
        g = self.g[self.n_decided :]
        if g.size == 0 or g.min() >= 0.0:
            return PlanCheck(0.0, 0.0, 0.0, cost)
        viol = np.maximum(0.0, -g)
        return PlanCheck(float(viol[: self.n_p].max()), float(viol.max()), float(viol.sum()), cost)

    def decided_violation(self) -> float:
        """Worst violation of the rows no input can change (0 for the single integrator), at the
        point of the last :meth:`build`."""
        return max(0.0, -float(self.g[: self.n_decided].min())) if self.n_decided else 0.0

    def braking_plan(self) -> NDArray[np.float64]:
        """Plan that brings the ego to rest as fast as the input bounds allow, then holds it."""
        return np.tile(self.model.braking_input(self.x0, self.config.dt), (self.n_h, 1))

    def candidate_starts(self, n_pedestrians: int = 3) -> list[NDArray[np.float64]]:
        """Starting plans for feasibility recovery: braking, the reference, and evasions from the
        most binding pedestrians (the lowest CBF rows at the last built point)."""
        raise NotImplementedError

    def binding_pedestrians(self, count: int) -> NDArray[np.int64]:
        """Indices of the pedestrians with the lowest CBF rows at the last built point."""
        if self.n_p == 0:
            return np.zeros(0, dtype=np.int64)
        worst = self.g.reshape(self.n_h, self.n_p).min(axis=0)
        return np.argsort(worst, kind="stable")[:count]

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

    def decision_rows_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        """The rows an input sequence can change: :meth:`constraints_np` without the decided rows."""
        return self.constraints_np(u_flat)[self.n_decided :]

    def _extra_rows_np(self, xs: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.zeros(0)


class SingleIntegratorProblem(MpcProblem):
    """`proposed` with x+ = x + u dt and q = ||u - u_bar||^2 (Section III)."""

    feasibility_search = True

    def __init__(self, model: SingleIntegrator, cost: VelocityTrackingCost, config: MpcConfig) -> None:
        self.cost = cost
        self.goal = np.array(cost.goal)
        super().__init__(model, config)

    def _set_reference(self) -> None:
        goal = self.goal - self.origin
        self.ubar = np.ascontiguousarray(self.cost.reference.velocities(self.x0, goal, self.n_h, self.config.dt))

    def build(self, u: NDArray[np.float64]) -> float:
        c = self.config
        return kern.single_integrator_qp(
            self.x0, u, self.ubar, self.peds, self.vels, self.one_minus_gamma, c.safety_radius**2, c.dt,
            self.timing_code, self.ulo, self.uhi, self.f, self.A, self.bl, self.bu, self.g,
        )  # fmt: skip

    def initial_guess(self) -> NDArray[np.float64]:
        return np.clip(self.ubar, self.ulo, self.uhi)

    def candidate_starts(self, n_pedestrians: int = 3) -> list[NDArray[np.float64]]:
        """Constant-velocity plans: stop, the reference, and for each binding pedestrian
        backing away, passing on either side, and both diagonals, at the reference speed, half of
        it, a quarter of the input bound and the bound, and a dash at the bound that stops after
        a third of the horizon (the CBF rows are non-convex: a pedestrian can be passed on either
        side, or backed away from)."""
        starts = [np.zeros((self.n_h, 2)), self.initial_guess()]
        ref = float(np.hypot(*self.ubar[0]))
        top = float(self.uhi.min())
        speeds = [s for s in (ref, 0.5 * ref) if s > 1e-6] + [0.25 * top, top]
        dash = np.zeros((self.n_h, 1))
        dash[: max(1, self.n_h // 3)] = 1.0  # full speed for the first third of the horizon, then stop
        for j in self.binding_pedestrians(n_pedestrians):
            away = -self.peds[j]  # ego at the origin
            norm = float(np.hypot(*away))
            e = away / norm if norm > 1e-9 else np.array([1.0, 0.0])  # on top of the ego: any way out
            t = np.array([-e[1], e[0]])
            for d in (e, t, -t, (e + t) / np.sqrt(2), (e - t) / np.sqrt(2)):
                for s in speeds:
                    starts.append(np.clip(np.tile(s * d, (self.n_h, 1)), self.ulo, self.uhi))
                starts.append(np.clip(dash * (top * d), self.ulo, self.uhi))
        return starts

    def first_step_infeasible(self, tol: float, max_disks: int = 32) -> bool:
        """True when no first input u_0 meets every k = 0 row to within ``tol``: then no plan is
        hard-feasible (a certificate, so a solver can skip searching for one).

        The k = 0 rows depend on u_0 alone: the next position p = u_0 dt must lie in the input box
        times dt and outside the open disk |p - q_j(1)|^2 < R^2 + (1 - gamma_j) h_j(0) - tol of
        each pedestrian. A generic linear function attains its minimum over that compact set (if
        nonempty) at a vertex: a box corner, a crossing of a circle with a box edge, or of two
        circles; so the set is empty exactly when no such point is in it. False (no certificate)
        with more than ``max_disks`` disks reaching the box."""
        if self.n_p == 0:
            return False
        c = self.config
        r2 = c.safety_radius**2
        lo, hi = c.dt * self.ulo, c.dt * self.uhi  # the box of p (ego at the origin)
        q_next = self.peds + c.dt * self.vels if self.timing_code == 0 else self.peds
        h0 = np.einsum("ij,ij->i", self.peds, self.peds) - r2
        rho = r2 + self.one_minus_gamma * h0 - tol  # row_j >= -tol  <=>  |p - q_j(1)|^2 >= rho_j
        gap = np.maximum(lo - q_next, 0.0) + np.maximum(q_next - hi, 0.0)  # centre to the box
        near = (rho > 0.0) & (np.einsum("ij,ij->i", gap, gap) < rho)
        if not near.any():
            return False
        if int(near.sum()) > max_disks:
            return False
        cen, rad2 = q_next[near], rho[near]
        pts = [np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]]])]
        for axis in (0, 1):  # circles crossing the box edges x = lo/hi (axis 0), y = lo/hi (axis 1)
            other = 1 - axis
            for edge in (lo[axis], hi[axis]):
                s2 = rad2 - (edge - cen[:, axis]) ** 2
                ok = s2 >= 0.0
                s = np.sqrt(s2[ok])
                for sign in (-1.0, 1.0):
                    e = np.empty((s.size, 2))
                    e[:, axis] = edge
                    e[:, other] = cen[ok, other] + sign * s
                    pts.append(e)
        i, j = np.triu_indices(cen.shape[0], k=1)  # circle-circle crossings
        if i.size:
            d = cen[j] - cen[i]
            dd = np.einsum("ij,ij->i", d, d)
            a = (rad2[i] - rad2[j] + dd) / (2.0 * np.sqrt(np.maximum(dd, 1e-300)))
            h2 = rad2[i] - a * a
            ok = (dd > 0.0) & (h2 >= 0.0)
            dist = np.sqrt(dd[ok])[:, None]
            u = d[ok] / dist
            base = cen[i[ok]] + a[ok, None] * u
            perp = np.stack([-u[:, 1], u[:, 0]], axis=1) * np.sqrt(h2[ok])[:, None]
            pts += [base + perp, base - perp]
        p = np.concatenate(pts)
        eps = 1e-12
        p = p[np.all((p >= lo - eps) & (p <= hi + eps), axis=1)]
        if p.shape[0] == 0:
            return True
        diff = p[:, None, :] - cen[None, :, :]
        margin = (np.einsum("kji,kji->kj", diff, diff) - rad2[None, :]).min(axis=1)
        return not bool((margin >= -1e-9).any())

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
        self.n_sub = model.substeps(config.dt)
        # with one Euler step per dt the position at k = 1 depends on the state only; with
        # sub-steps u_0 moves it (a little), so those rows stay in the QP
        self.decided_steps = 1 if self.n_sub == 1 else 0
        super().__init__(model, config)

    def _set_reference(self) -> None:
        start = np.asarray(self.cost.start) - self.origin
        goal = np.asarray(self.cost.goal) - self.origin
        pts, yaw, v = self.cost.reference.lane_waypoints(self.x0[:2], start, goal, self.n_h, self.config.dt)
        self.ref_pts, self.ref_yaw, self.ref_v = np.ascontiguousarray(pts), yaw, v

    def build(self, u: NDArray[np.float64]) -> float:
        c = self.config
        m = self.model
        cost = kern.bicycle_qp(
            self.x0, u, self.u_prev, self.ref_pts, self.ref_yaw, self.ref_v, self.weights, m.wheelbase,
            m.speed_min, m.speed_max, self.peds, self.vels, self.one_minus_gamma, c.safety_radius**2, c.dt,
            self.n_sub, self.timing_code, self.ulo, self.uhi, self.H, self.f, self.A, self.bl, self.bu, self.g,
        )  # fmt: skip
        self.bl[self.n : self.n + self.n_decided] = -kern.INF  # decided rows: nothing to choose
        return cost

    def initial_guess(self) -> NDArray[np.float64]:
        return np.zeros((self.n_h, 2))

    def states_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        """:meth:`KinematicBicycle.step` along the horizon, in plain floats (the reference path's
        hot loop)."""
        u = np.asarray(u_flat, dtype=float).reshape(self.n_h, 2).tolist()
        h, wb = self.config.dt / self.n_sub, self.model.wheelbase
        px, py, yaw, v = (float(c) for c in self.x0)
        out = [[px, py, yaw, v]]
        for steer, acc in u:
            turn = math.tan(steer) / wb
            for _ in range(self.n_sub):
                px, py, yaw, v = (px + v * math.cos(yaw) * h, py + v * math.sin(yaw) * h,
                                  yaw + v * turn * h, v + acc * h)  # fmt: skip
            out.append([px, py, yaw, v])
        return np.array(out)

    def _plan(self, steer: float, accel: str) -> NDArray[np.float64]:
        """Constant steer with acceleration 'hold' (0), 'brake' (to rest at the strongest
        deceleration, never reversing) or 'ease' (half of it)."""
        m = self.model
        dt = self.config.dt
        u = np.zeros((self.n_h, 2))
        u[:, 0] = steer
        v = float(self.x0[3])
        for k in range(self.n_h):
            if accel == "hold":
                a = 0.0
            else:
                a_min = m.accel_min if accel == "brake" else 0.5 * m.accel_min
                a = min(m.accel_max, max(a_min, -v / dt))  # reach v = 0 exactly, never below
            u[k, 1] = a
            v += a * dt
        return u

    def braking_plan(self) -> NDArray[np.float64]:
        return self._plan(0.0, "brake")

    def candidate_starts(self, n_pedestrians: int = 3) -> list[NDArray[np.float64]]:
        """Constant-steer plans (straight, half and full lock either way) that hold speed,
        ease off or brake to rest."""
        sm = self.model.steer_max
        return [self._plan(st, acc) for acc in ("brake", "ease", "hold") for st in (0.0, 0.5 * sm, -0.5 * sm, sm, -sm)]

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
        lo, hi = self.speed_bounds()
        return np.concatenate([v - lo, hi - v])

    def speed_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Bounds on v(1..N_h): [speed_min, speed_max], widened to the speeds the acceleration
        bounds can reach from v(0), so that the speed rows are always feasible."""
        m = self.model
        k = np.arange(1, self.n_h + 1) * self.config.dt
        v0 = self.x0[3]
        return np.minimum(m.speed_min, v0 + k * m.accel_max), np.maximum(m.speed_max, v0 + k * m.accel_min)


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
