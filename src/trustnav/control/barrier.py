"""Barriers: the paper's `h_quad` (defined once, here), the trust-adaptive discrete CBF rows
`cbf_imp`, and the :class:`Barrier` protocol through which a user adds barriers of their own.

A barrier is a set of m functions h_i(x, k) of the ego state x at horizon step k (so obstacles may
move), safe where h_i >= 0. The problem turns each into the rows of `cbf_discrete`,

    h_i(x(k+1), k+1) - (1 - gamma_i) h_i(x(k), k) >= 0,   k = 0..N_h-1,

from the values and state Jacobians the barrier returns, vectorised over the horizon.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from trustnav.trust.params import as_number

__all__ = [
    "TIMINGS",
    "Barrier",
    "PedestrianBarrier",
    "RoadEdgeBarrier",
    "Timing",
    "barrier",
    "cbf_rows",
    "continuous_time_radius",
    "h_quad",
    "predict_pedestrians",
    "uncertainty_margins",
]

#: Where the pedestrian is taken in the h(k+1) term of `cbf_imp`:
#: "paper": at its predicted position x_p(t+k+1), as the paper writes `cbf_imp` (default);
#: "authors_code": at x_p(t+k) in both terms, as the authors' published code does.
Timing = Literal["paper", "authors_code"]
TIMINGS: tuple[str, ...] = ("paper", "authors_code")


@njit(cache=True)
def h_quad(dx, dy, r2):  # compiled for scalars and arrays alike
    """`h_quad`: phi = ||x_e - x_j||^2 - R^2 for the offset (dx, dy) = x_e - x_j and r2 = R^2.
    Its gradient in x_e is 2 (dx, dy). The one definition every path uses: the compiled QP
    kernels (scalars), :func:`barrier`, :func:`cbf_rows` and :class:`PedestrianBarrier` (arrays)."""
    return dx * dx + dy * dy - r2


@runtime_checkable
class Barrier(Protocol):
    """m barrier functions h_i(x, k) >= 0, each with its decay 1 - gamma_i of `cbf_discrete`.

    ``values`` is vectorised over the horizon: ``states`` (K, n_x) are ego states in world
    coordinates, ``steps`` (K,) their horizon step indices (time t + k dt, for obstacles that
    move) and ``dt`` the step; it returns h (K, m) and dh/dx (K, m, n_x). A barrier is added to a
    controller with ``MpcController(..., barriers=[...])``; nothing else in trustnav changes.
    """

    def size(self) -> int:
        """Number m of barrier functions."""
        ...

    def decay(self) -> NDArray[np.float64]:
        """1 - gamma_i for each function, shape (m,), in [0, 1]."""
        ...

    def values(
        self, states: NDArray[np.float64], steps: NDArray[np.int64], dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...


def barrier(ego: ArrayLike, pedestrians: ArrayLike, radius: float) -> NDArray[np.float64]:
    """`h_quad` between ego position(s) and pedestrians, broadcast over leading axes."""
    d = np.asarray(ego, dtype=float)[..., None, :] - np.asarray(pedestrians, dtype=float)
    return h_quad(d[..., 0], d[..., 1], float(radius) ** 2)


def continuous_time_radius(radius: float, max_relative_speed: float, dt: float) -> float:
    """Margin R' that keeps R between control steps: `cbf_discrete` holds h >= 0 at the steps
    only, and a chord of length c (the relative displacement in one step) whose ends are R' =
    sqrt(R^2 + c^2 / 4) from a pedestrian stays R away from it all along (relative motion linear
    within the step, as for the single integrator and constant-velocity pedestrians; the bicycle's
    arc is within its chord's sagitta of it). c = max_relative_speed * dt: the ego's largest speed
    plus the pedestrians'."""
    for name, value in (("radius", radius), ("max_relative_speed", max_relative_speed), ("dt", dt)):
        as_number(name, value)
    if not 0 < radius < np.inf or not 0 <= max_relative_speed < np.inf or not 0 < dt < np.inf:
        raise ValueError(
            f"need radius > 0, max_relative_speed >= 0 and dt > 0 (finite), got {radius!r}, "
            f"{max_relative_speed!r}, {dt!r}"
        )
    c = float(max_relative_speed) * float(dt)
    return float(np.sqrt(radius * radius + 0.25 * c * c))


def predict_pedestrians(pedestrians: ArrayLike, velocities: ArrayLike, steps: int, dt: float) -> NDArray[np.float64]:
    """Constant-velocity prediction `ped_predict`: positions (steps+1, N_p, 2)."""
    p = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
    v = np.asarray(velocities, dtype=float).reshape(-1, 2)
    k = np.arange(steps + 1, dtype=float)[:, None, None]
    return p[None] + k * dt * v[None]


def cbf_rows(
    ego_positions: ArrayLike,
    pedestrians: ArrayLike,
    velocities: ArrayLike,
    one_minus_gamma: ArrayLike,
    radius: float | ArrayLike,
    dt: float,
    timing: Timing = "paper",
) -> NDArray[np.float64]:
    """Values of the N_h x N_p rows of `cbf_imp`, >= 0 when satisfied.

    row[k, j] = phi(x_e(k+1), x_j(k+1 or k)) - (1 - gamma_j) phi(x_e(k), x_j(k)); ``radius`` is R,
    or one R_j per pedestrian.
    """
    pos = np.asarray(ego_positions, dtype=float)
    n = pos.shape[0] - 1
    q = predict_pedestrians(pedestrians, velocities, n, dt)
    q_next = q[1:] if timing == "paper" else q[:-1]
    r2 = np.broadcast_to(np.asarray(radius, dtype=float) ** 2, (q.shape[1],))
    d_now = pos[:-1, None] - q[:-1]
    d_next = pos[1:, None] - q_next
    h_now = h_quad(d_now[..., 0], d_now[..., 1], r2)
    h_next = h_quad(d_next[..., 0], d_next[..., 1], r2)
    return h_next - np.asarray(one_minus_gamma, dtype=float)[None, :] * h_now


class PedestrianBarrier:
    """The paper's barrier: `h_quad` around each pedestrian, predicted at constant velocity
    (`ped_predict`), with gamma_j from the pedestrian's trust by `weight` (``decay`` = 1 - gamma_j).

    The controller sets its data at every step from the pedestrians it is given; the problem
    fills its rows with a compiled kernel. ``values`` is the same barrier through the
    :class:`Barrier` protocol (reference path, tests). ``radius``: R, or R_j per pedestrian."""

    def __init__(
        self,
        positions: ArrayLike,
        velocities: ArrayLike,
        one_minus_gamma: ArrayLike,
        radius: float | ArrayLike,
    ) -> None:
        self.positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        self.velocities = np.asarray(velocities, dtype=float).reshape(-1, 2)
        self._decay = np.asarray(one_minus_gamma, dtype=float).reshape(-1)
        self.r2 = np.broadcast_to(np.asarray(radius, dtype=float) ** 2, (self.positions.shape[0],)).copy()

    def size(self) -> int:
        return self.positions.shape[0]

    def decay(self) -> NDArray[np.float64]:
        return self._decay

    def values(
        self, states: NDArray[np.float64], steps: NDArray[np.int64], dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        q = self.positions[None] + (np.asarray(steps, dtype=float) * dt)[:, None, None] * self.velocities[None]
        d = np.asarray(states, dtype=float)[:, None, :2] - q  # (K, m, 2)
        h = h_quad(d[..., 0], d[..., 1], self.r2)
        grad = np.zeros((*h.shape, states.shape[1]))
        grad[..., :2] = 2.0 * d
        return h, grad


_QUANTILES: dict[float, float] = {}


def _quantile(confidence: float) -> float:
    """The one-sided normal quantile z of ``confidence`` (remembered: a few per process)."""
    z = _QUANTILES.get(confidence)
    if z is None:
        z = _QUANTILES[confidence] = NormalDist().inv_cdf(confidence)
    return z


@njit(cache=True)
def _margins4(e, p, c, t, z, out):
    """:func:`uncertainty_margins` for (N, 4, 4) covariances: z sqrt(n' S n), S the position
    covariance predicted ``t`` ahead, n the unit line of approach (the largest eigenvalue of S at
    the ego's own position)."""
    for j in range(p.shape[0]):
        s00 = c[j, 0, 0] + t * (c[j, 0, 2] + c[j, 2, 0]) + t * t * c[j, 2, 2]
        s11 = c[j, 1, 1] + t * (c[j, 1, 3] + c[j, 3, 1]) + t * t * c[j, 3, 3]
        s01 = c[j, 0, 1] + t * (c[j, 0, 3] + c[j, 2, 1]) + t * t * c[j, 2, 3]
        s10 = c[j, 1, 0] + t * (c[j, 1, 2] + c[j, 3, 0]) + t * t * c[j, 3, 2]
        off = 0.5 * (s01 + s10)
        dx, dy = e[0] - p[j, 0], e[1] - p[j, 1]
        dist = np.sqrt(dx * dx + dy * dy)
        if dist > 1e-9:
            nx, ny = dx / dist, dy / dist
            var = nx * nx * s00 + 2.0 * nx * ny * off + ny * ny * s11
        else:  # the larger eigenvalue of the symmetric 2 x 2
            mid = 0.5 * (s00 + s11)
            var = mid + np.sqrt(0.25 * (s00 - s11) ** 2 + off * off)
        out[j] = z * np.sqrt(max(var, 0.0))


def uncertainty_margins(
    ego: ArrayLike,
    positions: ArrayLike,
    covariances: ArrayLike,
    lead_time: float,
    confidence: float,
) -> NDArray[np.float64]:
    """Per-pedestrian margins (m) added to R for estimated pedestrian states (measurement-robust
    `h_quad`).

    ``covariances`` (N, 4, 4) of (x, y, v_x, v_y), or (N, 2, 2) of the position only. The position
    error of pedestrian j, predicted ``lead_time`` seconds ahead at constant velocity (the
    horizon plus the latency), has covariance S_j = P_pp + T (P_pv + P_vp) + T^2 P_vv. Only its
    component along the line of approach n_j (unit, pedestrian -> ego) moves the true distance to
    first order, so with probability ``confidence`` the true distance is at least the estimated
    one minus z sqrt(n_j' S_j n_j), z the one-sided normal quantile; keeping the estimated
    distance >= R + that margin keeps the true one >= R (chance-constrained CBF; the
    measurement-robust CBF of Dean et al., CoRL 2020, tightens h by the error bound times
    ||grad h|| = 2 d, the same to first order). At the ego's own position (no direction) the
    largest eigenvalue of S_j is used.
    """
    if not 0.5 <= confidence < 1.0:
        raise ValueError(f"confidence must be in [0.5, 1), got {confidence!r}")
    if not (np.isfinite(lead_time) and lead_time >= 0):
        raise ValueError(f"lead_time must be a finite number of seconds >= 0, got {lead_time!r}")
    e = np.asarray(ego, dtype=float).reshape(-1)[:2]
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    c = np.asarray(covariances, dtype=float)
    n_p = p.shape[0]
    if c.shape not in ((n_p, 4, 4), (n_p, 2, 2)) or not np.all(np.isfinite(c)):
        raise ValueError(f"covariances must be finite, shape ({n_p}, 4, 4) or ({n_p}, 2, 2), got shape {c.shape}")
    if c.shape[1] == 4:  # the common case (a tracker's states): one compiled pass (the same arithmetic)
        out = np.empty(n_p)
        _margins4(np.ascontiguousarray(e), np.ascontiguousarray(p), np.ascontiguousarray(c), float(lead_time),
                  _quantile(confidence), out)  # fmt: skip
        return out
    s = c[:, :2, :2].copy()
    if c.shape[1] == 4:
        t = float(lead_time)
        s += t * (c[:, :2, 2:] + c[:, 2:, :2]) + t * t * c[:, 2:, 2:]
    s = 0.5 * (s + np.transpose(s, (0, 2, 1)))
    d = e[None] - p
    dist = np.linalg.norm(d, axis=1)
    var = np.linalg.eigvalsh(s)[:, -1] if n_p else np.zeros(0)
    ok = dist > 1e-9
    n = d[ok] / dist[ok, None]
    var[ok] = np.einsum("ni,nij,nj->n", n, s[ok], n)
    z = NormalDist().inv_cdf(confidence)
    return z * np.sqrt(np.maximum(var, 0.0))


class RoadEdgeBarrier:
    """The drivable corridor of a straight road as two barrier functions on the ego's position:
    h_left = (w_left - d) and h_right = (d + w_right), where d is the signed lateral offset of the
    position from the line ``start -> end`` (left positive) and w_left, w_right the room on each
    side, less ``margin`` (half the car's width: the body stays on the road). Linear in the
    position, so `cbf_discrete` keeps the car inside when it can; a plan that cannot is relaxed and
    reported like a pedestrian row. ``gamma``: the rate at which the car may approach an edge.

    ``front`` (m, > 0 for a model whose third state is its heading): two more rows keep the point
    ``front`` ahead of the position along the heading on the road too. A car whose centre alone is
    kept could reach the edge turned toward it and stop there, its nose over the kerb, unable to
    drive on without leaving the road (a bicycle does not reverse); with its front kept as well, it
    straightens before it reaches the edge.

    ``turn_radius`` (m, the car's smallest turning radius at the position: wheelbase / tan(steer
    max); 0: the front point alone): the front rows keep on the road the farthest the front
    point reaches while the car turns back from the edge at that radius. Turned toward an edge by
    less than beta = atan(front / turn_radius), the front moves away from the edge as soon as the
    car turns back, and the row is the front point's as above. Turned more, it first swings
    further out, on a circle of radius sqrt(turn_radius^2 + front^2) about the turning centre:
    the row keeps that circle's outermost point on the road, so a car stopped at the row's
    boundary can still leave along the arc (with the front point alone, a car turned past beta
    with its front at the edge can go neither on nor back). Equal to the front point's row, and
    its slope, at beta; the same rows whenever the car is turned less."""

    def __init__(
        self,
        start: ArrayLike,
        end: ArrayLike,
        left: float,
        right: float,
        margin: float = 0.0,
        gamma: float = 0.5,
        front: float = 0.0,
        turn_radius: float = 0.0,
    ) -> None:
        a, b = np.asarray(start, dtype=float).reshape(2), np.asarray(end, dtype=float).reshape(2)
        axis = b - a
        length = float(np.hypot(*axis))
        if not np.isfinite(axis).all() or length <= 0:
            raise ValueError(f"road start and end must be two different finite points, got {start!r}, {end!r}")
        room_left, room_right = float(left) - float(margin), float(right) - float(margin)
        if not (room_left + room_right > 0 and np.isfinite([room_left, room_right]).all()):
            raise ValueError(f"the road leaves no room for the car: left {left}, right {right}, margin {margin}")
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"road gamma must be in (0, 1], got {gamma!r}")
        self.start = a
        self.normal = np.array([-axis[1], axis[0]]) / length  # left of the driving direction
        self.room = (room_left, room_right)
        self.gamma = float(gamma)
        if not (np.isfinite(front) and front >= 0):
            raise ValueError(f"road front must be a finite distance >= 0 m, got {front!r}")
        self.front = float(front)
        if not (np.isfinite(turn_radius) and turn_radius >= 0):
            raise ValueError(f"road turn_radius must be a finite distance >= 0 m, got {turn_radius!r}")
        self.turn_radius = float(turn_radius) if self.front > 0 else 0.0

    def size(self) -> int:
        return 4 if self.front > 0 else 2

    def decay(self) -> NDArray[np.float64]:
        return np.full(self.size(), 1.0 - self.gamma)

    def offset(self, positions: ArrayLike) -> NDArray[np.float64]:
        """Signed lateral offset of positions (..., 2) from the road's line (left positive)."""
        return (np.asarray(positions, dtype=float) - self.start) @ self.normal

    def values(
        self, states: NDArray[np.float64], steps: NDArray[np.int64], dt: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        d = self.offset(states[:, :2])
        rows = [self.room[0] - d, d + self.room[1]]
        grad = np.zeros((states.shape[0], self.size(), states.shape[1]))
        grad[:, 0, :2] = -self.normal
        grad[:, 1, :2] = self.normal
        if self.front > 0:  # the point ``front`` ahead along the heading (state 2)
            yaw = states[:, 2]
            ahead = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
            df = d + self.front * (ahead @ self.normal)
            turn = self.front * (np.stack([-np.sin(yaw), np.cos(yaw)], axis=1) @ self.normal)  # d(df)/d(yaw)
            rows += [self.room[0] - df, df + self.room[1]]
            grad[:, 2, :2], grad[:, 2, 2] = -self.normal, -turn
            grad[:, 3, :2], grad[:, 3, 2] = self.normal, turn
            if self.turn_radius > 0:  # turned past beta: the front's swing on the arc back
                r, f = self.turn_radius, self.front
                lateral = ahead @ self.normal
                along = ahead @ np.array([self.normal[1], -self.normal[0]])
                d_along = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1) @ np.array([self.normal[1], -self.normal[0]])
                swing = math.hypot(r, f) - r * along
                for row, sign in ((2, -1.0), (3, 1.0)):
                    toward = -sign * lateral
                    past = (toward > 0) & (toward * r > f * along)
                    rows[row] = np.where(past, self.room[row - 2] + sign * d - swing, rows[row])
                    grad[past, row, 2] = r * d_along[past]
        return np.stack(rows, axis=1), grad
