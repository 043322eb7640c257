"""Smartphone-use confidence C_sm for `smato_score`.

The paper classifies the person crop with a fine-tuned image classifier; no such model can be had
offline, so the default reads the pose (COCO 17 keypoints, image y downwards):

* texting: a wrist raised ``raise_band`` (0.55-0.95) of the way from its hip up to its shoulder and
  in front of the torso, weighted up when the head is pitched down (nose below the ears);
* calling: a wrist at the face (near an ear).

C_sm = max(texting, calling) in [0, 1]. :class:`PhoneClassifier` is the interface; an image
classifier on the person crop (the paper's design) plugs in the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.types import Person

__all__ = ["PhoneClassifier", "PoseGeometryPhoneClassifier", "phone_label"]


@runtime_checkable
class PhoneClassifier(Protocol):
    """(frame RGB, person) -> confidence in [0, 1] that the person is using a smartphone."""

    def __call__(self, frame: NDArray[np.uint8], person: Person) -> float: ...


def phone_label(confidence: float, low: float = 0.4, high: float = 0.7) -> str:
    """'N' (no), 'U' (unsure) or 'Y' (yes) for a phone-use confidence."""
    return "N" if confidence < low else ("U" if confidence < high else "Y")


def _ramp(x: float, lo: float, hi: float) -> float:
    return float(np.clip((x - lo) / (hi - lo), 0.0, 1.0))


@dataclass(frozen=True)
class PoseGeometryPhoneClassifier:
    """Pose cues of phone use (see module docstring); thresholds in body-relative units."""

    raise_band: tuple[float, float] = (0.55, 0.95)
    raise_softness: float = 0.15
    front_of_torso: float = 0.7  # wrist within this many torso lengths of the torso's centre line
    head_down: tuple[float, float] = (0.0, 0.15)  # nose below ear line, in torso lengths: no -> full cue
    head_weight: float = 0.4  # share of the texting cue that needs the head pitched down
    wrist_confidence: tuple[float, float] = (0.3, 0.7)  # wrist confidence: cue ignored -> fully used
    face_distance: float = 0.35  # wrist-to-ear distance, in torso lengths, for a call

    def __post_init__(self) -> None:
        lo, hi = self.raise_band
        if not 0.0 <= lo < hi <= 1.5:
            raise ValueError(f"raise_band must be 0 <= low < high <= 1.5, got {self.raise_band!r}")
        if not 0.0 <= self.head_weight <= 1.0:
            raise ValueError(f"head_weight must be in [0, 1], got {self.head_weight!r}")
        if self.raise_softness <= 0 or self.front_of_torso <= 0 or self.face_distance <= 0:
            raise ValueError("raise_softness, front_of_torso and face_distance must be positive")
        if not self.head_down[0] < self.head_down[1]:
            raise ValueError(f"head_down must be (no cue, full cue) increasing, got {self.head_down!r}")

    def __call__(self, frame: NDArray[np.uint8] | None, person: Person) -> float:
        return self.confidence(person.keypoints, person.confidences)

    def confidence(self, keypoints: NDArray[np.float64], confidences: NDArray[np.float64] | None = None) -> float:
        """C_sm from 17 COCO keypoints (pixels) and their confidences; NaN keypoints are ignored.

        A wrist's cues count in proportion to its confidence (ramp ``wrist_confidence``): the far
        arm of a person in profile, or hands hidden in front of the body, are guesses.
        """
        kp = np.asarray(keypoints, dtype=float)
        if kp.shape != (17, 2):
            raise ValueError(f"keypoints must have shape (17, 2), got {kp.shape}")
        ok_body = np.isfinite(kp).all(axis=1)
        if not ok_body[[5, 6, 11, 12]].all():
            return 0.0
        shoulders = kp[[5, 6]].mean(axis=0)
        hips = kp[[11, 12]].mean(axis=0)
        torso = float(np.hypot(*(hips - shoulders)))
        if torso < 1e-6:
            return 0.0
        # body-relative units use the torso length: shoulder and head widths vanish in profile
        down = 0.0
        if ok_body[[0, 3, 4]].all():
            drop = (kp[0, 1] - kp[[3, 4], 1].mean()) / torso
            down = _ramp(drop, *self.head_down)
        lo, hi = self.raise_band
        texting = calling = 0.0
        conf = np.ones(17) if confidences is None else np.asarray(confidences, dtype=float)
        for wrist, shoulder, hip in ((9, 5, 11), (10, 6, 12)):
            seen = _ramp(float(conf[wrist]), *self.wrist_confidence)
            if not ok_body[wrist] or seen <= 0.0:
                continue
            span = kp[hip, 1] - kp[shoulder, 1]
            if span <= 1e-6:
                continue
            r = (kp[hip, 1] - kp[wrist, 1]) / span
            band = min(_ramp(r, lo - self.raise_softness, lo), 1.0 - _ramp(r, hi, hi + self.raise_softness))
            centre = abs(kp[wrist, 0] - 0.5 * (shoulders[0] + hips[0])) / torso
            front = 1.0 - _ramp(centre, self.front_of_torso, 1.6 * self.front_of_torso)
            texting = max(texting, seen * band * front * (1.0 - self.head_weight + self.head_weight * down))
            for ear in (3, 4):
                if ok_body[ear]:
                    d = math.hypot(*(kp[wrist] - kp[ear])) / torso
                    calling = max(calling, seen * (1.0 - _ramp(d, self.face_distance, 1.5 * self.face_distance)))
        return float(np.clip(max(texting, calling), 0.0, 1.0))
