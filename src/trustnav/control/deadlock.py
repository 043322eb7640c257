"""Deadlock resolution: a route layer above the MPC that takes a wedged vehicle around pedestrians.

A CBF controller that tracks a velocity toward its goal stops for good in front of pedestrians
whose barriers together cancel every forward motion: two static pedestrians less than 2R apart
across its path, a pocket with pedestrians on three sides, a few standing just beyond R ahead
(Grover et al. analyse these equilibria of CBF-QPs; their resolution adds motion along the
barrier's boundary). Here the constraints are not touched, so safety is exactly the MPC's: the
layer only moves the goal the cost tracks.

- **Wedged**: the vehicle has been slower than ``stall_speed`` for ``stall_time`` while its goal is
  further than ``reach`` and a pedestrian ahead is within R + ``clearance``.
- **Route**: a shortest path to the goal on a grid of ``cell`` m over the box around the vehicle and
  the goal widened by ``search_margin`` (Dijkstra on the grid graph, 8 neighbours). Cells inside any
  pedestrian's R are closed; cells within ``clearance`` of an R cost up to ``1 + proximity_cost``
  times their length, so the route keeps its distance where it can and squeezes through where it
  must. The path is cut to a few waypoints: each straight leg keeps at least the clearance the
  grid path had along it.
- **Following**: the cost tracks the first waypoint; a waypoint is dropped when the vehicle is within
  ``reach`` of it or the next one (the goal after the last) is in sight, clear of every
  pedestrian's R by ``clearance`` / 2, so corners are cut as soon as they can be. A route that makes
  no progress for ``max_detour_time`` is dropped, and planned again if the vehicle is still wedged.
- **No room**: when no route exists inside the box the vehicle waits, and each step says so
  (:attr:`DeadlockResolver.note`); the route is searched again every ``stall_time`` until the
  pedestrians move.

Applies to costs that track a goal with a planar velocity (``VelocityTrackingCost``: the single
integrator of the paper's Section III); a vehicle on a lane (``LaneTrackingCost``) yields and waits
instead. The paper's scenario presets run without it (``MpcConfig(deadlock=None)``), as the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from trustnav.control._validate import require_positive

__all__ = ["DeadlockConfig", "DeadlockResolver", "plan_route"]

MAX_CELLS = 80_000  # the grid is coarsened beyond this many cells (planning stays a few ms)


@dataclass(frozen=True)
class DeadlockConfig:
    """Thresholds of :class:`DeadlockResolver` (module docstring); speeds in m/s, times in s,
    distances in m."""

    stall_speed: float = 0.1
    stall_time: float = 0.5
    clearance: float = 1.0
    reach: float = 0.5
    max_detour_time: float = 10.0
    search_margin: float = 15.0
    cell: float = 0.25
    proximity_cost: float = 4.0

    def __post_init__(self) -> None:
        names = ("stall_speed", "stall_time", "clearance", "reach", "max_detour_time", "search_margin", "cell")
        require_positive("deadlock", self, (*names, "proximity_cost"), zero_ok=("proximity_cost",))


class DeadlockResolver:
    """Per-controller memory of the route layer: call :meth:`goal` once per control step."""

    def __init__(self, config: DeadlockConfig, dt: float) -> None:
        self.config = config
        self.dt = dt
        self.reset()

    def reset(self) -> None:
        self._stalled = 0.0
        self._route: list[NDArray[np.float64]] = []  # waypoints still to reach, in order
        self._since_progress = 0.0
        self._next_search = 0.0  # stall time at which a route is searched for again
        self.note: str | None = None  # what the layer did on the latest step (None: nothing)

    def idle(self, speed: float) -> bool:
        """True, with :meth:`goal`'s bookkeeping for it done, when :meth:`goal` would return None at
        once: the vehicle moves (``speed`` of its last command) and follows no route. False, with
        nothing changed, otherwise."""
        if self._route or speed < self.config.stall_speed:
            return False
        self.note = None
        self._stalled = self._next_search = 0.0
        return True

    def goal(
        self,
        position: NDArray[np.float64],
        speed: float,
        goal: NDArray[np.float64],
        pedestrians: NDArray[np.float64],
        radii: NDArray[np.float64],
    ) -> NDArray[np.float64] | None:
        """The point the cost should track this step instead of ``goal`` (None: the goal itself).

        position: the vehicle's (2,); speed: of its last command; pedestrians (N, 2) and their radii
        (N,) (R plus any uncertainty margin)."""
        c = self.config
        if self.idle(speed):  # moving and on no route: nothing to do (the common case)
            return None
        self.note = None
        dist_goal = float(np.hypot(*(goal - position)))
        if self._route:
            if dist_goal <= c.reach:
                self._route = []
            else:
                self._since_progress += self.dt
                if self._advance(position, goal, pedestrians, radii):
                    self._since_progress = 0.0
                if self._since_progress > c.max_detour_time:
                    self._route = []
                if self._route:
                    self.note = "wedged: going around the pedestrians ahead"
                    return self._route[0]
        if dist_goal <= c.reach or len(pedestrians) == 0:
            self._stalled = self._next_search = 0.0
            return None
        rel = pedestrians - position
        dist = np.hypot(rel[:, 0], rel[:, 1])
        ahead = (rel @ (goal - position) > 0) & (dist <= radii + c.clearance)
        if speed >= c.stall_speed or not ahead.any():
            self._stalled = self._next_search = 0.0
            return None
        self._stalled += self.dt
        if self._stalled < c.stall_time:
            return None
        if self._stalled + 1e-9 < self._next_search:  # no room a moment ago: keep waiting
            self.note = "wedged with no room to go around: waiting for the pedestrians to move"
            return None
        route = plan_route(position, goal, pedestrians, radii, c)
        if route is None:
            self._next_search = self._stalled + c.stall_time
            self.note = "wedged with no room to go around: waiting for the pedestrians to move"
            return None
        self._route, self._since_progress, self._stalled, self._next_search = route, 0.0, 0.0, 0.0
        self._advance(position, goal, pedestrians, radii)
        if not self._route:  # the goal is in sight after all: the MPC alone will do
            return None
        self.note = "wedged: going around the pedestrians ahead"
        return self._route[0]

    def _advance(self, position, goal, pedestrians, radii) -> bool:
        """Drop the waypoints reached or passed (the one after, or the goal, is in sight); True if any."""
        c, dropped = self.config, False
        while self._route:
            after = self._route[1] if len(self._route) > 1 else goal
            near = float(np.hypot(*(self._route[0] - position))) <= c.reach
            if near or _clear(position, after, pedestrians, radii + 0.5 * c.clearance):
                self._route.pop(0)
                dropped = True
            else:
                break
        return dropped


def plan_route(
    position: NDArray[np.float64],
    goal: NDArray[np.float64],
    pedestrians: NDArray[np.float64],
    radii: NDArray[np.float64],
    config: DeadlockConfig,
) -> list[NDArray[np.float64]] | None:
    """Waypoints from ``position`` to ``goal`` (the goal itself excluded) that keep out of every
    pedestrian's R, through the box around both widened by ``config.search_margin``; None when no
    such route exists in the box (module docstring: **Route**)."""
    c = config
    lo = np.minimum(position, goal) - c.search_margin
    hi = np.maximum(position, goal) + c.search_margin
    cell = max(c.cell, math.sqrt(float(np.prod(hi - lo)) / MAX_CELLS))
    nx, ny = (np.ceil((hi - lo) / cell).astype(int) + 1).tolist()
    xs, ys = lo[0] + cell * np.arange(nx), lo[1] + cell * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")  # (nx, ny)
    reach = radii[:, None] + c.clearance
    near = np.all((pedestrians >= lo - reach) & (pedestrians <= hi + reach), axis=1)
    margin = np.full((nx, ny), np.inf)
    for p, r in zip(pedestrians[near], radii[near], strict=True):
        np.minimum(margin, np.hypot(gx - p[0], gy - p[1]) - r, out=margin)
    end = _cell_of(goal, lo, cell, nx, ny)
    free = margin >= 0.0
    if not free[end]:
        return None
    weight = 1.0 + c.proximity_cost * np.clip((c.clearance - margin) / c.clearance, 0.0, 1.0)
    n = nx * ny
    idx = np.arange(n).reshape(nx, ny)
    rows, cols, vals = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = (slice(0, nx - di), slice(max(0, -dj), ny - max(0, dj)))
        b = (slice(di, nx), slice(max(0, dj), ny + min(0, dj)))
        ok = free[a] & free[b]
        w = cell * math.hypot(di, dj) * 0.5 * (weight[a] + weight[b])
        rows.append(idx[a][ok])
        cols.append(idx[b][ok])
        vals.append(w[ok])
    # the vehicle is node n, joined to the free cells around it that it reaches in a straight line
    # (a wedged vehicle sits at R, where the cells nearest to it may be inside some R)
    si, sj = _cell_of(position, lo, cell, nx, ny)
    around = idx[max(0, si - 2) : si + 3, max(0, sj - 2) : sj + 3].ravel()
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    links = [k for k in around if free.ravel()[k] and _clear(position, xy[k], pedestrians, radii)]
    if not links:
        return None
    rows.append(np.full(len(links), n))
    cols.append(np.array(links))
    vals.append(np.hypot(*(xy[links] - position).T) * weight.ravel()[links] + 1e-9)
    r_, c_, v_ = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    graph = coo_matrix((v_, (r_, c_)), shape=(n + 1, n + 1)).tocsr()
    e = int(idx[end])
    dist, pred = dijkstra(graph, directed=False, indices=n, return_predecessors=True)
    if not math.isfinite(dist[e]):
        return None
    nodes = [e]
    while nodes[-1] != n:
        nodes.append(int(pred[nodes[-1]]))
    nodes.reverse()
    pts = np.vstack([position, xy[nodes[1:]]])
    pts[-1] = goal
    keep = np.append(margin.ravel(), 0.0)[nodes]
    route, i = [], 0
    while i < len(pts) - 1:  # the farthest node each straight leg reaches without losing clearance
        j = i + 1
        while j + 1 < len(pts):
            lost = max(0.0, min(c.clearance, float(keep[i + 1 : j + 2].min()) - 0.5 * cell))
            if not _clear(pts[i], pts[j + 1], pedestrians, radii + lost):
                break
            j += 1
        route.append(pts[j].copy())
        i = j
    return route[:-1]


def _cell_of(point, lo, cell, nx, ny) -> tuple[int, int]:
    i = int(np.clip(round((point[0] - lo[0]) / cell), 0, nx - 1))
    j = int(np.clip(round((point[1] - lo[1]) / cell), 0, ny - 1))
    return i, j


def _clear(a: NDArray[np.float64], b: NDArray[np.float64], pedestrians: NDArray[np.float64],
           radii: NDArray[np.float64]) -> bool:  # fmt: skip
    """No pedestrian's ``radii`` reaches the straight leg a -> b (the leg may start inside it, as a
    wedged vehicle does: only pedestrians the leg comes closer to than where it starts count)."""
    ab = b - a
    n2 = float(ab @ ab)
    t = np.clip(((pedestrians - a) @ ab) / n2, 0.0, 1.0) if n2 > 0 else np.zeros(len(pedestrians))
    closest = np.hypot(*(pedestrians - (a + t[:, None] * ab)).T)
    start = np.hypot(*(pedestrians - a).T)
    return bool(((closest >= radii) | (closest >= start - 1e-9)).all())
