"""Deadlock resolution: a route layer above the MPC that takes a wedged vehicle around a group.

A CBF controller that tracks a velocity toward its goal stops for good in front of pedestrians
whose barriers together cancel every forward motion: two static pedestrians less than 2R apart
across its path, or a few standing just beyond R ahead (Grover et al. analyse these equilibria of
CBF-QPs; their resolution adds motion along the barrier's boundary). Here the constraints are not
touched, so safety is exactly the MPC's: the layer only moves the goal the cost tracks.

- **Wedged**: the vehicle has been slower than ``stall_speed`` for ``stall_time`` while its goal is
  further than ``reach`` and a pedestrian ahead is within R + ``clearance``.
- **Detour**: the pedestrians ahead within ``group_radius`` R are one group. For each side of the
  line to the goal, a waypoint beside the group's outermost member on that side, R + ``clearance``
  out, level with the group; the side with the shorter detour whose waypoint lies outside every
  pedestrian's R + ``clearance`` is taken. The cost then tracks the waypoint until the vehicle is
  within ``reach`` of it (or ``max_detour_time`` passes), then the goal again.
- **No room**: when neither waypoint is free the vehicle waits, and each step says so
  (:attr:`DeadlockResolver.note`), until the pedestrians move.

Applies to costs that track a goal with a planar velocity (``VelocityTrackingCost``: the single
integrator of the paper's Section III); a vehicle on a lane (``LaneTrackingCost``) yields and waits
instead. The paper's scenario presets run without it (``MpcConfig(deadlock=None)``), as the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["DeadlockConfig", "DeadlockResolver"]


@dataclass(frozen=True)
class DeadlockConfig:
    """Thresholds of :class:`DeadlockResolver` (module docstring); speeds in m/s, times in s,
    distances in m, ``group_radius`` in units of R."""

    stall_speed: float = 0.1
    stall_time: float = 0.5
    clearance: float = 1.0
    reach: float = 0.5
    max_detour_time: float = 10.0
    group_radius: float = 2.5

    def __post_init__(self) -> None:
        for name in ("stall_speed", "stall_time", "clearance", "reach", "max_detour_time", "group_radius"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < math.inf:
                raise ValueError(f"deadlock {name} must be a positive finite number, got {v!r}")


class DeadlockResolver:
    """Per-controller memory of the route layer: call :meth:`goal` once per control step."""

    def __init__(self, config: DeadlockConfig, dt: float) -> None:
        self.config = config
        self.dt = dt
        self.reset()

    def reset(self) -> None:
        self._stalled = 0.0
        self._route: list[NDArray[np.float64]] = []  # waypoints still to reach, in order
        self._detour_for = 0.0
        self.note: str | None = None  # what the layer did on the latest step (None: nothing)

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
        self.note = None
        to_goal = goal - position
        dist_goal = float(np.hypot(*to_goal))
        if self._route:
            self._detour_for += self.dt
            if float(np.hypot(*(self._route[0] - position))) <= c.reach:
                self._route.pop(0)
            if not self._route or self._detour_for > c.max_detour_time or dist_goal <= c.reach:
                self._route = []
            else:
                self.note = "wedged: going around the pedestrians ahead"
                return self._route[0]
        if dist_goal <= c.reach or len(pedestrians) == 0:
            self._stalled = 0.0
            return None
        ahead_dir = to_goal / dist_goal
        rel = pedestrians - position
        dist = np.hypot(rel[:, 0], rel[:, 1])
        ahead = (rel @ ahead_dir > 0) & (dist <= radii + c.clearance)
        if speed >= c.stall_speed or not ahead.any():
            self._stalled = 0.0
            return None
        self._stalled += self.dt
        if self._stalled < c.stall_time:
            return None
        route = self._detour(position, ahead_dir, pedestrians, radii)
        if route is None:
            self.note = "wedged with no room to go around: waiting for the pedestrians to move"
            return None
        self._route, self._detour_for, self._stalled = route, 0.0, 0.0
        self.note = "wedged: going around the pedestrians ahead"
        return route[0]

    def _detour(
        self,
        position: NDArray[np.float64],
        ahead_dir: NDArray[np.float64],
        pedestrians: NDArray[np.float64],
        radii: NDArray[np.float64],
    ) -> list[NDArray[np.float64]] | None:
        """Waypoints around the group ahead: beside it on the side with the shorter detour, straight
        there when the way is clear, else after backing out of the notch the vehicle sits in; every
        leg of the route keeps out of every pedestrian's R."""
        c = self.config
        normal = np.array([-ahead_dir[1], ahead_dir[0]])
        rel = pedestrians - position
        along, across = rel @ ahead_dir, rel @ normal
        r_max = float(radii.max())
        group = (along > -r_max) & (np.hypot(along, across) <= c.group_radius * r_max)
        if not group.any():
            return None
        dist = np.hypot(along, across)
        close = (dist <= radii + c.clearance) & (along > -r_max)
        away = -ahead_dir
        if close.any():  # back out along the direction that leaves every close pedestrian
            pull = (rel[close] / dist[close, None]).mean(axis=0)
            if float(np.hypot(*pull)) > 1e-3:
                away = -pull / float(np.hypot(*pull))
        start = position + r_max * away  # out of the notch before moving sideways
        level = float(along[group].max())  # beside the group's far member
        options = []
        for side in (1.0, -1.0):
            out = float((side * across[group] + radii[group]).max()) + c.clearance
            beside = position + level * ahead_dir + side * out * normal
            for route, extra in (([beside], 0.0), ([start, start + side * out * normal, beside], 2.0 * r_max)):
                legs = zip([position, *route[:-1]], route, strict=True)
                free = all(bool((np.hypot(*(pedestrians - w).T) >= radii + c.clearance - 1e-6).all()) for w in route)
                if free and all(_clear(a, b, pedestrians, radii) for a, b in legs):
                    options.append((out + extra, side, route))
        if not options:
            return None
        return min(options, key=lambda o: (o[0], -o[1]))[2]


def _clear(a: NDArray[np.float64], b: NDArray[np.float64], pedestrians: NDArray[np.float64],
           radii: NDArray[np.float64]) -> bool:  # fmt: skip
    """No pedestrian's R reaches the straight leg a -> b (the leg may start at R, as a wedged
    vehicle does: only pedestrians the leg comes closer to than where it starts count)."""
    ab = b - a
    n2 = float(ab @ ab)
    t = np.clip(((pedestrians - a) @ ab) / n2, 0.0, 1.0) if n2 > 0 else np.zeros(len(pedestrians))
    closest = np.hypot(*(pedestrians - (a + t[:, None] * ab)).T)
    start = np.hypot(*(pedestrians - a).T)
    return bool(((closest >= radii) | (closest >= start - 1e-9)).all())
