"""Problem `proposed`, assembled from parts: a dynamics model, a cost and a list of barriers.

A problem object holds the data of the current step (ego state, pedestrians with their
velocities and trusts, the cost's reference) and evaluates the problem for an input sequence U
(N_h x n_u) in two ways:

* :meth:`MpcProblem.build` fills the linearised QP of the SQP solver: the model's rollout and
  sensitivities, the cost's Gauss-Newton model, the CBF rows of `cbf_discrete` of every barrier
  (the pedestrians' `cbf_imp` first, then the user's barriers), then the model's state rows. The
  built-in model/cost pairs (single integrator + velocity tracking, bicycle + lane tracking) have
  fused compiled kernels for the model, cost and pedestrian rows (:data:`FUSED_KERNELS`); any
  other model or cost goes through the protocols, with the same result;
* :meth:`MpcProblem.cost_np` / :meth:`MpcProblem.constraints_np` evaluate cost and
  constraints in plain numpy, as the paper's code does, for the SLSQP reference solver.

Row layout: CBF rows k * N_o + j for obstacle j (pedestrians first, then the functions of each
user barrier in order) at step k, then the state rows.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import _kernels as kern
from trustnav.control import _qp, starts
from trustnav.control.barrier import TIMINGS, Barrier, RoadEdgeBarrier, Timing, cbf_rows
from trustnav.control.caution import CautionConfig
from trustnav.control.costs import (
    Cost,
    LaneStage,
    LaneTrackingCost,
    PositionTrackingCost,
    TrackingWeights,
    VelocityTrackingCost,
)
from trustnav.control.deadlock import DeadlockConfig
from trustnav.control.models import Dynamics, DynamicsModel, KinematicBicycle, SingleIntegrator
from trustnav.control.reference import BoundedProportionalReference as BPReference
from trustnav.control.yielding import YieldConfig
from trustnav.trust import PAPER_GAMMA_NUMERICAL, GammaParams, gamma

__all__ = [
    "FUSED_KERNELS",
    "BicycleProblem",
    "LaneTrackingCost",
    "MpcConfig",
    "MpcProblem",
    "PlanCheck",
    "PositionTrackingCost",
    "SingleIntegratorProblem",
    "TrackingWeights",
    "VelocityTrackingCost",
    "as_pedestrians",
    "check_margins",
    "make_problem",
]


@dataclass(frozen=True)
class MpcConfig:
    """Horizon N_h, step dt, margin R, gamma(trust) of `weight`, CBF timing, latency (s), the
    wall-clock deadline of one controller step (s; None = half of dt), and ``confidence``: the
    probability with which R is kept from a pedestrian whose state comes with a covariance
    (:func:`~trustnav.control.barrier.uncertainty_margins`; unused for exact states).

    ``deterministic``: no wall-clock deadline; each step is bounded by the solver's iteration
    budget alone (``SqpSolver``'s ``max_iter``, ``max_restarts`` and ``phase1_qps``), so its result
    depends on its inputs only, never on the machine's load (reproducible runs, tests, offline
    studies). The default (False) is the real-time mode: the deadline cuts a solve short.

    ``deadlock``: the route layer that takes a wedged vehicle around a group of pedestrians
    (:mod:`~trustnav.control.deadlock`; costs that track a goal with a planar velocity); None: the
    paper's plain controller, which stops for good when wedged (the paper's presets use None).

    ``yielding``: the layer that makes a car on a lane brake and wait for a pedestrian it cannot
    pass without leaving the road (:mod:`~trustnav.control.yielding`; a ``LaneTrackingCost`` with a
    ``RoadEdgeBarrier``); None: the MPC alone.

    ``caution``: the trust-aware speed bound (:mod:`~trustnav.control.caution`: the car can stop
    short of the region a pedestrian could reach before the camera would show a step-out, larger
    as trust falls); None (default): the paper's controller, unchanged."""

    horizon: int = 7
    dt: float = 0.05
    safety_radius: float = 3.0
    gamma: GammaParams = field(default_factory=lambda: PAPER_GAMMA_NUMERICAL)
    timing: Timing = "paper"
    latency: float = 0.0
    deadline: float | None = None
    confidence: float = 0.95
    deterministic: bool = False
    deadlock: DeadlockConfig | None = field(default_factory=DeadlockConfig)
    yielding: YieldConfig | None = field(default_factory=YieldConfig)
    caution: CautionConfig | None = None

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
        if not 0.5 <= self.confidence < 1.0:
            raise ValueError(f"confidence must be in [0.5, 1), got {self.confidence!r}")
        if not isinstance(self.deterministic, bool):
            raise ValueError(f"deterministic must be True or False, got {self.deterministic!r}")
        if self.deadlock is not None and not isinstance(self.deadlock, DeadlockConfig):
            raise ValueError(f"deadlock must be a DeadlockConfig or None, got {self.deadlock!r}")
        if self.yielding is not None and not isinstance(self.yielding, YieldConfig):
            raise ValueError(f"yielding must be a YieldConfig or None, got {self.yielding!r}")
        if self.caution is not None and not isinstance(self.caution, CautionConfig):
            raise ValueError(f"caution must be a CautionConfig or None, got {self.caution!r}")


MAX_COORDINATE = 1e12  # m; beyond it float64 spacing exceeds 0.1 mm


