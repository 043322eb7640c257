"""Smartphone-use confidence C_sm for `smato_score`.

The paper classifies the person crop with a fine-tuned image classifier; no such model can be had
offline, so the default reads the pose (COCO 17 keypoints, image y downwards):

* texting: a wrist raised ``raise_band`` (0.55-0.95) of the way from its hip up to its shoulder and
  in front of the torso, weighted up when the head is pitched down (nose below the ears);
* calling: a wrist at the face (near an ear).

C_sm = max(texting, calling) in [0, 1]. :class:`PhoneClassifier` is the interface; an image
classifier on the person crop (the paper's design) plugs in the same way: :class:`CropPhoneClassifier`
runs a user's ONNX/TFLite file through OpenCV's DNN module, fused by confidence (:func:`fuse_crop`).

One frame's geometry cannot tell a held phone from an arm on its swing: :class:`TemporalPhoneModel`
follows each track over the last seconds (hands held still in the phone pose vs swinging with the
gait) and fuses that with the frame's geometry; it is the pipeline's default (see
docs/perception.md, "Phone use over time").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.types import Person

__all__ = [
    "LABELLED_PHONE_CALIBRATION",
    "CropPhoneClassifier",
    "PhoneCalibration",
    "PhoneClassifier",
    "PoseGeometryPhoneClassifier",
    "TemporalPhoneModel",
    "TemporalPhoneResult",
    "fuse_crop",
    "phone_label",
]


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
    # seen from behind: the face's best keypoint confidence (nose, eyes; occlusion-aware: ~1 facing,
    # the near eye ~0.7 in profile, all ~0 from the back) from no cue -> full cue; hands in front of
    # the torso are then hidden by the body, their keypoints guesses
    facing_confidence: tuple[float, float] | None = (0.2, 0.5)
    pair_distance: tuple[float, float] = (0.35, 0.5)  # wrists this close (torso lengths): held together
    # head pitch from the face mesh (degrees below the camera ray: no cue -> full cue), used by the
    # texting cue in proportion to the face's confidence where the face was judged
    face_pitch_down: tuple[float, float] = (5.0, 20.0)

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
        for name in ("facing_confidence", "pair_distance", "face_pitch_down"):
            pair = getattr(self, name)
            if pair is not None and not 0.0 <= pair[0] < pair[1]:
                raise ValueError(f"{name} must be (low, high) with 0 <= low < high, got {pair!r}")

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
        return float(np.clip(self.per_wrist(kp, confidences).max(initial=0.0), 0.0, 1.0))

    def per_wrist(
        self, keypoints: NDArray[np.float64], confidences: NDArray[np.float64] | None = None
    ) -> NDArray[np.float64]:
        """The cue of each wrist (left, right): max(texting, calling, both hands) for that hand, in [0, 1]."""
        texting, calling, pair = self.parts(keypoints, confidences)
        return np.clip(np.maximum(np.maximum(texting, calling), pair), 0.0, 1.0)

    def parts(
        self,
        keypoints: NDArray[np.float64],
        confidences: NDArray[np.float64] | None = None,
        facing: float | None = None,
        face: tuple[float, float] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """(texting per wrist, calling per wrist, both hands held together) from one frame's pose.

        texting: the wrist raised ``raise_band`` of the way from hip to shoulder, in front of the
        torso, weighted by the head pitched down (``head_weight``), times its confidence ramp and the
        facing factor (off for a person seen from behind, ``facing_confidence``: the hands are then
        hidden by the body and the head, their keypoints guesses); calling: the wrist at an ear,
        times the facing factor; both hands: the two wrists within ``pair_distance`` torso lengths
        of each other, both in the raise band in front of the torso (a phone held in both hands):
        seen = 1 - (1 - s_l)(1 - s_r) (one well-seen wrist vouches for the pair: hands together in
        front are half hidden), the head weight as for texting, times the facing factor.

        ``facing``: that factor as given (e.g. judged over a track's recent frames) instead of from
        this frame's face keypoint confidences (:meth:`facing`). ``face``: (pitch in degrees, > 0
        tilted up, and confidence c in [0, 1]) of the head from the face mesh
        (:class:`~trustnav.perception.face.FaceResult`); where given, texting needs the eyes on the
        hands in proportion to c: the head weight becomes hw + (1 - hw) c and the head-down reading
        (1 - c) down_keypoints + c ramp(-pitch, ``face_pitch_down``), so a near person whose face
        looks ahead is not texting with a hand at the chest. Not used by default (a phone held at
        the mouth while looking at the camera is phone use too; docs/perception.md).
        """
        kp = np.asarray(keypoints, dtype=float)
        texting, calling = np.zeros(2), np.zeros(2)
        ok_body = np.isfinite(kp).all(axis=1)
        if kp.shape != (17, 2) or not ok_body[[5, 6, 11, 12]].all():
            return texting, calling, 0.0
        shoulders = kp[[5, 6]].mean(axis=0)
        hips = kp[[11, 12]].mean(axis=0)
        torso = float(np.hypot(*(hips - shoulders)))
        if torso < 1e-6:
            return texting, calling, 0.0
        down = 0.0
        if ok_body[[0, 3, 4]].all():
            drop = (kp[0, 1] - kp[[3, 4], 1].mean()) / torso
            down = _ramp(drop, *self.head_down)
        pair_head = 1.0 - self.head_weight + self.head_weight * down  # keypoints' head reading (not the face's)
        head_weight = self.head_weight
        if face is not None and math.isfinite(face[0]) and face[1] > 0.0:
            c = min(float(face[1]), 1.0)
            head_weight = self.head_weight + (1.0 - self.head_weight) * c
            down = (1.0 - c) * down + c * _ramp(-float(face[0]), *self.face_pitch_down)
        lo, hi = self.raise_band
        conf = np.ones(17) if confidences is None else np.asarray(confidences, dtype=float)
        if facing is None:
            facing = self.facing(conf if confidences is not None else None)
        seen_w, posture = np.zeros(2), np.zeros(2)  # confidence ramp; band x front (no head, no facing)
        for side, (wrist, shoulder, hip) in enumerate(((9, 5, 11), (10, 6, 12))):
            seen = _ramp(float(conf[wrist]), *self.wrist_confidence)
            if not ok_body[wrist] or seen <= 0.0:
                continue
            seen_w[side] = seen
            span = kp[hip, 1] - kp[shoulder, 1]
            if span > 1e-6:
                r = (kp[hip, 1] - kp[wrist, 1]) / span
                band = min(_ramp(r, lo - self.raise_softness, lo), 1.0 - _ramp(r, hi, hi + self.raise_softness))
                centre = abs(kp[wrist, 0] - 0.5 * (shoulders[0] + hips[0])) / torso
                front = 1.0 - _ramp(centre, self.front_of_torso, 1.6 * self.front_of_torso)
                posture[side] = band * front
                texting[side] = seen * posture[side] * (1.0 - head_weight + head_weight * down) * facing
                for ear in (3, 4):
                    if ok_body[ear]:
                        d = math.hypot(*(kp[wrist] - kp[ear])) / torso
                        near = 1.0 - _ramp(d, self.face_distance, 1.5 * self.face_distance)
                        calling[side] = max(calling[side], seen * near * facing)
        pair = 0.0
        if ok_body[[9, 10]].all() and seen_w.all():
            close = 1.0 - _ramp(math.hypot(*(kp[9] - kp[10])) / torso, *self.pair_distance)
            seen = 1.0 - (1.0 - seen_w[0]) * (1.0 - seen_w[1])
            pair = float(close * seen * min(posture) * pair_head * facing)
        return np.clip(texting, 0.0, 1.0), np.clip(calling, 0.0, 1.0), float(np.clip(pair, 0.0, 1.0))

    def facing(self, confidences: NDArray[np.float64] | None) -> float:
        """1 for a person whose face is toward the camera or in profile, falling to 0 for one seen
        from behind (the best confidence of nose and eyes, :meth:`face_seen`, below
        ``facing_confidence``); 1 without confidences."""
        seen = self.face_seen(confidences)
        if self.facing_confidence is None or not math.isfinite(seen):
            return 1.0
        return _ramp(seen, *self.facing_confidence)

    @staticmethod
    def face_seen(confidences: NDArray[np.float64] | None) -> float:
        """The largest confidence of nose and eyes (COCO 0-2): one face keypoint the camera sees
        (a profile's near eye; one keypoint dropped out does not hide a face); NaN without them."""
        if confidences is None:
            return math.nan
        c = np.asarray(confidences, dtype=float)[:3]
        c = c[np.isfinite(c)]
        return float(c.max()) if c.size else math.nan

    def hands_together(self, keypoints: NDArray[np.float64], confidences: NDArray[np.float64] | None = None) -> float:
        """The "phone held in both hands in front of the torso" posture in [0, 1] (:meth:`parts`)."""
        return self.parts(keypoints, confidences)[2]


# -- calibration: the cue's value as a probability ----------------------------------------------


@dataclass(frozen=True)
class PhoneCalibration:
    """P(phone use | C) = 1 / (1 + exp(-(intercept + slope * C))): a Platt map of the phone cue's value C.

    The pose cue is built from rules, not fitted as a probability: on the labelled real people its
    values of 0.1-0.5 belong to phone users far more often than they say (docs/perception.md, "Phone
    use calibrated"). The map makes C_sm (the input of `smato_score`) a probability; it is monotone
    (``slope`` > 0), so it orders people as C does, and moves the 0.5 verdict to C = :attr:`threshold`.
    Fitted by :meth:`fit` (``benchmarks/phone_track_evidence.py --calibrate``).
    """

    intercept: float
    slope: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.intercept) and math.isfinite(self.slope) and self.slope > 0):
            got = f"{self.intercept!r}, {self.slope!r}"
            raise ValueError(f"PhoneCalibration needs a finite intercept and a positive slope, got {got}")

    def __call__(self, confidence: float) -> float:
        """The calibrated probability of ``confidence`` (NaN stays NaN: not judged)."""
        c = float(confidence)
        if math.isnan(c):
            return math.nan
        z = self.intercept + self.slope * c
        return float(1.0 / (1.0 + math.exp(-z))) if z >= 0 else float(math.exp(z) / (1.0 + math.exp(z)))

    @property
    def threshold(self) -> float:
        """The cue value C that maps to probability 0.5."""
        return -self.intercept / self.slope

    @classmethod
    def fit(cls, values: NDArray[np.float64], labels: NDArray[np.bool_], ridge: float = 1e-3) -> PhoneCalibration:
        """Logistic regression of ``labels`` (phone use true/false) on the cue ``values`` (Newton's
        method; ``ridge`` * |(intercept, slope)|^2 added to the negative log-likelihood so that
        separable data give a finite map). ValueError unless both classes are present."""
        x = np.asarray(values, dtype=float).ravel()
        y = np.asarray(labels, dtype=float).ravel()
        if x.shape != y.shape or not np.isfinite(x).all():
            raise ValueError(f"PhoneCalibration.fit: values and labels must be finite and of one length, got "
                             f"{x.size} values ({int(np.isfinite(x).sum())} finite) and {y.size} labels")  # fmt: skip
        if not (0 < y.sum() < y.size):
            raise ValueError(f"PhoneCalibration.fit: the labels need both phone users and non-users, got "
                             f"{int(y.sum())} users of {y.size}")  # fmt: skip
        design = np.stack([np.ones_like(x), x], axis=1)
        w = np.zeros(2)
        for _ in range(100):
            p = 1.0 / (1.0 + np.exp(-(design @ w)))
            grad = design.T @ (p - y) + 2.0 * ridge * w
            hess = (design * (p * (1.0 - p))[:, None]).T @ design + 2.0 * ridge * np.eye(2)
            step = np.linalg.solve(hess, grad)
            w = w - step
            if float(np.abs(step).max()) < 1e-10:
                break
        return cls(float(w[0]), float(w[1]))


