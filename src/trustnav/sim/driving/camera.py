"""The ego vehicle's forward camera: mount (scenario data), pose in the world and pinhole projection.

World coordinates are the paper's map coordinates: metres, x/y on the ground, z up, yaw counter-
clockwise from +x. The camera looks along the ego's heading, tilted down by ``pitch_deg``; image
u grows to the right, v downwards, and the optical axis meets the image at its centre
(``width / 2``, ``height / 2``), pixel ``i`` covering ``[i, i + 1)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["NEAR", "CameraPose", "CameraSpec"]

NEAR = 0.1  # metres: nearer points (and those behind) are out of view


@dataclass(frozen=True)
class CameraSpec:
    """Camera intrinsics and its mount on the ego vehicle (the authors' CARLA sensor by default).

    fov_deg is the horizontal field of view; forward and up place the camera relative to the ego
    reference point (along its heading, above the ground); pitch_deg > 0 looks down; rate is the
    frames captured per second (= trust-estimation rate; the authors' ``sensor_tick`` = 1 s).
    """

    width: int = 1280
    height: int = 720
    fov_deg: float = 70.0
    forward: float = 1.5
    up: float = 1.7
    pitch_deg: float = 0.0
    rate: float = 1.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 16 <= value <= 8192:
                raise ValueError(f"{name} must be an integer number of pixels in [16, 8192], got {value!r}")
        if not 1.0 <= self.fov_deg <= 170.0:
            raise ValueError(f"fov_deg must be in [1, 170] degrees, got {self.fov_deg!r}")
        if not math.isfinite(self.forward):
            raise ValueError(f"forward must be finite, got {self.forward!r}")
        if not 0.0 < self.up <= 50.0:
            raise ValueError(f"up must be in (0, 50] metres above the ground, got {self.up!r}")
        if not -80.0 <= self.pitch_deg <= 80.0:
            raise ValueError(f"pitch_deg must be in [-80, 80] degrees, got {self.pitch_deg!r}")
        if not 0.0 < self.rate <= 1000.0:
            raise ValueError(f"rate must be in (0, 1000] frames per second, got {self.rate!r}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        return 0.5 * self.width / math.tan(math.radians(0.5 * self.fov_deg))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal_px))

    def pose(self, ego_xy: ArrayLike, ego_yaw: float) -> CameraPose:
        """The camera in the world for an ego at ``ego_xy`` (metres) heading ``ego_yaw`` (rad)."""
        xy = np.asarray(ego_xy, dtype=float).reshape(-1)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"ego_xy must be two finite numbers, got {ego_xy!r}")
        if not math.isfinite(ego_yaw):
            raise ValueError(f"ego_yaw must be finite, got {ego_yaw!r}")
        c, s = math.cos(ego_yaw), math.sin(ego_yaw)
        position = np.array([xy[0] + self.forward * c, xy[1] + self.forward * s, self.up])
        return CameraPose(self, position, float(ego_yaw), math.radians(self.pitch_deg))


@dataclass(frozen=True, eq=False)
class CameraPose:
    """A camera placed in the world: optical centre, heading and downward pitch (rad)."""

    spec: CameraSpec
    position: NDArray[np.float64]
    yaw: float
    pitch: float
    _axes: NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=float).reshape(-1)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"position must be three finite numbers, got {self.position!r}")
        if not (math.isfinite(self.yaw) and math.isfinite(self.pitch)) or abs(self.pitch) >= 0.5 * math.pi:
            raise ValueError(f"yaw must be finite and |pitch| < pi/2, got {self.yaw!r}, {self.pitch!r}")
        pos.setflags(write=False)
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "_axes", _camera_axes(self.yaw, self.pitch))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return self.spec.focal_px

    @property
    def forward(self) -> NDArray[np.float64]:
        """Unit optical axis (world)."""
        return self._axes[0].copy()

    @property
    def right(self) -> NDArray[np.float64]:
        """Unit vector to the image's right (world)."""
        return self._axes[1].copy()

    @property
    def up(self) -> NDArray[np.float64]:
        """Unit vector to the image's top (world)."""
        return self._axes[2].copy()

    def to_camera(self, points: ArrayLike) -> NDArray[np.float64]:
        """World points (N, 3) -> camera coordinates (N, 3): (right, up, depth along the axis)."""
        p = _points(points) - self.position
        f, r, u = self._axes
        return np.stack([p @ r, p @ u, p @ f], axis=1)

    def project(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World points (N, 3) -> (uv (N, 2) pixels, depth (N,) metres along the optical axis).

        depth <= 0 for points behind the camera; their uv are NaN.
        """
        cam = self.to_camera(points)
        depth = cam[:, 2]
        fpx = self.spec.focal_px
        uv = np.full((len(cam), 2), np.nan)
        ok = depth > 1e-9
        uv[ok, 0] = 0.5 * self.spec.width + fpx * cam[ok, 0] / depth[ok]
        uv[ok, 1] = 0.5 * self.spec.height - fpx * cam[ok, 1] / depth[ok]
        return uv, depth

    def in_view(self, points: ArrayLike, near: float = NEAR) -> NDArray[np.bool_]:
        """(N,) bool: in front of the camera (depth > near) and inside the image."""
        uv, depth = self.project(points)
        with np.errstate(invalid="ignore"):
            inside = (
                (uv[:, 0] >= 0.0) & (uv[:, 0] < self.spec.width) & (uv[:, 1] >= 0.0) & (uv[:, 1] < self.spec.height)
            )
        return (depth > near) & inside

    def look_target(self, distance: float = 10.0) -> NDArray[np.float64]:
        """A world point on the optical axis ``distance`` metres ahead (e.g. for a view matrix)."""
        return self.position + distance * self._axes[0]


def _camera_axes(yaw: float, pitch: float) -> NDArray[np.float64]:
    """Rows: forward (optical axis), right, up, for heading ``yaw`` and downward ``pitch``."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    forward = np.array([cy * cp, sy * cp, -sp])
    right = np.array([sy, -cy, 0.0])
    up = np.cross(right, forward)
    return np.stack([forward, right, up])


def _points(points: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=float)
    if p.ndim == 1:
        p = p.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    return p
