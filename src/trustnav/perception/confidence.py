"""Keypoint confidences that carry occlusion, derived from BlazePose's 3D head geometry.

The LOOKING eye-contact model was trained on OpenPifPaf confidences, where a face keypoint turned
away from the camera (the far eye and ear of a person in profile; the whole face of a person seen
from behind) has a low confidence. BlazePose's own "visibility" is ~1 for all of them, with which the
model calls everyone attentive. Instead, the head's yaw is estimated from the two ears' landmarks
(x from the image, z from BlazePose's depth, which shares x's scale), and each face keypoint gets a
confidence from how far its surface normal points towards the camera:

    yaw = atan2(kappa (z_left_ear - z_right_ear), x_left_ear - x_right_ear)   (0: facing the camera)
    facing_k = cos(yaw + phi_k),  phi = 0 (nose), +/-35 deg (eyes), +/-90 deg (ears)
    c_k = clip(base_k + gain_k * facing_k, floor, 1) * visibility_k

Body keypoints keep BlazePose's visibility. ``kappa`` < 1 damps BlazePose's noisier depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["BLAZEPOSE_TO_COCO", "HeadConfidenceParams", "face_confidences", "head_yaw", "occlusion_confidences"]

# index of each COCO keypoint among BlazePose's 33 landmarks
BLAZEPOSE_TO_COCO: tuple[int, ...] = (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)


@dataclass(frozen=True)
class HeadConfidenceParams:
    """Constants of the head-geometry confidences (see module docstring)."""

    kappa: float = 0.5
    eye_angle_deg: float = 35.0
    face_base: float = 0.3
    face_gain: float = 0.7
    ear_base: float = 0.55
    ear_gain: float = 0.45
    floor: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 <= self.kappa <= 2.0:
            raise ValueError(f"kappa must be in [0, 2], got {self.kappa!r}")
        if not 0.0 <= self.eye_angle_deg <= 90.0:
            raise ValueError(f"eye_angle_deg must be in [0, 90], got {self.eye_angle_deg!r}")
        if not 0.0 <= self.floor < 1.0:
            raise ValueError(f"floor must be in [0, 1), got {self.floor!r}")


def head_yaw(lm: NDArray[np.float64], kappa: float = 0.5) -> float:
    """Head yaw in radians from BlazePose landmarks (33, >=3: x, y, z in pixels): 0 facing the camera,
    +pi/2 left ear away (right side of the face shown), -pi/2 right ear away, +/-pi back to camera."""
    left, right = lm[7], lm[8]
    return math.atan2(kappa * (left[2] - right[2]), left[0] - right[0])


def occlusion_confidences(
    lm: NDArray[np.float64], params: HeadConfidenceParams = HeadConfidenceParams()
) -> NDArray[np.float64]:
    """17 COCO confidences from 33 BlazePose landmarks (x, y, z pixels, visibility, presence)."""
    lm = np.asarray(lm, dtype=float)
    if lm.ndim != 2 or lm.shape[0] != 33 or lm.shape[1] < 4:
        raise ValueError(f"landmarks must have shape (33, >=4) (x, y, z, visibility), got {lm.shape}")
    vis = np.clip(lm[list(BLAZEPOSE_TO_COCO), 3], 0.0, 1.0)
    conf = vis.copy()
    conf[:5] = face_confidences(vis[:5], head_yaw(lm, params.kappa), params)
    return conf


def face_confidences(
    visibility: NDArray[np.float64], yaw: float, params: HeadConfidenceParams = HeadConfidenceParams()
) -> NDArray[np.float64]:
    """Confidences of the 5 COCO face keypoints (nose, eyes, ears) for a head turned by ``yaw``
    (radians, :func:`head_yaw`'s convention) and BlazePose's ``visibility`` of them. The yaw may come
    from the ears' depth or, where a face is seen well enough, from the face mesh
    (:class:`~trustnav.perception.cues.FaceEyeContactCue`)."""
    eye = math.radians(params.eye_angle_deg)
    # COCO 0..4: nose, left eye, right eye, left ear, right ear; phi > 0 turns with the left side
    phi = np.array([0.0, eye, -eye, math.pi / 2, -math.pi / 2])
    facing = np.cos(yaw + phi)
    base = np.array([params.face_base] * 3 + [params.ear_base] * 2)
    gain = np.array([params.face_gain] * 3 + [params.ear_gain] * 2)
    return np.clip(base + gain * facing, params.floor, 1.0) * np.asarray(visibility, dtype=float)
