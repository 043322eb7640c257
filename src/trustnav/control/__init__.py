"""Trust-adaptive MPC with discrete CBF constraints (`proposed`, `cbf_imp`): models, barriers,
costs, references, the problem assembled from them, solvers and the controller. Models, costs
and barriers are protocols (:class:`Dynamics`, :class:`Cost`, :class:`Barrier`): a user adds
their own without editing trustnav. Imports trustnav.trust only (for `weight`)."""

from trustnav.control.barrier import (
    TIMINGS,
    Barrier,
    PedestrianBarrier,
    RoadEdgeBarrier,
    barrier,
    cbf_rows,
    continuous_time_radius,
    h_quad,
    predict_pedestrians,
)
from trustnav.control.caution import CautionConfig, CautionDecision, caution_bound, reaction_time
from trustnav.control.costs import Cost, LaneTrackingCost, PositionTrackingCost, TrackingWeights, VelocityTrackingCost
from trustnav.control.deadlock import DeadlockConfig
from trustnav.control.models import CompiledDynamics, Dynamics, DynamicsModel, KinematicBicycle, SingleIntegrator
from trustnav.control.mpc import MpcController, MpcSolution
from trustnav.control.problem import (
    FUSED_KERNELS,
    BicycleProblem,
    MpcConfig,
    MpcProblem,
    SingleIntegratorProblem,
    make_problem,
)
from trustnav.control.reference import BoundedProportionalReference
from trustnav.control.solvers import (
    AuthorsSlsqpSolver,
    SlsqpSolver,
    SolveResult,
    SolveStatus,
    SqpSolver,
    make_solver,
    rank_key,
)
from trustnav.control.yielding import YieldConfig

__all__ = [
    "FUSED_KERNELS",
    "TIMINGS",
    "AuthorsSlsqpSolver",
    "Barrier",
    "BicycleProblem",
    "BoundedProportionalReference",
    "CautionConfig",
    "CautionDecision",
    "CompiledDynamics",
    "Cost",
    "DeadlockConfig",
    "Dynamics",
    "DynamicsModel",
    "KinematicBicycle",
    "LaneTrackingCost",
    "MpcConfig",
    "MpcController",
    "MpcProblem",
    "MpcSolution",
    "PedestrianBarrier",
    "PositionTrackingCost",
    "RoadEdgeBarrier",
    "SingleIntegrator",
    "SingleIntegratorProblem",
    "SlsqpSolver",
    "SolveResult",
    "SolveStatus",
    "SqpSolver",
    "TrackingWeights",
    "VelocityTrackingCost",
    "YieldConfig",
    "barrier",
    "caution_bound",
    "cbf_rows",
    "continuous_time_radius",
    "h_quad",
    "make_problem",
    "make_solver",
    "predict_pedestrians",
    "rank_key",
    "reaction_time",
]
