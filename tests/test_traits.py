"""Traits as parts (issue 17): the paper's three as the default preset, bit-identical to the formulas
of `smato_score`, `eye_score`, `pose_conf`, `pose_score`, `lin_comb` and `agg_trust`; any set of
traits with weights; user-defined traits that need no change to trustnav."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from trustnav.trust import (
    MOVING_AVERAGE_TRUST,
    PAPER_TRAITS,
    PAPER_TRUST,
    CueTrait,
    EyeContact,
    PoseFluctuation,
    Sighting,
    SmartphoneUse,
    TraitSet,
    TraitStep,
    TrustEstimator,
    TrustParams,
    eye_trait_init,
    eye_trait_update,
    fluctuation_confidence,
    paper_traits,
    pose_trait_init,
    pose_trait_update,
    relative_pose,
    smartphone_trait_init,
    smartphone_trait_update,
    total_score,
    trust_init,
    trust_update,
)


def _reference(observations: list[Sighting], p: TrustParams) -> list[tuple[float, ...]]:
    """The estimator as it was written before traits were parts, from the function-level formulas:
    (s1, s2, s3, S, tau, C_fluc) after each observation (one track, no forgetting)."""
    out = []
    s1 = s2 = s3 = tau = fl = math.nan
    prev = None
    for k, o in enumerate(observations):
        rel = None if o.keypoints is None else relative_pose(o.keypoints, o.bbox)
        if k == 0:
            s1 = math.nan if o.c_smartphone is None else float(smartphone_trait_init(o.c_smartphone, p))
            s2 = math.nan if o.c_eye is None else float(eye_trait_init(o.c_eye, p))
            s3 = pose_trait_init(p)
            score = float(total_score([s1, s2, s3], p))
            tau = float(trust_init(score, p))
            prev = rel
        else:
            if o.c_smartphone is not None:
                s1 = float(
                    smartphone_trait_init(o.c_smartphone, p)
                    if math.isnan(s1)
                    else smartphone_trait_update(s1, o.c_smartphone, p)
                )
            if o.c_eye is not None:
                s2 = float(eye_trait_init(o.c_eye, p) if math.isnan(s2) else eye_trait_update(s2, o.c_eye, p))
            if rel is not None:
                if prev is not None and np.any(np.isfinite(rel - prev).all(axis=1)):
                    fl = fluctuation_confidence(rel, prev, p)
                    s3 = float(pose_trait_update(s3, fl, p))
                prev = rel
            score = float(total_score([s1, s2, s3], p))
            tau = float(trust_update(tau, score, p))
        out.append((s1, s2, s3, score, tau, fl))
    return out


def _random_observations(seed: int, n: int = 80) -> list[Sighting]:
    rng = np.random.default_rng(seed)
    obs = []
    for k in range(n):
        c1 = None if rng.random() < 0.25 else float(rng.random())
        c2 = None if rng.random() < 0.25 else float(rng.random())
        kp = box = None
        if rng.random() < 0.7:
            x0, y0 = rng.uniform(0, 500, 2)
            kp = np.column_stack([rng.uniform(x0, x0 + 40, 17), rng.uniform(y0, y0 + 100, 17)])
            kp[rng.integers(0, 17, rng.integers(0, 4))] = np.nan
            box = np.array([x0 - 1, y0 - 1, x0 + 41, y0 + 101])
        obs.append(Sighting(5, 0.1 * k, c_smartphone=c1, c_eye=c2, keypoints=kp, bbox=box))
    return obs


@pytest.mark.parametrize("params", [PAPER_TRUST, MOVING_AVERAGE_TRUST, TrustParams(nu1=0, nu2=0, nu3=0)])
@pytest.mark.parametrize("seed", range(4))
def test_default_traits_are_bit_identical_to_the_paper_formulas(params, seed):
    observations = _random_observations(seed)
    ref = _reference(observations, params)
    for est in (TrustEstimator(params, keep_time=10.0), TrustEstimator(params, 10.0, traits=paper_traits(params))):
        got = []
        for o in observations:
            st = est.add_sighting(o)
            got.append((st.smartphone, st.eye, st.pose, st.score, st.trust, st.fluctuation))
        # exact equality (NaN in the same places): same floating-point operations as before
        assert np.array_equal(np.array(got), np.array(ref), equal_nan=True)


def test_paper_preset_holds_the_papers_traits_and_weights():
    assert PAPER_TRAITS.names == ("smartphone", "eye_contact", "pose_fluctuation")
    assert tuple(PAPER_TRAITS.weights) == PAPER_TRUST.rho == (0.4, 0.5, 0.1)
    sm, eye, pose = PAPER_TRAITS
    assert (sm.nu, sm.nu0, eye.nu, eye.nu0) == (0.6, 1.0, 0.10, 1.0)
    assert (pose.nu, pose.nu0, pose.sensitivity) == (0.8, 0.5, 0.25)
    assert paper_traits(PAPER_TRUST) == PAPER_TRAITS
    assert TrustEstimator().traits == PAPER_TRAITS
    ma = paper_traits(TrustParams(rho=(0.2, 0.3, 0.5), nu2=0.3))
    assert tuple(ma.weights) == (0.2, 0.3, 0.5) and ma.traits[1].nu == 0.3


@dataclass(frozen=True)
class RedLightCrossing(CueTrait):
    """A user's trait: crossing at a red light, never forgotten: s(0) = 1 - c, s(t) = min(s, 1 - c)."""

    name: str = "red_light"
    weight: float = 0.5
    cue: str = "red_light"

    def start(self, c):
        return 1.0 - c

    def step(self, prev, c):
        return min(prev, 1.0 - c)