#: The Platt map of the default phone cue (the temporal pose model) fitted on every labelled
#: person-frame of walk_a, phone_a, street and rendered, the labels carried along each labelled
#: person's track between agreeing labelled frames (``benchmarks/phone_track_evidence.py
#: --calibrate``; 197 person-frames). Its 0.5 verdict lies at C = 0.419. Leave-one-set-out, the
#: maps fitted on three sets give phone F1 0.877 on the fourth's labelled frames (docs/perception.md).
LABELLED_PHONE_CALIBRATION = PhoneCalibration(-2.888, 6.894)


# -- phone use over time --------------------------------------------------------------------------


@dataclass
class _Track:
    times: list[float] = field(default_factory=list)
    hands: list[NDArray[np.float64]] = field(default_factory=list)  # per-wrist texting / both hands (2,)
    calls: list[NDArray[np.float64]] = field(default_factory=list)  # per-wrist calling (2,)
    noses: list[float] = field(default_factory=list)  # best face keypoint confidence (facing or not)
    seen: list[NDArray[np.float64]] = field(default_factory=list)  # per-wrist confidence ramp (2,)
    wrists: list[NDArray[np.float64]] = field(default_factory=list)  # (2, 2) torso-relative, NaN if unseen
    splits: list[float] = field(default_factory=list)  # wrists on opposite sides of the torso (a stride)
    torso_px: list[float] = field(default_factory=list)  # torso length in pixels (keypoint noise floor)


