"""Warm starts of the solver's feasibility recovery, and the first-step certificate (issue 36).

When the hard QP at an iterate is infeasible, :class:`~trustnav.control.solvers.SqpSolver` ranks
candidate starting plans by their exact violation (:func:`candidate_starts`), and asks once per
solve whether the k = 0 rows admit any first input at all (:func:`first_step_infeasible`). Both
belong to the solver and read the problem's data (``p``: an
:class:`~trustnav.control.problem.MpcProblem`, duck-typed here so that this module imports nothing
but the models: no import circle). A model of the user's may give its own as methods
``candidate_starts(problem)`` and ``first_step_infeasible(problem, tol)``; they are used instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.control.barrier import h_quad
from trustnav.control.models import KinematicBicycle, SingleIntegrator

__all__ = [
    "bicycle_starts",
    "candidate_starts",
    "default_starts",
    "first_step_infeasible",
    "single_integrator_first_step_infeasible",
    "single_integrator_starts",
]


def candidate_starts(p: Any) -> list[NDArray[np.float64]]:
    """Starting plans (each (N_h, n_u)) of the feasibility recovery for problem ``p``: the model's
    own hook where it has one, else those of its kind."""
    model = p.model
    hook = getattr(model, "candidate_starts", None)
    if hook is not None:
        return hook(p)
    if isinstance(model, SingleIntegrator):
        return single_integrator_starts(p)
    if isinstance(model, KinematicBicycle):
        return bicycle_starts(p)
    return default_starts(p)


def first_step_infeasible(p: Any, tol: float) -> bool:
    """True when no first input meets every pedestrian's k = 0 row (a certificate that no plan is
    hard-feasible); False when unknown. The model's own hook where it has one."""
    model = p.model
    hook = getattr(model, "first_step_infeasible", None)
    if hook is not None:
        return bool(hook(p, tol))
    if isinstance(model, SingleIntegrator):
        return single_integrator_first_step_infeasible(p, tol)
    return False


def default_starts(p: Any) -> list[NDArray[np.float64]]:
    """Starting plans for the feasibility recovery (each (N_h, nu)): braking, the cost's
    initial guess, and constant inputs at the corners of the input box."""
    lo, hi = p.model.input_bounds()
    n_h = p.n_h
    corners = np.array(np.meshgrid(*np.stack([lo, hi], axis=1))).reshape(p.model.nu, -1).T
    return [p.braking_plan(), p.initial_guess()] + [np.tile(c, (n_h, 1)) for c in corners]


def single_integrator_starts(p: Any) -> list[NDArray[np.float64]]:
    """Constant-velocity plans: stop, the cost's initial guess, and for each of the three most
    binding obstacles backing away, passing on either side, and both diagonals, at the
    reference speed, half of it, a quarter of the input bound and the bound, and a dash at the
    bound that stops after a third of the horizon (the CBF rows are non-convex: an obstacle can
    be passed on either side, or backed away from)."""
    guess = p.initial_guess()
    starts = [np.zeros((p.n_h, 2)), guess]
    ref = float(np.hypot(*guess[0]))
    top = float(p.uhi.min())
    speeds = [s for s in (ref, 0.5 * ref) if s > 1e-6] + [0.25 * top, top]
    dash = np.zeros((p.n_h, 1))
    dash[: max(1, p.n_h // 3)] = 1.0  # full speed for the first third of the horizon, then stop
    for j in p.binding_obstacles(3):
        away = p.escape_direction(j)
        norm = float(np.hypot(*away))
        e = away / norm if norm > 1e-9 else np.array([1.0, 0.0])  # on top of the ego: any way out
        t = np.array([-e[1], e[0]])
        for d in (e, t, -t, (e + t) / np.sqrt(2), (e - t) / np.sqrt(2)):
            for s in speeds:
                starts.append(np.clip(np.tile(s * d, (p.n_h, 1)), p.ulo, p.uhi))
            starts.append(np.clip(dash * (top * d), p.ulo, p.uhi))
    return starts


def single_integrator_first_step_infeasible(p: Any, tol: float, max_disks: int = 32) -> bool:
    """True when no first input u_0 meets every pedestrian's k = 0 row to within ``tol``: then
    no plan is hard-feasible (a certificate, so a solver can skip searching for one; other
    barriers only add rows).

    The k = 0 rows depend on u_0 alone: the next position p = u_0 dt must lie in the input box
    times dt and outside the open disk |p - q_j(1)|^2 < R^2 + (1 - gamma_j) h_j(0) - tol of
    each pedestrian. A generic linear function attains its minimum over that compact set (if
    nonempty) at a vertex: a box corner, a crossing of a circle with a box edge, or of two
    circles; so the set is empty exactly when no such point is in it. False (no certificate)
    with more than ``max_disks`` disks reaching the box."""
    if p.n_p == 0:
        return False
    c = p.config
    r2 = p.r2
    lo, hi = c.dt * p.ulo, c.dt * p.uhi  # the box of p (ego at the origin)
    q_next = p.peds + c.dt * p.vels if p.timing_code == 0 else p.peds
    h0 = h_quad(p.peds[:, 0], p.peds[:, 1], r2)
    rho = r2 + p.one_minus_gamma * h0 - tol  # row_j >= -tol  <=>  |p - q_j(1)|^2 >= rho_j
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
    pt = np.concatenate(pts)
    eps = 1e-12
    pt = pt[np.all((pt >= lo - eps) & (pt <= hi + eps), axis=1)]
    if pt.shape[0] == 0:
        return True
    diff = pt[:, None, :] - cen[None, :, :]
    margin = (np.einsum("kji,kji->kj", diff, diff) - rad2[None, :]).min(axis=1)
    return not bool((margin >= -1e-9).any())


def bicycle_starts(p: Any) -> list[NDArray[np.float64]]:
    """Constant-steer plans (straight, half and full lock either way) that hold speed,
    ease off or brake to rest."""
    sm, x0, n_h, dt = p.model.steer_max, p.x0, p.n_h, p.config.dt
    steers = (0.0, 0.5 * sm, -0.5 * sm, sm, -sm)
    return [p.model.plan(x0, n_h, dt, st, acc) for acc in ("brake", "ease", "hold") for st in steers]
