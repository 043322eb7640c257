"""People found by the shape of their body: OpenCV's HOG people detector as a third proposer (issue 19, item 4).

BlazePose's detector finds a person by the face. Through video compression the face's fine detail
goes first, so people seen from behind or small are lost (walk_a through MP4 at 36 dB: a man with
his back to the camera, 28 of 28 frames). Person segmentation (:mod:`segment_search`) proposes
people of at least 80 px whatever their orientation. The histogram-of-oriented-gradients people
detector (Dalal and Triggs, CVPR 2005; OpenCV's default people detector, trained on INRIA Person)
reads the outline of head, shoulders and legs, which survives compression: on walk_a's MP4 frames,
enlarged 1.5x (so that people from ~64 px fill its 64 x 128 window), it finds that man in every
frame, for ~150 ms per 640x480 frame on one core.

It also fires on poles, shop windows, signs and parts of people, so, like segmentation, it only
*proposes*: a window gives the landmark model a square region around the person it frames, and
the fit must pass the backend's checks plus those of :func:`consistent` (most of the body's
landmarks present, the fitted person of a height the window can hold and standing where the window
put it) and be made of person pixels: person segmentation run on a square around the fitted box
must mark at least :data:`MIN_PERSON_SHARE` of it (:func:`segment_square`). The landmark model
alone fits a confident body on a street sign's "16°C" (crossing.jpg; person pixels 0.0); the people
it finds on the labelled frames and walk_a's MP4 frames have 0.23-0.86.
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "MIN_HEIGHT_PX",
    "MIN_PERSON_SHARE",
    "MIN_PRESENCE",
    "BodyDetector",
    "consistent",
    "person_share",
    "search_scale",
    "segment_square",
    "window_region",
]

#: The smallest person searched for, as a share of the frame's shorter side (64 px at 640x480).
#: The frame is resized so that such a person fills the detector's window (:func:`search_scale`).
MIN_HEIGHT_SHARE = 64 / 480
#: Height (pixels) of the person in the detector's 128 px window.
WINDOW_PERSON_PX = 96
#: The detector's window (width, height), pixels of the enlarged frame.
WINDOW = (64, 128)
#: Pyramid step of the search (OpenCV's default 1.05 costs twice as much for the same people).
PYRAMID_STEP = 1.1
#: A person found from a body window is at least this tall (pixels).
MIN_HEIGHT_PX = 60
#: Mean presence of the body landmarks (11-28) a fit on a body window needs (as for segmentation:
#: no face was found there, so the fit must be sure).
MIN_PRESENCE = 0.9
#: Share of the window's height a person fills in the detector's training windows.
PERSON_SHARE = 0.75
#: Least share of the fitted person's box that person segmentation marks as person pixels.
MIN_PERSON_SHARE = 0.2


#: Held while a search runs with OpenCV's pool set to one thread (a setting of the whole process).
_ONE_THREAD = threading.Lock()


class BodyDetector:
    """OpenCV's HOG people detector, people from ``min_share`` x the frame's shorter side up; one
    per thread. A search runs on the calling thread only: OpenCV's own thread pool is set to one
    thread for its duration and restored after (searches are serialised by a lock, since the setting
    is the process's), because trustnav's backends already keep every core busy with their own
    workers and OpenCV's pool would take the core of the frame loop."""

    def __init__(self, min_share: float = MIN_HEIGHT_SHARE) -> None:
        import cv2

        if not hasattr(cv2, "HOGDescriptor_getDefaultPeopleDetector"):
            raise RuntimeError(
                f"OpenCV {cv2.__version__} has no HOG people detector: install opencv-python-headless 4.x "
                "(pyproject pins it) or set MediaPipeConfig(body_search=False)"
            )
        if not (math.isfinite(min_share) and 0.02 <= min_share <= 1.0):
            raise ValueError(f"min_share must be in [0.02, 1] (of the frame's shorter side), got {min_share!r}")
        self.min_share = min_share
        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def __call__(self, frame: NDArray[np.uint8]) -> list[NDArray[np.float64]]:
        """Windows [x0, y0, x1, y1] (frame pixels) the detector takes for a person."""
        import cv2

        h, w = frame.shape[:2]
        scale = search_scale(h, w, self.min_share)
        if round(w * scale) < WINDOW[0] or round(h * scale) < WINDOW[1]:
            return []  # smaller than one window: nobody to find (and OpenCV aborts on it)
        smooth = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
        big = cv2.resize(frame, None, fx=scale, fy=scale, interpolation=smooth)
        with _ONE_THREAD:
            before = cv2.getNumThreads()
            cv2.setNumThreads(1)
            try:
                rects, _ = self._hog.detectMultiScale(big, hitThreshold=0.0, winStride=(8, 8), padding=(8, 8),
                                                      scale=PYRAMID_STEP)  # fmt: skip
            finally:
                cv2.setNumThreads(before)
        return [np.array([x, y, x + bw, y + bh], dtype=np.float64) / scale for x, y, bw, bh in rects]


def search_scale(height: int, width: int, min_share: float = MIN_HEIGHT_SHARE) -> float:
    """The factor the frame is resized by so that a person ``min_share`` x its shorter side tall
    fills the detector's window (in [0.5, 2]: 1.5 at 640x480, 1.0 at 1280x720, 0.7 at 2048x1024)."""
    return float(np.clip(WINDOW_PERSON_PX / (min_share * min(height, width)), 0.5, 2.0))


def window_region(window: NDArray[np.float64]) -> NDArray[np.float64]:
    """The landmark region [cx, cy, side, rotation, NaN x 3] of a body window: a square of 1.25 x
    the person's height (as for a segmentation region) around the window's centre."""
    x0, y0, x1, y1 = window
    side = 1.25 * PERSON_SHARE * (y1 - y0)
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, side, 0.0, math.nan, math.nan, math.nan])


