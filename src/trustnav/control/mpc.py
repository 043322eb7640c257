"""Trust-adaptive MPC-CBF controller (`proposed`), one call per control step.

The controller takes pedestrians, their velocities and trusts as plain arrays at every step
(their number may change between steps), so it can run at its own rate, independently of
perception and trust estimation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control.models import DynamicsModel
from trustnav.control.problem import MpcConfig, MpcProblem, make_problem
from trustnav.control.solvers import FEAS_TOL, SlsqpSolver, SolveResult, SolveStatus, SqpSolver

__all__ = ["MpcController", "MpcSolution"]


@dataclass
class MpcSolution:
    """What one control step decided, and how."""

    control: NDArray[np.float64]  # u(t), the input to apply
    inputs: NDArray[np.float64]  # planned u(t..t+N_h-1)
    predicted_states: NDArray[np.float64]  # x(t..t+N_h) under the plan (after latency compensation)
    status: SolveStatus
    fallback: bool  # True: the solver failed and the braking fallback was applied
    slack_used: bool  # True: the hard CBF rows were infeasible and were relaxed
    cbf_violation: float  # worst relaxation of a CBF row (m^2), 0 when the hard problem held
    iterations: int
    solve_time: float  # seconds
    message: str = ""


class MpcController:
    """Receding-horizon controller: solve `proposed`, apply the first input, shift, repeat."""

    def __init__(
        self,
        model: DynamicsModel,
        cost: object,
        config: MpcConfig | None = None,
        solver: SqpSolver | SlsqpSolver | None = None,
    ) -> None:
        self.model = model
        self.config = config or MpcConfig()
        self.problem: MpcProblem = make_problem(model, cost, self.config)
        self.solver = solver or SqpSolver()
        self.reset()

    def reset(self) -> None:
        self._plan: NDArray[np.float64] | None = None
        self._last_control = np.zeros(self.model.nu)

    def compensate_latency(self, state: ArrayLike, pedestrians: ArrayLike, velocities: ArrayLike | None):
        """Predict ego (with the input being applied) and pedestrians (constant velocity) ahead by
        the configured latency, so the plan starts where the vehicle will be when it acts."""
        lat = self.config.latency
        x = self.model.check_state(state)
        peds = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
        if lat <= 0:
            return x, peds
        n_sub = max(1, int(np.ceil(lat / 0.02)))
        for _ in range(n_sub):
            x = self.model.step(x, self._last_control, lat / n_sub)
        if velocities is not None:
            peds = peds + np.asarray(velocities, dtype=float).reshape(-1, 2) * lat
        return x, peds

    def step(
        self,
        state: ArrayLike,
        pedestrians: ArrayLike,
        velocities: ArrayLike | None,
        trusts: ArrayLike,
    ) -> MpcSolution:
        """One MPC step from ego ``state`` with pedestrians (N_p, 2), velocities (N_p, 2) and
        trusts (N_p,) in [0, 1]."""
        x, peds = self.compensate_latency(state, pedestrians, velocities)
        p = self.problem
        p.set_stage(x, peds, velocities, trusts, self._last_control)
        if self._plan is None:
            u0 = p.initial_guess()
        else:
            u0 = np.vstack([self._plan[1:], self._plan[-1:]])
        res: SolveResult = self.solver.solve(p, u0)
        accept = res.status.ok or (res.status is SolveStatus.MAX_ITER and res.cbf_violation <= FEAS_TOL)
        if accept:
            plan = res.inputs
            fallback = False
        else:
            plan = np.tile(self.model.braking_input(x), (p.n_h, 1))
            fallback = True
        self._plan = plan.copy() if accept else None
        self._last_control = plan[0].copy()
        return MpcSolution(
            control=plan[0].copy(),
            inputs=plan,
            predicted_states=self.model.rollout(x, plan, self.config.dt),
            status=res.status,
            fallback=fallback,
            slack_used=res.slack_used,
            cbf_violation=res.cbf_violation,
            iterations=res.iterations,
            solve_time=res.solve_time,
            message=res.message,
        )
