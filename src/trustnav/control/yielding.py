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
- **An uncertain velocity** (``covariances``: the estimates' covariances of (x, y, v_x, v_y), whose
  sigma of the speed across the road counts; ``z``: the one-sided quantile of the controller's
  confidence) enters
  the judgement "the car is past them well before they block" on the unsafe side: their blocking
  is taken to begin when it would at their estimated velocity raised by z sigma toward the road's
  line (a velocity estimated from a frame or two lags a step-out), so the car passes in front
  only if it would at that speed too. Who blocks is judged at the estimated velocity, as the MPC
  predicts: the bound never makes someone standing at the kerb a crosser.

Applies to a car that follows a lane (``LaneTrackingCost``) with a ``RoadEdgeBarrier``. Without road
edges the car may swerve round anyone (the paper's Section IV controller) and the layer is idle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from trustnav.control._validate import require_positive

__all__ = ["YieldConfig", "YieldDecision", "Yielder"]

_NO_COVARIANCES = np.zeros((0, 4, 4))


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
        covariances: NDArray[np.float64] | None = None,
        z: float = 1.645,
    ) -> YieldDecision | None:
        """The stop for the nearest pedestrian the car must yield to, or None (drive on).

        position (2,) and speed of the car; its lane ``lane_start -> lane_goal``; the road's line
        through ``road_start`` with unit ``road_normal`` (left of the driving direction) and the
        room (left, right) the car's centre has from it; pedestrians and velocities (N, 2); radii
        (N,) (R plus any uncertainty margin); ``covariances`` (N, 4, 4) of each estimated (x, y, v_x,
        v_y) (None: the velocities are taken as exact) and ``z`` the quantile of its velocity."""
        c = self.config
        if len(pedestrians) == 0:
            return None
        axis = np.array([road_normal[1], -road_normal[0]])  # the driving direction
        left, right = room
        s_car = float((position - road_start) @ axis)
        cov = _NO_COVARIANCES if covariances is None else np.ascontiguousarray(covariances, dtype=float)
        if cov.shape[0] and cov.shape != (len(pedestrians), 4, 4):
            raise ValueError(f"covariances must have shape ({len(pedestrians)}, 4, 4), got {cov.shape}")
        stop_s, j = _blocking(
            np.ascontiguousarray(pedestrians, dtype=float), np.ascontiguousarray(velocities, dtype=float),
            np.ascontiguousarray(radii, dtype=float), np.ascontiguousarray(road_start, dtype=float), axis,
            np.ascontiguousarray(road_normal, dtype=float), float(left), float(right), s_car, float(c.lookahead),
            float(c.sample), float(c.crossing_speed), float(c.tolerance), float(c.clear_time), float(c.gap),
            max(float(speed), 0.1), cov, float(z),
        )  # fmt: skip
        best = None if j < 0 else (stop_s, j)
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


@njit(cache=True)
def _blocking(peds, vels, radii, road_start, axis, normal, left, right, s_car, lookahead, sample, crossing, tol,
              clear_time, gap, v, cov, z):  # fmt: skip
    """The nearest stop (along the road) for a pedestrian who blocks the corridor ahead within the
    lookahead, and who it is ((0, -1): none); one compiled pass of :meth:`Yielder.decide`'s test:
    sampled every ``sample`` s at constant velocity, a pedestrian blocks where they are within their
    radius of the corridor, ahead of the car, and leave no room on either side (a walker crossing
    toward a side closes it); one the car passes well before they block, at their estimated
    velocity and at it raised by z sigma (its component across the road, from ``cov`` (N, 4, 4);
    none where ``cov`` is empty) toward the road's line, is skipped."""
    ts = np.arange(0.0, lookahead + 1e-9, sample)
    n_t = ts.shape[0]
    s = np.empty(n_t)
    best_stop, best_j = 0.0, -1
    for j in range(peds.shape[0]):
        r = radii[j]
        v_lat = vels[j, 0] * normal[0] + vels[j, 1] * normal[1]
        walks_left = v_lat > crossing
        walks_right = v_lat < -crossing
        d0 = (peds[j, 0] - road_start[0]) * normal[0] + (peds[j, 1] - road_start[1]) * normal[1]
        toward = -1.0 if d0 > 0.0 else 1.0
        first = -1
        low = np.inf
        begins = np.inf  # the earliest blocking of either velocity
        fast = 0.0
        for h in range(2):
            if h == 1:
                if first <= 0 or cov.shape[0] == 0:
                    break
                var = (cov[j, 2, 2] * normal[0] * normal[0] + 2.0 * cov[j, 2, 3] * normal[0] * normal[1]
                       + cov[j, 3, 3] * normal[1] * normal[1])  # fmt: skip
                fast = z * math.sqrt(max(var, 0.0))  # only where the estimated velocity leaves the car first
                if not fast > 0.0:
                    break
            vx = vels[j, 0] + toward * fast * normal[0]
            vy = vels[j, 1] + toward * fast * normal[1]
            for k in range(n_t):
                px = peds[j, 0] + vx * ts[k] - road_start[0]
                py = peds[j, 1] + vy * ts[k] - road_start[1]
                sk = px * axis[0] + py * axis[1]
                if h == 0:
                    s[k] = sk
                d = px * normal[0] + py * normal[1]
                room_left = (d + r <= left - tol) and not walks_left
                room_right = (d - r >= -right + tol) and not walks_right
                near = (d - r < left) and (d + r > -right)
                if near and sk > s_car and not room_left and not room_right:
                    begins = min(begins, ts[k])
                    if h == 1:
                        break
                    if first < 0:
                        first = k
                    low = min(low, sk)
        if first < 0:
            continue
        if first > 0:
            top = s[0]
            for k in range(1, first):
                top = max(top, s[k])
            if (top + r - s_car) / v + clear_time <= begins:
                continue  # the car is past them well before they block
        stop = low - r - gap
        if best_j < 0 or stop < best_stop:
            best_stop, best_j = stop, j
    return best_stop, best_j
