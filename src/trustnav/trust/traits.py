"""The paper's trust equations as pure numpy functions.

Every function works on scalars or on arrays (one entry per pedestrian) and cites its equation
label in ``../shared/paper/trust_aware_safe_control.tex``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.trust.params import GammaParams, TrustParams, as_number

__all__ = [
    "N_KEYPOINTS",
    "eye_trait_init",
    "eye_trait_update",
    "fluctuation_confidence",
    "gamma",
    "pose_trait_init",
    "pose_trait_update",
    "relative_pose",
    "sat01",
    "smartphone_trait_init",
    "smartphone_trait_update",
    "total_score",
    "trust_init",
    "trust_update",
]

#: N_k in `pose_conf`: the 17 COCO body keypoints.
N_KEYPOINTS = 17


def sat01(v: ArrayLike) -> NDArray[np.float64] | float:
    """sat_[0,1]: clip onto [0, 1]."""
    out = np.clip(np.asarray(v, dtype=float), 0.0, 1.0)
    return float(out) if out.ndim == 0 else out


def _confidence(name: str, c: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(c, dtype=float)
    if np.any(~np.isfinite(arr)) or np.any(arr < 0.0) or np.any(arr > 1.0):
        raise ValueError(f"{name} must be confidences in [0, 1], got {c!r}")
    return arr


def _out(arr: NDArray[np.float64]) -> NDArray[np.float64] | float:
    return float(arr) if arr.ndim == 0 else arr


def smartphone_trait_init(c_sm: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """s_1(0) = nu01 (1 - C_sm(0)) (after `smato_score`)."""
    return _out(p.nu01 * (1.0 - _confidence("c_sm", c_sm)))


def smartphone_trait_update(s1_prev: ArrayLike, c_sm: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """`smato_score`: s_1(t) = nu1 s_1(t-1) + (1 - nu1)(1 - C_sm(t))."""
    c = _confidence("c_sm", c_sm)
    return _out(p.nu1 * np.asarray(s1_prev, dtype=float) + (1.0 - p.nu1) * (1.0 - c))


def eye_trait_init(c_eye: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """s_2(0) = nu02 C_eye(0) (after `eye_score`)."""
    return _out(p.nu02 * _confidence("c_eye", c_eye))


def eye_trait_update(s2_prev: ArrayLike, c_eye: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """`eye_score`: s_2(t) = sat(s_2(t-1) + nu2 C_eye(t)); monotone non-decreasing."""
    c = _confidence("c_eye", c_eye)
    return sat01(np.asarray(s2_prev, dtype=float) + p.nu2 * c)


def relative_pose(keypoints: ArrayLike, bbox: ArrayLike) -> NDArray[np.float64]:
    """P[n] = (P_abs[n] - X_bbox) / D_bbox: keypoints relative to the box (before `pose_conf`).

    keypoints: (17, 2) pixel coordinates (NaN marks a keypoint not found);
    bbox: [x1, y1, x2, y2] in pixels with x2 > x1 and y2 > y1.
    """
    kp = np.asarray(keypoints, dtype=float)
    if kp.shape != (N_KEYPOINTS, 2):
        raise ValueError(f"keypoints must have shape ({N_KEYPOINTS}, 2), got {kp.shape}")
    box = np.asarray(bbox, dtype=float).reshape(-1)
    if box.shape != (4,) or not np.all(np.isfinite(box)):
        raise ValueError(f"bbox must be 4 finite numbers [x1, y1, x2, y2], got {bbox!r}")
    size = box[2:] - box[:2]
    if np.any(size <= 0):
        raise ValueError(f"bbox must have x2 > x1 and y2 > y1, got {bbox!r}")
    return (kp - box[:2]) / size


def fluctuation_confidence(p_now: ArrayLike, p_prev: ArrayLike, p: TrustParams | float) -> float:
    """`pose_conf`: C_fluc = sat(F N_k / sum_n ||P(t)[n] - P(t-1)[n]||_2).

    ``p``: the TrustParams (F = ``p.fluctuation_sensitivity``) or F itself, a positive number.
    Keypoints missing (NaN) in either frame are left out and the sum is rescaled by
    N_k / (number present), so that F keeps its meaning as the constant of proportionality to
    the mean keypoint deviation. No keypoint in common: ValueError. A motionless pose (sum 0)
    gives full confidence 1.
    """
    if isinstance(p, TrustParams):
        sensitivity = p.fluctuation_sensitivity
    else:
        sensitivity = as_number("fluctuation sensitivity F", p)
        if not 0.0 < sensitivity < np.inf:
            raise ValueError(f"fluctuation sensitivity F (pose_conf) must be a positive number, got {p!r}")
    a = np.asarray(p_now, dtype=float)
    b = np.asarray(p_prev, dtype=float)
    if a.shape != (N_KEYPOINTS, 2) or b.shape != (N_KEYPOINTS, 2):
        raise ValueError(f"relative poses must have shape ({N_KEYPOINTS}, 2), got {a.shape} and {b.shape}")
    dist = np.linalg.norm(a - b, axis=1)
    present = np.isfinite(dist)
    n = int(present.sum())
    if n == 0:
        raise ValueError("no keypoint is present in both poses; pose fluctuation is undefined")
    total = float(dist[present].sum()) * N_KEYPOINTS / n
    if total <= 0.0:
        return 1.0
    return float(min(1.0, sensitivity * N_KEYPOINTS / total))


def pose_trait_init(p: TrustParams) -> float:
    """s_3(0) = nu03 (after `pose_score`)."""
    return p.nu03


def pose_trait_update(s3_prev: ArrayLike, c_fluc: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """`pose_score`: s_3(t) = nu3 s_3(t-1) + (1 - nu3) C_fluc(t)."""
    c = _confidence("c_fluc", c_fluc)
    return _out(p.nu3 * np.asarray(s3_prev, dtype=float) + (1.0 - p.nu3) * c)


def total_score(traits: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """`lin_comb`: S = sum_i rho_i s_i, over the last axis of ``traits`` (..., 3).

    NaN marks a trait not yet available for a pedestrian; its weight is then shared out over
    the available traits (rho renormalised), so that S stays in [0, 1].
    """
    s = np.asarray(traits, dtype=float)
    if s.shape[-1:] != (3,):
        raise ValueError(f"traits must have a last axis of 3 (smartphone, eye, pose), got shape {s.shape}")
    rho = np.asarray(p.rho)
    avail = np.isfinite(s)
    w = np.where(avail, rho, 0.0)
    wsum = w.sum(axis=-1)
    if np.any(wsum <= 0):
        raise ValueError("total score needs at least one available trait with non-zero weight")
    return _out(np.asarray((np.where(avail, s, 0.0) * w).sum(axis=-1) / wsum, dtype=float))


def trust_init(score0: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """tau(0) = beta0 S(0) (after `agg_trust`)."""
    return _out(p.beta0 * np.asarray(score0, dtype=float))


def trust_update(trust_prev: ArrayLike, score: ArrayLike, p: TrustParams) -> NDArray[np.float64] | float:
    """`agg_trust`: tau(t+1) = sat(alpha tau(t) + beta S(t+1))."""
    return sat01(p.alpha * np.asarray(trust_prev, dtype=float) + p.beta * np.asarray(score, dtype=float))


def gamma(trust: ArrayLike, p: GammaParams) -> NDArray[np.float64]:
    """`weight`: gamma_j = gamma_ini + delta tau_j ** lambda, vectorised over pedestrians.

    Trust outside [0, 1] (or NaN) is refused; with the conditions after `weight` (enforced by
    GammaParams) the result lies in [gamma_ini, gamma_ini + delta] within [0, 1].
    """
    t = np.asarray(trust, dtype=float)
    if t.size and not (t.min() >= 0.0 and t.max() <= 1.0):  # NaN fails both comparisons
        raise ValueError(f"trust must lie in [0, 1], got {trust!r}")
    return p.gamma_ini + p.delta * np.power(t, p.lam)
