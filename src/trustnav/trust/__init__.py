"""Pure mathematics of the paper's trust estimation (Section II) and trust-adaptive gamma (`weight`).

Traits are parts (:mod:`trustnav.trust.parts`): the estimator takes any :class:`TraitSet`; the
paper's three (:data:`PAPER_TRAITS`) are the default. Imports nothing else of trustnav.
"""

from trustnav.trust.estimator import TrackState, TrustEstimator
from trustnav.trust.params import (
    MOVING_AVERAGE_TRUST,
    PAPER_GAMMA_CARLA,
    PAPER_GAMMA_NUMERICAL,
    PAPER_TRUST,
    SECONDS_TRUST,
    GammaParams,
    TrustParams,
)
from trustnav.trust.parts import (
    PAPER_TRAITS,
    CueTrait,
    EyeContact,
    PoseFluctuation,
    SmartphoneUse,
    Trait,
    TraitSet,
    TraitStep,
    paper_traits,
)
from trustnav.trust.sighting import EYE_CONTACT, SMARTPHONE, Sighting
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
    "EYE_CONTACT",
    "MOVING_AVERAGE_TRUST",
    "N_KEYPOINTS",
    "PAPER_GAMMA_CARLA",
    "PAPER_GAMMA_NUMERICAL",
    "PAPER_TRAITS",
    "PAPER_TRUST",
    "SECONDS_TRUST",
    "SMARTPHONE",
    "CueTrait",
    "EyeContact",
    "GammaParams",
    "PoseFluctuation",
    "Sighting",
    "SmartphoneUse",
    "TrackState",
    "Trait",
    "TraitSet",
    "TraitStep",
    "TrustEstimator",
    "TrustParams",
    "eye_trait_init",
    "eye_trait_update",
    "fluctuation_confidence",
    "gamma",
    "paper_traits",
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
