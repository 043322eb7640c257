"""Yielding: a layer above the MPC that makes a car on a road brake and wait for pedestrians it cannot pass.

A car on a lane with the road's edges as barriers (:class:`~trustnav.control.barrier.RoadEdgeBarrier`)
cannot swerve round a pedestrian who stands or walks in the middle of the road: keeping R would
take it off the road. The MPC alone, looking a horizon of about half a second ahead, finds that out
when it is too late to brake. This layer looks further, with the same constant-velocity prediction
as the MPC, and moves the point the lane cost tracks to a stop short of such a pedestrian, so the
car slows in time, waits, and goes on when the way is clear. It never touches the constraints:
safety is exactly the MPC's.

For each pedestrian, predicted every ``sample`` s over ``lookahead`` s (lateral offset ``d`` from
the road's line, ``r`` its R plus any uncertainty margin; the car's centre may use
``[-room_right, room_left]``):

- **A side to pass on** has room when the car's centre can be ``r`` from the pedestrian there and
  stay on the road (``d + r <= room_left - tolerance`` on the left, ``d - r >= -room_right +
  tolerance`` on the right). A pedestrian crossing the road (lateral speed above ``crossing_speed``)
  is passed behind, never on the side they walk toward.
- **Blocking**: no side to pass on, while the pedestrian is within ``r`` of the corridor and ahead
  of the car's centre (beside or behind it, braking would stop the car next to them: the MPC's
  barrier keeps R there).
- **Yield** to a blocking pedestrian unless the car, at its present speed, has passed them
  ``clear_time`` s before their blocking begins. The stop is ``r + gap`` short of the nearest place
  the pedestrian blocks; the speed is capped to brake there at ``deceleration``.

Applies to a car that follows a lane (``LaneTrackingCost``) with a ``RoadEdgeBarrier``. Without road
edges the car may swerve round anyone (the paper's Section IV controller) and the layer is idle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from trustnav.control._validate import require_positive

__all__ = ["YieldConfig", "YieldDecision", "Yielder"]


@dataclass(frozen=True)
class YieldConfig:
    """Thresholds of :class:`Yielder` (module docstring); times in s, distances in m, speeds in
    m/s, ``deceleration`` in m/s^2."""

    lookahead: float = 4.0
    sample: float = 0.25
    deceleration: float = 3.0
    gap: float = 1.0
    tolerance: float = 0.1
    crossing_speed: float = 0.3
    clear_time: float = 1.0

    def __post_init__(self) -> None:
        names = ("lookahead", "sample", "deceleration", "gap", "tolerance", "crossing_speed", "clear_time")
        require_positive("yielding", self, names)


@dataclass(frozen=True)
class YieldDecision:
    """Where the car must stop (``stop``: a point on its lane), the speed cap that brakes there, the
    pedestrian it yields to (index into this step's pedestrians) and a note for the step's report."""

    stop: NDArray[np.float64]
    speed_cap: float
    pedestrian: int
    note: str


class Yielder:
    """Stateless per step: call :meth:`decide` with the step's car and pedestrians."""

    def __init__(self, config: YieldConfig) -> None:
        self.config = config

    def decide(
        self,
        position: NDArray[np.float64],
        speed: float,
        lane_start: NDArray[np.float64],
        lane_goal: NDArray[np.float64],
        road_start: NDArray[np.float64],
        road_normal: NDArray[np.float64],
        room: tuple[float, float],
        pedestrians: NDArray[np.float64],
        velocities: NDArray[np.float64],
        radii: NDArray[np.float64],
    ) -> YieldDecision | None:
        """The stop for the nearest pedestrian the car must yield to, or None (drive on).

        position (2,) and speed of the car; its lane ``lane_start -> lane_goal``; the road's line
        through ``road_start`` with unit ``road_normal`` (left of the driving direction) and the
        room (left, right) the car's centre has from it; pedestrians and velocities (N, 2); radii
        (N,) (R plus any uncertainty margin)."""
        c = self.config
        if len(pedestrians) == 0:
            return None
        axis = np.array([road_normal[1], -road_normal[0]])  # the driving direction
        left, right = room
        ts = np.arange(0.0, c.lookahead + 1e-9, c.sample)  # (T,)
        pred = pedestrians[:, None, :] + velocities[:, None, :] * ts[None, :, None]  # (N, T, 2)
        s = (pred - road_start) @ axis  # along the road (N, T)
        d = (pred - road_start) @ road_normal  # left of the line (N, T)
        s_car = float((position - road_start) @ axis)
        r = radii[:, None]
        v_lat = velocities @ road_normal  # (N,)
        walks_left = (v_lat > c.crossing_speed)[:, None]
        walks_right = (v_lat < -c.crossing_speed)[:, None]
        room_left = (d + r <= left - c.tolerance) & ~walks_left  # pass on their left: behind a walker going right
        room_right = (d - r >= -right + c.tolerance) & ~walks_right
        near = (d - r < left) & (d + r > -right)  # within r of the corridor
        ahead = s > s_car  # beside or behind the car is the MPC's: stopping there helps no one
        blocking = near & ahead & ~room_left & ~room_right  # (N, T)
        best: tuple[float, int] | None = None
        v = max(speed, 0.1)
        for j in np.flatnonzero(blocking.any(axis=1)):
            k0 = int(np.argmax(blocking[j]))  # the first sample at which j blocks
            if k0 > 0 and (float(s[j, :k0].max()) + radii[j] - s_car) / v + c.clear_time <= ts[k0]:
                continue  # the car is past them well before they block
            stop = float(s[j, blocking[j]].min()) - radii[j] - c.gap
            if best is None or stop < best[0]:
                best = (stop, int(j))
        if best is None:
            return None
        stop_s, j = best
        room_to_stop = max(stop_s - s_car, 0.0)
        cap = math.sqrt(2.0 * c.deceleration * room_to_stop)
        lane = lane_goal - lane_start
        length = float(np.hypot(*lane))
        lane_dir = lane / length
        s_lane = float((position - lane_start) @ lane_dir)  # the car on its lane
        along = s_lane + (stop_s - s_car) / max(float(axis @ lane_dir), 1e-6)
        along = float(np.clip(along, min(0.01, length), length))  # never the lane's start: a lane needs a length
        stop = lane_start + along * lane_dir
        if room_to_stop > 0:
            note = f"yielding: stopping {room_to_stop:.1f} m ahead for a pedestrian the car cannot pass on the road"
        else:
            note = "yielding: waiting for a pedestrian the car cannot pass on the road"
        return YieldDecision(stop, cap, j, note)
