"""DAQP's C entry point ``daqp_quadprog``, called from compiled SQP loops.

The SQP of :class:`~trustnav.control.solvers.SqpSolver` spends most of a control step outside the
QP when each iteration goes through Python (kernel dispatch, DAQP's Python wrapper, the step).
For the fused single-integrator and bicycle problems, :func:`single_integrator_full_steps` (full
steps, then the line search; the rows' curvature in the Hessian from the seventh QP) and
:func:`bicycle_steps` (Armijo line search on the L1 merit; a road's edges too) run them in one
compiled call: build the QP (`cbf_imp` linearised, the fused kernels of
:mod:`trustnav.control._kernels`), solve it with DAQP's C API, step, repeat. The three
structures of that API (problem, settings, result) are
filled here with the layout of daqp 0.11's ``types.h`` / ``api.h``; the layout is checked at
import against DAQP's own defaults, and a mismatch (another DAQP build) leaves :data:`AVAILABLE`
False, so the solver keeps its Python path.
"""

from __future__ import annotations

import ctypes

import daqp
import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numpy.typing import NDArray

from trustnav.control._kernels import (
    ARMIJO,
    CURVATURE_START,
    INF,
    bicycle_qp,
    bicycle_rollout,
    clip_plan,
    flat_hessian,
    lane_march,
    merit_slope,
    merit_violation,
    one_minus_gamma,
    road_fill,
    row_violations,
    shift_plan,
    single_integrator_curvature,
    single_integrator_qp,
    single_integrator_rollout,
    velocity_stage,
)

__all__ = [
    "AVAILABLE",
    "QpStructs",
    "bicycle_step",
    "bicycle_steps",
    "single_integrator_full_steps",
    "single_integrator_step",
]

_SETTINGS_WORDS = 17  # sizeof(DAQPSettings) = 136 bytes
_PROBLEM_WORDS = 10  # sizeof(DAQPProblem) = 80 bytes
_RESULT_WORDS = 8  # sizeof(DAQPResult) = 64 bytes
_ACTIVE, _LOWER = 1, 2  # DAQP's constraint state bits (constants.h)


def _load():
    """DAQP's C library: ``daqp_default_settings`` through ctypes, and ``daqp_quadprog`` as an
    external symbol of the compiled loops (bound by name, so numba can cache them)."""
    try:
        lib = ctypes.CDLL(daqp.__file__)
        defaults = lib.daqp_default_settings
        lib.daqp_quadprog  # noqa: B018 - the symbol must exist
        llvm.load_library_permanently(daqp.__file__)
    except (OSError, AttributeError, RuntimeError):
        return None
    defaults.argtypes = [ctypes.c_void_p]
    defaults.restype = None
    return defaults


_defaults = _load()
# daqp_quadprog(DAQPResult*, DAQPProblem*, DAQPSettings*), the addresses passed as integers
_quadprog = types.ExternalFunction("daqp_quadprog", types.void(types.intp, types.intp, types.intp))


def _default_settings() -> NDArray[np.float64] | None:
    """DAQPSettings as DAQP fills it, or None when its layout is not the expected one (or the
    library could not be loaded)."""
    if _defaults is None:
        return None
    buf = np.zeros(_SETTINGS_WORDS)
    _defaults(buf.ctypes.data)
    words = buf.view(np.int32)
    # primal_tol, dual_tol, cycle_tol, iter_limit at their offsets (DAQP's documented defaults)
    if buf[0] != 1e-6 or buf[1] != 1e-12 or words[10] != 10 or words[11] != 10000:
        return None
    return buf


_DEFAULTS = _default_settings()
AVAILABLE = _DEFAULTS is not None


