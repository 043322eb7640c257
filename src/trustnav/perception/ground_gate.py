"""Only people who can be there: a person box must stand on the ground at a human size.

For a person of height H standing on flat ground, seen by a camera at height c with little roll,
the image height of the box is h = H (v_f - v_0) / c, where v_f is the image row of the feet and
v_0 the horizon's row (Hoiem, Efros and Hebert, "Putting objects in perspective", 2006). So the
feet lie below the horizon, and h / (v_f - v_0) is H / c for every person of one frame.

- **Camera known** (``camera``: a :class:`~trustnav.geometry.camera.CameraPose`): the feet are placed
  on the ground and a person of :data:`HEIGHT_RANGE_M` is projected there; the box must be that tall,
  within ``tolerance``, and its feet below the horizon.
- **Camera unknown**: the horizon and H / c are fitted from the frame's own confident people (and,
  in a video, those of the last frames: :class:`HorizonFit` keeps a window of them), by least
  squares on h = k v_f - k v_0 over the people that agree with the line through two of them that
  most agree with; a box whose height is off the line by more than a factor ``tolerance`` x the
  spread of human heights, or whose feet lie above the fitted horizon, is rejected. With fewer than
  :data:`MIN_PEOPLE` people in the window, or their feet within :data:`MIN_SPREAD` of a height of
  one another, only the prior is used: the feet lie below
  ``prior_horizon`` x the frame's height, and a box is at least ``prior_min_height`` of the distance
  from its feet to that row (a logo on a dashboard, at the bottom of the image, is far smaller than
  a person standing there would be).

People cut by the frame's bottom edge have no feet in view: the gate does not judge them.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["HEIGHT_RANGE_M", "MIN_PEOPLE", "GateConfig", "HorizonFit", "Rejection", "feet_in_view", "gate_boxes"]

#: Heights of the people the gate lets stand (m): a child of ~6 years to a tall adult.
HEIGHT_RANGE_M = (1.0, 2.1)
#: People needed (in the fit's window) to fit a horizon from the frame itself.
MIN_PEOPLE = 3
#: The feet rows of the people fitted must span at least this share of their median height.
MIN_SPREAD = 0.5
#: A person lies on a fitted line when their height is within this log-ratio of it (~ +-25 %).
INLIER = 0.22


@dataclass(frozen=True)
class GateConfig:
    """tolerance: factor by which a box may be taller or shorter than the heights allow (boxes are
    a few pixels off, people bend, the ground slopes); prior_horizon: the lowest horizon (share of
    the frame's height from the top) the gate assumes without a camera or a fit; prior_min_height:
    the least box height, as a share of the distance from its feet up to that row; window: people
    kept by :class:`HorizonFit` over a video's frames; bottom_margin: a box this close (px) to the
    frame's bottom edge has its feet cut off and is not judged."""

    tolerance: float = 1.5
    prior_horizon: float = 0.7
    prior_min_height: float = 0.3
    window: int = 60
    bottom_margin: float = 3.0

    def __post_init__(self) -> None:
        if not 1.0 <= self.tolerance <= 5.0:
            raise ValueError(f"tolerance must be in [1, 5], got {self.tolerance!r}")
        if not 0.0 < self.prior_horizon < 1.0:
            raise ValueError(f"prior_horizon must be in (0, 1) of the frame's height, got {self.prior_horizon!r}")
        if not 0.0 <= self.prior_min_height < 1.0:
            raise ValueError(f"prior_min_height must be in [0, 1), got {self.prior_min_height!r}")
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < MIN_PEOPLE:
            raise ValueError(f"window must be an integer >= {MIN_PEOPLE}, got {self.window!r}")
        if not 0.0 <= self.bottom_margin <= 50.0:
            raise ValueError(f"bottom_margin must be in [0, 50] px, got {self.bottom_margin!r}")


@dataclass(frozen=True)
class Rejection:
    """A box the gate rejected: its box [x1, y1, x2, y2], detection score and why."""

    bbox: tuple[float, float, float, float]
    score: float
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {"bbox": [round(v, 1) for v in self.bbox], "score": round(self.score, 3), "reason": self.reason}


class HorizonFit:
    """The horizon row v_0 and the ratio k = H / c fitted from people's (feet row, height) pairs.

    ``add`` people judged real; ``fit()`` returns (v_0, k, relative spread) or None with fewer than
    :data:`MIN_PEOPLE`. In a video the pairs of the last ``window`` people are kept (a camera on a car
    keeps its horizon within a few rows); :meth:`reset` between videos."""

    def __init__(self, window: int = 60) -> None:
        self._pairs: deque[tuple[float, float]] = deque(maxlen=window)

    def reset(self) -> None:
        self._pairs.clear()

    def add(self, feet: float, height: float) -> None:
        if math.isfinite(feet) and math.isfinite(height) and height > 0:
            self._pairs.append((float(feet), float(height)))

    def __len__(self) -> int:
        return len(self._pairs)

    def fit(self) -> tuple[float, float, float] | None:
        if len(self._pairs) < MIN_PEOPLE:
            return None
        v, h = np.array(self._pairs).T
        if np.ptp(v) < MIN_SPREAD * max(float(np.median(h)), 1.0):
            # feet on nearly one row: people's own heights (+-10 %) would set the slope, and the
            # horizon extrapolated from it could lie anywhere
            return None
        # the line with the most people within INLIER of it, over lines through two people (all
        # pairs, or a fixed sample of them: deterministic), then least squares on those people
        n = len(v)
        pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
        if len(pairs) > 300:
            pick = np.random.default_rng(0).choice(len(pairs), 300, replace=False)
            pairs = [pairs[i] for i in pick]
        best, keep = -1.0, np.ones(n, dtype=bool)
        for i, j in pairs:
            if abs(v[i] - v[j]) < 1e-6:
                continue
            a = (h[i] - h[j]) / (v[i] - v[j])
            if a <= 0:
                continue
            expected = a * (v - v[i]) + h[i]
            ok = expected > 1.0
            resid = np.where(ok, np.abs(np.log(h / np.maximum(expected, 1.0))), np.inf)
            inliers = resid < INLIER
            score = inliers.sum() - 0.01 * float(np.sum(np.minimum(resid[inliers], INLIER)))
            if score > best:
                best, keep = score, inliers
        if keep.sum() < MIN_PEOPLE:
            return None
        a, b = np.polyfit(v[keep], h[keep], 1)
        if a <= 0:
            return None  # heights that shrink toward the camera: not people on one ground plane
        spread = float(np.std(np.log(h[keep] / (a * v[keep] + b)))) if keep.sum() > 2 else 0.0
        return -b / a, float(a), spread


def _expected_heights(camera: Any, box: NDArray[np.float64]) -> tuple[float, float] | None:
    """Image heights (px) of people of :data:`HEIGHT_RANGE_M` standing where the box's feet are."""
    feet = np.array([[0.5 * (box[0] + box[2]), box[3]]])
    ray = camera.rays(feet)[0]
    if ray[2] >= -1e-6:  # the feet's ray does not reach the ground ahead: above the horizon
        return None
    ground = camera.ground_point(feet)[0]
    heads = np.array([ground + [0.0, 0.0, hm] for hm in HEIGHT_RANGE_M])
    uv, depth = camera.project(heads)
    if not np.all(depth > 0):
        return None
    return float(box[3] - uv[0, 1]), float(box[3] - uv[1, 1])


def feet_in_view(box: Sequence[float] | NDArray[np.float64], height: int, config: GateConfig | None = None) -> bool:
    """Whether ``box`` (x1, y1, x2, y2) stops above the frame's bottom edge (``height`` px) by more
    than ``bottom_margin``: a box cut by the edge has no feet in view for the gate to judge."""
    return float(box[3]) < height - 1 - (config or GateConfig()).bottom_margin


def gate_boxes(
    boxes: Sequence[NDArray[np.float64]],
    scores: Sequence[float],
    frame_size: tuple[int, int],
    *,
    config: GateConfig | None = None,
    camera: Any = None,
    fit: HorizonFit | None = None,
) -> tuple[list[int], list[Rejection]]:
    """Indices of the boxes that can be people standing on the ground, and the rejections.

    ``frame_size``: (width, height); ``camera``: a CameraPose (trustnav.geometry) when known;
    ``fit``: the horizon fit to judge by and to add the kept boxes to (None: this frame's boxes
    only). The boxes are judged against a fit that includes them: the fit is the line most of the
    people agree with, so a logo or a box in the sky among them does not move it."""
    config = config or GateConfig()
    _, h = frame_size
    keep: list[int] = []
    rejected: list[Rejection] = []
    judged = [i for i, b in enumerate(boxes) if feet_in_view(b, h, config)]
    if camera is not None:
        for i, b in enumerate(boxes):
            if i not in judged:
                keep.append(i)
                continue
            reason = _camera_reason(camera, np.asarray(b, dtype=float), config)
            if reason is None:
                keep.append(i)
            else:
                rejected.append(Rejection(tuple(map(float, b)), float(scores[i]), reason))
        return keep, rejected
    local = fit if fit is not None else HorizonFit(config.window)
    trial = HorizonFit(config.window + len(boxes))
    for v, hh in list(local._pairs):
        trial.add(v, hh)
    for i in judged:
        trial.add(float(boxes[i][3]), float(boxes[i][3] - boxes[i][1]))
    fitted = trial.fit()
    lo, hi = HEIGHT_RANGE_M
    human = math.log(hi / lo) / 2  # half the log range of human heights around their middle
    for i, b in enumerate(boxes):
        if i not in judged:
            keep.append(i)
            continue
        feet, height = float(b[3]), float(b[3] - b[1])
        reason = None
        if fitted is not None:
            v0, k, spread = fitted
            expected = k * (feet - v0)
            allowed = config.tolerance * max(human, 2 * spread)
            if feet <= v0:
                reason = f"feet at row {feet:.0f} above the horizon fitted from the frame's people (row {v0:.0f})"
            elif abs(math.log(height / expected)) > allowed:
                reason = (
                    f"{height:.0f} px tall where a person standing at row {feet:.0f} is ~{expected:.0f} px "
                    f"(horizon row {v0:.0f} fitted from the frame's people)"
                )
        else:
            row = config.prior_horizon * h
            if feet > row and height < config.prior_min_height * (feet - row):
                reason = (
                    f"{height:.0f} px tall with its feet at row {feet:.0f}: under {config.prior_min_height:g} of "
                    f"the {feet - row:.0f} px up to the lowest horizon assumed (row {row:.0f})"
                )
        if reason is None:
            keep.append(i)
        else:
            rejected.append(Rejection(tuple(map(float, b)), float(scores[i]), reason))
    if fit is not None:
        for i in keep:
            if i in judged:
                fit.add(float(boxes[i][3]), float(boxes[i][3] - boxes[i][1]))
    return keep, rejected


def _camera_reason(camera: Any, box: NDArray[np.float64], config: GateConfig) -> str | None:
    expected = _expected_heights(camera, box)
    height = float(box[3] - box[1])
    if expected is None:
        return f"feet at row {box[3]:.0f} above the camera's horizon"
    lo, hi = expected
    if height < lo / config.tolerance or height > hi * config.tolerance:
        return f"{height:.0f} px tall where a person standing at row {box[3]:.0f} is {lo:.0f}-{hi:.0f} px (camera)"
    return None
