"""Compiled kernels that build the SQP subproblem of `proposed` (condensed, single shooting).

For the current iterate U they fill, in place, the QP in the step dU:

    min 1/2 dU' H dU + f' dU   s.t.  lo_k <= dU_k <= hi_k (simple bounds),
                                     bl_r <= A_r dU <= bu_r  (linearised rows)

The rows are first the N_h x N_p CBF rows of `cbf_imp` (row k * N_p + j, linearised with
analytic Jacobians), then model-specific linear rows. ``g`` receives the CBF row values at U
(>= 0 when satisfied); the return value is the cost at U.

timing: 0 = pedestrian at k+1 in the h(k+1) term (the paper), 1 = at k (the authors' code).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from trustnav.control.barrier import h_quad

INF = 1e20  # DAQP treats |bound| >= 1e20 as infinite
# the exact-Hessian SQP's QPs after this iteration add the rows' curvature
CURVATURE_START = 6
CURVATURE_FLOOR = 1e-2  # eigenvalue floor of the exact-Hessian SQP's (I + dt^2 C), see single_integrator_curvature


@njit(cache=True, fastmath=False)
def cbf_fill(pos, sens, peds, vels, omg, r2, dt, timing, stride, a_mat, bl, bu, g, nsimple):
    """Pedestrian CBF rows of `cbf_imp` (barrier `h_quad`) from ego positions pos (N+1, 2) and
    their sensitivities sens (N+1, 2, n): row k * stride + j for pedestrian j at step k, with
    r2[j] = R_j^2 (R, or R tightened by the pedestrian's position uncertainty)."""
    n_h = pos.shape[0] - 1
    n_p = peds.shape[0]
    n = sens.shape[2]
    for k in range(n_h):
        for j in range(n_p):
            qkx = peds[j, 0] + k * dt * vels[j, 0]
            qky = peds[j, 1] + k * dt * vels[j, 1]
            if timing == 0:
                qnx = qkx + dt * vels[j, 0]
                qny = qky + dt * vels[j, 1]
            else:
                qnx = qkx
                qny = qky
            dnx = pos[k + 1, 0] - qnx
            dny = pos[k + 1, 1] - qny
            dkx = pos[k, 0] - qkx
            dky = pos[k, 1] - qky
            w = omg[j]
            r = k * stride + j
            val = h_quad(dnx, dny, r2[j]) - w * h_quad(dkx, dky, r2[j])
            g[r] = val
            for i in range(n):  # gradient of h_quad: 2 (x_e - x_j)
                a_mat[r, i] = 2.0 * (dnx * sens[k + 1, 0, i] + dny * sens[k + 1, 1, i]) - 2.0 * w * (
                    dkx * sens[k, 0, i] + dky * sens[k, 1, i]
                )
            bl[nsimple + r] = -val
            bu[nsimple + r] = INF


@njit(cache=True)
def single_integrator_qp(
    x0, u, ubar, peds, vels, omg, r2, dt, timing, stride, ulo, uhi, pos, sens, f, a_mat, bl, bu, g
):  # fmt: skip
    """Single integrator x+ = x + u dt, cost sum ||u - u_bar||^2 (H = 2 I is constant); the
    positions and their sensitivities are left in ``pos`` and ``sens`` (sens[0] = 0)."""
    n_h = u.shape[0]
    n = 2 * n_h
    pos[0, 0] = x0[0]
    pos[0, 1] = x0[1]
    cost = 0.0
    for k in range(n_h):
        for d in range(2):
            pos[k + 1, d] = pos[k, d] + dt * u[k, d]
            e = u[k, d] - ubar[k, d]
            cost += e * e
            f[2 * k + d] = 2.0 * e
            bl[2 * k + d] = ulo[d] - u[k, d]
            bu[2 * k + d] = uhi[d] - u[k, d]
        for i in range(n):
            sens[k + 1, 0, i] = sens[k, 0, i]
            sens[k + 1, 1, i] = sens[k, 1, i]
        sens[k + 1, 0, 2 * k] = dt
        sens[k + 1, 1, 2 * k + 1] = dt
    cbf_fill(pos, sens, peds, vels, omg, r2, dt, timing, stride, a_mat, bl, bu, g, n)
    return cost


@njit(cache=True)
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def bicycle_qp(
    x0,
    u,
    u_prev,
    ref_pts,
    ref_yaw,
    ref_v,
    weights,
    wheelbase,
    vmin,
    vmax,
    peds,
    vels,
    omg,
    r2,
    dt,
    n_sub,
    timing,
    stride,
    m_cbf,
    ulo,
    uhi,
    xs,
    sens,
    h_mat,
    f,
    a_mat,
    bl,
    bu,
    g,
):
    """Kinematic bicycle (x, y, yaw, v; steer, accel) with the Section IV tracking cost; one
    step of dt is ``n_sub`` Euler sub-steps (as :meth:`KinematicBicycle.step`).

    Residuals (weights w = [cte, heading, speed, steer, accel, steer rate, accel rate]):
    cross-track and heading error to the reference waypoints and speed error for k = 1..N,
    steer and acceleration for k = 0..N-1, and their rates with u(-1) = u_prev. Gauss-Newton
    Hessian H = 2 J' W J. Extra rows after the CBF rows: speed bounds v(k+1) in [vmin, vmax]
    (widened to the speeds reachable from v(0)), from row ``m_cbf`` on. The states and their
    sensitivities are left in ``xs`` and ``sens`` (columns of inputs after step k stay 0).
    """
    n_h = u.shape[0]
    n = 2 * n_h
    for d in range(4):
        xs[0, d] = x0[d]
    h = dt / n_sub
    for k in range(n_h):
        px, py, yaw, v = xs[k, 0], xs[k, 1], xs[k, 2], xs[k, 3]
        st, ac = u[k, 0], u[k, 1]
        turn = math.tan(st) / wheelbase
        cs = math.cos(st)
        dturn = h / (wheelbase * cs * cs)
        ncol = 2 * k + 2  # inputs after u_k do not move x(k+1)
        for i in range(ncol):
            for d in range(4):
                sens[k + 1, d, i] = sens[k, d, i]
        for _ in range(n_sub):  # Euler sub-steps of h with u_k held, and their sensitivities
            c = math.cos(yaw)
            s = math.sin(yaw)
            for i in range(ncol):
                s2, s3 = sens[k + 1, 2, i], sens[k + 1, 3, i]
                sens[k + 1, 0, i] += -v * s * h * s2 + c * h * s3
                sens[k + 1, 1, i] += v * c * h * s2 + s * h * s3
                sens[k + 1, 2, i] += turn * h * s3
            sens[k + 1, 2, 2 * k] += v * dturn
            sens[k + 1, 3, 2 * k + 1] += h
            px, py, yaw, v = px + v * c * h, py + v * s * h, yaw + v * turn * h, v + ac * h
        xs[k + 1, 0] = px
        xs[k + 1, 1] = py
        xs[k + 1, 2] = yaw
        xs[k + 1, 3] = v
    # residuals r and Jacobian jr (7 N x n)
    nr = 7 * n_h
    r = np.zeros(nr)
    jr = np.zeros((nr, n))
    wv = np.empty(nr)
    for k in range(n_h):
        kk = k + 1
        nx_ = -math.sin(ref_yaw[kk])
        ny_ = math.cos(ref_yaw[kk])
        r[k] = nx_ * (xs[kk, 0] - ref_pts[kk, 0]) + ny_ * (xs[kk, 1] - ref_pts[kk, 1])
        r[n_h + k] = _wrap(xs[kk, 2] - ref_yaw[kk])
        r[2 * n_h + k] = xs[kk, 3] - ref_v[kk]
        for i in range(2 * k + 2):  # inputs after u_k do not move x(k+1): their columns stay 0
            jr[k, i] = nx_ * sens[kk, 0, i] + ny_ * sens[kk, 1, i]
            jr[n_h + k, i] = sens[kk, 2, i]
            jr[2 * n_h + k, i] = sens[kk, 3, i]
        wv[k] = weights[0]
        wv[n_h + k] = weights[1]
        wv[2 * n_h + k] = weights[2]
        for d in range(2):
            r[(3 + d) * n_h + k] = u[k, d]
            jr[(3 + d) * n_h + k, 2 * k + d] = 1.0
            wv[(3 + d) * n_h + k] = weights[3 + d]
            prev = u_prev[d] if k == 0 else u[k - 1, d]
            r[(5 + d) * n_h + k] = u[k, d] - prev
            jr[(5 + d) * n_h + k, 2 * k + d] = 1.0
            if k > 0:
                jr[(5 + d) * n_h + k, 2 * (k - 1) + d] = -1.0
            wv[(5 + d) * n_h + k] = weights[5 + d]
    cost = 0.0
    for q in range(nr):
        cost += wv[q] * r[q] * r[q]
    # gradient 2 J' W r and Gauss-Newton Hessian 2 J' W J over the rows where both factors can be
    # nonzero, in ascending row order: the rows left out add products with a zero factor (+-0),
    # which change no sum, so the result is the dense sums' to the last bit, at a fifth of the work
    for i in range(n):
        ki, d = i // 2, i % 2  # input i is u_ki's steer (d = 0) or acceleration (d = 1)
        acc = 0.0
        for b in range(3):  # cross-track, heading, speed rows of the steps k >= ki
            for k in range(ki, n_h):
                q = b * n_h + k
                acc += jr[q, i] * wv[q] * r[q]
        q = (3 + d) * n_h + ki  # the input's own row
        acc += jr[q, i] * wv[q] * r[q]
        q = (5 + d) * n_h + ki  # its rate rows: at k = ki and k = ki + 1
        acc += jr[q, i] * wv[q] * r[q]
        if ki + 1 < n_h:
            q += 1
            acc += jr[q, i] * wv[q] * r[q]
        f[i] = 2.0 * acc
        for l in range(i, n):
            kl = l // 2
            acc = 0.0
            for b in range(3):
                for k in range(kl, n_h):
                    q = b * n_h + k
                    acc += jr[q, i] * wv[q] * jr[q, l]
            if l % 2 == d:  # an input row and rate rows hold one kind of input each
                if kl == ki:
                    q = (3 + d) * n_h + ki
                    acc += jr[q, i] * wv[q] * jr[q, l]
                    q = (5 + d) * n_h + ki
                    acc += jr[q, i] * wv[q] * jr[q, l]
                if (kl == ki or kl == ki + 1) and ki + 1 < n_h:
                    q = (5 + d) * n_h + ki + 1
                    acc += jr[q, i] * wv[q] * jr[q, l]
            h_mat[i, l] = 2.0 * acc
            h_mat[l, i] = 2.0 * acc
        h_mat[i, i] += 1e-9
    for k in range(n_h):
        for d in range(2):
            bl[2 * k + d] = ulo[d] - u[k, d]
            bu[2 * k + d] = uhi[d] - u[k, d]
    pos = np.ascontiguousarray(xs[:, :2])
    psens = np.ascontiguousarray(sens[:, :2, :])
    cbf_fill(pos, psens, peds, vels, omg, r2, dt, timing, stride, a_mat, bl, bu, g, n)
    for k in range(n_h):
        row = m_cbf + k
        for i in range(n):
            a_mat[row, i] = sens[k + 1, 3, i]
        # bounds widened to what the input bounds can reach from v(0), so that a speed outside
        # [vmin, vmax] (a car rolling back, an overspeed) is brought back without an infeasible QP
        lo_k = min(vmin, x0[3] + (k + 1) * dt * uhi[1])
        hi_k = max(vmax, x0[3] + (k + 1) * dt * ulo[1])
        bl[n + row] = lo_k - xs[k + 1, 3]
        bu[n + row] = hi_k - xs[k + 1, 3]
    return cost


@njit(cache=True)
def reference_velocities(x0, goal, gain, v_max, dt, rollout, out):
    """Bounded proportional reference over the horizon (see BoundedProportionalReference)."""
    px, py = x0[0], x0[1]
    for k in range(out.shape[0]):
        vx = gain * (goal[0] - px)
        vy = gain * (goal[1] - py)
        nrm = math.sqrt(vx * vx + vy * vy)
        if nrm > v_max:
            vx *= v_max / nrm
            vy *= v_max / nrm
        if k > 0 and not rollout:
            vx, vy = out[0, 0], out[0, 1]
        out[k, 0] = vx
        out[k, 1] = vy
        px += vx * dt
        py += vy * dt


@njit(cache=True)
def single_integrator_rollout(x0, u, dt, out):
    """Positions x(0..N) = x0 + cumulative sum of u dt (the arithmetic of numpy's cumsum, then + x0)."""
    for d in range(2):
        out[0, d] = x0[d]
        acc = 0.0
        for k in range(u.shape[0]):
            acc += u[k, d] * dt
            out[k + 1, d] = acc + x0[d]


@njit(cache=True)
def bicycle_rollout(x0, u, dt, n_sub, wheelbase, out):
    """States x(0..N) of the kinematic bicycle, ``n_sub`` Euler sub-steps per dt (as
    :meth:`KinematicBicycle.step`, operation for operation)."""
    px, py, yaw, v = x0[0], x0[1], x0[2], x0[3]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = px, py, yaw, v
    h = dt / n_sub
    for k in range(u.shape[0]):
        turn = math.tan(u[k, 0]) / wheelbase
        acc = u[k, 1]
        for _ in range(n_sub):
            px, py, yaw, v = px + v * math.cos(yaw) * h, py + v * math.sin(yaw) * h, yaw + v * turn * h, v + acc * h
        out[k + 1, 0], out[k + 1, 1], out[k + 1, 2], out[k + 1, 3] = px, py, yaw, v


@njit(cache=True)
def lane_march(a, t_hat, s, length, gain, v_max, dt, rollout, pts, speeds):
    """Waypoints along the lane from arc length s (see ``BoundedProportionalReference.lane_waypoints``)."""
    for k in range(speeds.shape[0]):
        speeds[k] = min(v_max, gain * (length - s))
        pts[k, 0] = a[0] + s * t_hat[0]
        pts[k, 1] = a[1] + s * t_hat[1]
        if rollout:
            s = min(length, s + speeds[k] * dt)


@njit(cache=True)
def one_minus_gamma(trust, gamma_ini, delta, lam, out):
    """1 - gamma_j by `weight` (gamma_j = gamma_ini + delta trust_j^lambda) into ``out``; False
    (``out`` incomplete) when a trust is outside [0, 1] or NaN."""
    for i in range(trust.shape[0]):
        t = trust[i]
        if not (t >= 0.0 and t <= 1.0):
            return False
        out[i] = 1.0 - (gamma_ini + delta * t**lam)
    return True


@njit(cache=True)
def row_violations(g, start, n_first):
    """(worst violation of the rows g[start:start + n_first], worst of g[start:], their sum):
    violations max(0, -row) of the CBF rows from ``start`` on (one pass, no temporaries)."""
    first = 0.0
    worst = 0.0
    total = 0.0
    for i in range(start, g.shape[0]):
        v = -g[i]
        if v > 0.0:
            total += v
            if v > worst:
                worst = v
            if i < start + n_first and v > first:
                first = v
    return first, worst, total


@njit(cache=True)
def velocity_stage(
    x_in, peds_in, trust, gamma_ini, delta, lam, goal_x, goal_y, gain, v_max, dt, rollout, max_coordinate,
    x0, origin, peds, omg, ref,
):  # fmt: skip
    """The step's data of a planar-velocity problem (``VelocityTrackingCost`` with its bounded
    proportional reference) in one call, as :meth:`MpcProblem.set_checked_stage` writes it: the
    ego-centred state ``x0`` and pedestrians ``peds`` about ``origin`` (the ego's position),
    1 - gamma_j (:func:`one_minus_gamma`) and the reference u_bar (:func:`reference_velocities`,
    from the goal in ego-centred coordinates). Returns 0, or 1 (the ego is beyond
    ``max_coordinate``), 2 (a trust outside [0, 1] or NaN): the outputs are then incomplete."""
    ox, oy = x_in[0], x_in[1]
    if abs(ox) > max_coordinate or abs(oy) > max_coordinate:
        return 1
    if not one_minus_gamma(trust, gamma_ini, delta, lam, omg):
        return 2
    origin[0], origin[1] = ox, oy
    for i in range(x_in.shape[0]):
        x0[i] = x_in[i]
    x0[0], x0[1] = 0.0, 0.0
    for i in range(peds_in.shape[0]):
        peds[i, 0] = peds_in[i, 0] - ox
        peds[i, 1] = peds_in[i, 1] - oy
    goal = np.empty(2)
    goal[0], goal[1] = goal_x - ox, goal_y - oy
    reference_velocities(x0, goal, gain, v_max, dt, rollout, ref)
    return 0


@njit(cache=True)
def clip_plan(u0, lo, hi, out):
    """``out`` = u0 (N, n_u) clipped to [lo, hi] per input, as np.minimum(np.maximum(u0, lo), hi)
    (NaN kept)."""
    for k in range(u0.shape[0]):
        for d in range(u0.shape[1]):
            v = u0[k, d]
            if v < lo[d]:
                v = lo[d]
            elif v > hi[d]:
                v = hi[d]
            out[k, d] = v


@njit(cache=True)
def shift_plan(plan, out):
    """``out`` = the plan (N, n_u) shifted by one step, its last input held."""
    n = plan.shape[0]
    for k in range(n):
        src = k + 1 if k + 1 < n else n - 1
        for d in range(plan.shape[1]):
            out[k, d] = plan[src, d]


@njit(cache=True)
def under_speed_cap(u, v0, top, lo, dt):
    """The bicycle's plan ``u`` (N, 2: steer, acceleration) with its accelerations lowered, in
    place, where needed so that the speed from ``v0`` stays within caution's speed rows: at most
    ``top`` at step k + 1, widened (as the model widens them) to ``v0 + (k + 1) dt lo``, the speed
    braking at ``lo`` reaches; never below ``lo``."""
    v = v0
    for k in range(u.shape[0]):
        hi = max(top, v0 + (k + 1) * dt * lo)
        if v + u[k, 1] * dt > hi:
            u[k, 1] = max((hi - v) / dt, lo)
        v += u[k, 1] * dt


@njit(cache=True)
def shift_under_speed_cap(plan, shifted, u, v0, top, lo, dt):
    """:func:`shift_plan` of ``plan`` into ``shifted``, and into ``u`` the same under caution's speed
    rows (:func:`under_speed_cap`): the start of a capped step in one call."""
    shift_plan(plan, shifted)
    for k in range(u.shape[0]):
        for d in range(u.shape[1]):
            u[k, d] = shifted[k, d]
    under_speed_cap(u, v0, top, lo, dt)


@njit(cache=True)
def single_integrator_curvature(lam, nsimple, omg, stride, n_p, dt, floor, h_mat):
    """The Hessian of the SQP's QP with the pedestrian rows' curvature (an exact-Hessian SQP) for
    the single integrator with cost sum ||u - u_bar||^2: H = 2 (I + dt^2 C) (x) I_2, where C is the
    Hessian of - sum_r mu_r g_r (rows g_r of `cbf_imp` with `h_quad`, multipliers mu_r = -lam[nsimple
    + r] >= 0 of the last hard QP, DAQP's sign for an active lower bound) over the N_h planar steps.
    Row (k, j) has Hessian 2 dt^2 (M_{k+1} - (1 - gamma_j) M_k), M_t[a, b] = 1 where a, b < t, so
    C[a, b] depends on max(a, b) alone. Where I + dt^2 C - floor I is not positive definite (a
    Cholesky test), its eigenvalues are clipped at ``floor`` (the convexification of CasADi's
    ``eigen-clip``); ``floor`` <= 0: the cost's Hessian alone (a Gauss-Newton SQP). Returns the
    smallest eigenvalue where it clipped, else 1.0."""
    n_h = h_mat.shape[0] // 2
    if floor <= 0.0:
        flat_hessian(h_mat)
        return 1.0
    w = np.zeros(n_h + 1)  # w[t]: the weight of M_t
    any_active = False
    for k in range(n_h):
        for j in range(n_p):
            mu = -lam[nsimple + k * stride + j]
            if mu > 0.0:
                any_active = True
                w[k + 1] -= mu
                w[k] += mu * omg[j]
    red = np.eye(n_h)
    low = 1.0
    if any_active:
        tail = 0.0
        for s in range(n_h - 1, -1, -1):  # tail = sum over t > s of w[t]
            tail += w[s + 1]
            c = dt * dt * tail
            for a in range(s + 1):  # entries with max(a, b) = s
                red[a, s] += c
                if a != s:
                    red[s, a] += c
        work = np.empty((n_h, n_h))
        if not _positive_definite(red, -floor, work):  # clip the eigenvalues below floor (rarely needed)
            vals, vecs = np.linalg.eigh(red)
            low = vals[0]
            for i in range(n_h):
                if vals[i] < floor:
                    vals[i] = floor
            red = (vecs * vals) @ vecs.T
    for a in range(n_h):
        for b in range(n_h):
            v = 2.0 * red[a, b]
            h_mat[2 * a, 2 * b] = v
            h_mat[2 * a + 1, 2 * b + 1] = v
            h_mat[2 * a, 2 * b + 1] = 0.0
            h_mat[2 * a + 1, 2 * b] = 0.0
    return low


@njit(cache=True)
def flat_hessian(h_mat):
    """H = 2 I: the single integrator's cost Hessian alone (the first QP of a solve)."""
    n = h_mat.shape[0]
    for a in range(n):
        for b in range(n):
            h_mat[a, b] = 0.0
        h_mat[a, a] = 2.0


@njit(cache=True)
def _positive_definite(mat, shift, work):
    """True when mat + shift I is positive definite (an in-place Cholesky in ``work``)."""
    n = mat.shape[0]
    for i in range(n):
        for j in range(i + 1):
            acc = mat[i, j] + (shift if i == j else 0.0)
            for k in range(j):
                acc -= work[i, k] * work[j, k]
            if i == j:
                if acc <= 0.0:
                    return False
                work[i, i] = math.sqrt(acc)
            else:
                work[i, j] = acc / work[j, j]
    return True


@njit(cache=True)
def _road_value(road, i, x, y, yaw):
    """Road-edge function i of :class:`~trustnav.control.barrier.RoadEdgeBarrier` at a world
    position and heading; ``road`` = (start x, start y, normal x, normal y, room left, room right,
    front, 1 - gamma, turn radius). Returns (h, dh/dx, dh/dy, dh/dyaw)."""
    nx_, ny_ = road[2], road[3]
    d = (x - road[0]) * nx_ + (y - road[1]) * ny_
    sign = -1.0 if i % 2 == 0 else 1.0  # left edge: room - d, right edge: d + room
    room = road[4] if i % 2 == 0 else road[5]
    if i < 2:
        return room + sign * d, sign * nx_, sign * ny_, 0.0
    front = road[6]
    c, s = math.cos(yaw), math.sin(yaw)
    lateral = c * nx_ + s * ny_  # the heading's component toward the left edge
    radius = road[8]
    if radius > 0:
        along = c * ny_ - s * nx_
        toward = -sign * lateral  # toward this row's edge
        if toward > 0 and toward * radius > front * along:  # turned past atan(front / radius)
            # the front's farthest reach on the arc back at the smallest turning radius
            swing = math.sqrt(radius * radius + front * front) - radius * along
            return room + sign * d - swing, sign * nx_, sign * ny_, radius * (-s * ny_ - c * nx_)
    df = d + front * lateral
    turn = front * (-s * nx_ + c * ny_)
    return room + sign * df, sign * nx_, sign * ny_, sign * turn


@njit(cache=True)
def road_fill(xs, sens, ox, oy, road, n_road, stride, n_p, a_mat, bl, bu, g, nsimple):
    """The rows of `cbf_discrete` of a road's edges (``n_road`` functions: 2, or 4 with the car's
    front) at the states ``xs`` (ego-centred, about ``ox, oy``) and their sensitivities: row
    k * stride + n_p + i is h_i(x(k+1)) - (1 - gamma) h_i(x(k)), as
    :meth:`MpcProblem._fill_user_rows` builds it for the barrier through its protocol."""
    n_h = xs.shape[0] - 1
    n = sens.shape[2]
    omg = road[7]
    nxs = xs.shape[1]
    for k in range(n_h):
        for i in range(n_road):
            yaw0 = xs[k, 2] if nxs > 2 else 0.0
            yaw1 = xs[k + 1, 2] if nxs > 2 else 0.0
            h0, gx0, gy0, gw0 = _road_value(road, i, xs[k, 0] + ox, xs[k, 1] + oy, yaw0)
            h1, gx1, gy1, gw1 = _road_value(road, i, xs[k + 1, 0] + ox, xs[k + 1, 1] + oy, yaw1)
            r = k * stride + n_p + i
            val = h1 - omg * h0
            g[r] = val
            for c in range(n):
                j1 = gx1 * sens[k + 1, 0, c] + gy1 * sens[k + 1, 1, c]
                j0 = gx0 * sens[k, 0, c] + gy0 * sens[k, 1, c]
                if i >= 2:
                    j1 += gw1 * sens[k + 1, 2, c]
                    j0 += gw0 * sens[k, 2, c]
                a_mat[r, c] = j1 - omg * j0
            bl[nsimple + r] = -val
            bu[nsimple + r] = INF


ARMIJO = 1e-4  # sufficient decrease of the SQP's line search on the L1 merit (a share of its slope)


@njit(cache=True)
def merit_violation(bl, bu, nsimple, first):
    """The L1 merit's violation at the QP's point (dU = 0): sum over the rows from ``first`` on of
    how far each misses its bounds, max(0, bl) + max(0, -bu) (CBF rows: max(0, -row); the model's
    state rows, e.g. the bicycle's speed bounds, too, so that a step the QP takes to restore them
    is not judged by the cost alone)."""
    total = 0.0
    for r in range(nsimple + first, bl.shape[0]):
        if bl[r] > 0.0:
            total += bl[r]
        if bu[r] < 0.0:
            total -= bu[r]
    return total


@njit(cache=True)
def merit_slope(f, step, n, mu, violation):
    """Directional derivative bound of the L1 merit cost + mu * violation along a QP step that
    meets the linearised rows: f . step - mu * violation, and never above 0."""
    s = 0.0
    for i in range(n):
        s += f[i] * step[i]
    s -= mu * violation
    return min(s, 0.0)


@njit(cache=True)
def bicycle_advance(px, py, yaw, v, turn, acc, h, n, out):
    """``n`` Euler sub-steps of ``h`` of the kinematic bicycle (:meth:`KinematicBicycle.step`) with
    the input held (``turn`` = tan(steer) / wheelbase); the state into ``out``."""
    for _ in range(n):
        px, py, yaw, v = px + v * math.cos(yaw) * h, py + v * math.sin(yaw) * h, yaw + v * turn * h, v + acc * h
    out[0], out[1], out[2], out[3] = px, py, yaw, v


@njit
def user_sensitivities(step_fn, jacobian_fn, x0, u, dt, xs, sens):
    """States x_0..x_N and their sensitivities dx_k/dU (S_{k+1} = A_k S_k + B_k E_k) of a model
    whose one step and Jacobians are the user's compiled functions ``step_fn(x, u, dt, out)`` and
    ``jacobian_fn(x, u, dt, a, b)`` (:class:`~trustnav.control.models.CompiledDynamics`); one
    compiled loop instead of a Python call per step. Not cached: numba compiles it once per pair
    of user functions in a process."""
    n_h, nu = u.shape
    nx = x0.shape[0]
    n = n_h * nu
    a = np.empty((nx, nx))
    b = np.empty((nx, nu))
    for i in range(nx):
        xs[0, i] = x0[i]
        for c in range(n):
            sens[0, i, c] = 0.0
    for k in range(n_h):
        jacobian_fn(xs[k], u[k], dt, a, b)
        cols = (k + 1) * nu  # inputs after u_k do not move x(k+1)
        for i in range(nx):
            for c in range(cols):
                acc = 0.0
                for j in range(nx):
                    acc += a[i, j] * sens[k, j, c]
                sens[k + 1, i, c] = acc
            for c in range(cols, n):
                sens[k + 1, i, c] = 0.0
            for d in range(nu):
                sens[k + 1, i, k * nu + d] += b[i, d]
        step_fn(xs[k], u[k], dt, xs[k + 1])


@njit
def user_rollout(step_fn, x0, u, dt, xs):
    """States x_0..x_N of a :class:`~trustnav.control.models.CompiledDynamics` model."""
    for i in range(x0.shape[0]):
        xs[0, i] = x0[i]
    for k in range(u.shape[0]):
        step_fn(xs[k], u[k], dt, xs[k + 1])


@njit(cache=True)
def position_tracking(stage, xs, sens, u, u_prev, wp, wu, wr, hessian, gradient):
    """:class:`~trustnav.control.costs.PositionTrackingCost`'s Gauss-Newton model in one compiled
    pass: cost wp sum ||p(k+1) - x_bar(k+1)||^2 + wu sum ||u(k)||^2 + wr sum ||u(k) - u(k-1)||^2,
    H = 2 J' W J + 1e-9 I and gradient 2 J' W r in place (positions' Jacobian from ``sens``)."""
    n_h, nu = u.shape
    n = n_h * nu
    cost = 0.0
    for i in range(n):
        gradient[i] = 0.0
        for j in range(n):
            hessian[i, j] = 0.0
    for k in range(n_h):
        for d in range(2):
            r = xs[k + 1, d] - stage[k, d]
            cost += wp * r * r
            for i in range(n):
                s_i = sens[k + 1, d, i]
                if s_i == 0.0:
                    continue
                gradient[i] += 2.0 * wp * s_i * r
                for j in range(n):
                    hessian[i, j] += 2.0 * wp * s_i * sens[k + 1, d, j]
        for d in range(nu):
            i = k * nu + d
            cost += wu * u[k, d] * u[k, d]
            gradient[i] += 2.0 * wu * u[k, d]
            hessian[i, i] += 2.0 * wu
            prev = u_prev[d] if k == 0 else u[k - 1, d]
            rate = u[k, d] - prev
            cost += wr * rate * rate
            gradient[i] += 2.0 * wr * rate  # d rate_k / d u_k = 1, d rate_{k+1} / d u_k = -1
            hessian[i, i] += 2.0 * wr
            if k > 0:
                gradient[i - nu] -= 2.0 * wr * rate
                hessian[i - nu, i - nu] += 2.0 * wr
                hessian[i, i - nu] -= 2.0 * wr
                hessian[i - nu, i] -= 2.0 * wr
    for i in range(n):
        hessian[i, i] += 1e-9
    return cost
