"""Pure mathematics of the paper's trust estimation (Section II) and trust-adaptive gamma (`weight`).

Imports nothing else of trustnav.
"""

from trustnav.trust.estimator import Observation, TrackState, TrustEstimator
from trustnav.trust.params import (
    MOVING_AVERAGE_TRUST,
    PAPER_GAMMA_CARLA,
    PAPER_GAMMA_NUMERICAL,
    PAPER_TRUST,
    GammaParams,
    TrustParams,
)
from trustnav.trust.traits import (
    N_KEYPOINTS,
    eye_trait_init,
    eye_trait_update,
    fluctuation_confidence,
    gamma,
    pose_trait_init,
    pose_trait_update,
    relative_pose,
    sat01,
    smartphone_trait_init,
    smartphone_trait_update,
    total_score,
    trust_init,
    trust_update,
)

__all__ = [
    "MOVING_AVERAGE_TRUST",
    "N_KEYPOINTS",
    "PAPER_GAMMA_CARLA",
    "PAPER_GAMMA_NUMERICAL",
    "PAPER_TRUST",
    "GammaParams",
    "Observation",
    "TrackState",
    "TrustEstimator",
    "TrustParams",
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
