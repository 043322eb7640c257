"""Pedestrians who behave (issue 21, item 3): optional scenario data, ``[pedestrian.behaviour]``.

Without a behaviour a pedestrian moves at its constant ``velocity`` from t = 0 (the paper's model,
bit for bit as before). With one it:

* **steps out** at ``start_time`` (s): it stands at ``position`` until then (a sudden step-out when
  it then walks onto the road);
* **walks a path**: ``waypoints`` after ``position``, at ``speed`` (m/s), and stands at the last;
  without waypoints it moves at ``velocity`` (from ``start_time``);
* **waits at the kerb and accepts a gap**: reaching path point ``wait_at`` (0 = ``position``,
  k = ``waypoints[k-1]``) it stands until the car's time to reach that point, along the car's
  heading at its current speed, exceeds ``gap`` (s), or the car is past it, or it has waited
  ``max_wait`` (s); then it goes on. A stopped car (yielding) gives an unbounded gap;
* **looks the part**: ``moving_pose`` (e.g. ``"texting_walk"``, walking while texting) while it
  moves, its ``pose`` while it stands; the body faces where it walks.

The controller still predicts pedestrians with constant velocity (as the paper): the world is
richer than its model. :class:`PedestrianMotion` advances one pedestrian by sub-steps of the plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray

from trustnav.schema import Dotted, Integer, Maybe, Number, OneOf, Pair, Seq, check_fields, load
from trustnav.sim.driving import body

__all__ = ["BehaviourSpec", "PedestrianMotion"]


@dataclass(frozen=True)
class BehaviourSpec:
    """What a pedestrian does (see the module): path, speed, step-out time, kerb wait and gap."""

    waypoints: Annotated[tuple[tuple[float, float], ...], Seq(Pair())] = ()
    speed: Annotated[float, Number(lo=0, lo_open=True, unit=" m/s")] = 1.3
    start_time: Annotated[float, Number(lo=0, unit=" s")] = 0.0
    wait_at: Annotated[int | None, Maybe(Integer(0, note=" (a path index: 0 = position)"))] = None
    gap: Annotated[float, Number(lo=0, unit=" s")] = 4.0
    max_wait: Annotated[float, Number(lo=0, finite=False, unit=" s")] = math.inf
    moving_pose: Annotated[str | None, Maybe(OneOf(*body.POSES), "the standing pose")] = None

    def __post_init__(self) -> None:
        check_fields(self, Dotted("behaviour"))
        if self.wait_at is not None and not self.wait_at < len(self.waypoints):
            raise ValueError(f"behaviour wait_at must index a path point with one after it (0..."
                             f"{len(self.waypoints) - 1}: 0 = position), got {self.wait_at}")  # fmt: skip


class PedestrianMotion:
    """One pedestrian's state in the world: position, velocity, whether it waits; advanced by
    :meth:`advance` with the ego's state (for the gap decision)."""

    def __init__(self, position: tuple[float, float], velocity: tuple[float, float], spec: BehaviourSpec) -> None:
        self.spec = spec
        self.path = np.array([position, *spec.waypoints], dtype=float)
        self.free_velocity = np.asarray(velocity, dtype=float)
        self.position = self.path[0].copy()
        self.velocity = np.zeros(2)
        self.time = 0.0
        self.target = 1  # the next path point
        self.waited = 0.0
        self.crossing = spec.wait_at is None  # gap accepted (or none to wait for)

    @property
    def moving(self) -> bool:
        return bool(np.hypot(*self.velocity) > 1e-9)

    def _gap_ok(self, ego: NDArray[np.float64]) -> bool:
        kerb = self.path[self.spec.wait_at]  # type: ignore[index]
        heading = np.array([math.cos(ego[2]), math.sin(ego[2])])
        ahead = float((kerb - ego[:2]) @ heading)
        if ahead < -1.0:  # the car is past the crossing
            return True
        return ahead / max(float(ego[3]), 1e-3) > self.spec.gap

    def advance(self, h: float, ego: NDArray[np.float64]) -> None:
        """Move ``h`` seconds with the car at ``ego`` (x, y, yaw, v)."""
        s = self.spec
        self.time += h
        if self.time <= s.start_time + 1e-12:
            self.velocity = np.zeros(2)
            return
        if not s.waypoints:
            self.velocity = self.free_velocity.copy()
            self.position = self.position + h * self.velocity
            return
        if self.target >= len(self.path):
            self.velocity = np.zeros(2)
            return
        if not self.crossing and self.target - 1 == s.wait_at:
            if self._gap_ok(ego) or self.waited >= s.max_wait:
                self.crossing = True
            else:
                self.waited += h
                self.velocity = np.zeros(2)
                return
        d = self.path[self.target] - self.position
        dist = float(np.hypot(*d))
        step = s.speed * h
        if step >= dist:  # reach the point (the rest of the step is not carried over)
            self.position = self.path[self.target].copy()
            self.target += 1
        else:
            self.position = self.position + d / dist * step
        self.velocity = d / dist * s.speed if dist > 0 else np.zeros(2)

    def pose(self, standing_pose: str) -> str:
        return self.spec.moving_pose if (self.moving and self.spec.moving_pose) else standing_pose

    def body_yaw(self, standing_yaw: float) -> float:
        return math.atan2(self.velocity[1], self.velocity[0]) if self.moving else standing_yaw


def behaviour_from(v: Any) -> BehaviourSpec | None:
    """A ``[pedestrian.behaviour]`` table (None: none); unknown keys refused with the key meant."""
    if v is None or isinstance(v, BehaviourSpec):
        return v
    return load(BehaviourSpec, v, Dotted("behaviour"))
