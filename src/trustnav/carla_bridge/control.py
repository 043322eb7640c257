"""trustnav's command (steer angle rad, acceleration m/s^2) -> CARLA's ``VehicleControl`` pedals.

CARLA takes a normalised steer in [-1, 1] (+1 = the wheels' maximum angle to the right) and
throttle and brake in [0, 1]; it has no acceleration input. The maps, documented and tested:

* steer: ``steer_carla = sign * clip(steer / max_steer, -1, 1)``, ``max_steer`` the largest
  ``max_steer_angle`` of the vehicle's front wheels (its ``get_physics_control()``, degrees), and
  ``sign`` from :meth:`MapFrame.steer_sign` (+1 with the paper's numbers: a positive angle turns
  +x toward +y in both frames).
* throttle/brake, linear in the acceleration asked for, one pedal at a time:
  ``a >= deadband``: throttle = clip((a + drag * v) / full_throttle_accel, 0, 1), brake 0;
  ``a <= -deadband``: brake = clip(-a / full_brake_decel, 0, 1), throttle 0;
  in between: both 0 (coast). ``full_throttle_accel`` is the acceleration full throttle gives at
  low speed, ``full_brake_decel`` the deceleration of full brake, ``drag`` (1/s) adds throttle
  in proportion to speed to hold it against rolling and air resistance. The defaults are rough
  figures for CARLA's passenger cars (not measured here: no server); the MPC closes the loop on
  the measured speed every step, so errors in this map show as tracking error, not instability.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PedalMap", "VehicleCommand", "max_steer_angle", "to_vehicle_command"]


@dataclass(frozen=True)
class PedalMap:
    """Acceleration (m/s^2) -> throttle / brake in [0, 1] (see the module's docstring)."""

    full_throttle_accel: float = 3.5
    full_brake_decel: float = 8.0
    drag: float = 0.02
    deadband: float = 0.05

    def __post_init__(self) -> None:
        for name in ("full_throttle_accel", "full_brake_decel"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number (m/s^2), got {v!r}")
        for name in ("drag", "deadband"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {v!r}")

    def pedals(self, accel: float, speed: float = 0.0) -> tuple[float, float]:
        """(throttle, brake) for acceleration ``accel`` (m/s^2) at ``speed`` (m/s)."""
        if not (math.isfinite(accel) and math.isfinite(speed)):
            raise ValueError(f"accel and speed must be finite, got {accel!r}, {speed!r}")
        if accel >= self.deadband:
            return _clip01((accel + self.drag * max(speed, 0.0)) / self.full_throttle_accel), 0.0
        if accel <= -self.deadband:
            return 0.0, _clip01(-accel / self.full_brake_decel)
        return 0.0, 0.0


@dataclass(frozen=True)
class VehicleCommand:
    """CARLA ``VehicleControl`` fields: steer in [-1, 1], throttle and brake in [0, 1]."""

    steer: float
    throttle: float
    brake: float

    def __post_init__(self) -> None:
        if not -1.0 <= self.steer <= 1.0:
            raise ValueError(f"steer must be in [-1, 1], got {self.steer!r}")
        for name in ("throttle", "brake"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")


def to_vehicle_command(
    steer: float,
    accel: float,
    speed: float,
    max_steer: float,
    pedals: PedalMap | None = None,
    steer_sign: float = 1.0,
) -> VehicleCommand:
    """trustnav's (steer rad, accel m/s^2) at ``speed`` -> CARLA's normalised controls.
    ``max_steer``: the vehicle's maximum road-wheel angle (rad); ``steer_sign`` +-1 from the
    map frame."""
    if not (math.isfinite(max_steer) and 0.0 < max_steer < math.pi / 2):
        raise ValueError(f"max_steer must be in (0, pi/2) rad, got {max_steer!r}")
    if steer_sign not in (1.0, -1.0):
        raise ValueError(f"steer_sign must be +1 or -1, got {steer_sign!r}")
    if not math.isfinite(steer):
        raise ValueError(f"steer must be finite, got {steer!r}")
    throttle, brake = (pedals or PedalMap()).pedals(accel, speed)
    s = max(-1.0, min(1.0, steer / max_steer))
    return VehicleCommand(steer=steer_sign * s + 0.0, throttle=throttle, brake=brake)


def max_steer_angle(wheel_max_steer_deg: list[float]) -> float:
    """The vehicle's maximum steer angle (rad): the largest ``max_steer_angle`` (degrees) among its
    wheels (the front ones steer; rear wheels report 0)."""
    angles = [float(a) for a in wheel_max_steer_deg if math.isfinite(float(a))]
    best = max((abs(a) for a in angles), default=0.0)
    if not 0.0 < best < 90.0:
        raise ValueError(f"no usable wheel max_steer_angle (degrees) in {wheel_max_steer_deg!r}")
    return math.radians(best)


def _clip01(x: float) -> float:
    return max(0.0, min(1.0, x))