class PlanCheck(NamedTuple):
    """Exact check of one plan: violations of the CBF rows (m^2) and cost."""

    first_row: float  # worst violation of the k = 0 rows (those that decide the next state)
    worst: float  # worst violation over the horizon
    total: float  # sum of violations over the horizon
    cost: float
    barrier: float = 0.0  # worst violation of the user barriers' rows (the road's edges) alone


def _sum(arr: NDArray[np.float64]) -> float:
    """Sum of a float array, cheap for the few numbers of a step's data (a non-finite entry, or an
    overflow, makes it non-finite)."""
    return sum(arr.ravel().tolist()) if arr.size <= 64 else float(arr.sum())


def _points(value: ArrayLike, name: str) -> NDArray[np.float64]:
    """An (N, 2) array of finite points (N may be 0); anything else is refused by name and shape."""
    if (
        type(value) is np.ndarray
        and value.dtype == np.float64
        and value.ndim == 2
        and value.shape[1] == 2
        and value.flags.c_contiguous
        and math.isfinite(_sum(value))
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


def check_margins(margins: ArrayLike | None, n_p: int) -> NDArray[np.float64] | None:
    """Validated per-pedestrian margins (N,) >= 0 metres, or None."""
    if margins is None:
        return None
    try:
        m = np.asarray(margins, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"margins must be {n_p} non-negative numbers (m), got {margins!r}") from exc
    if m.shape != (n_p,) or not np.all(np.isfinite(m)) or np.any(m < 0):
        raise ValueError(f"margins must be {n_p} finite non-negative numbers (m), one per pedestrian, got {margins!r}")
    return np.ascontiguousarray(m)


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


class _ProtocolModel(DynamicsModel):
    """A model that follows :class:`Dynamics` without subclassing :class:`DynamicsModel`: the
    protocol's methods are its own, the rest are the base class's defaults."""

    def __init__(self, model: Any) -> None:
        self._model = model
        self.nx, self.nu, self.name = int(model.nx), int(model.nu), str(model.name)
        self.state_names = tuple(getattr(model, "state_names", ()))
        self.input_names = tuple(getattr(model, "input_names", ()))

    def step(self, x, u, dt):
        return np.asarray(self._model.step(x, u, dt), dtype=float)

    def jacobians(self, x, u, dt):
        a, b = self._model.jacobians(x, u, dt)
        return np.asarray(a, dtype=float), np.asarray(b, dtype=float)

    def input_bounds(self):
        lo, hi = self._model.input_bounds()
        return np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)


def as_model(model: Any) -> DynamicsModel:
    """``model`` itself when it subclasses :class:`DynamicsModel`, else wrapped (it must follow
    the :class:`Dynamics` protocol)."""
    if isinstance(model, DynamicsModel):
        return model
    if not isinstance(model, Dynamics):
        raise ValueError(
            f"model must follow the Dynamics protocol (nx, nu, name, step, jacobians, input_bounds), got {model!r}"
        )
    return _ProtocolModel(model)


def _check_barriers(barriers: Sequence[Any]) -> tuple[Barrier, ...]:
    out = tuple(barriers)
    for i, b in enumerate(out):
        if not isinstance(b, Barrier):
            raise ValueError(f"barriers[{i}] must follow the Barrier protocol (size, decay, values), got {b!r}")
        decay = np.asarray(b.decay(), dtype=float)
        if decay.shape != (b.size(),) or not np.all((decay >= 0.0) & (decay <= 1.0)):
            raise ValueError(
                f"barriers[{i}].decay() must give {b.size()} values 1 - gamma in [0, 1], got {decay.tolist()!r}"
            )
    return out


#: Compiled kernels that fuse a built-in model, its cost and the pedestrian rows in one call:
#: (model class, cost class) -> builder(problem, U) -> cost. Exact classes only (a subclass may
#: change the equations); every other pair is assembled through the protocols.
FUSED_KERNELS: dict[tuple[type, type], Callable[[MpcProblem, NDArray[np.float64]], float]] = {}


