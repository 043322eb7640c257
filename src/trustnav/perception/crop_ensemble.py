"""Offline landmark fits made steadier: each confirmed person fitted again on slightly moved crops.

The BlazePose landmark model reads a person from a square region of the frame; moving that region
by one pixel moves the wrists and the face points by a few pixels and, on small people, the cues
that read them (the phone posture of `smato_score`, LOOKING's input of `eye_score`) across their
thresholds: ``benchmarks/trust_eval.py --jitter 3`` spreads phone F1 over 0.83-0.87 and eye-contact
recall over 0.91-0.96 from whole-pixel shifts of the frames alone. :class:`CropEnsembleBackend`
reduces that noise rather than tuning thresholds on it: after the detector path confirms a person
(:meth:`~trustnav.perception.mediapipe_backend.MediaPipePoseBackend._confirm`), the landmark model
is run again on the accepted region moved and scaled by :data:`CROP_PERTURBATIONS`; each fit the
backend would accept as the same person (upright, hips where the region put them, its extent
overlapping the first fit's by IoU >= :data:`SAME_FIT_IOU`) joins, and the person's 33 landmarks
(x, y, depth, visibility, presence) are their per-coordinate median. Keypoints and the occlusion
confidences are recomputed from the median; the box, the score and the region followed to the next
frame stay those of the first fit (detection and tracking are unchanged).

Offline only and opt-in (``trustnav estimate --crop-fits 5``; the default is one fit everywhere):
each extra fit costs one landmark run per person. It was measured and not made the default: it
holds the keypoints ~30 % steadier under a one-pixel shift of the frame, but the labelled sets'
phone and eye-contact figures do not improve (docs/perception.md, "Landmarks fitted on moved
crops").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.confidence import BLAZEPOSE_TO_COCO, occlusion_confidences
from trustnav.perception.mediapipe_backend import MediaPipeConfig, MediaPipePoseBackend
from trustnav.perception.types import box_iou

__all__ = ["CROP_PERTURBATIONS", "DEFAULT_CROP_FITS", "SAME_FIT_IOU", "CropEnsembleBackend", "median_landmarks"]

#: Moves of the accepted landmark region for the extra fits: (dx, dy) in pixels, then a scale of its
#: side. The first ``fits - 1`` are used (``CropEnsembleBackend(fits=...)``): the default 5 fits are
#: the region as accepted and moved by one pixel left, right, down and up.
CROP_PERTURBATIONS: tuple[tuple[float, float, float], ...] = (
    (1.0, 0.0, 1.0),
    (-1.0, 0.0, 1.0),
    (0.0, 1.0, 1.0),
    (0.0, -1.0, 1.0),
    (0.0, 0.0, 0.97),
    (0.0, 0.0, 1.03),
)

#: Fits per confirmed person of :class:`CropEnsembleBackend` unless given (the first and 4 moved ones).
DEFAULT_CROP_FITS = 5

#: An extra fit joins the median only if its landmarks' extent overlaps the first fit's this much
#: (a moved crop can make the model jump to a neighbour).
SAME_FIT_IOU = 0.7


def median_landmarks(fits: Sequence[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Per-coordinate median of several (33, 5) landmark arrays of one person (x, y, z, visibility,
    presence); ValueError on no fits or mismatched shapes."""
    if not len(fits):
        raise ValueError("median_landmarks needs at least one fit")
    shapes = {np.shape(f) for f in fits}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"landmark fits must share one shape (landmarks x values), got {sorted(shapes)}")
    return np.median(np.stack([np.asarray(f, dtype=float) for f in fits]), axis=0)


def _extent(lm: NDArray[np.float64]) -> NDArray[np.float64]:
    pts = lm[:, :2]
    return np.r_[pts.min(axis=0), pts.max(axis=0)]


class CropEnsembleBackend(MediaPipePoseBackend):
    """:class:`~trustnav.perception.mediapipe_backend.MediaPipePoseBackend` whose detector-path fits
    are the median of ``fits`` landmark fits on moved crops (module docstring). ``fits`` = 1 is the
    plain backend. Only the detector proposer is affected."""

    def __init__(self, config: MediaPipeConfig | None = None, *, video: bool = False, fits: int = DEFAULT_CROP_FITS):
        if not isinstance(fits, int) or not 1 <= fits <= len(CROP_PERTURBATIONS) + 1:
            raise ValueError(f"crop fits must be an integer in [1, {len(CROP_PERTURBATIONS) + 1}], got {fits!r}")
        super().__init__(config, video=video)
        self.fits = fits

    def _confirm(self, g: Any, frame: NDArray[np.uint8], rois: NDArray, score: float, box: NDArray, w: int, h: int):  # type: ignore[override]
        out = super()._confirm(g, frame, rois, score, box, w, h)
        if out is None or self.fits <= 1:
            return out
        lm0, nxt, roi, person = out
        first = _extent(lm0)
        fits = [lm0]
        for dx, dy, scale in CROP_PERTURBATIONS[: self.fits - 1]:
            moved = np.array(roi, dtype=float).copy()
            moved[0] += dx
            moved[1] += dy
            moved[2] *= scale
            res = g.landmarks(frame, moved)
            if res is None:
                continue
            lm = res[0]
            if self._person(lm, 1.0, w, h, moved) is None or box_iou(_extent(lm), first) < SAME_FIT_IOU:
                continue
            fits.append(lm)
        lm = median_landmarks(fits)
        extra = {**person.extra, "blazepose": lm, "crop_fits": len(fits)}
        coco = lm[list(BLAZEPOSE_TO_COCO)]
        steadier = replace(person, keypoints=coco[:, :2].copy(), confidences=occlusion_confidences(lm), extra=extra)
        return lm, nxt, roi, steadier
