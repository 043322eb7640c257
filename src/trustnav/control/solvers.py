"""Solvers for problem `proposed`: a fast SQP on DAQP (default) and two SLSQP reference baselines.

Both return a :class:`SolveResult` with a status; neither returns an unchecked solution: the
CBF rows are evaluated exactly at the returned inputs and their worst violation is reported.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass, field

import daqp
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from trustnav.control import _kernels as kern
from trustnav.control.barrier import h_quad
from trustnav.control.problem import MpcProblem, PlanCheck

__all__ = [
    "FEAS_TOL",
    "AuthorsSlsqpSolver",
    "SlsqpSolver",
    "SolveResult",
    "SolveStatus",
    "SqpSolver",
    "make_solver",
    "rank_key",
]

DEADLINE = "deadline"  # QP flag: not started, it would not end before the deadline
FEAS_TOL = 1e-6  # tolerance on CBF rows (units of the barrier, m^2) to call a solution feasible
PRIMAL_TOL = 1e-9  # DAQP's tolerance on the QP's rows
MERIT_WEIGHT = 1e4  # weight of the CBF violation in the L1 merit of the line search (hard rows)


class SolveStatus(enum.Enum):
    OPTIMAL = "optimal"  # converged, every CBF row holds
    RELAXED = "relaxed"  # converged with slack: no hard-feasible plan was found
    MAX_ITER = "max_iter"  # iteration limit or deadline reached; the best checked plan, violation reported
    FAILED = "failed"  # the QP / NLP solver failed
    FALLBACK = "fallback"  # the controller applied a checked fallback plan (previous plan or braking)

    @property
    def ok(self) -> bool:
        return self in (SolveStatus.OPTIMAL, SolveStatus.RELAXED)


@dataclass
class SolveResult:
    inputs: NDArray[np.float64]  # (N_h, n_u)
    status: SolveStatus
    iterations: int
    cost: float
    cbf_violation: float  # max over rows of max(0, -row), exact, at `inputs`
    slack_used: bool  # the returned plan violates some CBF row (by more than FEAS_TOL)
    message: str = ""
    solve_time: float = 0.0
    first_row_violation: float = 0.0  # max over the k = 0 rows, exact, at `inputs`
    recovered: bool = False  # a feasibility recovery found a hard-feasible start
    restarts: int = 0  # candidate starts tried by the recovery
    deadline_hit: bool = False


def rank_key(check: PlanCheck) -> tuple[float, float, float, float]:
    """Order of plans: violation of the user barriers' rows (the road's edges: a plan that leaves
    the road ranks after every plan that keeps it), then first-row violation, then total violation
    over the horizon, then cost (violations within FEAS_TOL count as none)."""
    bv = check.barrier if check.barrier > FEAS_TOL else 0.0
    fv = check.first_row if check.first_row > FEAS_TOL else 0.0
    tv = check.total if check.worst > FEAS_TOL else 0.0
    return bv, fv, tv, check.cost if math.isfinite(check.cost) else math.inf


class _Best:
    """The best plan seen so far by :func:`rank_key` (every point the solver evaluates exactly)."""

    def __init__(self) -> None:
        self.key: tuple[float, float, float, float] | None = None
        self.u: NDArray[np.float64] | None = None
        self.check = PlanCheck(math.inf, math.inf, math.inf, math.inf)

    def offer(self, u: NDArray[np.float64], check: PlanCheck) -> None:
        if not math.isfinite(check.total + float(u.sum())):
            return
        key = rank_key(check)
        if self.key is None or key < self.key:
            self.key, self.u, self.check = key, u, check  # callers never modify an offered array


class SqpSolver:
    """Sequential quadratic programming on `proposed` with DAQP for each QP.

    Each iteration linearises the CBF rows (and, for the bicycle, the dynamics) at the current
    iterate with analytic Jacobians and solves a dense QP in the step. The CBF rows are
    non-convex (a pedestrian can be passed on either side, or backed away from), so a QP that is
    infeasible at one linearisation says little about the problem: the solver then runs a
    **feasibility recovery**, ranking the problem's candidate starts (braking, the reference, the
    best point so far, evasions from the binding pedestrians) by their exact CBF violation and
    trying the hard QP at each until one is feasible, and continues with hard rows from there
    (a point tried once in a solve is not tried again). When none is, a **feasibility (phase-1)
    SQP** minimises the total violation from varied starts (bang-bang plans at the input bounds,
    two-segment plans, and pseudo-random plans from a fixed seed, so a solve stays a pure function
    of its problem; budget ``phase1_qps`` QPs per solve): hard-feasible sets can be thin regions
    that only plans with varying inputs reach (a dash through a gap between pedestrians), which
    no constant-velocity candidate linearises into. Only when that fails as well does it relax:
    slacks with an exact L1 penalty ``slack_penalty`` (plus a tiny quadratic term), one per CBF
    row for the most binding pedestrians and fewer, shared ones for the rest
    (:meth:`_slack_columns`), so the QP stays small with hundreds of pedestrians; a hard-feasible
    plan seen on the way beats a relaxed one. Nonlinear models (and linear ones after
    ``full_step_iterations``) take a backtracking step on the L1 merit cost + mu * (violation of
    every row the QP holds), accepted on Armijo's sufficient decrease; when no trial decreases the
    merit, the solve ends at the iterate (no progress is possible along the QP's step), so the
    iteration limit is reached only by steps that keep making progress. ``hessian="exact"``
    (default): where the rows' curvature is known in closed form (the
    single integrator tracking a velocity, :attr:`MpcProblem.exact_capable`), every QP after a
    solve's sixth (``_kernels.CURVATURE_START``: steps that converge in six stay as they were)
    adds it, weighted by the last hard QP's multipliers and convexified by clipping eigenvalues
    (an exact-Hessian SQP, converging in a few iterations where many rows are active);
    ``"gauss-newton"``: the cost's Hessian alone, as before issue 36. Every point evaluated is
    checked exactly; an unconverged solve whose best plan violates
    a row runs the feasibility SQP from it (restoration). With a deadline (seconds) the best
    checked plan so far is returned when it passes; the recovery, phase 1 included, stops at 80 %
    of the deadline (the rest is for relaxing). Problems solved without an infeasible QP never reach any of this.
    """

    name = "sqp-daqp"

    class _Recovery:
        """Per-solve state of the feasibility recovery: the points whose hard QP was tried (an
        infeasible one stays infeasible; from a feasible one the SQP came back to an infeasible
        linearisation), and what is left of the feasibility SQP's QP budget."""

        def __init__(self, qps: int) -> None:
            self.tried: set[bytes] = set()
            self.phase1_qps = qps
            self.phase1_starts = 0  # starts of the feasibility SQP tried
            self._hopeless: bool | None = None

        def hopeless(self, p: MpcProblem) -> bool:
            """True when the problem certifies that no plan is hard-feasible (its k = 0 rows admit no
            first input; see ``SingleIntegrator.first_step_infeasible``); asked once per solve."""
            if self._hopeless is None:
                self._hopeless = bool(p.first_step_infeasible(FEAS_TOL))
            return self._hopeless

        def first_time(self, u: NDArray[np.float64]) -> bool:
            """True the first time a point is seen (and remembers it)."""
            key = np.ascontiguousarray(u, dtype=float).tobytes()
            if key in self.tried:
                return False
            self.tried.add(key)
            return True

    def __init__(
        self,
        max_iter: int = 50,
        tol: float = 1e-9,
        slack_penalty: float = 1e6,
        slack_quadratic: float = 1e-2,
        max_restarts: int = 12,
        row_slack_pedestrians: int = 8,
        slack_budget: int = 56,
        full_step_iterations: int = 10,
        phase1_starts: int = 32,
        phase1_iterations: int = 8,
        phase1_qps: int = 48,
        phase1_progress: float = 0.2,
        phase1_seed: int = 0,
        hessian: str = "exact",
    ) -> None:
        if max_iter < 1 or not tol > 0 or not slack_penalty > 0 or not slack_quadratic > 0:
            raise ValueError("max_iter >= 1, tol > 0, slack_penalty > 0 and slack_quadratic > 0 are required")
        if max_restarts < 0 or row_slack_pedestrians < 0:
            raise ValueError("max_restarts and row_slack_pedestrians must be >= 0")
        if phase1_starts < 0 or phase1_iterations < 1 or phase1_qps < 0 or not 0 <= phase1_progress < 1:
            raise ValueError(
                "phase1_starts >= 0, phase1_iterations >= 1, phase1_qps >= 0 and 0 <= phase1_progress < 1 are required"
            )
        if hessian not in ("exact", "gauss-newton"):
            raise ValueError(f"hessian must be 'exact' or 'gauss-newton', got {hessian!r}")
        self.hessian = hessian
        self.max_iter = max_iter
        self.tol = tol
        self.slack_penalty = slack_penalty
        self.slack_quadratic = slack_quadratic
        self.max_restarts = max_restarts
        self.row_slack_pedestrians = row_slack_pedestrians
        self.slack_budget = slack_budget
        self.full_step_iterations = full_step_iterations
        self.phase1_starts = phase1_starts
        self.phase1_iterations = phase1_iterations
        self.phase1_qps = phase1_qps
        self.phase1_progress = phase1_progress
        self.phase1_seed = phase1_seed
        # one DAQP workspace per (problem kind, QP size, mode): problems of different models or
        # costs never share a workspace; a constant Hessian is kept only for the problem that set it
        self._models: dict[tuple, daqp.Model] = {}
        self._owners: dict[tuple, MpcProblem] = {}
        self._qp_seconds: dict[tuple, float] = {}  # last solve time per size
        self._lam: NDArray[np.float64] = np.zeros(0)  # the multipliers of the last QP solved

    # ---- QPs ----
    def _slack_columns(
        self, p: MpcProblem, row_pedestrians: int | None = None, hard_barriers: bool = False
    ) -> tuple[NDArray[np.int64], int]:
        """Column (after the n inputs) of the slack of each CBF row (pedestrians and user barriers
        alike: one obstacle per barrier function; -1: no slack, the row stays hard), and the slack
        count. ``hard_barriers``: the user barriers' rows (the road's edges) get no slack, so a
        relaxed plan gives up room to the pedestrians only and brakes rather than leave the road.

        DAQP's work grows with (rows) x (variables)^2, so the slacks are budgeted: one per row for
        the most binding pedestrians (at most ``row_slack_pedestrians``, or ``row_pedestrians``
        when given, and at most ``slack_budget`` rows), one per pedestrian for up to 16 more, one
        shared by the rest.
        """
        order = p.binding_obstacles(p.n_obs)
        n_rp = self.row_slack_pedestrians if row_pedestrians is None else row_pedestrians
        n_row = min(n_rp, p.n_obs, self.slack_budget // p.n_h)
        n_own = min(p.n_obs - n_row, 16)
        slot = np.empty(p.n_obs, dtype=np.int64)
        slot[order] = np.arange(p.n_obs)
        k = np.repeat(np.arange(p.n_h), p.n_obs)
        s = slot[np.tile(np.arange(p.n_obs), p.n_h)]
        per_row = n_row * p.n_h
        cols = np.where(s < n_row, s * p.n_h + k, per_row + np.minimum(s - n_row, n_own))
        n_shared = 1 if p.n_obs > n_row + n_own else 0
        if hard_barriers and p.n_user:
            cols[np.tile(np.arange(p.n_obs), p.n_h) >= p.n_p] = -1
        return cols, per_row + n_own + n_shared

    def _qp(
        self,
        p: MpcProblem,
        slack: tuple[NDArray[np.int64], int] | None,
        until: float | None = None,
        phase1: bool = False,
    ):
        """Solve the QP at the last built point; (step, flag), step None when infeasible or failed.
        With ``until`` (a perf_counter time) a QP whose last solve of this size would not end by
        then is not started: (None, DEADLINE). ``phase1`` (with ``slack``): the feasibility QP of
        :meth:`_phase1`, min ||dU||^2 + penalty * slacks (no cost term); its step comes back with
        the slacks appended."""
        t_start = time.perf_counter()
        relaxed = slack is not None
        if slack is None:
            h, f, a, bu, bl = p.H, p.f, p.A, p.bu, p.bl
        else:
            cols, ns = slack
            n, m, mc = p.n, p.m, p.m_cbf
            h = np.zeros((n + ns, n + ns))
            h[:n, :n] = 2.0 * np.eye(n) if phase1 else p.H
            h[n:, n:] = np.eye(ns) * self.slack_quadratic
            f = np.concatenate([np.zeros(n) if phase1 else p.f, np.full(ns, self.slack_penalty)])
            a = np.zeros((m, n + ns))
            a[:, :n] = p.A
            soft = cols >= 0
            a[np.arange(mc)[soft], n + cols[soft]] = 1.0
            bl = np.concatenate([p.bl[:n], np.zeros(ns), p.bl[n:]])
            bu = np.concatenate([p.bu[:n], np.full(ns, 1e20), p.bu[n:]])
        if a.shape[0] == 0:  # no rows: DAQP gets one row that always holds
            a = np.zeros((1, h.shape[0]))
            bl = np.append(bl, -1e20)
            bu = np.append(bu, 1e20)
        key = (p.kind, h.shape[0], a.shape[0], "phase1" if phase1 else relaxed)
        if until is not None and t_start + self._qp_seconds.get(key, 0.0) > until:
            return None, DEADLINE
        model = self._models.get(key)
        if model is None:
            model = daqp.Model()
            flag, _ = model.setup(h, f, a, bu, bl)
            # rows held to 1e-9 (DAQP's default is 1e-6): with a small gamma the barrier of
            # `cbf_discrete` settles at -tol / gamma, microns inside R at 1e-6
            model.settings = {"primal_tol": PRIMAL_TOL}
            if flag < 0:
                return None, flag
            self._models[key] = model
            self._owners[key] = p
        else:
            # H of a linear model with a constant-Hessian cost is constant: leave it in place
            # unless another problem set it; so is the feasibility QP's (per size)
            if ((p.nonlinear or relaxed or p.exact_hessian) and not phase1) or self._owners.get(key) is not p:
                self._owners[key] = p
                flag = model.update(H=h, f=f, A=a, bupper=bu, blower=bl)
            else:
                flag = model.update(f=f, A=a, bupper=bu, blower=bl)
            if flag is not None and flag < 0:
                return None, flag
        x, _, exitflag, info = model.solve()
        self._qp_seconds[key] = time.perf_counter() - t_start
        self._lam = info["lam"]
        if exitflag < 0:
            return None, exitflag
        return np.asarray(x if phase1 else x[: p.n]), exitflag

    @staticmethod
    def _settle(p: MpcProblem, best: _Best, seen: list[NDArray[np.float64]]) -> None:
        """Check the iterates not yet checked exactly and offer them (rebuilds the QP buffers)."""
        for u in seen:
            if math.isfinite(float(u.sum())):
                best.offer(u, p.evaluate(u))
        seen.clear()

    def _recover(
        self,
        p: MpcProblem,
        u: NDArray[np.float64],
        best: _Best,
        budget: int,
        until: float | None,
        memo: SqpSolver._Recovery,
    ):
        """Feasibility recovery: candidate starts ranked by exact violation; the first whose
        hard QP is feasible. Points tried before in this solve are skipped (the same point gives
        the same QP). When none is left, or the budget of ``budget`` QPs is spent, the
        feasibility SQP of :meth:`_phase1` runs from varied starts. Returns (start, step, cost,
        tried) or (None, None, nan, tried), tried counting the candidate starts only."""
        p.build(u)  # binding pedestrians at the point where the QP failed
        p.flatten()  # the candidates' hard QPs with the cost's Hessian: no multipliers there yet
        memo.first_time(u)
        if budget <= 0:  # the candidates' budget is spent: the feasibility SQP only
            start, step, cost = self._phase1(p, best, until, memo)
            return start, step, cost, 0
        starts = [u] + ([best.u] if best.u is not None else []) + p.candidate_starts()
        ranked = []
        for c in starts:
            c = np.minimum(np.maximum(c, p.ulo), p.uhi)
            chk = p.evaluate(c)
            best.offer(c, chk)
            ranked.append((rank_key(chk), len(ranked), c))
        ranked.sort(key=lambda r: (r[0], r[1]))
        tried = 0
        for _, idx, c in ranked:
            if idx == 0:  # the point whose QP just failed
                continue
            if tried >= budget:
                break
            if not memo.first_time(c):  # tried already (a duplicate, or a start that led here)
                continue
            cost = p.build(c)
            step, flag = self._qp(p, None, until)
            if flag == DEADLINE:
                return None, None, math.nan, tried
            tried += 1
            if step is not None:
                return c.copy(), step, cost, tried
        start, step, cost = self._phase1(p, best, until, memo)
        return start, step, cost, tried

    def _phase1_plans(self, p: MpcProblem) -> list[NDArray[np.float64]]:
        """Starts of the feasibility SQP, the same at every call: constant inputs at the corners
        and edge midpoints of the input box (bang-bang), then, from a generator seeded with
        ``phase1_seed``, by turns a uniform random plan, two segments of box corners (or rest)
        switching at a random step, and a random corner at every step."""
        lo, hi = p.ulo, p.uhi
        nu, n_h = lo.size, p.n_h
        mid = np.minimum(np.maximum(0.0, lo), hi)
        levels = np.stack([lo, mid, hi])
        grid = np.indices((3,) * nu).reshape(nu, -1).T  # (3^nu, nu) level indices, row-major
        corners = [levels[idx, np.arange(nu)] for idx in grid if (idx != 1).any()]
        plans = [np.tile(c, (n_h, 1)) for c in corners]
        segments = np.array([*corners, mid])
        rng = np.random.default_rng(self.phase1_seed)
        for i in range(max(0, self.phase1_starts - len(plans))):
            if i % 3 == 0:
                plan = rng.uniform(lo, hi, size=(n_h, nu))
            elif i % 3 == 1:
                k = int(rng.integers(1, n_h)) if n_h > 1 else 1
                a, b = rng.integers(len(segments), size=2)
                plan = np.vstack([np.tile(segments[a], (k, 1)), np.tile(segments[b], (n_h - k, 1))])
            else:
                plan = segments[rng.integers(len(corners), size=n_h)]
            plans.append(plan)
        return plans[: self.phase1_starts]

    def _phase1(self, p: MpcProblem, best: _Best, until: float | None, memo: SqpSolver._Recovery):
        """Feasibility (phase-1) SQP from the starts of :meth:`_phase1_plans`, the least
        violating first: each iteration solves the QP min ||dU||^2 + penalty * slacks subject to
        the slackened linearised rows (no cost term) and takes a backtracking step on the exact
        total violation. As soon as the linearised rows at an iterate hold without slack, the hard
        QP there is feasible: (start, step, cost). (None, None, nan) when the per-solve budget of
        ``phase1_qps`` QPs, the starts or the time run out. Every point is checked and offered."""
        if memo.phase1_qps <= 0 or p.m_cbf == 0 or memo.hopeless(p):
            return None, None, math.nan
        ranked = []
        for c in self._phase1_plans(p):
            c = np.minimum(np.maximum(c, p.ulo), p.uhi)
            chk = p.evaluate(c)
            best.offer(c, chk)
            ranked.append((chk.total, len(ranked), c))
        ranked.sort(key=lambda r: (r[0], r[1]))
        for _, _, u in ranked:
            if memo.phase1_qps <= 0 or (until is not None and time.perf_counter() > until):
                break
            if not memo.first_time(u):
                continue
            memo.phase1_starts += 1
            out = self._feasibility_sqp(p, u, best, until, memo, to_hard_qp=True)
            if out is not None:
                memo.first_time(out[0])  # a later recovery does not start here again
                return out
        return None, None, math.nan

    def _feasibility_sqp(
        self,
        p: MpcProblem,
        u: NDArray[np.float64],
        best: _Best,
        until: float | None,
        memo: SqpSolver._Recovery,
        to_hard_qp: bool,
    ):
        """Iterations of the feasibility SQP of :meth:`_phase1` from ``u`` (at most
        ``phase1_iterations``, charged to the per-solve QP budget). With ``to_hard_qp`` it ends
        at the first iterate whose hard QP is feasible and returns (start, step, cost); otherwise
        it drives the exact violation down (every point offered to ``best``) and returns None.
        None also when it stalls or runs out of budget or time."""
        cost = p.build(u)
        p.flatten()
        chk = p.check_built(cost)
        for _ in range(self.phase1_iterations):
            if memo.phase1_qps <= 0 or (not to_hard_qp and chk.worst <= 1e-3 * FEAS_TOL):
                return None
            viol = chk.total
            # one slack per pedestrian (the 16 most binding) and one shared: the total violation
            # needs no slack per row, and the QP is 2-3x faster than with them
            x, flag = self._qp(p, self._slack_columns(p, row_pedestrians=0), until, phase1=True)
            memo.phase1_qps -= 1
            if x is None:
                return None
            if to_hard_qp and float(x[p.n :].max(initial=0.0)) <= 1e-9:
                # the linearised rows at u hold without slack: the hard QP at u is feasible
                step, flag = self._qp(p, None, until)
                memo.phase1_qps -= 1
                if step is not None:
                    return u.copy(), step, cost
                if flag == DEADLINE:
                    return None
            d = x[: p.n].reshape(u.shape)
            alpha = 1.0
            for _ in range(8):
                trial = np.minimum(np.maximum(u + alpha * d, p.ulo), p.uhi)
                c1 = p.build(trial)
                c_chk = p.check_built(c1)
                best.offer(trial, c_chk)
                if c_chk.total < viol:
                    break
                alpha *= 0.5
            else:
                return None  # no decrease along the step: a local minimum of the violation
            if c_chk.total > (1.0 - self.phase1_progress) * viol or not memo.first_time(trial):
                return None  # stalled, or on a path already followed
            u, cost, chk = trial, c1, c_chk  # the buffers hold the data at u
        return None

    @dataclass(slots=True)
    class _State:
        """Per-solve state of :meth:`solve`."""

        p: MpcProblem
        u: NDArray[np.float64]
        until: float | None  # perf_counter time of the deadline
        until_recovery: float | None  # the recovery stops here (the rest is for relaxing)
        memo: SqpSolver._Recovery
        best: _Best = field(default_factory=_Best)
        seen: list[NDArray[np.float64]] = field(default_factory=list)  # iterates not yet checked
        slack: tuple[NDArray[np.int64], int] | None = None  # slack columns while relaxed
        step: NDArray[np.float64] | None = None
        cost: float = math.nan
        fresh: bool = False  # the problem's buffers already hold the data at u (accepted trial)
        it: int = 0
        restarts: int = 0
        converged: bool = False
        recovered: bool = False
        deadline_hit: bool = False
        second_chance: bool = False
        final_built: bool = False  # the problem's buffers hold the data at u, s.cost its cost
        message: str = ""

    def solve(self, problem: MpcProblem, u0: NDArray[np.float64], deadline: float | None = None) -> SolveResult:
        """SQP iterations from ``u0`` (see the class): a QP at each iterate (recovering or relaxing
        when it is infeasible), a step, until the step is below ``tol``; then the final plan is
        checked, and beaten or restored where a better checked plan exists."""
        t0 = time.perf_counter()
        p = problem
        p.exact_hessian = p.exact_capable and self.hessian == "exact"
        if type(u0) is np.ndarray and u0.dtype == np.float64 and u0.shape == (p.n_h, p.ulo.shape[0]):
            u = np.empty(u0.shape)  # the controller's warm start: clipped in one compiled call
            kern.clip_plan(u0, p.ulo, p.uhi, u)
        else:
            u = np.minimum(np.maximum(np.asarray(u0, dtype=float).reshape(p.n_h, -1), p.ulo), p.uhi)
        until = None if deadline is None else t0 + deadline
        compiled = self._run_compiled(p, u, until)
        if compiled is None:
            p.flatten()  # the first QP of a solve: the cost's Hessian alone
        if compiled is not None and compiled[1] > 0:
            # the common case: the compiled loop converged; the QP buffers hold the data at u
            final = p.check_built(compiled[2])
            if final.worst <= FEAS_TOL:
                return SolveResult(u.copy(), SolveStatus.OPTIMAL, compiled[0], final.cost, final.worst, False, "",
                                   time.perf_counter() - t0, final.first_row)  # fmt: skip
        # the feasibility SQP is part of the recovery (off with max_restarts = 0), for problems that
        # ask for it (validated on the single integrator)
        phase1 = self.max_restarts > 0 and p.feasibility_search
        s = self._State(
            p=p,
            u=u,
            until=until,
            until_recovery=None if deadline is None else t0 + 0.8 * deadline,
            memo=self._Recovery(self.phase1_qps if phase1 else 0),
        )
        first, done = self._compiled_steps(s, compiled)
        for s.it in range(first, self.max_iter + 1 if not done else first):
            if s.until is not None and time.perf_counter() > s.until:
                s.deadline_hit = True
                break
            flag = self._iterate_qp(s)
            if s.step is None:
                if flag == DEADLINE:
                    s.deadline_hit = True
                else:
                    s.message = f"DAQP exit flag {flag} at SQP iteration {s.it}"
                break
            if self._take_step(s) < self.tol:
                if s.slack is not None and not s.second_chance and float(p.g[p.n_decided :].min()) < -FEAS_TOL:
                    # the relaxed solve converged near the feasible set: once, try the hard
                    # rows again from there before accepting the relaxation
                    s.second_chance, s.slack = True, None
                    continue
                s.converged = True
                break
        return self._result(s, deadline, t0)

    def _run_compiled(self, p: MpcProblem, u: NDArray[np.float64], until: float | None):
        """The first iterations in one compiled call (:meth:`MpcProblem.compiled_steps`) while the
        hard QP is feasible: the general loop's arithmetic (:meth:`_iterate_qp`,
        :meth:`_take_step`: full steps for a linear problem, up to ``full_step_iterations``; the
        L1-merit line search for a nonlinear one) without its per-iteration Python work, from
        ``u`` (changed in place). Used where the deadline cannot cut them short (it is checked
        between QPs otherwise): twice the last QP's time, times the iterations, fits. Returns
        (iterations, state, cost, last, compiled output) or None where it did not run."""
        last = self._compiled_budget(p, until)
        if last is None:
            return None
        out = p.compiled_steps(u, last, self.tol, PRIMAL_TOL, MERIT_WEIGHT, self.full_step_iterations)
        if out is None:
            return None
        return out[0], out[1], out[2], last, out

    def _compiled_budget(self, p: MpcProblem, until: float | None) -> int | None:
        """The iterations the compiled loop may take (see :meth:`_run_compiled`), or None where it
        cannot run: no DAQP workspace of this size and owner yet, or too little time left."""
        key = (p.kind, p.n, p.m, False)
        if p.m == 0 or self._owners.get(key) is not p or self._models.get(key) is None:
            return None  # first QP of this size or owner: the general path sets DAQP up
        last = self.max_iter if p.nonlinear else min(self.max_iter, self.full_step_iterations)
        if until is not None:
            left = (until - time.perf_counter()) / max(2.0 * self._qp_seconds.get(key, math.inf), 1e-12)
            if left <= last:
                return None
            if not p.nonlinear:  # the line-search iterations too, as many as fit
                last = min(self.max_iter, max(last, int(left) - 1))
        elif not p.nonlinear:
            last = self.max_iter
        return last

    def solve_whole_step(
        self,
        p: MpcProblem,
        x: NDArray[np.float64],
        peds: NDArray[np.float64],
        vels: NDArray[np.float64],
        tr: NDArray[np.float64],
        prev: NDArray[np.float64],
        u_prev: NDArray[np.float64],
        deadline: float | None = None,
    ) -> tuple[int, float, float, float, float, float, NDArray[np.float64], NDArray[np.float64]] | None:
        """:meth:`MpcProblem.set_checked_stage`, the warm start from the previous plan ``prev``
        and :meth:`solve` in one compiled call (:meth:`MpcProblem.whole_step`) where the problem
        allows it and the compiled loop converges to a plan that passes its check, the common
        case: the result :meth:`solve` would give OPTIMAL, as (iterations, cost, first-row
        violation, worst violation, state-limit violation, decided rows' violation, plan, predicted
        states). None: the caller takes the general path, which runs as if this call had not."""
        last = self._compiled_budget(p, None if deadline is None else time.perf_counter() + deadline)
        if last is None:
            return None
        p.exact_hessian = p.exact_capable and self.hessian == "exact"
        return p.whole_step(x, peds, vels, tr, prev, u_prev, last, self.tol, PRIMAL_TOL, MERIT_WEIGHT,
                            self.full_step_iterations, FEAS_TOL)  # fmt: skip

    def _compiled_steps(self, s: SqpSolver._State, compiled=None) -> tuple[int, bool]:
        """Hands the result of :meth:`_run_compiled` (run on ``s.u``) to the general loop.
        Returns (iteration to continue at, solve done); an infeasible QP hands the iterate over,
        its QP data built (``fresh``), to the general loop, which solves that QP again and
        recovers."""
        if compiled is None:
            return 1, False
        it, state, s.cost, last, out = compiled
        s.seen.extend(out[4])
        s.it = it
        if state < 0:
            s.fresh = True
            return it, False
        s.step = s.u  # not None: a QP was solved (the step itself is not used after this)
        s.fresh = s.p.nonlinear  # the buffers hold the data at the last accepted trial
        if state > 0:  # the buffers hold the data at the final iterate: its exact check needs no build
            s.converged = s.final_built = True
            return it, True
        return last + 1, False

    def _iterate_qp(self, s: SqpSolver._State):
        """The QP at the current iterate; when the hard QP is infeasible, the feasibility recovery
        (a hard-feasible start), else the relaxation from the best point seen. Sets ``s.step``
        (None when no QP could be solved) and returns the QP's flag."""
        p = s.p
        if not s.fresh:
            s.cost = p.build(s.u)
        s.fresh = False
        s.seen.append(s.u)  # ranked only when needed (recovery, relaxation, an unconverged end)
        s.step, flag = self._qp(p, s.slack, s.until if s.it > 1 else None)  # the first QP always runs
        if s.step is not None and s.slack is None and s.it >= kern.CURVATURE_START:
            p.curve(self._lam)  # the next QP's Hessian (exact-Hessian problems)
        if s.step is not None or flag == DEADLINE or s.slack is not None or p.m_cbf == 0:
            return flag
        self._settle(p, s.best, s.seen)
        memo = s.memo
        if self.max_restarts > 0 and (s.restarts < self.max_restarts or (memo.phase1_qps > 0 and not memo.hopeless(p))):
            start, s.step, c_start, tried = self._recover(
                p, s.u, s.best, self.max_restarts - s.restarts, s.until_recovery, memo
            )
            s.restarts += tried
            if s.step is not None:
                s.u, s.cost, s.recovered = start, c_start, True
                if s.it >= kern.CURVATURE_START:
                    p.curve(self._lam)
        if s.step is None:  # no hard-feasible start found: relax from the best point seen
            if s.best.u is not None:
                s.u = s.best.u.copy()
            s.cost = p.build(s.u)
            p.flatten()
            # the road's rows stay hard (the car brakes rather than leave the road); only when
            # no step keeps them do they get slacks as well
            s.slack = self._slack_columns(p, hard_barriers=True)
            s.step, flag = self._qp(p, s.slack, s.until)
            if s.step is None and flag != DEADLINE and p.n_user:
                s.slack = self._slack_columns(p)
                s.step, flag = self._qp(p, s.slack, s.until)
        return flag

    def _take_step(self, s: SqpSolver._State) -> float:
        """Move the iterate along the QP's step: a full step for linear problems, a backtracking
        line search on the L1 merit otherwise (and once full steps have not converged: the
        non-convex rows can make them cycle). Returns the length of the step taken (max norm)."""
        p = s.p
        d = s.step.reshape(s.u.shape)
        alpha = 1.0
        if p.nonlinear or s.it > self.full_step_iterations:
            if s.slack is not None:  # relaxed: the CBF rows' violation, a simple decrease (as before)
                mu = 10.0 * self.slack_penalty
                viol0, slope = float(np.maximum(0.0, -p.g).sum()), 0.0
            else:  # Armijo on cost + mu * the violation of every row (the compiled loops' arithmetic)
                mu = MERIT_WEIGHT
                viol0 = kern.merit_violation(p.bl, p.bu, p.n, p.n_decided)
                slope = kern.merit_slope(p.f, s.step, p.n, mu, viol0)
            merit0 = s.cost + mu * viol0
            accepted = False
            for _ in range(8):
                trial = np.minimum(np.maximum(s.u + alpha * d, p.ulo), p.uhi)  # np.clip, without its overhead
                c1 = p.build(trial)
                if s.slack is not None:
                    v1 = float(np.maximum(0.0, -p.g).sum())
                else:
                    v1 = kern.merit_violation(p.bl, p.bu, p.n, p.n_decided)
                if c1 + mu * v1 <= merit0 + kern.ARMIJO * alpha * slope + 1e-12 * (1 + abs(merit0)):
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted and s.slack is None:  # no decrease of the merit along the step: stop here
                s.fresh = False
                return 0.0
            s.u, s.cost, s.fresh = trial, c1, True  # the last build was at this trial: reuse it
        else:
            s.u = s.u + alpha * d  # the QP keeps u + d within the input bounds (to DAQP's tolerance)
        return alpha * float(np.abs(d).max())

    def _final_plan(self, s: SqpSolver._State) -> tuple[bool, bool, PlanCheck | None]:
        """(done, relaxation_beaten, final check): ``done`` when the converged iterate itself is
        returned. Otherwise the best checked plan wins, after every candidate start and a
        restoration (the feasibility SQP from the best plan) have had their chance."""
        p, best, memo = s.p, s.best, s.memo
        if s.final_built:
            final = p.check_built(s.cost)
        else:
            final = p.evaluate(s.u) if math.isfinite(float(s.u.sum())) else None
        done = s.converged and final is not None and (final.worst <= FEAS_TOL or s.slack is not None)
        relaxation_beaten = False
        if done and s.slack is not None and final.worst > FEAS_TOL:
            # the relaxation converged to a violating plan, but a hard-feasible plan may have been
            # seen on the way (a recovered start, a feasibility SQP iterate): it beats the relaxation
            self._settle(p, best, s.seen)
            relaxation_beaten = best.check.worst <= FEAS_TOL
            done = not relaxation_beaten
        if not done:
            if final is not None:
                best.offer(s.u, final)
            self._settle(p, best, s.seen)
            if best.check.worst > FEAS_TOL and p.m_cbf:  # an exactly feasible candidate beats it
                p.build(s.u)
                for c in p.candidate_starts():
                    c = np.minimum(np.maximum(c, p.ulo), p.uhi)
                    best.offer(c, p.evaluate(c))
                if best.check.worst > FEAS_TOL and best.u is not None and memo.phase1_qps > 0 and not memo.hopeless(p):
                    # restoration: the feasibility SQP from the best plan (its exact violation is
                    # often second order once its linearisation holds)
                    self._feasibility_sqp(p, best.u, best, s.until, memo, to_hard_qp=False)
        return done, relaxation_beaten, final

    def _result(self, s: SqpSolver._State, deadline: float | None, t0: float) -> SolveResult:
        """The returned plan (see :meth:`_final_plan`) with its exact check and its status."""
        done, relaxation_beaten, final = self._final_plan(s)
        restarts = s.restarts + s.memo.phase1_starts  # reported: all starts tried
        elapsed = time.perf_counter() - t0
        message = s.message
        if s.best.u is None and not done:  # nothing finite was ever evaluated
            return SolveResult(s.u, SolveStatus.FAILED, s.it, math.nan, math.nan, True, message or "non-finite iterate",
                               elapsed, math.nan, s.recovered, restarts, s.deadline_hit)  # fmt: skip
        out_u, out = (s.u, final) if done else (s.best.u, s.best.check)  # done: the converged iterate
        out_hv = out.worst
        slack_used = out_hv > FEAS_TOL
        if s.step is None and message.startswith("DAQP"):
            status = SolveStatus.FAILED
        elif relaxation_beaten:
            status = SolveStatus.MAX_ITER
            message = (f"the relaxed SQP converged to a plan violating CBF rows by {final.worst:.3g}; "
                       "the best hard-feasible plan seen returned")  # fmt: skip
        elif not s.converged:
            status = SolveStatus.MAX_ITER
            why = f"deadline of {deadline * 1e3:.1f} ms" if s.deadline_hit else f"{self.max_iter} SQP iterations"
            message = f"no convergence within {why}; best checked plan returned (violation {out_hv:.3g})"
        elif slack_used:
            status = SolveStatus.RELAXED
            message = (f"no hard-feasible plan found ({restarts} recovery starts tried); "
                       f"CBF rows relaxed by up to {out_hv:.3g}")  # fmt: skip
        else:
            status = SolveStatus.OPTIMAL
            if s.recovered:
                message = f"hard-feasible plan recovered after an infeasible linearisation ({restarts} starts tried)"
        return SolveResult(out_u.copy(), status, s.it, out.cost, out_hv, slack_used, message, elapsed, out.first_row,
                           s.recovered, restarts, s.deadline_hit)  # fmt: skip


def _slsqp_result(p: MpcProblem, res, t0: float) -> SolveResult:
    """A scipy SLSQP result, checked exactly against the CBF rows an input can change."""
    u = np.asarray(res.x, dtype=float).reshape(p.n_h, -1)
    rows = p.constraints_np(u)[p.n_decided : p.m_cbf]
    viol = float(max(0.0, -rows.min())) if rows.size else 0.0
    first = float(max(0.0, -rows[: p.n_p].min())) if rows.size else 0.0
    message = str(res.message)
    if res.status == 0 and viol <= FEAS_TOL:
        status = SolveStatus.OPTIMAL
    elif res.status == 9:
        status = SolveStatus.MAX_ITER
    else:
        status = SolveStatus.FAILED
        if res.status == 0:
            message = f"{message}, but CBF rows violated by up to {viol:.3g}"
    return SolveResult(u, status, int(res.nit), float(res.fun), viol, viol > FEAS_TOL, message,
                       time.perf_counter() - t0, first)  # fmt: skip


class SlsqpSolver:
    """Reference baseline "SLSQP, tuned": scipy SLSQP on Python closures with finite-difference
    gradients, warm-started by the controller from the shifted previous plan.

    Tuned against the authors' code (see :class:`AuthorsSlsqpSolver`): ftol 1e-10 and up to 500
    iterations, and by default all rows are one vectorised numpy function (``per_row=True``
    makes every CBF row its own closure). No relaxation: an infeasible problem is reported as
    FAILED, and the controller then applies its best checked fallback.
    """

    name = "slsqp"

    def __init__(self, ftol: float = 1e-10, max_iter: int = 500, per_row: bool = False) -> None:
        if not ftol > 0 or max_iter < 1:
            raise ValueError(f"ftol must be > 0 and max_iter >= 1, got {ftol!r} and {max_iter!r}")
        self.ftol = ftol
        self.max_iter = max_iter
        self.per_row = per_row

    def solve(self, problem: MpcProblem, u0: NDArray[np.float64], deadline: float | None = None) -> SolveResult:
        """One SLSQP run (``deadline`` is not enforced: scipy cannot be interrupted)."""
        t0 = time.perf_counter()
        p = problem
        bounds = list(zip(p.lo, p.hi, strict=True))
        if self.per_row:
            n_rows = p.decision_rows_np(np.asarray(u0, dtype=float).reshape(-1)).size
            cons = [{"type": "ineq", "fun": lambda u, r=r: p.decision_rows_np(u)[r]} for r in range(n_rows)]
        else:
            cons = [{"type": "ineq", "fun": p.decision_rows_np}] if p.m > p.n_decided else []
        x0 = np.clip(np.asarray(u0, dtype=float).reshape(-1), p.lo, p.hi)
        res = minimize(p.cost_np, x0, method="SLSQP", bounds=bounds, constraints=cons,
                       options={"ftol": self.ftol, "maxiter": self.max_iter})  # fmt: skip
        return _slsqp_result(p, res, t0)


class AuthorsSlsqpSolver:
    """Reference baseline "SLSQP, authors' style": the MPC written as the paper's code writes it.

    One Python closure per pedestrian and horizon step (each rolls the horizon out again), one
    per extra model row; scipy's default ``ftol`` (1e-6) and ``maxiter`` (100); finite-difference
    gradients. The warm start is the solver's own: the previous step's solution as it was, not
    shifted by one step (``warm_start="previous"``; the first step, and any step after the number
    of pedestrians changed, starts from zero input), or zero input at every step
    (``warm_start="zeros"``). The controller's shifted plan is not used. Rows no input can
    change (the bicycle's k = 0 rows) are left out, as in :class:`SlsqpSolver`.
    """

    name = "slsqp-authors"

    def __init__(self, warm_start: str = "previous") -> None:
        if warm_start not in ("previous", "zeros"):
            raise ValueError(f"warm_start must be 'previous' or 'zeros', got {warm_start!r}")
        self.warm_start = warm_start
        self._previous: NDArray[np.float64] | None = None

    @staticmethod
    def _row(p: MpcProblem, k: int, j: int):
        """Closure of the CBF row of pedestrian j at horizon step k (`cbf_imp`)."""
        c = p.config
        dt, r2 = c.dt, float(p.r2[j])
        q_now = p.peds[j] + k * dt * p.vels[j]
        q_next = q_now + dt * p.vels[j] if c.timing == "paper" else q_now
        omg = float(p.one_minus_gamma[j])

        def row(u: NDArray[np.float64]) -> float:
            xs = p.states_np(u)
            h_now = float(h_quad(xs[k, 0] - q_now[0], xs[k, 1] - q_now[1], r2))
            h_next = float(h_quad(xs[k + 1, 0] - q_next[0], xs[k + 1, 1] - q_next[1], r2))
            return h_next - omg * h_now

        return row

    def solve(self, problem: MpcProblem, u0: NDArray[np.float64], deadline: float | None = None) -> SolveResult:
        """One SLSQP run; ``u0`` (the controller's shifted plan) is ignored, see the class."""
        t0 = time.perf_counter()
        p = problem
        steps = range(p.decided_steps, p.n_h)
        cons = [{"type": "ineq", "fun": self._row(p, k, j)} for k in steps for j in range(p.n_p)]
        # user barriers' rows (k * N_o + j, j >= N_p) and model rows (speed bounds), one closure each
        user = [k * p.n_obs + j for k in steps for j in range(p.n_p, p.n_obs)]
        extra = [p.m_cbf + i for i in range(p.constraints_np(np.zeros(p.n)).size - p.m_cbf)]
        cons += [{"type": "ineq", "fun": lambda u, r=r: p.constraints_np(u)[r]} for r in user + extra]
        prev = self._previous
        if self.warm_start == "previous" and prev is not None and prev.size == p.n and np.isfinite(prev).all():
            x0 = prev
        else:
            x0 = np.zeros(p.n)
        x0 = np.clip(x0, p.lo, p.hi)
        res = minimize(p.cost_np, x0, method="SLSQP", bounds=list(zip(p.lo, p.hi, strict=True)), constraints=cons)
        self._previous = np.asarray(res.x, dtype=float).copy()
        return _slsqp_result(p, res, t0)


def make_solver(name: str) -> SqpSolver | SlsqpSolver | AuthorsSlsqpSolver:
    """A solver by name: 'sqp' (default), 'sqp-gauss-newton' (the SQP without the rows' curvature, as
    before issue 36), 'slsqp' (SLSQP, tuned) or 'slsqp-authors' (the authors' style)."""
    if name in ("sqp", "sqp-daqp", "default"):
        return SqpSolver()
    if name == "sqp-gauss-newton":
        return SqpSolver(hessian="gauss-newton")
    if name == "slsqp":
        return SlsqpSolver()
    if name == "slsqp-authors":
        return AuthorsSlsqpSolver()
    raise ValueError(
        f"unknown solver {name!r}: expected 'sqp' (default), 'sqp-gauss-newton', 'slsqp' (tuned) or 'slsqp-authors'"
    )
