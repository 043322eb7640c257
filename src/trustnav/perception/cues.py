"""Cue extractors: frame + the people found in it -> one confidence per person for one trait cue.

A cue feeds a trait of :mod:`trustnav.trust.parts` by name: the pipeline puts ``smartphone`` into
``Observation.c_smartphone``, ``eye_contact`` into ``Observation.c_eye`` and any other cue into
``Observation.cues``. The defaults are the paper's two image cues, eye contact (LOOKING, C_eye of
`eye_score`) and smartphone use (C_sm of `smato_score`); pose fluctuation (`pose_conf`) needs no
extractor, it reads the keypoints. A new cue (e.g. ``head_turned``) is any object with a ``name``
that is callable as ``cue(frame, people) -> confidences``; NaN marks a person it cannot judge.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.looking import LookingModel, normalise_keypoints
from trustnav.perception.phone import PhoneClassifier, PoseGeometryPhoneClassifier
from trustnav.perception.types import Person
from trustnav.trust.observation import EYE_CONTACT, SMARTPHONE

__all__ = ["CueExtractor", "EyeContactCue", "PhoneUseCue", "check_cues", "default_cues", "run_cue"]


@runtime_checkable
class CueExtractor(Protocol):
    """(frame RGB, people of the frame) -> one confidence in [0, 1] (or NaN) per person, in order."""

    @property
    def name(self) -> str: ...

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> Sequence[float]: ...


@dataclass(frozen=True)
class EyeContactCue:
    """C_eye for `eye_score`: the LOOKING model on each person's 17 keypoints and confidences."""

    model: LookingModel
    name: str = EYE_CONTACT

    def __post_init__(self) -> None:
        if not hasattr(self.model, "predict"):
            raise ValueError(f"eye_model must be a LookingModel (with predict), got {type(self.model).__name__}")

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> NDArray[np.float64]:
        if not people:
            return np.zeros(0)
        inputs = np.stack([normalise_keypoints(p.keypoints, p.confidences, frame.shape[1]) for p in people])
        return self.model.predict(inputs)


@dataclass(frozen=True)
class PhoneUseCue:
    """C_sm for `smato_score`: a :class:`~trustnav.perception.phone.PhoneClassifier` per person."""

    classifier: PhoneClassifier = field(default_factory=PoseGeometryPhoneClassifier)
    name: str = SMARTPHONE

    def __post_init__(self) -> None:
        if not callable(self.classifier):
            raise ValueError(f"phone must be a PhoneClassifier (callable), got {type(self.classifier).__name__}")

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> list[float]:
        return [float(self.classifier(frame, p)) for p in people]


def default_cues(eye_model: LookingModel, phone: PhoneClassifier | None = None) -> tuple[CueExtractor, ...]:
    """The paper's image cues: eye contact (LOOKING) and smartphone use (pose geometry by default)."""
    return (EyeContactCue(eye_model), PhoneUseCue(phone or PoseGeometryPhoneClassifier()))


def check_cues(cues: Sequence[CueExtractor]) -> tuple[CueExtractor, ...]:
    """``cues`` as a tuple, each with a unique non-empty ``name`` and callable, else ValueError."""
    if isinstance(cues, (str, bytes)) or not isinstance(cues, Sequence):
        raise ValueError(f"cues must be a sequence of cue extractors, got {cues!r}")
    seen: set[str] = set()
    for i, c in enumerate(cues):
        name = getattr(c, "name", None)
        if not isinstance(name, str) or not name or not callable(c):
            raise ValueError(f"cues[{i}] must be a cue extractor (a name and a call (frame, people)), got {c!r}")
        if name in seen:
            raise ValueError(f"cue names must be unique, {name!r} appears twice")
        seen.add(name)
    return tuple(cues)


def run_cue(cue: CueExtractor, frame: NDArray[np.uint8], people: Sequence[Person]) -> list[float]:
    """The cue's confidences for ``people``, checked: one per person, each in [0, 1] or NaN."""
    values = list(cue(frame, people))
    if len(values) != len(people):
        raise ValueError(f"cue {cue.name!r} gave {len(values)} confidences for {len(people)} people")
    out = [float(v) for v in values]
    for v in out:
        if not (math.isnan(v) or 0.0 <= v <= 1.0):
            raise ValueError(f"cue {cue.name!r} gave {v!r}; a confidence must lie in [0, 1] (NaN: not judged)")
    return out