class QpStructs:
    """DAQPProblem, DAQPSettings and DAQPResult for the QP held in ``h, f, a, bu, bl`` (arrays
    the problem fills in place: the structures point at them, nothing is copied per solve)."""

    def __init__(self, h, f, a, bu, bl, primal_tol: float) -> None:
        if not AVAILABLE:
            raise RuntimeError("DAQP's C API has an unexpected layout: use the Python path")
        n, m = f.shape[0], bu.shape[0]
        self.arrays = (h, f, a, bu, bl)  # kept alive while the structures point at them
        self.settings = _DEFAULTS.copy()
        self.settings[0] = primal_tol
        self.sense = np.zeros(m, dtype=np.int32)
        self.x = np.zeros(n)
        self.lam = np.zeros(m)
        self.problem = np.zeros(_PROBLEM_WORDS, dtype=np.int64)
        words = self.problem.view(np.int32)
        words[0], words[1], words[2] = n, m, n  # n, m (simple bounds + rows), ms (simple bounds)
        self.problem[2:9] = [h.ctypes.data, f.ctypes.data, a.ctypes.data, bu.ctypes.data, bl.ctypes.data,
                             self.sense.ctypes.data, 0]  # fmt: skip
        self.result = np.zeros(_RESULT_WORDS, dtype=np.int64)
        self.result[0], self.result[1] = self.x.ctypes.data, self.lam.ctypes.data
        self.result_words = self.result.view(np.int32)  # exitflag at word 8
        self.addresses = (self.result.ctypes.data, self.problem.ctypes.data, self.settings.ctypes.data)
        # the compiled loops' trailing arguments
        self.tail = (self.sense, self.x, self.lam, self.result_words, *self.addresses)

    def holds(self, h, f, a, bu, bl) -> bool:
        """True when the structures point at these very arrays."""
        x = self.arrays
        return x[0] is h and x[1] is f and x[2] is a and x[3] is bu and x[4] is bl


@njit(cache=True)
def single_integrator_full_steps(
    max_it, tol, u, seen, x0, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat,
    bl, bu, g, sense, xsol, lam, result_words, result_addr, problem_addr, settings_addr, full_its, mu, trial,
    h_mat, n_p, floor,
):  # fmt: skip
    """SQP steps of the single-integrator problem from ``u`` (changed in place), as
    :meth:`SqpSolver._iterate_qp` and :meth:`SqpSolver._take_step` take them: the QP at u, solved
    by DAQP; full steps u <- u + dU for the first ``full_its`` iterations, then the backtracking
    line search of :func:`bicycle_steps` on the L1 merit (weight ``mu``; ``trial`` its buffer);
    stop when the step taken, max |alpha dU|, is below tol. The iterate of each QP is copied to
    ``seen``. The first ``CURVATURE_START`` QPs' Hessian ``h_mat`` is the cost's (2 I); every later one adds the
    pedestrian rows' curvature weighted by the last QP's multipliers
    (:func:`~trustnav.control._kernels.single_integrator_curvature`, eigenvalues clipped at
    ``floor``): an exact-Hessian SQP, which converges in a few iterations where the Gauss-Newton
    Hessian alone converged linearly (many active rows, fewer than the inputs).

    Returns (iterations, state, cost at the last built point, DAQP exit flag): state 1 converged
    (the QP buffers hold the data at the final u, the cost is its cost), 0 ``max_it`` iterations
    without converging, -1 the QP at u failed (u is that iterate, the QP buffers hold its data).
    DAQP starts from the working set of the last QP it solved (its multipliers ``lam``, kept from
    one control step to the next), as a ``daqp.Model`` does."""
    n_h = u.shape[0]
    n = 2 * n_h
    cost = 0.0
    flag = 0
    fresh = False
    flat_hessian(h_mat)
    for it in range(1, max_it + 1):
        if not fresh:
            cost = single_integrator_qp(
                x0, u, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat, bl, bu, g
            )
        fresh = False
        _warm_start(sense, lam)
        _quadprog(result_addr, problem_addr, settings_addr)
        flag = result_words[8]
        if flag < 0:
            return it, -1, cost, flag
        for k in range(n_h):
            seen[it - 1, k, 0] = u[k, 0]
            seen[it - 1, k, 1] = u[k, 1]
        if it >= CURVATURE_START:  # the next QP's Hessian: with the rows' curvature once it is slow
            single_integrator_curvature(lam, n, omg, stride, n_p, dt, floor, h_mat)
        step = 0.0
        if it <= full_its:
            for k in range(n_h):
                for d in range(2):
                    dk = xsol[2 * k + d]
                    u[k, d] = u[k, d] + dk
                    if abs(dk) > step:
                        step = abs(dk)
            if step < tol:  # converged: the QP buffers and the cost at the final iterate, for its check
                cost = single_integrator_qp(
                    x0, u, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat, bl, bu, g
                )
                return it, 1, cost, flag
            continue
        viol0 = merit_violation(bl, bu, n, 0)
        merit0 = cost + mu * viol0
        slope = merit_slope(f, xsol, n, mu, viol0)
        alpha = 1.0
        c1 = cost
        accepted = False
        for _ in range(8):
            _trial_point(u, xsol, alpha, ulo, uhi, trial)
            c1 = single_integrator_qp(
                x0, trial, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat, bl, bu, g
            )
            if c1 + mu * merit_violation(bl, bu, n, 0) <= merit0 + ARMIJO * alpha * slope + 1e-12 * (1.0 + abs(merit0)):
                accepted = True
                break
            alpha *= 0.5
        if not accepted:  # no decrease of the merit along the QP's step: no progress is possible here
            cost = single_integrator_qp(
                x0, u, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat, bl, bu, g
            )
            return it, 1, cost, flag
        step = _accept(u, trial, xsol, step)
        cost, fresh = c1, True  # the buffers hold the data at the accepted trial
        if alpha * step < tol:
            return it, 1, cost, flag
    return max_it, 0, cost, flag