def consistent(box: NDArray[np.float64], landmarks: NDArray[np.float64], window: NDArray[np.float64]) -> bool:
    """A landmark fit on a body window is of the person the window frames: at least
    :data:`MIN_HEIGHT_PX` tall and :data:`MIN_PRESENCE` present, 0.45-1.1 of the window's height, its
    centre within a quarter of that height of the window's centre (the window frames a whole person)."""
    height = float(box[3] - box[1])
    span = float(window[3] - window[1])
    if height < MIN_HEIGHT_PX or float(np.mean(landmarks[11:29, 4])) < MIN_PRESENCE:
        return False
    if not 0.45 * span <= height <= 1.1 * span:
        return False
    centre = (box[:2] + box[2:]) / 2 - (window[:2] + window[2:]) / 2
    return bool(math.hypot(*centre) <= 0.25 * span)


def segment_square(box: NDArray[np.float64], width: int, height: int) -> tuple[int, int, int, int]:
    """The window (x0, y0, x1, y1) segmented to check a fitted ``box``: a square of 1.6 x its height
    around it (the segmentation model wants the person with some scene around), inside the frame."""
    side = max(16, round(1.6 * float(box[3] - box[1])))
    cx, cy = float(box[0] + box[2]) / 2, float(box[1] + box[3]) / 2
    x0 = min(max(0, round(cx - side / 2)), max(0, width - side))
    y0 = min(max(0, round(cy - side / 2)), max(0, height - side))
    return x0, y0, min(width, x0 + side), min(height, y0 + side)


def person_share(box: NDArray[np.float64], mask: NDArray[np.float32], window: tuple[int, int, int, int]) -> float:
    """Share of ``box`` (frame pixels) that ``mask`` (person probabilities of ``window``) marks as a person's."""
    x0, y0 = window[:2]
    bx0, by0 = max(round(float(box[0])) - x0, 0), max(round(float(box[1])) - y0, 0)
    bx1, by1 = round(float(box[2])) - x0, round(float(box[3])) - y0
    inner = mask[by0:by1, bx0:bx1]
    return float((inner > 0.5).mean()) if inner.size else 0.0
