"""Cue extractors: frame + the people found in it -> one confidence per person for one trait cue.

A cue feeds a trait of :mod:`trustnav.trust.parts` by name: the pipeline puts ``smartphone`` into
``Sighting.c_smartphone``, ``eye_contact`` into ``Sighting.c_eye`` and any other cue into
``Sighting.cues``. The defaults are the paper's two image cues, eye contact (LOOKING, C_eye of
`eye_score`) and smartphone use (C_sm of `smato_score`); pose fluctuation (`pose_conf`) needs no
extractor, it reads the keypoints. A new cue (e.g. ``head_turned``) is any object with a ``name``
that is callable as ``cue(frame, people) -> confidences``; NaN marks a person it cannot judge.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.confidence import BLAZEPOSE_TO_COCO, face_confidences, head_yaw
from trustnav.perception.face import FACE_FIELDS, FaceConfig, FaceEyeContact, FaceResult, fuse_eye_contact
from trustnav.perception.looking import LookingModel, normalise_keypoints
from trustnav.perception.phone import (
    LABELLED_PHONE_CALIBRATION,
    PhoneCalibration,
    PhoneClassifier,
    PoseGeometryPhoneClassifier,
    TemporalPhoneModel,
    fuse_crop,
)
from trustnav.perception.types import Person
from trustnav.trust.sighting import EYE_CONTACT, SMARTPHONE

__all__ = [
    "CueExtractor",
    "EyeContactCue",
    "FaceEyeContactCue",
    "FaceFieldCue",
    "PhoneUseCue",
    "check_cues",
    "default_cues",
    "run_cue",
    "with_face",
]


@runtime_checkable
class CueExtractor(Protocol):
    """(frame RGB, people of the frame) -> one confidence in [0, 1] (or NaN) per person, in order."""

    @property
    def name(self) -> str: ...

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> Sequence[float]: ...


@dataclass(frozen=True)
class EyeContactCue:
    """C_eye for `eye_score`: the LOOKING model on each person's 17 keypoints and confidences.

    ``posture``: with a :class:`~trustnav.perception.phone.PoseGeometryPhoneClassifier`, a person
    holding something in both hands in front of the torso (a phone held to be read,
    :meth:`~trustnav.perception.phone.PoseGeometryPhoneClassifier.hands_together`, h in [0, 1]) has
    their eyes on it: C_eye is multiplied by 1 - ``posture_weight`` * h (the default cues)."""

    model: LookingModel
    name: str = EYE_CONTACT
    posture: PoseGeometryPhoneClassifier | None = None
    posture_weight: float = 0.8

    def __post_init__(self) -> None:
        if not hasattr(self.model, "predict"):
            raise ValueError(f"eye_model must be a LookingModel (with predict), got {type(self.model).__name__}")
        if not 0.0 <= self.posture_weight <= 1.0:
            raise ValueError(f"posture_weight must be in [0, 1], got {self.posture_weight!r}")

    def looking(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> NDArray[np.float64]:
        """LOOKING's eye-contact probability per person (no posture veto)."""
        if not people:
            return np.zeros(0)
        inputs = np.stack([normalise_keypoints(p.keypoints, p.confidences, frame.shape[1]) for p in people])
        return self.model.predict(inputs)

    def veto(self, people: Sequence[Person], values: NDArray[np.float64]) -> NDArray[np.float64]:
        """``values`` times 1 - posture_weight * (both hands held together in front), per person."""
        if self.posture is None or not len(people):
            return np.asarray(values, dtype=float)
        held = np.array([self.posture.hands_together(p.keypoints, p.confidences) for p in people])
        return np.asarray(values, dtype=float) * (1.0 - self.posture_weight * held)

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> NDArray[np.float64]:
        return self.veto(people, self.looking(frame, people))


