"""Traits as parts: each trait s_i of `lin_comb` is a small object, and the estimator takes any set.

A trait has a ``name``, a ``weight`` (rho_i in `lin_comb`), an :meth:`~Trait.initial` step (the
"(0)" formula, at a track's first observation) and an :meth:`~Trait.update` step (the recursive
formula, at every later observation), both reading an :class:`~trustnav.trust.sighting.Sighting`.
A step returns a :class:`TraitStep`: the value s_i in [0, 1] (NaN while the trait is not available),
the input confidence it used and anything it must remember for the next update.

The paper's three (Section II) are :class:`SmartphoneUse` (`smato_score`), :class:`EyeContact`
(`eye_score`) and :class:`PoseFluctuation` (`pose_conf`, `pose_score`); :data:`PAPER_TRAITS` (=
``paper_traits(PAPER_TRUST)``) is the default of :class:`~trustnav.trust.estimator.TrustEstimator`.
A trait fed by one confidence cue subclasses :class:`CueTrait` and writes two formulas::

    @dataclass(frozen=True)
    class RedLightCrossing(CueTrait):
        name: str = "red_light"
        weight: float = 0.2
        cue: str = "red_light"  # read from Sighting(cues={"red_light": c})

        def start(self, c: float) -> float:  # s(0)
            return 1.0 - c

        def step(self, prev: float, c: float) -> float:  # s(t) from s(t-1): never forgets
            return min(prev, 1.0 - c)

    TrustEstimator(traits=[*PAPER_TRAITS, RedLightCrossing()])
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.trust import traits as tr
from trustnav.trust.params import PAPER_TRUST, TrustParams, as_number
from trustnav.trust.sighting import EYE_CONTACT, SMARTPHONE, Sighting

__all__ = [
    "PAPER_TRAITS",
    "CueTrait",
    "EyeContact",
    "PoseFluctuation",
    "SmartphoneUse",
    "Trait",
    "TraitSet",
    "TraitStep",
    "paper_traits",
]


@dataclass(frozen=True)
class TraitStep:
    """One trait of one track after a step: ``value`` s_i (NaN: not available yet), ``confidence``
    the input it last used (NaN: none yet), ``memory`` what the next update needs (or None),
    ``time`` of the observation it last used (s; NaN: not recorded)."""

    value: float
    confidence: float = math.nan
    memory: Any = None
    time: float = math.nan


def relax(value: float, target: float, dt: float, time_constant: float) -> float:
    """The rate-invariant step: ``value`` relaxed toward ``target`` over ``dt`` seconds with
    ``time_constant`` (exact for dx/dt = (target - x) / T with the target held)."""
    return float(target + (value - target) * math.exp(-max(dt, 0.0) / time_constant))


@runtime_checkable
class Trait(Protocol):
    """One trait s_i of `lin_comb`: name, weight rho_i, "(0)" formula and recursive update."""

    @property
    def name(self) -> str: ...

    @property
    def weight(self) -> float: ...

    def initial(self, obs: Sighting) -> TraitStep:
        """The trait at a track's first observation (NaN value if its input is missing)."""
        ...

    def update(self, prev: TraitStep, obs: Sighting) -> TraitStep:
        """The trait after a later observation; ``prev`` unchanged if its input is missing."""
        ...


def _check_name_weight(kind: str, name: object, weight: object) -> float:
    if not isinstance(name, str) or not name:
        raise ValueError(f"{kind} name must be a non-empty string, got {name!r}")
    w = as_number(f"trait {name!r} weight", weight)
    if not 0.0 <= w < math.inf:
        raise ValueError(f"trait {name!r} weight (rho in lin_comb) must be a finite number >= 0, got {weight!r}")
    return w


def _check_time_constant(name: str, t: object) -> None:
    if t is not None and not 0.0 < as_number(f"trait {name!r} time_constant", t) < math.inf:
        raise ValueError(f"trait {name!r} time_constant must be a positive number of seconds (or None), got {t!r}")