class Stillness:
    """A user's trait written against the protocol only: the share of observations with a pose."""

    name = "stillness"
    weight = 1.0

    def initial(self, obs):
        return TraitStep(1.0 if obs.keypoints is not None else 0.0, memory=1)

    def update(self, prev, obs):
        n = prev.memory + 1
        return TraitStep((prev.value * prev.memory + (obs.keypoints is not None)) / n, memory=n)


def test_user_defined_traits_work_without_touching_trustnav():
    est = TrustEstimator(traits=[*PAPER_TRAITS, RedLightCrossing()])
    st = est.add_sighting(Sighting(1, 0.0, c_smartphone=0.0, c_eye=1.0))
    # red_light not seen yet: not available, its weight shared out over the paper's three
    assert math.isnan(st.value("red_light"))
    assert st.score == pytest.approx((0.4 * 1.0 + 0.5 * 1.0 + 0.1 * 0.5) / 1.0)
    st = est.add_sighting(Sighting(1, 1.0, c_smartphone=0.0, c_eye=1.0, cues={"red_light": 0.9}))
    assert st.value("red_light") == pytest.approx(0.1)
    st = est.add_sighting(Sighting(1, 2.0, cues={"red_light": 0.0}))
    assert st.value("red_light") == pytest.approx(0.1)  # never forgotten
    expected = (0.4 * st.smartphone + 0.5 * st.eye + 0.1 * st.pose + 0.5 * 0.1) / 1.5
    assert st.score == pytest.approx(expected)
    assert st.values == {"smartphone": st.smartphone, "eye_contact": st.eye, "pose_fluctuation": st.pose,
                         "red_light": st.value("red_light")}  # fmt: skip
    # a protocol-only trait, alone: lin_comb of one trait is that trait
    solo = TrustEstimator(traits=TraitSet((Stillness(),)))
    kp = np.column_stack([np.linspace(0, 10, 17), np.linspace(0, 20, 17)])
    solo.add_sighting(Sighting(2, 0.0, keypoints=kp, bbox=[0, 0, 10, 20]))
    st2 = solo.add_sighting(Sighting(2, 1.0))
    assert st2.score == pytest.approx(0.5) and math.isnan(st2.smartphone) and st2.relative_pose is None
    assert st2.trust == pytest.approx(0.55 * 1.0 + 0.08 * 0.5)  # agg_trust from PAPER_TRUST


@pytest.mark.parametrize(
    ("traits", "message"),
    [
        ([], "at least one trait"),
        ([SmartphoneUse(), SmartphoneUse(weight=0.2)], "trait names must be unique, 'smartphone' appears twice"),
        ([SmartphoneUse(weight=0.0), EyeContact(weight=0.0)], "weights must not all be zero"),
        ([SmartphoneUse(), "eye"], r"traits\[1\] must be a Trait"),
        ("smartphone", "traits must be a sequence of Trait objects"),
    ],
)
def test_trait_sets_are_validated_with_clear_messages(traits, message):
    with pytest.raises(ValueError, match=message):
        TraitSet(traits)
    with pytest.raises(ValueError, match=message):
        TrustEstimator(traits=traits)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: SmartphoneUse(weight=-0.1), r"trait 'smartphone' weight .* must be a finite number >= 0"),
        (lambda: EyeContact(weight=float("nan")), "trait 'eye_contact' weight must be a number"),
        (lambda: RedLightCrossing(name=""), "trait name must be a non-empty string"),
        (lambda: RedLightCrossing(cue=3), "trait 'red_light': cue must be a non-empty string"),
        (lambda: SmartphoneUse(nu=1.5), r"trait 'smartphone' nu must lie in \[0, 1\]"),
        (lambda: EyeContact(nu0=0.0), r"trait 'eye_contact' nu0 must lie in \(0, 1\]"),
        (lambda: PoseFluctuation(sensitivity=0.0), "sensitivity .* must be positive"),
        (lambda: Sighting(1, 0.0, cues={"red_light": 1.5}), r"cue 'red_light' must be a confidence in \[0, 1\]"),
        (lambda: Sighting(1, 0.0, cues={"smartphone": 0.5}), "carried by Sighting.c_smartphone"),
        (lambda: Sighting(1, 0.0, cues={3: 0.5}), "cue names must be non-empty strings"),
        (lambda: Sighting(1, 0.0, cues=[0.5]), "cues must be a mapping"),
    ],
)
def test_trait_and_cue_inputs_are_validated(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_trait_giving_a_bad_value_is_named_and_leaves_the_track_as_it_was():
    @dataclass(frozen=True)
    class Broken(CueTrait):
        name: str = "broken"
        weight: float = 1.0
        cue: str = "x"

        def start(self, c):
            return c

        def step(self, prev, c):
            return 2.0 * c  # out of [0, 1] for c > 0.5

    est = TrustEstimator(traits=[*PAPER_TRAITS, Broken()])
    st = est.add_sighting(Sighting(1, 0.0, c_eye=0.5, cues={"x": 0.2}))
    before = (dict(st.values), st.score, st.trust, st.last_seen, st.observations)
    with pytest.raises(ValueError, match=r"trait .broken.: update gave 1.8; a trait value must be a number in"):
        est.add_sighting(Sighting(1, 1.0, c_eye=1.0, cues={"x": 0.9}))
    assert (dict(st.values), st.score, st.trust, st.last_seen, st.observations) == before


def test_observation_cues_are_read_only_and_reach_traits_by_name():
    cues = {"red_light": 0.25}
    o = Sighting(1, 0.0, c_smartphone=0.5, cues=cues)
    cues["red_light"] = 0.9  # the observation keeps its own copy
    assert (o.cue("red_light"), o.cue("smartphone"), o.cue("eye_contact"), o.cue("other")) == (0.25, 0.5, None, None)
    with pytest.raises(TypeError):
        o.cues["red_light"] = 1.0