@dataclass(frozen=True)
class FaceEyeContactCue(EyeContactCue):
    """C_eye from LOOKING fused with the face (:mod:`trustnav.perception.face`) by confidence:
    C_eye = (1 - a) p_looking + a p_face, a = max_face_weight * c_face; LOOKING alone on people too
    small for a face (:func:`~trustnav.perception.face.fuse_eye_contact`)."""

    face: FaceEyeContact = field(default_factory=FaceEyeContact)

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> NDArray[np.float64]:
        faces = self.face(frame, people)
        looking = self.looking(frame, [self._face_yawed(p, f) for p, f in zip(people, faces, strict=True)])
        w = self.face.config.max_face_weight
        fused = [
            fuse_eye_contact(float(p), f.probability, f.confidence, w) for p, f in zip(looking, faces, strict=True)
        ]
        return self.veto(people, np.array(fused, dtype=float))

    def _face_yawed(self, person: Person, face: FaceResult) -> Person:
        """``person`` with the face keypoints' confidences (LOOKING's input) from a head yaw that moves
        from the ears' depth (:func:`~trustnav.perception.confidence.head_yaw`) to the face mesh's
        yaw as the face is seen better: weight w = size x agreement, size ramping from
        ``FaceConfig.face_px_min`` to :data:`FACE_YAW_MIN_PX` (w = 1 from there: the mesh's yaw;
        BlazePose's ears often read the body's orientation, -80 deg where the mesh reads -30 deg) and
        agreement that of the shifted fits of a small face (:class:`~trustnav.perception.face.FaceResult`).
        The two angles are mixed on the circle; a face whose reading flips with its crop keeps the body's."""
        lm = person.extra.get("blazepose")
        if lm is None or not math.isfinite(face.yaw):
            return person
        lo = self.face.config.face_px_min
        size = min(max((face.face_px - lo) / max(FACE_YAW_MIN_PX - lo, 1e-9), 0.0), 1.0)
        w = size * min(max(face.agreement, 0.0), 1.0)
        if w <= 0.0:
            return person
        lm = np.asarray(lm, dtype=float)
        mesh = math.radians(face.yaw)
        if w < 1.0:
            ears = head_yaw(lm)
            mesh = math.atan2(
                (1 - w) * math.sin(ears) + w * math.sin(mesh), (1 - w) * math.cos(ears) + w * math.cos(mesh)
            )
        conf = np.array(person.confidences, dtype=float)
        vis = np.clip(lm[list(BLAZEPOSE_TO_COCO[:5]), 3], 0.0, 1.0)
        conf[:5] = face_confidences(vis, mesh)
        return replace(person, confidences=conf)


#: The face height (px) from which the face mesh's yaw alone sets LOOKING's face-keypoint confidences
#: (below it, mixed with the ears' yaw by size and agreement: :meth:`FaceEyeContactCue._face_yawed`).
FACE_YAW_MIN_PX = 20.0


@dataclass(frozen=True)
class FaceFieldCue:
    """The face analysis's own numbers as record fields: ``eye_contact_face`` (p_face) or
    ``face_confidence`` (c_face); NaN (not judged) where no face was looked for. Shares the
    analysis (cached per frame) of the :class:`FaceEyeContactCue` it is built with."""

    face: FaceEyeContact
    name: str = FACE_FIELDS[0]

    def __post_init__(self) -> None:
        if self.name not in FACE_FIELDS:
            raise ValueError(f"a face field is one of {FACE_FIELDS}, got {self.name!r}")

    def __call__(self, frame: NDArray[np.uint8], people: Sequence[Person]) -> list[float]:
        faces = self.face(frame, people)
        if self.name == FACE_FIELDS[0]:
            return [f.probability for f in faces]
        return [math.nan if math.isnan(f.probability) else f.confidence for f in faces]


def with_face(
    cues: Sequence[CueExtractor], face: FaceEyeContact | FaceConfig | None = None
) -> tuple[CueExtractor, ...]:
    """``cues`` with the LOOKING eye-contact cue replaced by :class:`FaceEyeContactCue` (same model)
    and the face fields (:data:`~trustnav.perception.face.FACE_FIELDS`) added; ``trustnav estimate
    --face``. ``face``: an analyser to share (its graphs load once) or its configuration.
    ValueError if ``cues`` has no :class:`EyeContactCue`."""
    face = face if isinstance(face, FaceEyeContact) else FaceEyeContact(face)
    out: list[CueExtractor] = []
    found = False
    for c in cues:
        if isinstance(c, EyeContactCue) and not found:
            kw = {"posture": c.posture, "posture_weight": c.posture_weight}
            out.append(FaceEyeContactCue(c.model, c.name, face=face, **kw))
            found = True
        elif isinstance(c, PhoneUseCue) and c.face is not None:
            out.append(dataclasses.replace(c, face=face))  # one face analysis per frame, shared
        else:
            out.append(c)
    if not found:
        raise ValueError("with_face needs an EyeContactCue (LOOKING) among the cues to fuse the face with")
    return (*out, *(FaceFieldCue(face, n) for n in FACE_FIELDS))