@njit(cache=True)
def single_integrator_step(
    x_in, peds_in, vels, trust, prev, max_it, x0, origin, peds, omg, ref, shifted, lam0, gamma_ini, delta, lam_g,
    goal_x, goal_y, gain, v_max, dt, rollout, max_coordinate, tol, seen, r2, timing, n_decided, ulo, uhi, pos, sens,
    f, a_mat, bl, bu, g, sense, xsol, lam, result_words, result_addr, problem_addr, settings_addr, full_its, mu,
    h_mat, floor,
):  # fmt: skip
    """A whole control step of the single-integrator problem with a velocity-tracking cost, in one
    compiled call: the step's data (:func:`velocity_stage`, from world-frame ``x_in``,
    ``peds_in``, ``trust``), the warm start (the previous plan ``prev`` shifted by one step, its
    last input held, clipped to the bounds), the SQP (:func:`single_integrator_full_steps`), the
    exact check of the final plan (:func:`row_violations`) and its predicted positions. The same
    arithmetic, in the same order, as the controller's general path; a Python step through it
    touches a few objects instead of hundreds, which is what costs when the caches are cold.

    The step's data is written to ``x0``, ``origin``, ``peds``, ``1 - gamma`` (``omg``) and u_bar
    (``ref``), DAQP's working set on entry (``lam``'s values) to ``lam0`` (a caller that hands the
    step to the general path restores it, so that path runs as if this call had not);
    ``shifted`` is scratch. Returns (code, iterations, state, cost, first-row violation, worst
    violation, plan, predicted positions): code 0 ran, 1 / 2 as :func:`velocity_stage`, 3 a
    non-finite state, pedestrian or velocity (nothing ran: the general path refuses the input by
    name); state as :func:`single_integrator_full_steps`, the violations only where it is 1."""
    n_p = peds_in.shape[0]
    n_h = prev.shape[0]
    u = np.empty((n_h, 2))
    predicted = np.empty((n_h + 1, 2))
    total = x_in[0] + x_in[1]
    for j in range(n_p):
        total += peds_in[j, 0] + peds_in[j, 1] + vels[j, 0] + vels[j, 1]
    if not np.isfinite(total):
        return 3, 0, 0, 0.0, 0.0, 0.0, u, predicted
    lam0[:] = lam
    code = velocity_stage(
        x_in, peds_in, trust, gamma_ini, delta, lam_g, goal_x, goal_y, gain, v_max, dt, rollout, max_coordinate,
        x0, origin, peds, omg, ref,
    )  # fmt: skip
    if code != 0:
        return code, 0, 0, 0.0, 0.0, 0.0, u, predicted
    shift_plan(prev, shifted)
    clip_plan(shifted, ulo, uhi, u)
    it, state, cost, _ = single_integrator_full_steps(
        max_it, tol, u, seen, x0, ref, peds, vels, omg, r2, dt, timing, n_p, ulo, uhi, pos, sens, f, a_mat, bl, bu,
        g, sense, xsol, lam, result_words, result_addr, problem_addr, settings_addr, full_its, mu, shifted, h_mat, n_p,
        floor,
    )  # fmt: skip
    first = worst = 0.0
    if state > 0:
        first, worst, _ = row_violations(g, n_decided, n_p)
        single_integrator_rollout(x_in, u, dt, predicted)
    return 0, it, state, cost, first, worst, u, predicted