def _unit(name: str, value: object, *, lo_open: bool = False) -> float:
    v = as_number(name, value)
    if not ((v > 0.0) if lo_open else (v >= 0.0)) or v > 1.0:
        raise ValueError(f"{name} must lie in {'(' if lo_open else '['}0, 1], got {value!r}")
    return v


@dataclass(frozen=True)
class CueTrait:
    """A trait driven by one confidence cue of the observation (``obs.cue(cue)``).

    Subclasses give :meth:`start` (the "(0)" formula) and :meth:`step` (the update). The cue
    missing from an observation leaves the trait as it was; a trait never fed yet is NaN (not
    available: `lin_comb` shares its weight out) and its first cue applies :meth:`start`.
    """

    name: str
    weight: float
    cue: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "weight", _check_name_weight("trait", self.name, self.weight))
        if not isinstance(self.cue, str) or not self.cue:
            raise ValueError(f"trait {self.name!r}: cue must be a non-empty string, got {self.cue!r}")

    def start(self, c: float) -> float:
        """s(0) from the first confidence c."""
        raise NotImplementedError(f"{type(self).__name__} must define start(c)")

    def step(self, prev: float, c: float) -> float:
        """s(t) from s(t-1) and the confidence c(t)."""
        raise NotImplementedError(f"{type(self).__name__} must define step(prev, c)")

    def step_after(self, prev: float, c: float, dt: float) -> float:
        """s(t) from s(t - dt): :meth:`step` (one step per observation) unless the trait has a
        time constant (the rate-invariant law of :class:`~trustnav.trust.params.TrustParams`)."""
        return self.step(prev, c)

    def initial(self, obs: Sighting) -> TraitStep:
        c = obs.cue(self.cue)
        return TraitStep(math.nan, time=obs.time) if c is None else TraitStep(float(self.start(c)), c, time=obs.time)

    def update(self, prev: TraitStep, obs: Sighting) -> TraitStep:
        c = obs.cue(self.cue)
        if c is None:
            return prev
        if math.isnan(prev.value):
            value = self.start(c)
        elif math.isnan(prev.time):
            value = self.step(prev.value, c)
        else:
            value = self.step_after(prev.value, c, obs.time - prev.time)
        return TraitStep(float(value), c, time=obs.time)


@dataclass(frozen=True)
class SmartphoneUse(CueTrait):
    """`smato_score`: s_1(0) = nu0 (1 - C_sm(0)); s_1(t) = nu s_1(t-1) + (1 - nu)(1 - C_sm(t)).
    With ``time_constant`` T (s): s_1 relaxes toward 1 - C_sm with T (rate-invariant law)."""

    name: str = SMARTPHONE
    weight: float = 0.4
    cue: str = SMARTPHONE
    nu: float = 0.6
    nu0: float = 1.0
    time_constant: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "nu", _unit(f"trait {self.name!r} nu", self.nu))
        object.__setattr__(self, "nu0", _unit(f"trait {self.name!r} nu0", self.nu0, lo_open=True))
        _check_time_constant(self.name, self.time_constant)

    def start(self, c: float) -> float:
        return self.nu0 * (1.0 - c)

    def step(self, prev: float, c: float) -> float:
        return self.nu * prev + (1.0 - self.nu) * (1.0 - c)

    def step_after(self, prev: float, c: float, dt: float) -> float:
        if self.time_constant is None:
            return self.step(prev, c)
        return relax(prev, 1.0 - c, dt, self.time_constant)


@dataclass(frozen=True)
class EyeContact(CueTrait):
    """`eye_score`: s_2(0) = nu0 C_eye(0); s_2(t) = sat(s_2(t-1) + nu C_eye(t)) (never decreases).
    With ``time_constant`` T (s): s_2 relaxes toward C_eye with T (rate-invariant law; eye
    contact then has to be kept up, not only made once)."""

    name: str = EYE_CONTACT
    weight: float = 0.5
    cue: str = EYE_CONTACT
    nu: float = 0.10
    nu0: float = 1.0
    time_constant: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "nu", _unit(f"trait {self.name!r} nu", self.nu))
        object.__setattr__(self, "nu0", _unit(f"trait {self.name!r} nu0", self.nu0, lo_open=True))
        _check_time_constant(self.name, self.time_constant)

    def start(self, c: float) -> float:
        return self.nu0 * c

    def step(self, prev: float, c: float) -> float:
        return float(tr.sat01(prev + self.nu * c))

    def step_after(self, prev: float, c: float, dt: float) -> float:
        if self.time_constant is None:
            return self.step(prev, c)
        return relax(prev, c, dt, self.time_constant)