@dataclass(frozen=True)
class PhoneUseCue:
    """C_sm for `smato_score`: a :class:`~trustnav.perception.phone.PhoneClassifier` per person.

    With ``temporal`` (a :class:`~trustnav.perception.phone.TemporalPhoneModel`, the default of
    :func:`default_cues`) and the people's track IDs and the frame time (the pipeline passes them:
    ``uses_tracks``), C_sm is the posture over the last seconds of each track fused with this frame's
    geometry; without them, the classifier on this frame alone. ``crop``: a user's image classifier
    on the person crop (:class:`~trustnav.perception.phone.CropPhoneClassifier`), fused by
    confidence (:func:`~trustnav.perception.phone.fuse_crop`). ``face``: the face analysis (shared
    with the eye-contact cue, so it runs once per frame) whose head pitch tells the pose classifier
    whether a near person looks down at their hands
    (:meth:`~trustnav.perception.phone.PoseGeometryPhoneClassifier.parts`).
    """

    classifier: PhoneClassifier = field(default_factory=PoseGeometryPhoneClassifier)
    name: str = SMARTPHONE
    temporal: TemporalPhoneModel | None = None
    crop: PhoneClassifier | None = None
    face: FaceEyeContact | None = None
    uses_tracks: ClassVar[bool] = True  # run_cue passes track_ids and time

    def __post_init__(self) -> None:
        if not callable(self.classifier):
            raise ValueError(f"phone must be a PhoneClassifier (callable), got {type(self.classifier).__name__}")
        if self.temporal is not None and not hasattr(self.temporal, "add_pose"):
            raise ValueError(f"temporal must be a TemporalPhoneModel, got {type(self.temporal).__name__}")
        if self.crop is not None and not callable(self.crop):
            raise ValueError(f"crop must be a PhoneClassifier (callable), got {type(self.crop).__name__}")

    def __call__(
        self,
        frame: NDArray[np.uint8],
        people: Sequence[Person],
        track_ids: Sequence[int] | None = None,
        time: float | None = None,
    ) -> list[float]:
        heads: list[tuple[float, float] | None] = [None] * len(people)
        if self.face is not None and people:
            heads = [None if math.isnan(f.pitch) else (f.pitch, f.confidence) for f in self.face(frame, people)]
        if self.temporal is not None and track_ids is not None:
            out = [
                self.temporal.add_pose(tid, time, p.keypoints, p.confidences, face=h).phone
                for tid, p, h in zip(track_ids, people, heads, strict=True)
            ]
        elif self.face is not None and isinstance(self.classifier, PoseGeometryPhoneClassifier):
            out = []
            for p, h in zip(people, heads, strict=True):
                texting, calling, pair = self.classifier.parts(p.keypoints, p.confidences, face=h)
                out.append(float(max(texting.max(), calling.max(), pair)))
        else:
            out = [float(self.classifier(frame, p)) for p in people]
        if self.crop is not None:
            out = [
                fuse_crop(c, float(self.crop(frame, p)), float(p.bbox[3] - p.bbox[1]))
                for c, p in zip(out, people, strict=True)
            ]
        return out


def default_cues(
    eye_model: LookingModel,
    phone: PhoneClassifier | None = None,
    face: FaceEyeContact | FaceConfig | None = None,
    phone_calibration: PhoneCalibration | None = LABELLED_PHONE_CALIBRATION,
) -> tuple[CueExtractor, ...]:
    """The paper's image cues: eye contact and smartphone use.

    Eye contact: LOOKING fused by confidence with the face (:class:`FaceEyeContactCue`; the face is
    looked at only on people at least ``FaceConfig.min_person_px`` tall, LOOKING alone below), with
    the both-hands posture veto (:class:`EyeContactCue`). ``face``: an analyser to share or its
    configuration. Smartphone use: by default the pose geometry made temporal per track
    (:class:`~trustnav.perception.phone.TemporalPhoneModel`), its value made a probability by
    ``phone_calibration`` (the Platt map fitted on the labelled sets,
    :data:`~trustnav.perception.phone.LABELLED_PHONE_CALIBRATION`; None: the model's raw value); a
    user's ``phone`` classifier is used as given, frame by frame."""
    geometry = phone if isinstance(phone, PoseGeometryPhoneClassifier) else PoseGeometryPhoneClassifier()
    face = face if isinstance(face, FaceEyeContact) else FaceEyeContact(face)
    eye = FaceEyeContactCue(eye_model, face=face, posture=geometry)
    if phone is None or isinstance(phone, PoseGeometryPhoneClassifier):
        return (eye, PhoneUseCue(geometry, temporal=TemporalPhoneModel(geometry, calibration=phone_calibration)))
    return (eye, PhoneUseCue(phone))


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


def run_cue(
    cue: CueExtractor,
    frame: NDArray[np.uint8],
    people: Sequence[Person],
    *,
    track_ids: Sequence[int] | None = None,
    time: float | None = None,
) -> list[float]:
    """The cue's confidences for ``people``, checked: one per person, each in [0, 1] or NaN.

    A cue with ``uses_tracks = True`` (temporal cues) is called as ``cue(frame, people,
    track_ids=..., time=...)`` (track ID per person, -1 if untracked; frame time in seconds, None
    if unknown); every other cue as ``cue(frame, people)``."""
    if getattr(cue, "uses_tracks", False):
        values = list(cue(frame, people, track_ids=track_ids, time=time))
    else:
        values = list(cue(frame, people))
    if len(values) != len(people):
        raise ValueError(f"cue {cue.name!r} gave {len(values)} confidences for {len(people)} people")
    out = [float(v) for v in values]
    for v in out:
        if not (math.isnan(v) or 0.0 <= v <= 1.0):
            raise ValueError(f"cue {cue.name!r} gave {v!r}; a confidence must lie in [0, 1] (NaN: not judged)")
    return out
