"""The one camera model of trustnav: intrinsics, mount on the ego vehicle, pose in the world,
projection and back-projection. The renderer, the keypoint sensor, ground-plane localisation and
the CARLA bridge all use it (it imports nothing of trustnav).

World coordinates are the paper's map coordinates: metres, x/y on the ground, z up, yaw counter-
clockwise from +x. The camera looks along the ego's heading, tilted down by ``pitch_deg`` and
rolled by ``roll_deg`` (clockwise as seen from behind the camera); image u grows to the right, v
downwards, and the optical axis meets the image at the principal point (``cx``, ``cy``; by default
the centre ``width / 2``, ``height / 2``), pixel ``i`` covering ``[i, i + 1)``. The focal length
comes from the horizontal field of view, or is given in pixels (``focal``, a K matrix's f_x = f_y).
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
    ``roll_deg`` rolls the image clockwise; ``focal`` (px) overrides the focal length that ``fov_deg``
    gives, ``cx``/``cy`` the principal point (None: the image centre): see :meth:`from_matrix`.
    """

    width: int = 1280
    height: int = 720
    fov_deg: float = 70.0
    forward: float = 1.5
    up: float = 1.7
    pitch_deg: float = 0.0
    rate: float = 1.0
    roll_deg: float = 0.0
    focal: float | None = None
    cx: float | None = None
    cy: float | None = None

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
        if not -45.0 <= self.roll_deg <= 45.0:
            raise ValueError(f"roll_deg must be in [-45, 45] degrees, got {self.roll_deg!r}")
        if self.focal is not None and not 1.0 <= self.focal <= 1e5:
            raise ValueError(f"focal must be in [1, 1e5] pixels (or None: from fov_deg), got {self.focal!r}")
        for name, size in (("cx", self.width), ("cy", self.height)):
            v = getattr(self, name)
            if v is not None and not 0.0 <= v <= size:
                raise ValueError(f"{name} must be inside the image [0, {size}] pixels (or None: centre), got {v!r}")

    @classmethod
    def from_matrix(cls, k: ArrayLike, width: int, height: int, **mount: float) -> CameraSpec:
        """A camera from a 3x3 intrinsic matrix K (square pixels, no skew: f_x = f_y within 1 %)
        and its mount (``forward``, ``up``, ``pitch_deg``, ``roll_deg``, ``rate``)."""
        m = np.asarray(k, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise ValueError(f"K must be a finite 3x3 matrix, got {k!r}")
        fx, fy, skew = m[0, 0], m[1, 1], m[0, 1]
        if not (fx > 0 and fy > 0 and abs(fx - fy) <= 0.01 * fx and abs(skew) <= 1e-6 * fx):
            raise ValueError(f"K must have f_x = f_y > 0 (square pixels) and no skew, got {m.tolist()!r}")
        fov = math.degrees(2.0 * math.atan(0.5 * width / fx))
        return cls(width=width, height=height, fov_deg=fov, focal=float(fx), cx=float(m[0, 2]), cy=float(m[1, 2]),
                   **mount)  # fmt: skip

    @property
    def principal(self) -> tuple[float, float]:
        """Principal point (cx, cy) in pixels."""
        return (0.5 * self.width if self.cx is None else self.cx, 0.5 * self.height if self.cy is None else self.cy)

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The 3x3 intrinsic matrix K."""
        f = self.focal_px
        cx, cy = self.principal
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels)."""
        if self.focal is not None:
            return float(self.focal)
        return 0.5 * self.width / math.tan(math.radians(0.5 * self.fov_deg))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal_px))

    def pose(self, ego_xy: ArrayLike, ego_yaw: float, pitch_offset: float = 0.0) -> CameraPose:
        """The camera in the world for an ego at ``ego_xy`` (metres) heading ``ego_yaw`` (rad);
        ``pitch_offset`` (rad, > 0 nose down) is the body's pitch on top of the mount's (braking)."""
        xy = np.asarray(ego_xy, dtype=float).reshape(-1)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"ego_xy must be two finite numbers, got {ego_xy!r}")
        if not math.isfinite(ego_yaw):
            raise ValueError(f"ego_yaw must be finite, got {ego_yaw!r}")
        c, s = math.cos(ego_yaw), math.sin(ego_yaw)
        position = np.array([xy[0] + self.forward * c, xy[1] + self.forward * s, self.up])
        pitch = math.radians(self.pitch_deg) + float(pitch_offset)
        return CameraPose(self, position, float(ego_yaw), pitch, math.radians(self.roll_deg))


