"""Solvers for problem `proposed`: a fast SQP on DAQP (default) and the paper-style SLSQP reference.

Both return a :class:`SolveResult` with a status; neither returns an unchecked solution: the
CBF rows are evaluated exactly at the returned inputs and their worst violation is reported.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass

import daqp
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from trustnav.control.problem import MpcProblem

__all__ = ["SlsqpSolver", "SolveResult", "SolveStatus", "SqpSolver", "make_solver"]

FEAS_TOL = 1e-6  # tolerance on CBF rows (units of the barrier, m^2) to call a solution feasible


class SolveStatus(enum.Enum):
    OPTIMAL = "optimal"  # converged, every CBF row holds
    RELAXED = "relaxed"  # converged with slack: the hard problem was infeasible
    MAX_ITER = "max_iter"  # iteration limit reached; rows checked, violation reported
    FAILED = "failed"  # the QP / NLP solver failed; the controller applies its fallback

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
    slack_used: bool
    message: str = ""
    solve_time: float = 0.0


def _check(problem: MpcProblem, u: NDArray[np.float64]) -> tuple[float, float]:
    """Exact cost and worst CBF row violation at U (compiled evaluation)."""
    cost = problem.build(u)
    viol = float(max(0.0, -problem.g.min())) if problem.g.size else 0.0
    return cost, viol


class SqpSolver:
    """Sequential quadratic programming on `proposed` with DAQP for each QP.

    Each iteration linearises the CBF rows (and, for the bicycle, the dynamics) at the current
    iterate with analytic Jacobians and solves a dense QP in the step. If a QP is infeasible, the
    rest of the solve uses one slack s >= 0 per CBF row with an exact L1 penalty
    ``slack_penalty`` (plus a tiny quadratic term so the QP stays strictly convex): whenever the
    hard problem is feasible and its multipliers are below the penalty, the slack is zero and
    the hard solution is returned. Nonlinear models take a backtracking step on an L1 merit.
    """

    name = "sqp-daqp"

    def __init__(
        self,
        max_iter: int = 50,
        tol: float = 1e-9,
        slack_penalty: float = 1e6,
        slack_quadratic: float = 1e-2,
    ) -> None:
        if max_iter < 1 or not tol > 0 or not slack_penalty > 0 or not slack_quadratic > 0:
            raise ValueError("max_iter >= 1, tol > 0, slack_penalty > 0 and slack_quadratic > 0 are required")
        self.max_iter = max_iter
        self.tol = tol
        self.slack_penalty = slack_penalty
        self.slack_quadratic = slack_quadratic
        self._models: dict[tuple[int, int, bool], daqp.Model] = {}

    def _qp(self, p: MpcProblem, relaxed: bool):
        if not relaxed:
            h, f, a, bu, bl = p.H, p.f, p.A, p.bu, p.bl
        else:
            n, m, mc = p.n, p.m, p.m_cbf
            h = np.zeros((n + mc, n + mc))
            h[:n, :n] = p.H
            h[n:, n:] = np.eye(mc) * self.slack_quadratic
            f = np.concatenate([p.f, np.full(mc, self.slack_penalty)])
            a = np.zeros((m, n + mc))
            a[:, :n] = p.A
            a[:mc, n:] = np.eye(mc)
            bl = np.concatenate([p.bl[:n], np.zeros(mc), p.bl[n:]])
            bu = np.concatenate([p.bu[:n], np.full(mc, 1e20), p.bu[n:]])
        if a.shape[0] == 0:  # no rows: DAQP gets one row that always holds
            a = np.zeros((1, h.shape[0]))
            bl = np.append(bl, -1e20)
            bu = np.append(bu, 1e20)
        key = (h.shape[0], a.shape[0], relaxed)
        model = self._models.get(key)
        if model is None:
            model = daqp.Model()
            flag, _ = model.setup(h, f, a, bu, bl)
            if flag < 0:
                return None, flag
            self._models[key] = model
        else:
            # H of a linear model's problem is constant: leave it (and its factorisation) in place
            if p.nonlinear or relaxed:
                flag = model.update(H=h, f=f, A=a, bupper=bu, blower=bl)
            else:
                flag = model.update(f=f, A=a, bupper=bu, blower=bl)
            if flag is not None and flag < 0:
                return None, flag
        x, _, exitflag, _ = model.solve()
        if exitflag < 0:
            return None, exitflag
        return np.asarray(x[: p.n]), exitflag

    def solve(self, problem: MpcProblem, u0: NDArray[np.float64]) -> SolveResult:
        t0 = time.perf_counter()
        p = problem
        u = np.minimum(np.maximum(np.asarray(u0, dtype=float).reshape(p.n_h, -1), p.ulo), p.uhi)
        relaxed = False
        converged = False
        message = ""
        it = 0
        fresh = False  # True when the problem's buffers already hold the data at u (accepted trial)
        for it in range(1, self.max_iter + 1):
            if not fresh:
                cost = p.build(u)
            fresh = False
            step, flag = self._qp(p, relaxed)
            if step is None and not relaxed and p.m_cbf > 0:
                relaxed = True
                step, flag = self._qp(p, relaxed)
            if step is None:
                message = f"DAQP exit flag {flag} at SQP iteration {it}"
                return SolveResult(u, SolveStatus.FAILED, it, float("nan"), float("nan"), relaxed, message,
                                   time.perf_counter() - t0)  # fmt: skip
            d = step.reshape(u.shape)
            alpha = 1.0
            if p.nonlinear:
                viol0 = float(np.maximum(0.0, -p.g).sum())
                mu = 10.0 * self.slack_penalty if relaxed else 1e4
                merit0 = cost + mu * viol0
                for _ in range(8):
                    trial = np.clip(u + alpha * d, p.ulo, p.uhi)
                    c1 = p.build(trial)
                    if c1 + mu * float(np.maximum(0.0, -p.g).sum()) <= merit0 + 1e-12 * (1 + abs(merit0)):
                        break
                    alpha *= 0.5
                u, cost, fresh = trial, c1, True  # the last build was at this trial: reuse it
            else:
                # the QP keeps u + d within the input bounds (to DAQP's tolerance)
                u += alpha * d
            if alpha * float(np.abs(d).max()) < self.tol:
                converged = True
                break
        cost, viol = _check(p, u)
        if not math.isfinite(u.sum() + cost):
            return SolveResult(u, SolveStatus.FAILED, it, cost, viol, relaxed, "non-finite iterate",
                               time.perf_counter() - t0)  # fmt: skip
        slack_used = viol > FEAS_TOL
        if not converged:
            status = SolveStatus.MAX_ITER
            message = f"no convergence in {self.max_iter} SQP iterations"
        elif slack_used:
            status = SolveStatus.RELAXED
            message = f"hard CBF rows infeasible; relaxed by up to {viol:.3g}"
        else:
            status = SolveStatus.OPTIMAL
        return SolveResult(u, status, it, cost, viol, slack_used, message, time.perf_counter() - t0)


class SlsqpSolver:
    """Reference baseline: scipy SLSQP on Python closures, written as the paper's code does it.

    Gradients are finite differences (no ``jac`` given). By default all rows are one vectorised
    numpy function (the faster, conservative baseline); ``per_row=True`` makes every CBF row its
    own closure that rolls the horizon out again (10-100x slower still). No relaxation: an
    infeasible problem is reported as FAILED.
    """

    name = "slsqp"

    def __init__(self, ftol: float = 1e-10, max_iter: int = 500, per_row: bool = False) -> None:
        self.ftol = ftol
        self.max_iter = max_iter
        self.per_row = per_row

    def solve(self, problem: MpcProblem, u0: NDArray[np.float64]) -> SolveResult:
        t0 = time.perf_counter()
        p = problem
        bounds = list(zip(p.lo, p.hi, strict=True))
        if self.per_row:
            n_rows = p.constraints_np(np.asarray(u0, dtype=float).reshape(-1)).size
            cons = [{"type": "ineq", "fun": lambda u, r=r: p.constraints_np(u)[r]} for r in range(n_rows)]
        else:
            cons = [{"type": "ineq", "fun": p.constraints_np}] if p.m > 0 else []
        x0 = np.clip(np.asarray(u0, dtype=float).reshape(-1), p.lo, p.hi)
        res = minimize(p.cost_np, x0, method="SLSQP", bounds=bounds, constraints=cons,
                       options={"ftol": self.ftol, "maxiter": self.max_iter})  # fmt: skip
        u = np.asarray(res.x).reshape(p.n_h, -1)
        rows = p.constraints_np(u)[: p.m_cbf]
        viol = float(max(0.0, -rows.min())) if rows.size else 0.0
        if res.status == 0 and viol <= FEAS_TOL:
            status = SolveStatus.OPTIMAL
        elif res.status == 9:
            status = SolveStatus.MAX_ITER
        else:
            status = SolveStatus.FAILED
        return SolveResult(u, status, int(res.nit), float(res.fun), viol, False, str(res.message),
                           time.perf_counter() - t0)  # fmt: skip


def make_solver(name: str) -> SqpSolver | SlsqpSolver:
    if name in ("sqp", "sqp-daqp", "default"):
        return SqpSolver()
    if name == "slsqp":
        return SlsqpSolver()
    raise ValueError(f"unknown solver {name!r}: expected 'sqp' (default) or 'slsqp'")
