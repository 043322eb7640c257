"""What every pose backend returns: people with a box, 17 COCO keypoints and their confidences."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["COCO_KEYPOINTS", "N_KEYPOINTS", "Person", "PoseBackend", "box_iou", "check_frame"]

COCO_KEYPOINTS: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
N_KEYPOINTS = len(COCO_KEYPOINTS)


@dataclass(frozen=True)
class Person:
    """One person in one frame (pixel coordinates of that frame).

    bbox: [x1, y1, x2, y2]; keypoints: (17, 2) COCO order (NaN where a backend has none);
    confidences: (17,) in [0, 1], low for keypoints the backend believes occluded;
    score: detection score in [0, 1]; extra: backend-specific data (e.g. BlazePose's 33 landmarks).
    """

    bbox: NDArray[np.float64]
    keypoints: NDArray[np.float64]
    confidences: NDArray[np.float64]
    score: float
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        box = np.asarray(self.bbox, dtype=float)
        if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] <= box[0] or box[3] <= box[1]:
            raise ValueError(f"bbox must be [x1, y1, x2, y2] with x2 > x1 and y2 > y1, got {self.bbox!r}")
        kp = np.asarray(self.keypoints, dtype=float)
        if kp.shape != (N_KEYPOINTS, 2):
            raise ValueError(f"keypoints must have shape ({N_KEYPOINTS}, 2), got {kp.shape}")
        conf = np.asarray(self.confidences, dtype=float)
        if conf.shape != (N_KEYPOINTS,) or np.any((conf < 0) | (conf > 1)):
            raise ValueError(f"confidences must be {N_KEYPOINTS} values in [0, 1], got {conf!r}")
        if not 0.0 <= self.score <= 1.0:
            raise ValueError(f"score must be in [0, 1], got {self.score!r}")
        object.__setattr__(self, "bbox", box)
        object.__setattr__(self, "keypoints", kp)
        object.__setattr__(self, "confidences", conf)


@runtime_checkable
class PoseBackend(Protocol):
    """frame (H x W x 3 uint8, RGB) -> people. Backends may keep state between frames of one video."""

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]: ...


def check_frame(frame: object, name: str = "frame") -> NDArray[np.uint8]:
    """Return ``frame`` as a contiguous H x W x 3 uint8 array, or raise ValueError naming what is wrong."""
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"{name} must be a numpy array H x W x 3 of uint8, got {type(frame).__name__}")
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.shape[0] < 1 or frame.shape[1] < 1:
        raise ValueError(f"{name} must have shape H x W x 3, got {frame.shape}")
    if frame.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8 (0-255), got {frame.dtype}")
    return np.ascontiguousarray(frame)


def box_iou(a: NDArray | tuple, b: NDArray | tuple) -> float:
    """Intersection over union of two [x1, y1, x2, y2] boxes."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return float(inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter))
