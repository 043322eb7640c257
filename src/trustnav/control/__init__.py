"""Trust-adaptive MPC with discrete CBF constraints (`proposed`, `cbf_imp`): models, barrier,
references, problems, solvers and the controller. Imports trustnav.trust only (for `weight`)."""

from trustnav.control.barrier import TIMINGS, barrier, cbf_rows, continuous_time_radius, predict_pedestrians
from trustnav.control.models import DynamicsModel, KinematicBicycle, SingleIntegrator
from trustnav.control.mpc import MpcController, MpcSolution
from trustnav.control.problem import (
    BicycleProblem,
    LaneTrackingCost,
    MpcConfig,
    MpcProblem,
    SingleIntegratorProblem,
    TrackingWeights,
    VelocityTrackingCost,
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

__all__ = [
    "TIMINGS",
    "AuthorsSlsqpSolver",
    "BicycleProblem",
    "BoundedProportionalReference",
    "DynamicsModel",
    "KinematicBicycle",
    "LaneTrackingCost",
    "MpcConfig",
    "MpcController",
    "MpcProblem",
    "MpcSolution",
    "SingleIntegrator",
    "SingleIntegratorProblem",
    "SlsqpSolver",
    "SolveResult",
    "SolveStatus",
    "SqpSolver",
    "TrackingWeights",
    "VelocityTrackingCost",
    "barrier",
    "cbf_rows",
    "continuous_time_radius",
    "make_problem",
    "make_solver",
    "predict_pedestrians",
    "rank_key",
]