class MpcProblem:
    """Condensed MPC problem `proposed` with n = N_h n_u decision variables, assembled from a
    dynamics model, a cost and barriers: the paper's pedestrian barrier (data set per step by
    :meth:`set_stage`) and any user barriers (:class:`~trustnav.control.barrier.Barrier`)."""

    def __init__(self, model: Dynamics, cost: Cost, config: MpcConfig, barriers: Sequence[Barrier] = ()) -> None:
        self.model = as_model(model)
        if not isinstance(cost, Cost):
            raise ValueError(
                f"cost must follow the Cost protocol (check, prepare, evaluate, value, initial_guess), got {cost!r}"
            )
        cost.check(self.model)
        self.cost = cost
        self.config = config
        self.barriers = _check_barriers(barriers)
        self.n_user = sum(b.size() for b in self.barriers)
        model = self.model
        self.n_h = config.horizon
        self.n = self.n_h * model.nu
        ulo, uhi = model.input_bounds()
        self.ulo = np.ascontiguousarray(ulo, dtype=float)
        self.uhi = np.ascontiguousarray(uhi, dtype=float)
        self.lo = np.tile(self.ulo, self.n_h)
        self.hi = np.tile(self.uhi, self.n_h)
        self.timing_code = 0 if config.timing == "paper" else 1
        self.decided_steps = model.decided_steps(config.dt)
        self.feasibility_search = bool(model.feasibility_search)
        self.nonlinear = not (model.linear and cost.constant_hessian)
        self.kind = (model.name, type(cost).__name__)  # problems that share a QP structure
        self._fused = FUSED_KERNELS.get((type(model), type(cost)))
        self._velocity_stage = type(model) is SingleIntegrator  # set_checked_stage: one compiled call
        self.n_state_rows = self.n_h * len(model.state_rows(np.zeros(model.nx), self.n_h, config.dt))
        self.x0 = np.zeros(model.nx)
        self.origin = np.zeros(2)
        self.xs = np.zeros((self.n_h + 1, model.nx))
        self.sens = np.zeros((self.n_h + 1, model.nx, self.n))
        self.u_prev = np.zeros(model.nu)
        self.stage: Any = None
        self.radii = np.zeros(0)
        self.r2 = np.zeros(0)
        self._constants: tuple | None = None  # what a fused kernel takes from the frozen model and cost
        self._plain_radii = False  # radii and r2 hold R for every pedestrian (no margins)
        self._qp_structs: _qp.QpStructs | None = None  # DAQP's C structures over H, f, A, bu, bl
        self._seen = np.empty((0, self.n_h, 2))  # iterates of the compiled loop
        self._whole_args: tuple | None = None  # whole_step's compiled call's fixed arguments
        # an exact-Hessian SQP where the rows' curvature is known in closed form (the single
        # integrator tracking a velocity: positions linear in U, cost Hessian 2 I); H then holds the
        # curvature of the last hard QP's multipliers (`curve`) or the cost's alone (`flatten`)
        # a road's edges as the only user barrier: its rows are built by a compiled kernel, in the
        # compiled SQP loop too (the drive's controller); (start, normal, room, front, 1 - gamma, turn radius)
        self._road = None
        self._n_road = 0
        if len(self.barriers) == 1 and type(self.barriers[0]) is RoadEdgeBarrier:
            b = self.barriers[0]
            if b.front == 0 or model.nx > 2:
                self._road = np.array([*b.start, *b.normal, *b.room, b.front, 1.0 - b.gamma, b.turn_radius])
                self._n_road = b.size()
        self.exact_capable = self._fused is _fused_single_integrator
        self.exact_hessian = self.exact_capable  # the solver may turn it off (SqpSolver(hessian=...))
        self._curved = False
        self.speed_cap = math.inf  # the step's bound on the speed rows (caution; inf: the model's)
        self._resize(0)

    def _resize(self, n_p: int) -> None:
        self.n_p = n_p
        self.n_obs = n_p + self.n_user  # obstacles: one CBF row each per horizon step
        self.n_decided = self.n_obs * self.decided_steps  # rows fixed by the current state
        self.m_cbf = self.n_obs * self.n_h
        self.m = self.m_cbf + self.n_state_rows
        self.H = 2.0 * np.eye(self.n)
        self._curved = False
        self.f = np.zeros(self.n)
        self.A = np.zeros((self.m, self.n))
        self.bl = np.zeros(self.n + self.m)
        self.bu = np.zeros(self.n + self.m)
        self.g = np.zeros(self.m_cbf)

    # ---- the step's data ----
    def set_stage(
        self,
        state: ArrayLike,
        pedestrians: ArrayLike,
        velocities: ArrayLike | None,
        trusts: ArrayLike,
        u_prev: ArrayLike | None = None,
        margins: ArrayLike | None = None,
    ) -> None:
        """Data of one MPC step; gamma_j from trust_j by `weight`; ``margins`` (N,) metres added to
        R for each pedestrian (None: none; see :func:`~trustnav.control.barrier.uncertainty_margins`).
        Inputs validated."""
        peds, vels, tr = as_pedestrians(pedestrians, velocities, trusts)
        m = check_margins(margins, peds.shape[0])
        self.set_checked_stage(self.model.check_state(state), peds, vels, tr, u_prev, m)

    def set_checked_stage(
        self,
        x0: NDArray[np.float64],
        peds: NDArray[np.float64],
        vels: NDArray[np.float64],
        tr: NDArray[np.float64],
        u_prev: ArrayLike | None = None,
        margins: NDArray[np.float64] | None = None,
    ) -> None:
        """:meth:`set_stage` for inputs already validated by :func:`as_pedestrians`,
        :func:`check_margins` and the model."""
        cost = self.cost
        if self._velocity_stage and type(cost) is VelocityTrackingCost and type(cost.reference) is BPReference:
            # the common case in one compiled call (the same arithmetic as the general code below,
            # which refuses bad data with its messages)
            n_p = tr.shape[0]
            x_new, origin, peds_c = np.empty(x0.shape[0]), np.empty(2), np.empty((n_p, 2))
            omg, ref = np.empty(n_p), np.empty((self.n_h, 2))
            gp, goal, r = self.config.gamma, cost.goal, cost.reference
            code = kern.velocity_stage(
                x0, peds, tr, gp.gamma_ini, gp.delta, gp.lam, float(goal[0]), float(goal[1]), float(r.gain),
                float(r.v_max), float(self.config.dt), r.mode == "rollout", MAX_COORDINATE, x_new, origin, peds_c,
                omg, ref,
            )  # fmt: skip
            if code == 0:
                self.vels, self.origin, self.x0, self.peds, self.one_minus_gamma = vels, origin, x_new, peds_c, omg
                self._set_radii(n_p, margins)
                if n_p != self.n_p:
                    self._resize(n_p)
                self.u_prev = np.zeros(self.model.nu) if u_prev is None else np.asarray(u_prev, dtype=float).copy()
                self.stage = ref
                return
        x0 = x0.copy()
        self.vels = vels
        # ego-centred coordinates: the problem is solved relative to the ego's position, so large
        # map coordinates (1e9 m) lose no precision; inputs are translation invariant
        ox, oy = float(x0[0]), float(x0[1])
        if abs(ox) > MAX_COORDINATE or abs(oy) > MAX_COORDINATE:
            raise ValueError(
                f"ego position {x0[:2].tolist()} is beyond +-{MAX_COORDINATE:g} m, where float64 cannot hold "
                "millimetre offsets between ego and pedestrians: use a local origin"
            )
        origin = x0[:2].copy()
        self.origin = origin
        x0[0] = x0[1] = 0.0
        self.x0 = x0  # a fresh 1-D copy: contiguous
        n_p = tr.shape[0]
        self.peds = peds - origin  # a new (N, 2) array: contiguous
        gp = self.config.gamma
        omg = np.empty(n_p)
        if not kern.one_minus_gamma(tr, gp.gamma_ini, gp.delta, gp.lam, omg):
            gamma(tr, gp)  # raises, naming the trusts outside [0, 1]
        self.one_minus_gamma = omg
        self._set_radii(n_p, margins)
        if n_p != self.n_p:
            self._resize(n_p)
        self.u_prev = np.zeros(self.model.nu) if u_prev is None else np.asarray(u_prev, dtype=float).copy()
        self.stage = cost.prepare(x0, origin, self.n_h, self.config.dt)

    def _set_radii(self, n_p: int, margins: NDArray[np.float64] | None) -> None:
        """R, plus each pedestrian's margin, and its square (kept from the last step when unchanged)."""
        if margins is not None:
            self.radii = self.config.safety_radius + margins
            self.r2 = np.ascontiguousarray(self.radii * self.radii)
            self._plain_radii = False
        elif not (self._plain_radii and self.radii.shape[0] == n_p):  # else: unchanged, kept
            self.radii = np.full(n_p, self.config.safety_radius)
            self.r2 = np.ascontiguousarray(self.radii * self.radii)
            self._plain_radii = True

    # ---- the linearised QP ----
    def build(self, u: NDArray[np.float64]) -> float:
        """Fill H, f, A, bl, bu, g for the step dU at U (N_h, n_u); returns the cost at U. The
        states and sensitivities at U are left in ``xs`` and ``sens``."""
        if self._fused is not None:
            cost = self._fused(self, u)
        else:
            cost = self._build_parts(u)
        if self.n_user:
            self._fill_user_rows()
        if self.n_decided:
            self.bl[self.n : self.n + self.n_decided] = -kern.INF  # decided rows: nothing to choose
        return cost

    def curve(self, lam: NDArray[np.float64]) -> None:
        """H of the next QP with the pedestrian rows' curvature weighted by the multipliers ``lam`` of
        the last hard QP (DAQP's, simple bounds first); problems without :attr:`exact_hessian`
        keep theirs (:func:`~trustnav.control._kernels.single_integrator_curvature`)."""
        if self.exact_hessian and lam.shape[0] == self.n + self.m:  # (not a relaxed QP's)
            kern.single_integrator_curvature(lam, self.n, self.one_minus_gamma, self.n_obs, self.n_p,
                                             float(self.config.dt), kern.CURVATURE_FLOOR, self.H)  # fmt: skip
            self._curved = True

    @property
    def curvature_floor(self) -> float:
        """The compiled loops' eigenvalue floor of the exact Hessian; 0: the cost's Hessian alone."""
        return kern.CURVATURE_FLOOR if self.exact_hessian else 0.0

    def flatten(self) -> None:
        """H back to the cost's Hessian alone (the first QP of a solve, recoveries, relaxations)."""
        if self._curved:
            kern.flat_hessian(self.H)
            self._curved = False

    def compiled_steps(
        self,
        u: NDArray[np.float64],
        max_it: int,
        tol: float,
        primal_tol: float,
        merit_weight: float,
        full_steps: int | None = None,
    ) -> tuple[int, int, float, int, NDArray[np.float64]] | None:
        """Up to ``max_it`` SQP iterations from ``u`` (changed in place) in one compiled call: full
        steps for the single integrator (:func:`~trustnav.control._qp.single_integrator_full_steps`;
        after ``full_steps`` iterations, when given, the line search of the bicycle's),
        steps with a line search on the L1 merit (weight ``merit_weight``) for the bicycle
        (:func:`~trustnav.control._qp.bicycle_steps`). None where there is no compiled loop (other
        models and costs, user barriers, no rows, DAQP's C API unavailable). Returns (iterations,
        state, cost, DAQP flag, the iterates whose QP was solved)."""
        fused = self._fused
        road = self.n_user and self._road is not None and fused is _fused_bicycle  # the drive's controller
        if fused is None or (self.n_user and not road) or self.m == 0 or not _qp.AVAILABLE:
            return None
        if fused is not _fused_single_integrator and fused is not _fused_bicycle:
            return None
        qs = self._qp_structs
        if qs is None or not qs.holds(self.H, self.f, self.A, self.bu, self.bl) or qs.settings[0] != primal_tol:
            qs = self._qp_structs = _qp.QpStructs(self.H, self.f, self.A, self.bu, self.bl, primal_tol)
        c = self.config
        seen = self._seen
        if seen.shape[0] != max_it:  # the iterates' buffer, reused: its rows are read before the next call
            seen = self._seen = np.empty((max_it, self.n_h, 2))
        tail = qs.tail
        if fused is _fused_single_integrator:
            it, state, cost, flag = _qp.single_integrator_full_steps(
                max_it, tol, u, seen, self.x0, self.stage, self.peds, self.vels, self.one_minus_gamma, self.r2,
                c.dt, self.timing_code, self.n_obs, self.ulo, self.uhi, self.xs, self.sens, self.f, self.A, self.bl,
                self.bu, self.g, *tail, max_it if full_steps is None else full_steps, merit_weight, np.empty_like(u),
                self.H, self.n_p, self.curvature_floor,
            )  # fmt: skip
            self._curved = True
        else:
            w, wheelbase, vmin, vmax, dt, n_sub = self._bicycle_constants()
            vmax = min(vmax, self.speed_cap)
            st = self.stage
            it, state, cost, flag = _qp.bicycle_steps(
                max_it, tol, merit_weight, u, seen, np.empty_like(u), self.x0, self.u_prev, st.points, st.yaw,
                st.speed, w, wheelbase, vmin, vmax, self.peds, self.vels, self.one_minus_gamma, self.r2, dt, n_sub,
                self.timing_code, self.n_obs, self.m_cbf, self.n_decided, self.ulo, self.uhi, self.xs, self.sens,
                self.H, self.f, self.A, self.bl, self.bu, self.g, *tail, float(self.origin[0]), float(self.origin[1]),
                self._road if road else _NO_ROAD, self._n_road if road else 0,
            )  # fmt: skip
        return it, state, cost, flag, seen[: it - 1 if state < 0 else it]

    def whole_step(
        self,
        x: NDArray[np.float64],
        peds: NDArray[np.float64],
        vels: NDArray[np.float64],
        tr: NDArray[np.float64],
        prev: NDArray[np.float64],
        u_prev: NDArray[np.float64],
        max_it: int,
        tol: float,
        primal_tol: float,
        merit_weight: float,
        full_steps: int,
        feas_tol: float,
        state_tol: float = 1e-6,
    ) -> tuple[int, float, float, float, float, float, NDArray[np.float64], NDArray[np.float64]] | None:
        """The step's data, the warm start from the previous plan ``prev`` (its last input held),
        up to ``max_it`` SQP iterations (as :meth:`compiled_steps`), the exact check and the
        predicted states in one compiled call for the common cases: a single integrator tracking a
        velocity (:func:`~trustnav.control._qp.single_integrator_step`) or a kinematic bicycle
        tracking a lane (:func:`~trustnav.control._qp.bicycle_step`), each with its bounded
        proportional reference, pedestrians of the last step's number with R alone, no user
        barriers, the DAQP structures of the last step. ``x``, ``peds``, ``vels``, ``tr``: float64
        C arrays of the right shapes (the caller checks; values are checked here); ``u_prev`` the
        last command (kept, not copied). Returns (iterations, cost, first-row violation, worst
        violation, state-limit violation, violation of the rows the state decides, plan, predicted
        states) when the loop converged to a plan whose rows all hold within ``feas_tol`` and that
        keeps the model's state limits within ``state_tol``, the problem then holding the step's
        data as :meth:`set_checked_stage` leaves it; else None, with DAQP's warm start as it was,
        so that the general path runs (recovering, repairing, or refusing a bad input by name)
        exactly as without this call."""
        qs, ck = self._qp_structs, self._whole_args
        n_p = self.n_p
        if not (
            ck is not None and ck[0] is self.cost and ck[1] is qs and ck[2] is self.r2 and ck[3] is self.f
            and ck[4] >= max_it and ck[5] == (tol, primal_tol, merit_weight, full_steps, self.curvature_floor)
        ):  # fmt: skip
            ck = self._whole_args = self._whole_arguments(max_it, tol, primal_tol, merit_weight, full_steps)
            if ck is None:
                return None
        if tr.shape[0] != n_p or not n_p or not self._plain_radii:
            return None
        bicycle = ck[9]
        self._curved = not bicycle
        try:
            if bicycle:
                out = _qp.bicycle_step(x, peds, vels, tr, prev, u_prev, max_it, *ck[6])
            else:
                out = _qp.single_integrator_step(x, peds, vels, tr, prev, max_it, *ck[6])
        except TypeError:  # not float64 C arrays of the right dimensions (no new compilation)
            return None
        if bicycle:
            code, it, state, value, first, worst, limit, decided, u, predicted = out
        else:
            code, it, state, value, first, worst, u, predicted = out
            limit = decided = 0.0
        if code != 0 or state <= 0 or worst > feas_tol or limit > state_tol or decided > feas_tol:
            if code == 0:
                qs.lam[:] = ck[7]
            return None
        self.vels, self.u_prev = vels, u_prev  # the controller's last command: never changed in place
        self.x0, self.origin, self.peds, self.one_minus_gamma, self.stage = ck[8]
        return it, value, first, worst, limit, decided, u, predicted

    def _whole_arguments(self, max_it: int, tol: float, primal_tol: float, merit_weight: float, full_steps: int):
        """What :meth:`whole_step` passes to its compiled call besides the step's data, with what it
        was made from (the cost, the DAQP structures, R^2 and the QP buffers it points at, the
        settings), DAQP's saved working set, the step's data arrays (as the problem's attributes:
        x0, origin, pedestrians, 1 - gamma, the cost's stage) and whether the model is the
        bicycle; None where the compiled step does not apply."""
        cost, qs = self.cost, self._qp_structs
        fused = self._fused
        if (
            fused not in (_fused_single_integrator, _fused_bicycle)
            or self.n_user
            or type(cost) not in (VelocityTrackingCost, LaneTrackingCost)
            or type(cost.reference) is not BPReference
            or qs is None
            or not qs.holds(self.H, self.f, self.A, self.bu, self.bl)
            or qs.settings[0] != primal_tol
        ):
            return None
        bicycle = fused is _fused_bicycle
        if (bicycle and (cost.reference.mode == "hold" or not isinstance(cost, LaneTrackingCost))) or (
            not bicycle and (self.n_decided or not isinstance(cost, VelocityTrackingCost))
        ):
            return None
        c, gp, r, goal = self.config, self.config.gamma, cost.reference, cost.goal
        n_h, nx = self.n_h, self.model.nx
        seen = np.empty((max(max_it, 64), n_h, 2))  # the loop's iterates: scratch here
        lam0 = np.empty(qs.lam.shape[0])
        gamma = (float(gp.gamma_ini), float(gp.delta), float(gp.lam))
        # the step's data: written in place at every whole step (the general path makes new arrays)
        data = [np.empty(nx), np.empty(2), np.empty((self.n_p, 2)), np.empty(self.n_p)]
        if bicycle:
            w, wheelbase, vmin, vmax, dt, n_sub = self._bicycle_constants()
            pts, yaw, speed = np.empty((n_h + 1, 2)), np.empty(n_h + 1), np.empty(n_h + 1)
            stage: Any = LaneStage(pts, yaw, speed)
            args = (
                *data, pts, yaw, speed, np.empty((n_h, 2)), np.empty((n_h, 2)), lam0, *gamma,
                float(cost.start[0]), float(cost.start[1]), float(goal[0]), float(goal[1]), float(r.gain),
                float(r.v_max), r.mode == "rollout", float(MAX_COORDINATE), float(tol), float(merit_weight), seen, w,
                wheelbase, vmin, vmax, dt, int(n_sub), self.r2, int(self.timing_code), int(self.m_cbf),
                int(self.n_decided), self.ulo, self.uhi, self.xs, self.sens, self.H, self.f, self.A, self.bl, self.bu,
                self.g, *qs.tail,
            )  # fmt: skip
        else:
            stage = np.empty((n_h, 2))
            args = (
                *data, stage, np.empty((n_h, 2)), lam0, *gamma, float(goal[0]), float(goal[1]), float(r.gain),
                float(r.v_max), float(c.dt), r.mode == "rollout", float(MAX_COORDINATE), float(tol), seen, self.r2,
                int(self.timing_code), int(self.n_decided), self.ulo, self.uhi, self.xs, self.sens, self.f, self.A,
                self.bl, self.bu, self.g, *qs.tail, int(full_steps), float(merit_weight), self.H,
                self.curvature_floor,
            )  # fmt: skip
        settings = (tol, primal_tol, merit_weight, full_steps, self.curvature_floor)
        return cost, qs, self.r2, self.f, seen.shape[0], settings, args, lam0, (*data, stage), bicycle

    def _bicycle_constants(self) -> tuple:
        """What the bicycle's fused kernels take from the frozen model and cost (gathered once)."""
        if self._constants is None:
            m: KinematicBicycle = self.model  # type: ignore[assignment]
            c = self.config
            self._constants = (self.cost.weights.as_array(), float(m.wheelbase), float(m.speed_min),
                               float(m.speed_max), float(c.dt), m.substeps(c.dt))  # fmt: skip
        return self._constants

    def _build_parts(self, u: NDArray[np.float64]) -> float:
        """:meth:`build` through the protocols: model sensitivities, cost, pedestrian rows,
        state rows."""
        c = self.config
        xs, sens = self.model.sensitivities(self.x0, u, c.dt)
        self.xs[:], self.sens[:] = xs, sens
        cost = self.cost.evaluate(self.stage, xs, sens, u, self.u_prev, self.H, self.f)
        self.bl[: self.n] = self.lo - u.ravel()
        self.bu[: self.n] = self.hi - u.ravel()
        if self.n_p:
            kern.cbf_fill(
                np.ascontiguousarray(xs[:, :2]), np.ascontiguousarray(sens[:, :2, :]), self.peds, self.vels,
                self.one_minus_gamma, self.r2, c.dt, self.timing_code, self.n_obs, self.A, self.bl,
                self.bu, self.g, self.n,
            )  # fmt: skip
        row = self.m_cbf
        for idx, lo, hi in self._state_rows():
            rows = slice(row, row + self.n_h)
            self.A[rows] = sens[1:, idx, :]
            self.bl[self.n + row : self.n + row + self.n_h] = lo - xs[1:, idx]
            self.bu[self.n + row : self.n + row + self.n_h] = hi - xs[1:, idx]
            row += self.n_h
        return cost

    def _state_rows(self) -> list:
        """The model's state rows at x0, the bicycle's speed bound lowered to ``speed_cap``
        (caution; widened, as the model's, to the speeds reachable from v(0))."""
        rows = self.model.state_rows(self.x0, self.n_h, self.config.dt)
        m = self.model
        if self.speed_cap < math.inf and type(m) is KinematicBicycle:
            k = np.arange(1, self.n_h + 1) * self.config.dt
            top = min(m.speed_max, self.speed_cap)
            rows = [(i, lo, np.maximum(top, float(self.x0[3]) + k * m.accel_min)) if i == 3 else (i, lo, hi)
                    for i, lo, hi in rows]  # fmt: skip
        return rows

    def _user_rows(
        self, xs: NDArray[np.float64], sens: NDArray[np.float64] | None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Rows of `cbf_discrete` of the user barriers at states xs (ego-centred): values
        (N_h, n_user) and, with ``sens``, their Jacobians (N_h, n_user, n)."""
        world = xs.copy()
        world[:, :2] += self.origin
        n_h, dt = self.n_h, self.config.dt
        now = np.arange(n_h)
        nxt = now + 1 if self.timing_code == 0 else now
        vals, jacs = [], []
        for b in self.barriers:
            h0, d0 = b.values(world[:-1], now, dt)
            h1, d1 = b.values(world[1:], nxt, dt)
            w = np.asarray(b.decay(), dtype=float)
            vals.append(np.asarray(h1) - w * np.asarray(h0))
            if sens is not None:
                j1 = np.einsum("kmx,kxn->kmn", d1, sens[1:])
                j0 = np.einsum("kmx,kxn->kmn", d0, sens[:-1])
                jacs.append(j1 - w[None, :, None] * j0)
        g = np.concatenate(vals, axis=1)
        return g, (np.concatenate(jacs, axis=1) if sens is not None else None)

    def _fill_user_rows(self) -> None:
        if self._road is not None:  # a road's edges: compiled, as the compiled SQP loop builds them
            kern.road_fill(self.xs, self.sens, float(self.origin[0]), float(self.origin[1]), self._road, self._n_road,
                           self.n_obs, self.n_p, self.A, self.bl, self.bu, self.g, self.n)  # fmt: skip
            return
        g, jac = self._user_rows(self.xs, self.sens)
        rows = (np.arange(self.n_h)[:, None] * self.n_obs + self.n_p + np.arange(self.n_user)[None, :]).ravel()
        self.g[rows] = g.ravel()
        self.A[rows] = jac.reshape(-1, self.n)
        self.bl[self.n + rows] = -g.ravel()
        self.bu[self.n + rows] = kern.INF

    def initial_guess(self) -> NDArray[np.float64]:
        return self.cost.initial_guess(self.stage, self.n_h, self.ulo, self.uhi)

    # ---- exact checks ----
    def evaluate(self, u: NDArray[np.float64]) -> PlanCheck:
        """Exact check of a plan U against the CBF rows (violations max(0, -row) in m^2) and its
        cost. Fills the QP buffers at U as a side effect (like :meth:`build`)."""
        cost = self.build(u)
        return self.check_built(cost)

    def check_built(self, cost: float) -> PlanCheck:
        """:class:`PlanCheck` of the point of the last :meth:`build` (which returned ``cost``)."""
        first, worst, total = kern.row_violations(self.g, self.n_decided, self.n_obs)  # one compiled pass
        barrier = 0.0
        if self.n_user and worst > 0.0:
            barrier = max(0.0, -float(self.g.reshape(self.n_h, self.n_obs)[:, self.n_p :].min()))
        return PlanCheck(first, worst, total, cost, barrier)

    def decided_violation(self) -> float:
        """Worst violation of the rows no input can change (0 for the single integrator), at the
        point of the last :meth:`build`."""
        return max(0.0, -float(self.g[: self.n_decided].min())) if self.n_decided else 0.0

    # ---- plans for the recovery and the fallbacks ----
    def braking_plan(self) -> NDArray[np.float64]:
        """Plan that brings the ego to rest as fast as the input bounds allow, then holds it."""
        return self.model.braking_plan(self.x0, self.n_h, self.config.dt)

    def candidate_starts(self) -> list[NDArray[np.float64]]:
        """Starting plans for feasibility recovery (:func:`trustnav.control.starts.candidate_starts`)."""
        return starts.candidate_starts(self)

    def first_step_infeasible(self, tol: float) -> bool:
        """True when the k = 0 rows admit no first input (a certificate that no plan is
        hard-feasible); False when unknown (:func:`trustnav.control.starts.first_step_infeasible`)."""
        return starts.first_step_infeasible(self, tol)

    def binding_obstacles(self, count: int) -> NDArray[np.int64]:
        """Indices of the obstacles (pedestrians, then user barrier functions) with the lowest
        CBF rows at the last built point."""
        if self.n_obs == 0:
            return np.zeros(0, dtype=np.int64)
        worst = self.g.reshape(self.n_h, self.n_obs).min(axis=0)
        return np.argsort(worst, kind="stable")[:count]

    binding_pedestrians = binding_obstacles  # the name before user barriers

    def escape_direction(self, j: int) -> NDArray[np.float64]:
        """Direction in the plane that increases obstacle j's barrier at the current position:
        away from pedestrian j (ego at the origin), or the position part of a user barrier's
        gradient."""
        if j < self.n_p:
            return -self.peds[j]
        _, grad = self._barrier_at_start(j - self.n_p)
        return grad[:2]

    def _barrier_at_start(self, i: int) -> tuple[float, NDArray[np.float64]]:
        world = self.x0.copy()
        world[:2] += self.origin
        for b in self.barriers:
            if i < b.size():
                h, d = b.values(world[None], np.zeros(1, dtype=np.int64), self.config.dt)
                return float(h[0, i]), np.asarray(d[0, i], dtype=float)
            i -= b.size()
        raise IndexError(i)

    # ---- plain numpy evaluation (reference path) ----
    def states_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        return self.model.rollout(self.x0, np.asarray(u_flat, dtype=float).reshape(self.n_h, -1), self.config.dt)

    def cost_np(self, u_flat: ArrayLike) -> float:
        u = np.asarray(u_flat, dtype=float).reshape(self.n_h, -1)
        return self.cost.value(self.stage, self.states_np(u), u, self.u_prev)

    def constraints_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        """All inequality rows (>= 0): CBF rows (the layout of :meth:`build`), then state rows
        as lower and upper bounds."""
        xs = self.states_np(u_flat)
        c = self.config
        rows = cbf_rows(xs[:, :2], self.peds, self.vels, self.one_minus_gamma, self.radii, c.dt, c.timing)
        if self.n_user:
            rows = np.concatenate([rows, self._user_rows(xs, None)[0]], axis=1)
        extra = [np.concatenate([xs[1:, idx] - lo, hi - xs[1:, idx]]) for idx, lo, hi in self._state_rows()]
        return np.concatenate([rows.ravel(), *extra])

    def decision_rows_np(self, u_flat: ArrayLike) -> NDArray[np.float64]:
        """The rows an input sequence can change: :meth:`constraints_np` without the decided rows."""
        return self.constraints_np(u_flat)[self.n_decided :]


_NO_ROAD = np.zeros(9)  # the compiled bicycle loop's road argument where there is none


def whole_step_kernel_loaded() -> None:
    """Once :meth:`MpcProblem.whole_step`'s compiled call is loaded, it compiles nothing more:
    inputs of other types (integers, views, another dimension) go to the general path, which
    converts or refuses them, instead of compiling a variant in the middle of a control loop."""
    for kernel in (_qp.single_integrator_step, _qp.bicycle_step):
        if kernel.signatures:
            kernel.disable_compile()


def _fused_single_integrator(p: MpcProblem, u: NDArray[np.float64]) -> float:
    c = p.config
    pos = p.xs  # nx = 2: the states are the positions
    return kern.single_integrator_qp(
        p.x0, u, p.stage, p.peds, p.vels, p.one_minus_gamma, p.r2, c.dt, p.timing_code, p.n_obs,
        p.ulo, p.uhi, pos, p.sens, p.f, p.A, p.bl, p.bu, p.g,
    )  # fmt: skip


def _fused_bicycle(p: MpcProblem, u: NDArray[np.float64]) -> float:
    w, wheelbase, vmin, vmax, dt, n_sub = p._bicycle_constants()  # frozen: gathered once per problem
    vmax = min(vmax, p.speed_cap)  # caution's bound of this step (inf without)
    st = p.stage
    return kern.bicycle_qp(
        p.x0, u, p.u_prev, st.points, st.yaw, st.speed, w, wheelbase, vmin, vmax, p.peds, p.vels,
        p.one_minus_gamma, p.r2, dt, n_sub, p.timing_code, p.n_obs, p.m_cbf, p.ulo, p.uhi, p.xs, p.sens, p.H, p.f,
        p.A, p.bl, p.bu, p.g,
    )  # fmt: skip


FUSED_KERNELS[(SingleIntegrator, VelocityTrackingCost)] = _fused_single_integrator
FUSED_KERNELS[(KinematicBicycle, LaneTrackingCost)] = _fused_bicycle


class SingleIntegratorProblem(MpcProblem):
    """Deprecated: ``MpcProblem(SingleIntegrator(...), VelocityTrackingCost(...), config)``."""

    def __init__(self, model: SingleIntegrator, cost: VelocityTrackingCost, config: MpcConfig) -> None:
        warnings.warn("SingleIntegratorProblem is deprecated: use MpcProblem", DeprecationWarning, stacklevel=2)
        super().__init__(model, cost, config)


class BicycleProblem(MpcProblem):
    """Deprecated: ``MpcProblem(KinematicBicycle(...), LaneTrackingCost(...), config)``."""

    def __init__(self, model: KinematicBicycle, cost: LaneTrackingCost, config: MpcConfig) -> None:
        warnings.warn("BicycleProblem is deprecated: use MpcProblem", DeprecationWarning, stacklevel=2)
        super().__init__(model, cost, config)


def make_problem(model: Dynamics, cost: Cost, config: MpcConfig, barriers: Sequence[Barrier] = ()) -> MpcProblem:
    """The problem of a model, its cost and extra barriers (ValueError when the cost does not fit
    the model)."""
    return MpcProblem(model, cost, config, barriers)
