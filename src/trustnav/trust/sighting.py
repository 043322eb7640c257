"""What perception saw of one track at one instant: the input of every trait (see :mod:`.parts`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from numbers import Integral
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from trustnav.trust.params import as_number

__all__ = ["EYE_CONTACT", "SMARTPHONE", "Sighting"]

#: Cue name of C_sm (`smato_score`), carried by :attr:`Sighting.c_smartphone`.
SMARTPHONE = "smartphone"
#: Cue name of C_eye (`eye_score`), carried by :attr:`Sighting.c_eye`.
EYE_CONTACT = "eye_contact"
_FIELD_OF = {SMARTPHONE: "c_smartphone", EYE_CONTACT: "c_eye"}


def _confidence(name: str, value: object) -> float:
    c = as_number(name, value)
    if not 0.0 <= c <= 1.0:
        raise ValueError(f"{name} must be a confidence in [0, 1] (or None), got {value!r}")
    return c


@dataclass(frozen=True)
class Sighting:
    """What perception saw of one track at one instant. Any trait input may be missing (None).

    c_smartphone, c_eye: the paper's cues C_sm and C_eye (cue names :data:`SMARTPHONE`,
    :data:`EYE_CONTACT`); keypoints (K, 2) with bbox [x1, y1, x2, y2]: pose fluctuation
    (`pose_conf`); cues: any other cue by name, a confidence in [0, 1] (read by user-defined
    traits through :meth:`cue`). A cue absent from ``cues`` is missing.
    """

    track_id: int
    time: float
    c_smartphone: float | None = None
    c_eye: float | None = None
    keypoints: NDArray[np.float64] | None = None
    bbox: NDArray[np.float64] | None = None
    cues: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.track_id, bool) or not isinstance(self.track_id, Integral):
            raise ValueError(f"observation track_id must be an integer, got {self.track_id!r}")
        object.__setattr__(self, "track_id", int(self.track_id))
        t = as_number("observation time", self.time)
        if not math.isfinite(t):
            raise ValueError(f"observation time must be finite seconds, got {self.time!r}")
        object.__setattr__(self, "time", t)
        for name in ("c_smartphone", "c_eye"):
            c = getattr(self, name)
            if c is not None:
                object.__setattr__(self, name, _confidence(name, c))
        if (self.keypoints is None) != (self.bbox is None):
            raise ValueError("keypoints and bbox must be given together (pose fluctuation needs both)")
        if self.keypoints is not None:
            kp = np.asarray(self.keypoints, dtype=float)
            box = np.asarray(self.bbox, dtype=float)
            if kp.ndim != 2 or kp.shape[1] != 2 or box.shape != (4,):
                raise ValueError(
                    f"keypoints must be (K, 2) and bbox [x1, y1, x2, y2], got shapes {kp.shape} and {box.shape}"
                )
            object.__setattr__(self, "keypoints", kp)
            object.__setattr__(self, "bbox", box)
        if not isinstance(self.cues, Mapping):
            raise ValueError(f"observation cues must be a mapping of cue name -> confidence, got {self.cues!r}")
        cues: dict[str, float] = {}
        for name, value in self.cues.items():
            if not isinstance(name, str) or not name:
                raise ValueError(f"observation cue names must be non-empty strings, got {name!r}")
            if name in _FIELD_OF:
                raise ValueError(f"cue {name!r} is carried by Sighting.{_FIELD_OF[name]}; pass it there")
            cues[name] = _confidence(f"cue {name!r}", value)
        object.__setattr__(self, "cues", MappingProxyType(cues))

    def cue(self, name: str) -> float | None:
        """Confidence of the cue ``name`` in this observation, or None when it is missing."""
        if name == SMARTPHONE:
            return self.c_smartphone
        if name == EYE_CONTACT:
            return self.c_eye
        return self.cues.get(name)
