"""People the pose detector does not see, found through person segmentation (issue 19, item 4).

BlazePose's detector finds a person by the face, so people seen in profile or from behind, and
small ones, are often missed (walk_a: 16 of 62 clearly visible real people in single frames).
MediaPipe's selfie-segmentation model, shipped in the same wheel, marks person pixels whatever
the person's orientation: run on tiles about a third of the frame's shorter side, it outlines the
pedestrians of a street scene, and also some person-like things (a car's wheel, a walk signal's
pictogram, a wall above a group).

So segmentation only *proposes*: each connected region of person pixels (wide ones split into
person-wide parts) gives a square region for the landmark model, which must fit a body there that
passes the backend's checks (upright, taller than wide, hips where the region put them) and three
more that tie the fit to the region it came from (:func:`plausible`): at least
:data:`MIN_HEIGHT_PX` tall, not a solid silhouette (a real person's box has background between
the legs and beside the arms), and feet at the bottom of the region of person pixels (a fit whose
region runs on far below its feet is not of that region's object). On the project's labelled real
frames (walk_a, phone_a, street), one frame at a time, this finds 11 of the 16 people the detector
misses, with no false box (``docs/perception.md``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["MIN_HEIGHT_PX", "MIN_PRESENCE", "blob_regions", "plausible", "segment_windows"]

#: Mask value above which a pixel counts as a person's.
MASK_THRESHOLD = 0.5
#: A person found from segmentation is at least this tall (pixels): below it the landmark model
#: fits bodies on small person-like shapes.
MIN_HEIGHT_PX = 80
#: Mean presence of the body landmarks (11-28) a fit on a segmentation region needs (a detector's
#: region needs ``MediaPipeConfig.min_presence``): with no face found there, the fit must be sure.
MIN_PRESENCE = 0.9
#: Largest share of a person's box covered by person pixels: a solid silhouette (a pictogram, a
#: sign) fills its box; a person leaves background between the legs and beside the arms (0.4-0.85
#: on the labelled frames).
MAX_COVER = 0.92
#: The fitted feet may end at most this share of the person's height above the bottom of the
#: region of person pixels (-0.11 to +0.05 on the labelled frames; a fit on a wall above a group,
#: or inside a car, ends far above its region's bottom).
MAX_FEET_GAP = 0.2
#: A region's width per person, as a share of its height, when a wide region is split.
PERSON_WIDTH = 0.45


def segment_windows(height: int, width: int, tile: float) -> list[tuple[int, int, int, int]]:
    """Square windows (x0, y0, x1, y1) of side ``tile`` x the shorter side, overlapping by half,
    covering the frame (the last row and column flush with its edges)."""
    side = max(16, round(tile * min(height, width)))
    step = max(1, side // 2)

    def starts(length: int) -> list[int]:
        if side >= length:
            return [0]
        out = list(range(0, length - side + 1, step))
        if out[-1] != length - side:
            out.append(length - side)
        return out

    return [(x, y, min(width, x + side), min(height, y + side)) for y in starts(height) for x in starts(width)]


def blob_regions(mask: NDArray[np.float32], min_height: float) -> list[tuple[NDArray[np.float64], tuple]]:
    """Landmark regions [cx, cy, side, rotation, NaN x 3] proposed by the person pixels of
    ``mask`` (H x W in [0, 1]): one per connected region at least ``min_height`` tall, or one per
    person-wide part of a wide region; each with its region's box (x, y, w, h)."""
    import cv2

    count, _, stats, _ = cv2.connectedComponentsWithStats((mask > MASK_THRESHOLD).astype(np.uint8), connectivity=8)
    out = []
    for i in range(1, count):
        x, y, bw, bh = (int(v) for v in stats[i, :4])
        if bh < min_height:
            continue
        parts = max(1, round(bw / (PERSON_WIDTH * bh)))
        for j in range(parts):
            cx = x + (j + 0.5) * bw / parts
            out.append((np.array([cx, y + bh / 2, 1.25 * bh, 0.0, math.nan, math.nan, math.nan]), (x, y, bw, bh)))
    return out


def plausible(box: NDArray[np.float64], landmarks: NDArray[np.float64], mask: NDArray[np.float32], blob: tuple) -> bool:
    """The checks that tie a landmark fit on a segmentation region to that region (module
    docstring): its box (x1, y1, x2, y2) at least :data:`MIN_HEIGHT_PX` tall and at most
    :data:`MAX_COVER` covered by person pixels, its lowest foot landmark (27-32) within
    :data:`MAX_FEET_GAP` of its height above the region's bottom."""
    x1, y1, x2, y2 = (round(float(v)) for v in box)
    height = y2 - y1
    if height < MIN_HEIGHT_PX:
        return False
    inner = mask[max(0, y1) : y2 + 1, max(0, x1) : x2 + 1]
    if inner.size == 0 or float((inner > MASK_THRESHOLD).mean()) > MAX_COVER:
        return False
    feet = float(np.max(landmarks[27:33, 1]))
    bottom = blob[1] + blob[3]
    return (feet - bottom) / height >= -MAX_FEET_GAP