@dataclass(frozen=True)
class TemporalPhoneResult:
    """One person's temporal phone reading: ``phone`` (C_sm), the single-frame ``geometry``, the
    ``temporal`` score over the window, its ``weight`` in the fusion and the seconds of history."""

    phone: float
    geometry: float
    temporal: float
    weight: float
    history_s: float


class TemporalPhoneModel:
    """Phone use from the posture over time, per track (see docs/perception.md, "Phone use over time").

    Keeps, per track, the last ``window_s`` seconds of: each wrist's geometry cue
    (:meth:`PoseGeometryPhoneClassifier.per_wrist`: raised in front of the torso or at the ear, head
    bent) and each wrist's position relative to the torso (origin the shoulders' midpoint, unit the
    torso length). Over the window, per wrist w:

    * ``G_w = sum(g_w) / max(sum(s_w), n / 2, 1)``: mean geometry cue over the frames the wrist was
      seen (``s_w`` its confidence ramp; the phone pose must be *held*, not reached once by a swing;
      a wrist seen in under half the frames is shrunk);
    * ``M_w`` = median distance of the wrist from its median position (torso lengths; one misplaced
      wrist is not a swing); ``still_w = 1 - ramp(M_w, lo, lo + still[1] - still[0])`` with
      ``lo = max(still[0], noise_px / torso_px)`` (keypoint noise on small people is no swing);
    * ``S_w = G_w * (1 - motion_weight * (1 - still_w))``.

    Gait, from two signs of arms swinging with the stride: the two wrists' horizontal offsets
    anti-correlated (Pearson r < 0) while both move, ``swing = ramp(-r, *antiphase) *
    ramp(min(M_l, M_r), lo, ...)``; and, frame by frame, the wrists on opposite sides of the torso's
    centre line, both at least ``split[0]``-``split[1]`` torso lengths from it and below the chest
    (one forward, one back: a stride; it also sees a swing sampled at 1 frame/s, too slowly for the
    first sign), averaged over the window: ``stride``. ``gait = max(swing, stride)``; temporal score
    ``S = max(S_l, S_r) * (1 - gait)``. Hands together in front (texting) or one at the ear (calling)
    are on one side or on the line: no stride. Fusion with the current frame's geometry ``g``:

        C_sm = (1 - w) * g + w * S,   w = max_weight * min(1, history_s / window_s)

    where ``history_s`` is the time from the oldest sample in the window to now: the first frame of a
    track (or a single image) is geometry only, and the temporal part's weight grows with seconds
    (not frames) of history, so the result does not depend on the frame rate. A track not seen for
    ``reset_after_s`` seconds (or whose time goes backwards) restarts; histories never mix tracks;
    a person without a track ID (-1) or without a time gets geometry only.

    ``calibration``: a :class:`PhoneCalibration` applied to ``phone`` (C_sm as a probability;
    ``geometry``, ``temporal`` and ``weight`` stay the model's own); the default cues use
    :data:`LABELLED_PHONE_CALIBRATION`, the model alone none.
    """

    def __init__(
        self,
        geometry: PoseGeometryPhoneClassifier | None = None,
        *,
        window_s: float = 2.0,
        max_weight: float = 0.8,
        still: tuple[float, float] = (0.1, 0.35),
        motion_weight: float = 0.6,
        noise_px: float = 3.0,
        antiphase: tuple[float, float] = (0.2, 0.6),
        split: tuple[float, float] = (0.1, 0.25),
        reset_after_s: float = 3.0,
        min_wrist_confidence: float = 0.5,
        calibration: PhoneCalibration | None = None,
    ) -> None:
        if not (window_s > 0 and reset_after_s > 0):
            raise ValueError("window_s and reset_after_s must be positive seconds")
        if not 0.0 <= max_weight <= 1.0:
            raise ValueError(f"max_weight must be in [0, 1], got {max_weight!r}")
        for name, (lo, hi) in (("still", still), ("antiphase", antiphase), ("split", split)):
            if not lo < hi:
                raise ValueError(f"{name} must be (low, high) increasing, got {(lo, hi)!r}")
        self.geometry = geometry or PoseGeometryPhoneClassifier()
        self.window_s = float(window_s)
        self.max_weight = float(max_weight)
        self.still = still
        self.motion_weight = float(motion_weight)
        self.noise_px = float(noise_px)
        self.antiphase = antiphase
        self.split = split
        self.reset_after_s = float(reset_after_s)
        self.min_wrist_confidence = float(min_wrist_confidence)
        if calibration is not None and not isinstance(calibration, PhoneCalibration):
            raise ValueError(f"calibration must be a PhoneCalibration, got {type(calibration).__name__}")
        self.calibration = calibration
        self._tracks: dict[int, _Track] = {}

    def reset(self) -> None:
        """Forget every track (a new video)."""
        self._tracks.clear()

    @property
    def track_ids(self) -> list[int]:
        return sorted(self._tracks)

    @staticmethod
    def _parts(tr: _Track) -> tuple[list, ...]:
        """The per-frame lists of a track (dropped together)."""
        return (tr.times, tr.hands, tr.calls, tr.noses, tr.seen, tr.wrists, tr.splits, tr.torso_px)

    def _wrists(self, kp: NDArray[np.float64], conf: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.full((2, 2), np.nan)
        if not np.isfinite(kp[[5, 6, 11, 12]]).all():
            return out
        shoulders = kp[[5, 6]].mean(axis=0)
        torso = float(np.hypot(*(kp[[11, 12]].mean(axis=0) - shoulders)))
        if torso < 1e-6:
            return out
        for side, wrist in enumerate((9, 10)):
            if np.isfinite(kp[wrist]).all() and conf[wrist] >= self.min_wrist_confidence:
                out[side] = (kp[wrist] - shoulders) / torso
        return out

    def _split(self, kp: NDArray[np.float64], wrists: NDArray[np.float64]) -> float:
        """1 when the wrists lie on opposite sides of the torso's centre line, both far from it."""
        if not np.isfinite(wrists).all():
            return 0.0
        torso_len = float(np.hypot(*(kp[[11, 12]].mean(axis=0) - kp[[5, 6]].mean(axis=0))))
        centre = 0.5 * (kp[[5, 6], 0].mean() + kp[[11, 12], 0].mean()) - kp[[5, 6], 0].mean()
        off = wrists[:, 0] - centre / torso_len
        if off[0] * off[1] >= 0:
            return 0.0
        low = _ramp(float(wrists[:, 1].min()), 0.3, 0.5)  # both hands below the chest: a hand at the ear is no stride
        return _ramp(float(np.abs(off).min()), *self.split) * low

    def add_pose(
        self,
        track_id: int | None,
        time: float | None,
        keypoints: NDArray[np.float64],
        confidences: NDArray[np.float64] | None = None,
        face: tuple[float, float] | None = None,
    ) -> TemporalPhoneResult:
        """Add this frame's pose of ``track_id`` at ``time`` (s) and return the fused reading;
        ``face``: the head's (pitch, confidence) from the face mesh where judged (:meth:`parts`)."""
        kp = np.asarray(keypoints, dtype=float)
        if kp.shape != (17, 2):
            raise ValueError(f"keypoints must have shape (17, 2), got {kp.shape}")
        conf = np.ones(17) if confidences is None else np.asarray(confidences, dtype=float)
        if track_id is None or track_id < 0 or time is None or not math.isfinite(time):
            texting, calling, pair = self.geometry.parts(kp, None if confidences is None else conf, face=face)
            g = float(max(texting.max(), calling.max(), pair))
            return self._result(g, g, g, 0.0, 0.0)
        texting, calling, pair = self.geometry.parts(kp, conf, facing=1.0, face=face)
        hands = np.maximum(texting, pair)
        t = float(time)
        # tracks unseen for long are dropped (bounded memory; a returning ID starts afresh)
        for tid in [k for k, tr in self._tracks.items() if t - tr.times[-1] > self.reset_after_s or t < tr.times[-1]]:
            del self._tracks[tid]
        tr = self._tracks.setdefault(int(track_id), _Track())
        if tr.times and t == tr.times[-1]:  # the same frame twice: replace
            for part in self._parts(tr):
                part.pop()
        wrists = self._wrists(kp, conf)
        tr.times.append(t)
        tr.hands.append(hands)
        tr.calls.append(calling)
        tr.noses.append(self.geometry.face_seen(conf if confidences is not None else None))
        lo, hi = self.geometry.wrist_confidence
        tr.seen.append(np.array([_ramp(float(conf[j]), lo, hi) if np.isfinite(kp[j]).all() else 0.0 for j in (9, 10)]))
        tr.wrists.append(wrists)
        tr.torso_px.append(float(np.hypot(*(kp[[11, 12]].mean(axis=0) - kp[[5, 6]].mean(axis=0)))))
        tr.splits.append(self._split(kp, wrists))
        while tr.times and tr.times[0] < t - self.window_s - 1e-9:
            for part in self._parts(tr):
                part.pop(0)
        history = t - tr.times[0]
        # seen from behind over the window (median face confidence): hands in front are guesses
        noses = np.array(tr.noses)
        facing = 1.0
        if np.isfinite(noses).any():
            facing = self.geometry.facing(np.full(3, float(np.nanmedian(noses))))
        cues = facing * np.maximum(np.stack(tr.hands), np.stack(tr.calls))  # (n, 2)
        g = float(cues[-1].max())
        if len(tr.times) < 2:
            return self._result(g, g, g, 0.0, history)
        # G_w: mean cue over the frames the wrist was seen (an unseen wrist is no evidence either way)
        seen = np.sum(tr.seen, axis=0)
        held = np.sum(cues, axis=0) / np.maximum(seen, max(1.0, 0.5 * len(tr.times)))
        pos = np.stack(tr.wrists)  # (n, 2 wrists, 2)
        motion = np.zeros(2)
        for side in (0, 1):
            p = pos[:, side]
            p = p[np.isfinite(p).all(axis=1)]
            if len(p) >= 2:
                # robust spread: median distance from the median position (one misplaced wrist is not a swing)
                motion[side] = float(np.median(np.hypot(*(p - np.median(p, axis=0)).T)))
        torso_px = float(np.nanmedian(tr.torso_px)) if np.isfinite(tr.torso_px).any() else 0.0
        lo = max(self.still[0], self.noise_px / torso_px) if torso_px > 1e-6 else self.still[0]
        still = 1.0 - np.clip((motion - lo) / (self.still[1] - self.still[0]), 0.0, 1.0)
        gait = 0.0
        both = np.isfinite(pos[:, :, 0]).all(axis=1)
        if both.sum() >= 3:
            xl, xr = pos[both, 0, 0], pos[both, 1, 0]
            if xl.std() > 1e-9 and xr.std() > 1e-9:
                r = float(np.corrcoef(xl, xr)[0, 1])
                gait = _ramp(-r, *self.antiphase) * _ramp(float(motion.min()), *self.still)
        gait = max(gait, float(np.mean(tr.splits)))
        s = float((held * (1.0 - self.motion_weight * (1.0 - still))).max()) * (1.0 - gait)
        w = self.max_weight * min(1.0, history / self.window_s)
        phone = float(np.clip((1.0 - w) * g + w * s, 0.0, 1.0))
        return self._result(phone, g, s, w, history)

    def _result(self, phone: float, g: float, s: float, w: float, history: float) -> TemporalPhoneResult:
        """The reading, ``phone`` through the calibration where there is one."""
        if self.calibration is not None:
            phone = self.calibration(phone)
        return TemporalPhoneResult(phone, g, s, w, history)


# -- an image classifier on the person crop (the paper's design) ---------------------------------


class CropPhoneClassifier:
    """A user's image classifier (e.g. EfficientNetV2 fine-tuned on person crops, the paper's
    approach) as a :class:`PhoneClassifier`: ``(frame, person) -> P(phone)``, NaN where the person is
    too small (under ``min_height_px``) to judge.

    ``model``: an ``.onnx`` or ``.tflite`` file, read with OpenCV's DNN module (``cv2.dnn``, already a
    dependency: no onnxruntime or TensorFlow needed). Input: the person's box widened by ``margin``,
    resized to ``input_size`` (width, height), RGB, ``(x / 255 - mean) / std`` per channel, NCHW
    (OpenCV's convention for ONNX and TFLite alike; ``layout="nhwc"`` for a ``runner`` that wants
    channels-last). Output: one logit/probability or
    two or more class scores; ``phone_index`` picks the phone class (softmax over classes, sigmoid
    for a single logit unless ``probabilities``). ``runner`` replaces the DNN (tests, other runtimes):
    a callable from the preprocessed batch (1, C, H, W or 1, H, W, C, float32) to the raw output.
    """

    def __init__(
        self,
        model: str | Path | None = None,
        *,
        input_size: tuple[int, int] = (224, 224),
        mean: tuple[float, float, float] = (0.485, 0.456, 0.406),
        std: tuple[float, float, float] = (0.229, 0.224, 0.225),
        layout: str = "nchw",
        phone_index: int = 1,
        probabilities: bool = False,
        margin: float = 0.1,
        min_height_px: float = 64.0,
        runner: Callable[[NDArray[np.float32]], NDArray] | None = None,
    ) -> None:
        if layout not in ("nchw", "nhwc"):
            raise ValueError(f"layout must be 'nchw' or 'nhwc', got {layout!r}")
        self.input_size = (int(input_size[0]), int(input_size[1]))
        self.mean = np.asarray(mean, dtype=np.float32)
        self.std = np.asarray(std, dtype=np.float32)
        self.layout = layout
        self.phone_index = int(phone_index)
        self.probabilities = probabilities
        self.margin = float(margin)
        self.min_height_px = float(min_height_px)
        if runner is not None:
            self._run = runner
            return
        if model is None:
            raise ValueError(
                "CropPhoneClassifier needs a model file: an image classifier of person crops exported to "
                "ONNX (.onnx) or TFLite (.tflite), e.g. an EfficientNetV2 fine-tuned on phone / no-phone crops"
            )
        path = Path(model)
        if not path.is_file():
            raise FileNotFoundError(f"phone crop classifier not found: {path} (an .onnx or .tflite file)")
        import cv2

        if path.suffix.lower() == ".onnx":
            net = cv2.dnn.readNetFromONNX(str(path))
        elif path.suffix.lower() == ".tflite":
            reader = getattr(cv2.dnn, "readNetFromTFLite", None)
            if reader is None:
                raise ValueError(f"this OpenCV ({cv2.__version__}) cannot read TFLite; export the model to ONNX")
            net = reader(str(path))
        else:
            raise ValueError(f"phone crop classifier must be an .onnx or .tflite file, got {path.name}")

        def run(batch: NDArray[np.float32]) -> NDArray:
            net.setInput(batch)
            return np.asarray(net.forward())

        self._run = run

    def preprocess(self, frame: NDArray[np.uint8], person: Person) -> NDArray[np.float32] | None:
        """The model's input for ``person`` (batch of one), or None if the crop is empty."""
        import cv2

        x1, y1, x2, y2 = person.bbox
        mx, my = self.margin * (x2 - x1), self.margin * (y2 - y1)
        h, w = frame.shape[:2]
        a, b = int(max(0, x1 - mx)), int(max(0, y1 - my))
        c, d = int(min(w, x2 + mx)), int(min(h, y2 + my))
        if c - a < 2 or d - b < 2:
            return None
        crop = cv2.resize(frame[b:d, a:c], self.input_size, interpolation=cv2.INTER_AREA)
        x = (crop.astype(np.float32) / 255.0 - self.mean) / self.std
        x = x[None] if self.layout == "nhwc" else x.transpose(2, 0, 1)[None]
        return np.ascontiguousarray(x, dtype=np.float32)

    def __call__(self, frame: NDArray[np.uint8] | None, person: Person) -> float:
        if frame is None or person.bbox[3] - person.bbox[1] < self.min_height_px:
            return math.nan
        x = self.preprocess(frame, person)
        if x is None:
            return math.nan
        out = np.asarray(self._run(x), dtype=float).reshape(-1)
        if out.size == 1:
            p = float(out[0]) if self.probabilities else 1.0 / (1.0 + math.exp(-float(out[0])))
        elif self.probabilities:
            p = float(out[self.phone_index] / max(out.sum(), 1e-12))
        else:
            e = np.exp(out - out.max())
            p = float(e[self.phone_index] / e.sum())
        return float(np.clip(p, 0.0, 1.0))


def fuse_crop(
    pose_phone: float,
    crop_phone: float,
    height_px: float,
    ramp_px: tuple[float, float] = (64, 200),
    max_weight: float = 0.7,
) -> float:
    """Pose-based C_sm fused with a crop classifier's P(phone) by confidence: the crop's weight
    ``max_weight * ramp(height_px, *ramp_px)`` grows with the person's height; NaN crop: pose only."""
    if math.isnan(crop_phone):
        return pose_phone
    if math.isnan(pose_phone):
        return crop_phone
    w = max_weight * _ramp(float(height_px), *ramp_px)
    return float((1.0 - w) * pose_phone + w * crop_phone)
