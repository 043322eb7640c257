"""Annotated frames for `trustnav estimate`: trust-coloured boxes, eye-contact skeletons, phone N/U/Y."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["SKELETON", "annotate", "trust_colour"]

# COCO 17 limbs
SKELETON: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 2), (1, 3), (2, 4), (5, 6), (5, 7), (7, 9), (6, 8), (8, 10),
    (5, 11), (6, 12), (11, 12), (11, 13), (13, 15), (12, 14), (14, 16),
)  # fmt: skip

GREEN, ORANGE, RED = (0, 200, 0), (0, 140, 255), (0, 0, 230)  # BGR


def trust_colour(trust: float) -> tuple[int, int, int]:
    """BGR colour of a trust value: green > 0.7, orange > 0.4, red otherwise."""
    return GREEN if trust > 0.7 else (ORANGE if trust > 0.4 else RED)


def _eye_colour(c: float) -> tuple[int, int, int]:
    """Red (no eye contact) through yellow to green (eye contact), BGR."""
    c = float(np.clip(c, 0.0, 1.0))
    return (0, round(255 * min(1.0, 2 * c)), round(255 * min(1.0, 2 * (1 - c))))


def annotate(
    frame_rgb: NDArray[np.uint8],
    records: Sequence[dict],
    keypoints: Sequence[NDArray[np.float64]],
    phone_labels: Sequence[str],
) -> NDArray[np.uint8]:
    """BGR image with, per person: box coloured by trust with 'id trust phone', skeleton coloured by
    eye contact. ``records`` are the rows of tracks.csv for this frame, in the order of ``keypoints``."""
    import cv2

    img = cv2.cvtColor(frame_rgb, cv2.COLOR_RGB2BGR)
    scale = max(1.0, img.shape[0] / 480)
    thick = max(1, round(scale))
    for rec, kp, label in zip(records, keypoints, phone_labels, strict=True):
        x1, y1, x2, y2 = (round(v) for v in rec["bbox"])
        colour = trust_colour(rec["trust"])
        eye = _eye_colour(rec["eye_contact"] if rec["eye_contact"] is not None else 0.0)
        for a, b in SKELETON:
            pa, pb = kp[a], kp[b]
            if np.isfinite(pa).all() and np.isfinite(pb).all():
                cv2.line(img, (round(pa[0]), round(pa[1])), (round(pb[0]), round(pb[1])), eye, thick, cv2.LINE_AA)
        cv2.rectangle(img, (x1, y1), (x2, y2), colour, thick + 1)
        text = f"{rec['track_id']} {rec['trust']:.2f} {label}"
        size = 0.4 * scale
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, size, thick)
        ty = max(th + 2, y1 - 3)
        cv2.rectangle(img, (x1, ty - th - 2), (x1 + tw + 2, ty + 2), colour, -1)
        cv2.putText(img, text, (x1 + 1, ty), cv2.FONT_HERSHEY_SIMPLEX, size, (255, 255, 255), thick, cv2.LINE_AA)
    return img