@njit(cache=True)
def bicycle_step(
    x_in, peds_in, vels, trust, prev, u_prev, max_it, x0, origin, peds, omg, pts, yaw, speed, shifted, trial, lam0,
    gamma_ini, delta, lam_g, start_x, start_y, goal_x, goal_y, gain, v_max, rollout, max_coordinate, tol, mu, seen,
    weights, wheelbase, vmin, vmax, dt, n_sub, r2, timing, m_cbf, n_decided, ulo, uhi, xs, sens, h_mat, f, a_mat, bl,
    bu, g, sense, xsol, lam, result_words, result_addr, problem_addr, settings_addr,
):  # fmt: skip
    """A whole control step of the kinematic bicycle with the lane-tracking cost, in one compiled
    call, as :func:`single_integrator_step` for the single integrator: the step's data (ego-centred
    state and pedestrians about ``origin``, 1 - gamma, the lane waypoints ``pts``, ``yaw``,
    ``speed`` of the bounded proportional reference), the warm start, the SQP
    (:func:`bicycle_steps`), the exact check and the predicted states. Returns (code, iterations,
    state, cost, first-row violation, worst violation, the state-limit violation (how far the
    predicted speed drops below ``vmin``), the violation of the rows the state decides, plan,
    predicted states): code 0 ran, 1 the ego beyond ``max_coordinate``, 2 a trust outside [0, 1],
    3 a non-finite input, 4 a lane of zero length (nothing ran); the violations only where the
    state is 1."""
    n_p = peds_in.shape[0]
    n_h = prev.shape[0]
    u = np.empty((n_h, 2))
    predicted = np.empty((n_h + 1, 4))
    total = x_in[0] + x_in[1] + x_in[2] + x_in[3]
    for j in range(n_p):
        total += peds_in[j, 0] + peds_in[j, 1] + vels[j, 0] + vels[j, 1]
    if not np.isfinite(total):
        return 3, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, u, predicted
    ox, oy = x_in[0], x_in[1]
    if abs(ox) > max_coordinate or abs(oy) > max_coordinate:
        return 1, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, u, predicted
    if not one_minus_gamma(trust, gamma_ini, delta, lam_g, omg):
        return 2, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, u, predicted
    # the lane reference, as BoundedProportionalReference.lane_waypoints computes it
    a = np.empty(2)
    a[0], a[1] = start_x - ox, start_y - oy
    axis_x, axis_y = (goal_x - ox) - a[0], (goal_y - oy) - a[1]
    length = np.hypot(axis_x, axis_y)
    if not length > 0.0:
        return 4, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, u, predicted
    t_hat = np.empty(2)
    t_hat[0], t_hat[1] = axis_x / length, axis_y / length
    s = (0.0 - a[0]) * t_hat[0] + (0.0 - a[1]) * t_hat[1]
    s = min(max(s, 0.0), length)
    lane_march(a, t_hat, s, length, gain, v_max, dt, rollout, pts, speed)
    heading = np.arctan2(t_hat[1], t_hat[0])
    for k in range(yaw.shape[0]):
        yaw[k] = heading
    lam0[:] = lam
    origin[0], origin[1] = ox, oy
    for i in range(x_in.shape[0]):
        x0[i] = x_in[i]
    x0[0], x0[1] = 0.0, 0.0
    for j in range(n_p):
        peds[j, 0] = peds_in[j, 0] - ox
        peds[j, 1] = peds_in[j, 1] - oy
    shift_plan(prev, shifted)
    clip_plan(shifted, ulo, uhi, u)
    it, state, cost, _ = bicycle_steps(
        max_it, tol, mu, u, seen, trial, x0, u_prev, pts, yaw, speed, weights, wheelbase, vmin, vmax, peds, vels,
        omg, r2, dt, n_sub, timing, n_p, m_cbf, n_decided, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g, sense,
        xsol, lam, result_words, result_addr, problem_addr, settings_addr, 0.0, 0.0, np.zeros(8), 0,
    )  # fmt: skip
    first = worst = limit = decided = 0.0
    if state > 0:
        first, worst, _ = row_violations(g, n_decided, n_p)
        bicycle_rollout(x_in, u, dt, n_sub, wheelbase, predicted)
        lowest = predicted[1, 3]
        for k in range(2, n_h + 1):
            lowest = min(lowest, predicted[k, 3])
        limit = max(0.0, vmin - lowest)
        if n_decided:
            low = g[0]
            for r in range(1, n_decided):
                low = min(low, g[r])
            decided = max(0.0, -low)
    return 0, it, state, cost, first, worst, limit, decided, u, predicted


@njit(cache=True)
def _warm_start(sense, lam):
    for i in range(sense.shape[0]):  # the working set of the last QP solved (its multipliers)
        lam_i = lam[i]
        sense[i] = _ACTIVE if lam_i > 1e-12 else (_ACTIVE | _LOWER if lam_i < -1e-12 else 0)


@njit(cache=True)
def _trial_point(u, xsol, alpha, ulo, uhi, trial):
    """The line search's trial point: u + alpha * the QP's step, clipped to the input bounds."""
    for k in range(u.shape[0]):
        for d in range(2):
            trial[k, d] = min(max(u[k, d] + alpha * xsol[2 * k + d], ulo[d]), uhi[d])


