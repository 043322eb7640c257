"""Coordinates between trustnav's scenarios and CARLA, in one place; and CARLA's camera buffer.

CARLA's world frame is left-handed: x forward, y right, z up (seen from above with z toward the
viewer, +y is clockwise from +x); its yaw is in degrees and turns +x toward +y. trustnav's frame is
right-handed: x, y on the ground, z up, yaw in radians counter-clockwise from +x (+x toward +y).

The paper's positions (Case I: ego (33.5, 129) -> (33.5, 75), pedestrians at (29.5, 101) and
(37.5, 101)) are CARLA map coordinates read off the simulator, and trustnav's scenarios use the
same numbers. So by default (:class:`MapFrame` ``flip_y=False``, "paper") a scenario's numbers
*are* CARLA's: ``carla (x, y) = (x, y)``, ``carla yaw = degrees(yaw)``; the car spawns where the
authors' did, and the bicycle model's numbers are the same in both (a positive steer angle turns
+x toward +y in both). Read right-handed, such a scene is the mirror image of what CARLA shows,
which matters only for geometry a camera sees; that geometry always goes through the physical
frame :func:`carla_to_physical` (y negated, yaw negated), where trustnav's camera model projects
exactly as CARLA's camera does.

``flip_y=True`` ("physical") places the scenario as trustnav's own world draws it: ``carla y =
-y``, ``carla yaw = -degrees(yaw)``; the layout is then the same as in trustnav's renders (the
attentive pedestrian on the car's right in Case I), at CARLA y = -129 .. -75.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MapFrame", "bgra_to_rgb", "carla_camera_project", "carla_to_physical", "physical_yaw"]


@dataclass(frozen=True)
class MapFrame:
    """Scenario coordinates <-> CARLA world coordinates (see the module's docstring).

    ``flip_y``: False ("paper", default): CARLA numbers = scenario numbers; True ("physical"):
    CARLA y = -y, yaw = -yaw, the same physical layout as trustnav's own world.
    """

    flip_y: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.flip_y, bool):
            raise ValueError(f"flip_y must be a bool, got {self.flip_y!r}")

    @property
    def sign(self) -> float:
        """-1 where y and yaw change sign between the scenario and CARLA, else 1."""
        return -1.0 if self.flip_y else 1.0

    def to_carla(self, x: float, y: float, z: float = 0.0) -> tuple[float, float, float]:
        """A scenario point (m) -> CARLA location (m)."""
        _finite("point", x, y, z)
        return float(x), self.sign * float(y), float(z)

    def from_carla(self, x: float, y: float, z: float = 0.0) -> tuple[float, float, float]:
        """A CARLA location (m) -> scenario point (m)."""
        _finite("CARLA location", x, y, z)
        return float(x), self.sign * float(y), float(z)

    def vector_from_carla(self, x: float, y: float) -> tuple[float, float]:
        """A CARLA ground vector (velocity, direction) -> scenario vector."""
        _finite("CARLA vector", x, y)
        return float(x), self.sign * float(y)

    def vector_to_carla(self, x: float, y: float) -> tuple[float, float]:
        """A scenario ground vector -> CARLA vector."""
        _finite("vector", x, y)
        return float(x), self.sign * float(y)

    def yaw_to_carla(self, yaw: float) -> float:
        """Scenario heading (rad, +x toward +y) -> CARLA yaw (degrees, in (-180, 180])."""
        _finite("yaw", yaw)
        return _wrap_deg(self.sign * math.degrees(yaw))

    def yaw_from_carla(self, yaw_deg: float) -> float:
        """CARLA yaw (degrees) -> scenario heading (rad, in (-pi, pi])."""
        _finite("CARLA yaw", yaw_deg)
        return math.radians(_wrap_deg(self.sign * yaw_deg))

    def steer_sign(self) -> float:
        """CARLA steer (+ = right turn = CARLA yaw increasing) per unit scenario steer (+ = yaw
        increasing): equal signs unless y is flipped."""
        return self.sign


def carla_to_physical(x: float, y: float, z: float = 0.0) -> NDArray[np.float64]:
    """A CARLA location -> the right-handed frame of the same physical scene (y negated), where
    trustnav's camera model and bodies live when they stand for what CARLA's camera sees."""
    _finite("CARLA location", x, y, z)
    return np.array([float(x), -float(y), float(z)])


def physical_yaw(yaw_deg: float) -> float:
    """A CARLA yaw (degrees) -> heading (rad) in the right-handed physical frame."""
    _finite("CARLA yaw", yaw_deg)
    return math.radians(_wrap_deg(-yaw_deg))


def carla_camera_project(
    points: ArrayLike,
    camera_xyz: ArrayLike,
    yaw_deg: float,
    pitch_deg: float,
    width: int,
    height: int,
    fov_deg: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project CARLA world points (N, 3) with CARLA's pinhole camera convention: the camera looks
    along its x (forward), y is the image's right, z its up; u = w/2 + f y / x, v = h/2 - f z / x
    with f = w / (2 tan(fov / 2)). Rotation as CARLA's (yaw about z, then pitch up about y; roll 0).
    Returns (uv (N, 2) px, depth (N,) m); uv is NaN behind the camera."""
    p = np.asarray(points, dtype=float).reshape(-1, 3) - np.asarray(camera_xyz, dtype=float).reshape(3)
    cy, sy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    cp, sp = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    forward = np.array([cp * cy, cp * sy, sp])  # CARLA's Rotation.get_forward_vector
    right = np.array([-sy, cy, 0.0])  # CARLA's Rotation.get_right_vector (roll 0)
    up = np.array([-sp * cy, -sp * sy, cp])  # CARLA's Rotation.get_up_vector (roll 0)
    depth = p @ forward
    f = 0.5 * width / math.tan(math.radians(0.5 * fov_deg))
    uv = np.full((len(p), 2), np.nan)
    ok = depth > 1e-9
    uv[ok, 0] = 0.5 * width + f * (p[ok] @ right) / depth[ok]
    uv[ok, 1] = 0.5 * height - f * (p[ok] @ up) / depth[ok]
    return uv, depth


def bgra_to_rgb(raw: bytes | bytearray | memoryview | NDArray[np.uint8], width: int, height: int) -> NDArray[np.uint8]:
    """CARLA's ``sensor.camera.rgb`` buffer (``Image.raw_data``: height x width x 4 bytes, BGRA, rows
    top to bottom) -> an (height, width, 3) RGB array (a copy)."""
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    buf = np.frombuffer(raw, dtype=np.uint8) if not isinstance(raw, np.ndarray) else raw.reshape(-1)
    if buf.size != width * height * 4:
        raise ValueError(f"camera buffer has {buf.size} bytes, expected {width} x {height} x 4 = {width * height * 4}")
    return np.ascontiguousarray(buf.reshape(height, width, 4)[:, :, 2::-1])


def _wrap_deg(a: float) -> float:
    """Degrees wrapped to (-180, 180]."""
    w = math.fmod(a + 180.0, 360.0)
    if w <= 0.0:
        w += 360.0
    return w - 180.0


def _finite(what: str, *values: float) -> None:
    if not all(isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) for v in values):
        raise ValueError(f"{what} must be finite numbers, got {values!r}")
