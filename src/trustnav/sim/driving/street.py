"""The static street of the driving world (road, sidewalks, kerb): geometry shared by the world
(where pedestrians stand), the renderer (what it draws) and sensing; imports nothing of trustnav."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["StreetSpec"]


@dataclass(frozen=True)
class StreetSpec:
    """The static street: a straight road from ``start`` to ``end`` (xy, metres) with sidewalks.

    road_width: kerb to kerb; sidewalk_width: each side; extend: road drawn this far beyond both
    ends; buildings / poles: whether to place them (randomly, from ``seed``).
    """

    start: tuple[float, float] = (33.5, 160.0)
    end: tuple[float, float] = (33.5, 40.0)
    road_width: float = 7.0
    sidewalk_width: float = 3.0
    kerb_height: float = 0.13
    extend: float = 80.0
    buildings: bool = True
    poles: bool = True
    seed: int = 0
    sun: tuple[float, float, float] = (0.0, 0.3, 1.0)  # lightDirection of TinyRenderer (world)
    ambient: float = 0.6
    diffuse: float = 0.5

    def __post_init__(self) -> None:
        for name in ("start", "end"):
            xy = tuple(float(v) for v in getattr(self, name))
            if len(xy) != 2 or not all(math.isfinite(v) for v in xy):
                raise ValueError(f"{name} must be two finite numbers (x, y), got {getattr(self, name)!r}")
            object.__setattr__(self, name, xy)
        if math.dist(self.start, self.end) < 1.0:
            raise ValueError("start and end must be at least 1 m apart")
        if not 2.0 <= self.road_width <= 40.0:
            raise ValueError(f"road_width must be in [2, 40] metres, got {self.road_width!r}")
        if not 0.0 <= self.sidewalk_width <= 20.0:
            raise ValueError(f"sidewalk_width must be in [0, 20] metres, got {self.sidewalk_width!r}")
        if not 0.0 <= self.kerb_height <= 0.4:
            raise ValueError(f"kerb_height must be in [0, 0.4] metres, got {self.kerb_height!r}")
        sun = tuple(float(v) for v in self.sun)
        if len(sun) != 3 or not all(math.isfinite(v) for v in sun) or sun[2] <= 0.0:
            raise ValueError(f"sun must be a direction (x, y, z) with z > 0, got {self.sun!r}")
        object.__setattr__(self, "sun", sun)
        if not (0.0 <= self.ambient <= 2.0 and 0.0 <= self.diffuse <= 2.0):
            raise ValueError(f"ambient and diffuse must be in [0, 2], got {self.ambient!r}, {self.diffuse!r}")
        if not 0.0 <= self.extend <= 500.0:
            raise ValueError(f"extend must be in [0, 500] metres, got {self.extend!r}")

    @property
    def direction(self) -> NDArray[np.float64]:
        """Unit vector along the road, start -> end."""
        d = np.subtract(self.end, self.start)
        return d / np.linalg.norm(d)

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def ground_height(self, xy: ArrayLike) -> float:
        """Height of the walkable surface at ``xy``: the kerb height on a sidewalk, else 0."""
        p = np.asarray(xy, dtype=float).reshape(-1)[:2] - np.asarray(self.start)
        d = self.direction
        lateral = abs(float(p[0] * -d[1] + p[1] * d[0]))
        half = 0.5 * self.road_width
        return self.kerb_height if half <= lateral <= half + 0.2 + self.sidewalk_width else 0.0