@dataclass(frozen=True)
class PoseFluctuation:
    """`pose_score` from `pose_conf`: s_3(0) = nu0 (available without an observation);
    s_3(t) = nu s_3(t-1) + (1 - nu) C_fluc(t), C_fluc comparing the pose relative to its box with
    the previous one of the same track, however long ago (memory: that relative pose).

    With ``time_constant`` T (s, the rate-invariant law): C_fluc compares the pose with the one
    ``interval`` seconds before (the nearest kept, its motion scaled to ``interval``; none older
    than half of it yet: no update), and s_3 relaxes toward C_fluc with T. Memory: the poses of the
    last two intervals with their times."""

    name: str = "pose_fluctuation"
    weight: float = 0.1
    nu: float = 0.8
    nu0: float = 0.5
    sensitivity: float = 0.25  # F in `pose_conf`
    time_constant: float | None = None
    interval: float = 1.0

    def __post_init__(self) -> None:
        _check_time_constant(self.name, self.time_constant)
        if not 0.0 < as_number(f"trait {self.name!r} interval", self.interval) < math.inf:
            raise ValueError(f"trait {self.name!r} interval must be positive seconds, got {self.interval!r}")
        object.__setattr__(self, "weight", _check_name_weight("trait", self.name, self.weight))
        object.__setattr__(self, "nu", _unit(f"trait {self.name!r} nu", self.nu))
        object.__setattr__(self, "nu0", _unit(f"trait {self.name!r} nu0", self.nu0, lo_open=True))
        f = as_number(f"trait {self.name!r} sensitivity", self.sensitivity)
        if not 0.0 < f < math.inf:
            raise ValueError(f"trait {self.name!r} sensitivity (F in pose_conf) must be positive, got {f!r}")
        object.__setattr__(self, "sensitivity", f)

    @staticmethod
    def _pose(obs: Sighting) -> NDArray[np.float64] | None:
        return None if obs.keypoints is None else tr.relative_pose(obs.keypoints, obs.bbox)

    def initial(self, obs: Sighting) -> TraitStep:
        rel = self._pose(obs)
        if self.time_constant is not None:
            return TraitStep(self.nu0, math.nan, [] if rel is None else [(obs.time, rel)], obs.time)
        return TraitStep(self.nu0, math.nan, rel, obs.time)

    def update(self, prev: TraitStep, obs: Sighting) -> TraitStep:
        rel = self._pose(obs)
        if rel is None:
            return prev
        if self.time_constant is not None:
            return self._update_in_seconds(prev, obs.time, rel)
        last = prev.memory
        if last is not None and np.any(np.isfinite(rel - last).all(axis=1)):
            c = tr.fluctuation_confidence(rel, last, self.sensitivity)
            return TraitStep(self.nu * prev.value + (1.0 - self.nu) * c, c, rel, obs.time)
        return TraitStep(prev.value, prev.confidence, rel, obs.time)

    def _update_in_seconds(self, prev: TraitStep, t: float, rel: NDArray[np.float64]) -> TraitStep:
        assert self.time_constant is not None
        kept = [(ti, p) for ti, p in (prev.memory or []) if t - ti <= 2.0 * self.interval and ti < t]
        old = [(ti, p) for ti, p in kept if t - ti >= 0.5 * self.interval and np.isfinite(rel - p).all(axis=1).any()]
        value, conf = prev.value, prev.confidence
        if old:
            ti, p = min(old, key=lambda item: abs((t - item[0]) - self.interval))
            # the motion over t - ti scaled to one interval: F is defined for poses `interval` apart
            scale = (t - ti) / self.interval
            conf = tr.fluctuation_confidence(rel, p, self.sensitivity * scale)
            prev_t = prev.time if math.isfinite(prev.time) else ti
            value = relax(prev.value, conf, t - prev_t, self.time_constant)
        return TraitStep(value, conf, [*kept, (t, rel)], t)