@njit(cache=True)
def _accept(u, trial, xsol, step):
    """Take the accepted trial as the iterate; the largest QP step component (at least ``step``)."""
    for k in range(u.shape[0]):
        for d in range(2):
            a = abs(xsol[2 * k + d])
            if a > step:
                step = a
            u[k, d] = trial[k, d]
    return step


@njit(cache=True)
def _bicycle_rows(
    x0, u, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds, vels, omg, r2, dt, n_sub, timing,
    stride, m_cbf, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g, ox, oy, road, n_road, n_decided,
):  # fmt: skip
    """The bicycle's QP data at ``u`` (:func:`~trustnav.control._kernels.bicycle_qp`), the road's rows
    (``n_road`` > 0) and the decided rows' lower bounds opened; returns the cost at ``u``."""
    n = 2 * u.shape[0]
    cost = bicycle_qp(
        x0, u, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds, vels, omg, r2, dt,
        n_sub, timing, stride, m_cbf, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g,
    )  # fmt: skip
    if n_road:
        road_fill(xs, sens, ox, oy, road, n_road, stride, peds.shape[0], a_mat, bl, bu, g, n)
    for r in range(n_decided):
        bl[n + r] = -INF
    return cost


@njit(cache=True)
def bicycle_steps(
    max_it, tol, mu, u, seen, trial, x0, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds,
    vels, omg, r2, dt, n_sub, timing, stride, m_cbf, n_decided, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g,
    sense, xsol, lam, result_words, result_addr, problem_addr, settings_addr, ox, oy, road, n_road,
):  # fmt: skip
    """SQP iterations of the kinematic-bicycle problem from ``u`` (changed in place), as
    :meth:`SqpSolver._iterate_qp` and :meth:`SqpSolver._take_step` take them for a nonlinear
    problem: the QP at u (DAQP, warm-started as in :func:`single_integrator_full_steps`), then a
    backtracking line search (at most 8 halvings) on the L1 merit cost + mu * sum max(0, -row);
    stop when alpha max |dU| < tol. Returns as :func:`single_integrator_full_steps`. ``n_road`` > 0:
    the rows of a road's edges (:func:`~trustnav.control._kernels.road_fill`, ``road`` its data, the
    ego-centred states about ``ox, oy``) after the pedestrians' at every step of the horizon."""
    n_h = u.shape[0]
    n = 2 * n_h
    cost = 0.0
    flag = 0
    fresh = False
    for it in range(1, max_it + 1):
        if not fresh:
            cost = _bicycle_rows(
                x0, u, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds, vels, omg, r2, dt, n_sub,
                timing, stride, m_cbf, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g, ox, oy, road, n_road, n_decided,
            )  # fmt: skip
        _warm_start(sense, lam)
        _quadprog(result_addr, problem_addr, settings_addr)
        flag = result_words[8]
        if flag < 0:
            return it, -1, cost, flag
        for k in range(n_h):
            seen[it - 1, k, 0] = u[k, 0]
            seen[it - 1, k, 1] = u[k, 1]
        viol0 = merit_violation(bl, bu, n, n_decided)
        merit0 = cost + mu * viol0
        slope = merit_slope(f, xsol, n, mu, viol0)
        alpha = 1.0
        c1 = cost
        accepted = False
        for _ in range(8):
            _trial_point(u, xsol, alpha, ulo, uhi, trial)
            c1 = _bicycle_rows(
                x0, trial, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds, vels, omg, r2, dt,
                n_sub, timing, stride, m_cbf, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g, ox, oy, road, n_road,
                n_decided,
            )  # fmt: skip
            trial_merit = c1 + mu * merit_violation(bl, bu, n, n_decided)
            if trial_merit <= merit0 + ARMIJO * alpha * slope + 1e-12 * (1.0 + abs(merit0)):
                accepted = True
                break
            alpha *= 0.5
        if not accepted:  # no decrease of the merit along the QP's step: no progress is possible here
            cost = _bicycle_rows(
                x0, u, u_prev, ref_pts, ref_yaw, ref_v, weights, wheelbase, vmin, vmax, peds, vels, omg, r2, dt, n_sub,
                timing, stride, m_cbf, ulo, uhi, xs, sens, h_mat, f, a_mat, bl, bu, g, ox, oy, road, n_road, n_decided,
            )  # fmt: skip
            return it, 1, cost, flag
        step = _accept(u, trial, xsol, 0.0)
        cost, fresh = c1, True  # the buffers hold the data at the accepted trial
        if alpha * step < tol:
            return it, 1, cost, flag
    return max_it, 0, cost, flag
