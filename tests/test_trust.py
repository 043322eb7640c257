"""Trust mathematics: the paper's formulas, invariants and parameter validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.trust import (
    MOVING_AVERAGE_TRUST,
    PAPER_GAMMA_CARLA,
    PAPER_GAMMA_NUMERICAL,
    PAPER_TRUST,
    GammaParams,
    Sighting,
    TrustEstimator,
    TrustParams,
    eye_trait_init,
    eye_trait_update,
    fluctuation_confidence,
    gamma,
    pose_trait_update,
    relative_pose,
    smartphone_trait_init,
    smartphone_trait_update,
    total_score,
    trust_init,
    trust_update,
)

unit = st.floats(0.0, 1.0, allow_nan=False)


def test_paper_presets_hold_section_iv_values():
    p = PAPER_TRUST
    assert p.rho == (0.4, 0.5, 0.1)
    assert (p.nu1, p.nu01, p.nu2, p.nu02, p.nu3, p.nu03) == (0.6, 1.0, 0.10, 1.0, 0.8, 0.5)
    assert (p.fluctuation_sensitivity, p.alpha, p.beta, p.beta0) == (0.25, 1.0, 0.08, 0.55)
    assert MOVING_AVERAGE_TRUST.alpha + MOVING_AVERAGE_TRUST.beta == pytest.approx(1.0)
    assert MOVING_AVERAGE_TRUST.beta0 == 1.0
    assert (PAPER_GAMMA_NUMERICAL.gamma_ini, PAPER_GAMMA_NUMERICAL.delta, PAPER_GAMMA_NUMERICAL.lam) == (
        0.03,
        0.08,
        1.5,
    )
    assert (PAPER_GAMMA_CARLA.gamma_ini, PAPER_GAMMA_CARLA.delta, PAPER_GAMMA_CARLA.lam) == (0.08, 0.55, 2.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rho": (0.5, 0.5, 0.5)}, "rho must sum to 1"),
        ({"rho": (0.5, 0.5)}, "rho must have 3 weights"),
        ({"rho": (1.2, -0.2, 0.0)}, r"rho\[0\] must lie in"),
        ({"nu1": 1.5}, "nu1 must lie in"),
        ({"nu01": 0.0}, r"nu01 must lie in \(0"),
        ({"beta0": 0.0}, "beta0 must lie in"),
        ({"alpha": -0.1}, "alpha must lie in"),
        ({"beta": float("nan")}, "beta must be a number"),
        ({"fluctuation_sensitivity": 0.0}, "fluctuation_sensitivity"),
    ],
)
def test_trust_params_refuse_invalid_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrustParams(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"gamma_ini": 0.5, "delta": 0.6}, r"gamma_ini \+ delta must be <= 1"),
        ({"lam": 0.5}, "lam .* must be a finite number >= 1"),
        ({"gamma_ini": 0.0}, "gamma_ini must lie in"),
        ({"delta": -0.1}, "delta must lie in"),
    ],
)
def test_gamma_params_enforce_conditions_after_weight(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GammaParams(**kwargs)


def test_trait_formulas_match_the_paper():
    p = PAPER_TRUST
    # smato_score: s1(0) = nu01 (1 - C); s1(t) = nu1 s1(t-1) + (1 - nu1)(1 - C)
    assert smartphone_trait_init(0.2, p) == pytest.approx(0.8)
    assert smartphone_trait_update(0.8, 0.9, p) == pytest.approx(0.6 * 0.8 + 0.4 * 0.1)
    # eye_score: s2(0) = nu02 C; s2(t) = sat(s2 + nu2 C)
    assert eye_trait_init(0.7, p) == pytest.approx(0.7)
    assert eye_trait_update(0.7, 0.5, p) == pytest.approx(0.75)
    assert eye_trait_update(0.98, 1.0, p) == 1.0
    # pose_score: s3(t) = nu3 s3 + (1 - nu3) C
    assert pose_trait_update(0.5, 1.0, p) == pytest.approx(0.8 * 0.5 + 0.2)
    # lin_comb and agg_trust
    assert total_score([0.8, 0.7, 0.5], p) == pytest.approx(0.4 * 0.8 + 0.5 * 0.7 + 0.1 * 0.5)
    assert trust_init(0.72, p) == pytest.approx(0.55 * 0.72)
    assert trust_update(0.5, 0.72, p) == pytest.approx(0.5 + 0.08 * 0.72)
    assert trust_update(0.99, 0.9, p) == 1.0
    # weight
    np.testing.assert_allclose(gamma([0.0, 0.5, 1.0], PAPER_GAMMA_NUMERICAL), 0.03 + 0.08 * np.array([0, 0.5**1.5, 1]))


def test_total_score_shares_weight_of_unavailable_traits():
    p = PAPER_TRUST
    # eye contact unknown: weights 0.4 and 0.1 renormalised to 0.8 and 0.2
    assert total_score([1.0, np.nan, 0.5], p) == pytest.approx(0.8 * 1.0 + 0.2 * 0.5)
    s = total_score(np.array([[1.0, 0.0, 0.5], [np.nan, np.nan, 0.3]]), p)
    np.testing.assert_allclose(s, [0.4 + 0.05, 0.3])


def test_relative_pose_and_pose_conf():
    p = PAPER_TRUST
    kp = np.column_stack([np.linspace(100, 140, 17), np.linspace(200, 300, 17)])
    box = [100, 200, 140, 300]
    rel = relative_pose(kp, box)
    np.testing.assert_allclose(rel[0], [0, 0])
    np.testing.assert_allclose(rel[-1], [1, 1])
    # every keypoint moves by 0.05 of the box: sum = 17 * 0.05 -> C = F * 17 / (17 * 0.05) = 5 -> sat 1
    assert fluctuation_confidence(rel + [0.05, 0.0], rel, p) == 1.0
    # every keypoint moves by 0.5: C = 0.25 / 0.5
    assert fluctuation_confidence(rel + [0.0, 0.5], rel, p) == pytest.approx(0.5)
    assert fluctuation_confidence(rel, rel, p) == 1.0
    # a keypoint missing in one frame: mean over the others, rescaled to N_k
    moved = rel + [0.0, 0.5]
    moved[3] = np.nan
    assert fluctuation_confidence(moved, rel, p) == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: relative_pose(np.zeros((5, 2)), [0, 0, 1, 1]), r"keypoints must have shape \(17, 2\)"),
        (lambda: relative_pose(np.zeros((17, 2)), [0, 0, 0, 1]), "x2 > x1"),
        (lambda: fluctuation_confidence(np.full((17, 2), np.nan), np.zeros((17, 2)), PAPER_TRUST), "no keypoint"),
        (lambda: smartphone_trait_update(0.5, 1.2, PAPER_TRUST), r"c_sm must be confidences in \[0, 1\]"),
        (lambda: gamma([0.5, 1.1], PAPER_GAMMA_NUMERICAL), r"trust must lie in \[0, 1\]"),
        (lambda: total_score([0.1, 0.2], PAPER_TRUST), "last axis of 3"),
    ],
)
def test_bad_inputs_are_refused_with_clear_messages(call, message):
    with pytest.raises(ValueError, match=message):
        call()


@settings(max_examples=150, deadline=None)
@given(
    confs=st.lists(st.tuples(unit, unit, unit), min_size=1, max_size=40),
    nu=st.tuples(unit, unit, unit),
    alpha=unit,
    beta=unit,
)
def test_traits_and_trust_stay_in_unit_interval(confs, nu, alpha, beta):
    p = TrustParams(nu1=nu[0], nu2=nu[1], nu3=nu[2], alpha=alpha, beta=beta)
    c_sm, c_eye, c_fl = confs[0]
    s1, s2, s3 = smartphone_trait_init(c_sm, p), eye_trait_init(c_eye, p), p.nu03
    tau = trust_init(total_score([s1, s2, s3], p), p)
    for c_sm, c_eye, c_fl in confs[1:]:
        s1 = smartphone_trait_update(s1, c_sm, p)
        s2 = eye_trait_update(s2, c_eye, p)
        s3 = pose_trait_update(s3, c_fl, p)
        score = total_score([s1, s2, s3], p)
        tau = trust_update(tau, score, p)
        for v in (s1, s2, s3, score, tau):
            assert 0.0 <= v <= 1.0


@settings(max_examples=150, deadline=None)
@given(scores=st.lists(unit, min_size=2, max_size=60), beta=unit, tau0=unit)
def test_trust_never_decreases_when_alpha_is_one(scores, beta, tau0):
    p = TrustParams(alpha=1.0, beta=beta)
    tau = tau0
    for s in scores:
        nxt = trust_update(tau, s, p)
        assert nxt >= tau
        tau = nxt


@settings(max_examples=200, deadline=None)
@given(
    gamma_ini=st.floats(1e-6, 1.0),
    frac=unit,
    lam=st.floats(1.0, 50.0),
    trusts=st.lists(unit, min_size=1, max_size=20),
)
def test_gamma_lies_in_unit_interval_when_conditions_hold(gamma_ini, frac, lam, trusts):
    delta = max(1e-9, frac * (1.0 - gamma_ini))
    if gamma_ini + delta > 1.0:
        delta = 1.0 - gamma_ini
    if delta <= 0:
        return
    g = gamma(trusts, GammaParams(gamma_ini=gamma_ini, delta=delta, lam=lam))
    assert np.all(g >= 0.0) and np.all(g <= 1.0)
    # more trust never means a smaller (more conservative) gamma
    order = np.argsort(trusts, kind="stable")
    assert np.all(np.diff(g[order]) >= -1e-15)


def _pose(shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    kp = np.column_stack([np.linspace(100, 140, 17) + shift, np.linspace(200, 300, 17)])
    return kp, np.array([95.0 + shift, 195.0, 145.0 + shift, 305.0])


def test_estimator_initialises_with_zero_formulas_and_updates_only_on_observation():
    p = PAPER_TRUST
    est = TrustEstimator(p, keep_time=1.0)
    kp, box = _pose()
    st0 = est.add_sighting(Sighting(7, 0.0, c_smartphone=0.1, c_eye=0.8, keypoints=kp, bbox=box))
    s0 = 0.4 * 0.9 + 0.5 * 0.8 + 0.1 * 0.5
    assert st0.score == pytest.approx(s0)
    assert st0.trust == pytest.approx(0.55 * s0)
    # a frame in which track 7 is not seen changes nothing for it
    est.add_frame([Sighting(8, 0.1, c_smartphone=0.9, c_eye=0.0)], time=0.1)
    assert est.trust(7) == pytest.approx(0.55 * s0)
    kp2, box2 = _pose(shift=3.0)  # the whole person moves: pose relative to the box is unchanged
    st1 = est.add_sighting(Sighting(7, 0.2, c_smartphone=0.1, c_eye=0.8, keypoints=kp2, bbox=box2))
    assert st1.fluctuation == 1.0
    assert st1.pose == pytest.approx(0.8 * 0.5 + 0.2 * 1.0)
    s1 = 0.4 * (0.6 * 0.9 + 0.4 * 0.9) + 0.5 * min(1.0, 0.8 + 0.1 * 0.8) + 0.1 * st1.pose
    assert st1.score == pytest.approx(s1)
    assert st1.trust == pytest.approx(0.55 * s0 + 0.08 * s1)
    np.testing.assert_allclose(est.trusts([7, 8, 99], default=0.0), [st1.trust, est.trust(8), 0.0])


def test_estimator_handles_missing_traits_and_forgets_lost_tracks():
    est = TrustEstimator(PAPER_TRUST, keep_time=0.5)
    st0 = est.add_sighting(Sighting(1, 0.0, c_eye=0.6))  # phone model gave nothing yet
    assert math.isnan(st0.smartphone)
    assert st0.score == pytest.approx((0.5 * 0.6 + 0.1 * 0.5) / 0.6)
    st1 = est.add_sighting(Sighting(1, 0.1, c_smartphone=0.0))  # first phone reading uses the (0) formula
    assert st1.smartphone == pytest.approx(1.0)
    assert st1.eye == pytest.approx(0.6)  # not observed this time: held
    est.add_frame([], time=0.55)
    assert 1 in est.tracks
    est.add_frame([], time=0.7)
    assert 1 not in est.tracks
    with pytest.raises(ValueError, match="keypoints and bbox must be given together"):
        Sighting(2, 0.0, keypoints=np.zeros((17, 2)))
    est.add_sighting(Sighting(3, 1.0))
    with pytest.raises(ValueError, match="older than its last one"):
        est.add_sighting(Sighting(3, 0.5))


# ------------------------------------------------------------------ trust in seconds (issue #19)


def _watch(params, fps: float, seconds: float, c_sm: float, c_eye: float, seed: int = 0) -> dict[float, float]:
    """Trust of one person showing the same behaviour for ``seconds`` at ``fps``: {time: trust}."""
    from trustnav.trust import Sighting, TrustEstimator

    rng = np.random.default_rng(seed)
    base = np.array([[50.0 + 20.0 * np.sin(i), 10.0 + 5.0 * i] for i in range(17)])
    est = TrustEstimator(params)
    out = {}
    for k in range(round(seconds * fps) + 1):
        t = k / fps
        kp = base + rng.normal(0.0, 0.4, base.shape)  # a person standing: keypoint jitter only
        est.add_sighting(Sighting(track_id=0, time=t, c_smartphone=c_sm, c_eye=c_eye, keypoints=kp,
                                bbox=np.array([0.0, 0.0, 100.0, 100.0])))  # fmt: skip
        out[round(t, 6)] = float(est.trust(0))
    return out


@pytest.mark.parametrize("behaviour", [(0.05, 0.7), (0.9, 0.05), (0.5, 0.3)])
def test_seconds_law_gives_the_same_trust_after_the_same_seconds_at_any_frame_rate(behaviour):
    from trustnav.trust import PAPER_TRUST, SECONDS_TRUST

    c_sm, c_eye = behaviour
    for t in (2.0, 4.0, 10.0):
        at = [_watch(SECONDS_TRUST, fps, 10.0, c_sm, c_eye)[t] for fps in (1, 5, 10, 30)]
        assert max(at) - min(at) <= 0.02, (t, at)
    paper = [_watch(PAPER_TRUST, fps, 10.0, c_sm, c_eye)[4.0] for fps in (1, 10)]
    if c_sm < 0.9:  # the per-frame law: ten times the frames, ten times the steps
        assert paper[1] - paper[0] > 0.1


def test_seconds_law_keeps_a_distracted_person_low_however_long_watched():
    from trustnav.trust import PAPER_TRUST, SECONDS_TRUST

    distracted = _watch(SECONDS_TRUST, 10, 120.0, 0.9, 0.05)
    attentive = _watch(SECONDS_TRUST, 10, 120.0, 0.05, 0.8)
    assert distracted[120.0] < 0.25 and attentive[120.0] > 0.75
    assert abs(distracted[120.0] - distracted[30.0]) < 0.02  # settled, not creeping up
    assert _watch(PAPER_TRUST, 1, 120.0, 0.9, 0.05)[120.0] > 0.5  # the paper's law only rises


def test_seconds_law_parameters_are_checked():
    from trustnav.trust import TrustParams

    with pytest.raises(ValueError, match="time_constants"):
        TrustParams(time_constants=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="time_constants"):
        TrustParams(time_constants=(1.0, 2.0, 0.0, 3.0))
    with pytest.raises(ValueError, match="fluctuation_interval"):
        TrustParams(fluctuation_interval=-1.0)