@dataclass(frozen=True, eq=False)
class CameraPose:
    """A camera placed in the world: optical centre, heading, downward pitch and roll (rad)."""

    spec: CameraSpec
    position: NDArray[np.float64]
    yaw: float
    pitch: float
    roll: float = 0.0
    _axes: NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=float).reshape(-1)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"position must be three finite numbers, got {self.position!r}")
        if not (math.isfinite(self.yaw) and math.isfinite(self.pitch)) or abs(self.pitch) >= 0.5 * math.pi:
            raise ValueError(f"yaw must be finite and |pitch| < pi/2, got {self.yaw!r}, {self.pitch!r}")
        pos.setflags(write=False)
        object.__setattr__(self, "position", pos)
        if not math.isfinite(self.roll) or abs(self.roll) >= 0.5 * math.pi:
            raise ValueError(f"roll must be finite with |roll| < pi/2, got {self.roll!r}")
        object.__setattr__(self, "_axes", _camera_axes(self.yaw, self.pitch, self.roll))

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
        cx, cy = self.spec.principal
        uv[ok, 0] = cx + fpx * cam[ok, 0] / depth[ok]
        uv[ok, 1] = cy - fpx * cam[ok, 1] / depth[ok]
        return uv, depth

    def rays(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Pixels (N, 2) -> unit viewing directions in the world (N, 3), the inverse of :meth:`project`."""
        p = np.asarray(uv, dtype=float).reshape(-1, 2)
        cx, cy = self.spec.principal
        f = self.spec.focal_px
        fwd, right, up = self._axes
        d = fwd[None] + ((p[:, 0] - cx) / f)[:, None] * right[None] - ((p[:, 1] - cy) / f)[:, None] * up[None]
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def back_project(self, uv: ArrayLike, depth: ArrayLike) -> NDArray[np.float64]:
        """Pixels (N, 2) at ``depth`` (N,) metres along the optical axis -> world points (N, 3)."""
        p = np.asarray(uv, dtype=float).reshape(-1, 2)
        z = np.broadcast_to(np.asarray(depth, dtype=float).reshape(-1), (len(p),))
        cx, cy = self.spec.principal
        f = self.spec.focal_px
        fwd, right, up = self._axes
        cam = np.stack([(p[:, 0] - cx) * z / f, -(p[:, 1] - cy) * z / f, z], axis=1)
        return self.position[None] + cam @ np.stack([right, up, fwd])

    def ground_point(self, uv: ArrayLike, height: ArrayLike = 0.0) -> NDArray[np.float64]:
        """Pixels (N, 2) -> where their rays meet the horizontal plane z = ``height`` (N, 3); NaN
        for a ray that does not descend to it (at or above the horizon)."""
        d = self.rays(uv)
        h = np.broadcast_to(np.asarray(height, dtype=float).reshape(-1), (len(d),))
        drop = self.position[2] - h
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d[:, 2] < -1e-9, drop / -d[:, 2], np.nan)
        s = np.where(s > 0, s, np.nan)
        return self.position[None] + s[:, None] * d

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


def _camera_axes(yaw: float, pitch: float, roll: float = 0.0) -> NDArray[np.float64]:
    """Rows: forward (optical axis), right, up, for heading ``yaw``, downward ``pitch`` and ``roll``
    (the image turned clockwise about the optical axis as seen from behind the camera)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    forward = np.array([cy * cp, sy * cp, -sp])
    right = np.array([sy, -cy, 0.0])
    up = np.cross(right, forward)
    if roll:
        cr, sr = math.cos(roll), math.sin(roll)
        right, up = cr * right - sr * up, sr * right + cr * up
    return np.stack([forward, right, up])


def _points(points: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=float)
    if p.ndim == 1:
        p = p.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    return p