@dataclass(frozen=True)
class TraitSet:
    """The traits of `lin_comb`, in order, with their weights rho_i.

    Names must be unique and weights >= 0, not all zero. Weights are relative: the total score is
    S = sum_i rho_i s_i / sum_i rho_i over the traits available (not NaN), so a trait not yet
    observed shares its weight out over the others and S stays in [0, 1]; with weights summing
    to 1 and every trait available this is `lin_comb` as written.
    """

    traits: tuple[Trait, ...]

    def __post_init__(self) -> None:
        if isinstance(self.traits, (str, bytes)) or not isinstance(self.traits, Iterable):
            raise ValueError(f"traits must be a sequence of Trait objects, got {self.traits!r}")
        traits = tuple(self.traits)
        if not traits:
            raise ValueError("traits must hold at least one trait")
        seen: set[str] = set()
        for i, t in enumerate(traits):
            if isinstance(t, TraitSet) or not isinstance(t, Trait):
                raise ValueError(
                    f"traits[{i}] must be a Trait (name, weight, initial(obs), update(prev, obs)), "
                    f"got {type(t).__name__}"
                )
            _check_name_weight(f"traits[{i}]", t.name, t.weight)
            if t.name in seen:
                raise ValueError(f"trait names must be unique, {t.name!r} appears twice")
            seen.add(t.name)
        if not any(float(t.weight) > 0.0 for t in traits):
            raise ValueError(f"trait weights must not all be zero, got {dict((t.name, t.weight) for t in traits)}")
        object.__setattr__(self, "traits", traits)

    def __iter__(self) -> Iterator[Trait]:
        return iter(self.traits)

    def __len__(self) -> int:
        return len(self.traits)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.traits)

    @property
    def weights(self) -> NDArray[np.float64]:
        return np.array([float(t.weight) for t in self.traits])

    def score(self, values: ArrayLike) -> NDArray[np.float64] | float:
        """`lin_comb` over the last axis of ``values`` (..., len(self)); NaN: not available."""
        s = np.asarray(values, dtype=float)
        if s.shape[-1:] != (len(self),):
            raise ValueError(f"trait values must have a last axis of {len(self)} {self.names}, got shape {s.shape}")
        avail = np.isfinite(s)
        w = np.where(avail, self.weights, 0.0)
        wsum = w.sum(axis=-1)
        if np.any(wsum <= 0):
            raise ValueError("total score needs at least one available trait with non-zero weight")
        out = np.asarray((np.where(avail, s, 0.0) * w).sum(axis=-1) / wsum, dtype=float)
        return float(out) if out.ndim == 0 else out

    @classmethod
    def of(cls, traits: TraitSet | Sequence[Trait]) -> TraitSet:
        """``traits`` as a TraitSet (a TraitSet is returned as it is)."""
        return traits if isinstance(traits, TraitSet) else cls(traits)  # type: ignore[arg-type]


def paper_traits(params: TrustParams = PAPER_TRUST) -> TraitSet:
    """The paper's three traits with the constants and weights rho of ``params`` (Section II)."""
    if not isinstance(params, TrustParams):
        raise ValueError(f"params must be a TrustParams (e.g. PAPER_TRUST), got {type(params).__name__}")
    p = params
    t1, t2, t3, _ = p.time_constants or (None, None, None, None)
    return TraitSet((
        SmartphoneUse(weight=p.rho[0], nu=p.nu1, nu0=p.nu01, time_constant=t1),
        EyeContact(weight=p.rho[1], nu=p.nu2, nu0=p.nu02, time_constant=t2),
        PoseFluctuation(weight=p.rho[2], nu=p.nu3, nu0=p.nu03, sensitivity=p.fluctuation_sensitivity,
                        time_constant=t3, interval=p.fluctuation_interval),
    ))  # fmt: skip


#: The paper's Section IV traits: smartphone use 0.4, eye contact 0.5, pose fluctuation 0.1.
PAPER_TRAITS = paper_traits(PAPER_TRUST)
