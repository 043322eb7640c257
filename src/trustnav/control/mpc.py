"""Trust-adaptive MPC-CBF controller (`proposed`), one call per control step.

The controller takes pedestrians, their velocities and trusts as plain arrays at every step
(their number may change between steps), so it can run at its own rate, independently of
perception and trust estimation.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control._kernels import shift_plan, shift_under_speed_cap, under_speed_cap
from trustnav.control.barrier import Barrier, RoadEdgeBarrier, _quantile, uncertainty_margins
from trustnav.control.caution import (
    _caution_step,
    _least_bound,
    _unseen_step,
    bound_constants,
    caution_bound,
    caution_note,
)
from trustnav.control.costs import Cost, LaneTrackingCost, PositionTrackingCost, VelocityTrackingCost
from trustnav.control.deadlock import DeadlockResolver
from trustnav.control.models import Dynamics, KinematicBicycle, SingleIntegrator
from trustnav.control.problem import MpcConfig, MpcProblem, as_pedestrians, whole_step_kernel_loaded
from trustnav.control.reference import BoundedProportionalReference
from trustnav.control.solvers import (
    FEAS_TOL,
    MERIT_WEIGHT,
    PRIMAL_TOL,
    AuthorsSlsqpSolver,
    SlsqpSolver,
    SolveResult,
    SolveStatus,
    SqpSolver,
    rank_key,
)
from trustnav.control.yielding import Yielder
from trustnav.trust.params import as_number

__all__ = ["MpcController", "MpcSolution"]

_wall = time.perf_counter  # (``time`` is also an argument name of MpcController.step)
STATE_TOL = 1e-6  # tolerance on the model's hard state limits (bicycle: m/s below speed_min)


@dataclass(slots=True)
class MpcSolution:
    """What one control step decided, and how. Every field describes the plan actually returned."""

    control: NDArray[np.float64]  # u(t), the input to apply
    inputs: NDArray[np.float64]  # planned u(t..t+N_h-1)
    predicted_states: NDArray[np.float64]  # x(t..t+N_h) under the plan (after latency compensation)
    status: SolveStatus  # the solver's status, or FALLBACK when a fallback plan was applied
    fallback: bool  # True: the shifted previous plan or braking was applied instead of the solver's plan
    slack_used: bool  # True: the returned plan violates some CBF row (no hard-feasible plan was found)
    cbf_violation: float  # worst CBF-row violation of the returned plan (m^2), 0 when every row holds
    iterations: int
    solve_time: float  # seconds, the whole step
    message: str = ""
    source: str = "solver"  # "solver", "previous_plan" or "braking"
    first_row_violation: float = 0.0  # worst violation of the first rows an input can change (k = 0)
    decided_violation: float = 0.0  # worst violation of rows fixed by the current state (one-Euler-step bicycle k = 0)
    recovered: bool = False  # the solver's feasibility recovery found a hard-feasible start
    deadline_hit: bool = False  # the step deadline cut the solve short
    state_violation: float = 0.0  # worst break of the model's hard state limits (bicycle: v < speed_min), m/s
    state_repaired: bool = False  # the chosen plan broke a state limit and was repaired or replaced by braking
    detour: str | None = None  # the route layer's note: going around a group, no room to, yielding (None: nothing)


# frozen dataclasses whose checks (__post_init__) only validate or normalise their fields
_CHECK_ONLY = (LaneTrackingCost, VelocityTrackingCost, PositionTrackingCost, BoundedProportionalReference)


def _revised(obj, **changes):  # type: ignore[no-untyped-def]
    """``dataclasses.replace(obj, **changes)`` without re-running the checks of a validated frozen
    dataclass of :data:`_CHECK_ONLY` (8 us a step for a cost and its reference), for changes the
    caller knows to be valid; other types through ``replace``."""
    if type(obj) not in _CHECK_ONLY:
        return replace(obj, **changes)
    new = object.__new__(type(obj))
    fields = obj.__dict__.copy()
    fields.update(changes)
    object.__setattr__(new, "__dict__", fields)  # (one dict, not a __setattr__ per change)
    return new


class MpcController:
    """Receding-horizon controller: solve `proposed`, apply the first input, shift, repeat.

    Every step returns a checked plan: when the solver does not end OPTIMAL, its plan, the
    shifted previous plan and braking to rest are checked against the exact CBF rows and the
    best by (user barriers' violation, first-row violation, total violation over the horizon, cost) is
    applied (:func:`rank_key`).

    The problem is assembled from ``model`` (any :class:`~trustnav.control.models.Dynamics`),
    ``cost`` (any :class:`~trustnav.control.costs.Cost`), the pedestrians given at every step (the
    paper's barrier, gamma from trust) and ``barriers``, any number of user barriers
    (:class:`~trustnav.control.barrier.Barrier`: keep-out zones, road edges).
    """

    def __init__(
        self,
        model: Dynamics,
        cost: Cost,
        config: MpcConfig | None = None,
        solver: SqpSolver | SlsqpSolver | AuthorsSlsqpSolver | None = None,
        barriers: Sequence[Barrier] = (),
    ) -> None:
        self.config = config or MpcConfig()
        self.problem: MpcProblem = MpcProblem(model, cost, self.config, barriers)
        self.model = self.problem.model
        self.solver = solver or SqpSolver()
        self._deadlock = None
        if self.config.deadlock is not None and isinstance(self.problem.cost, VelocityTrackingCost):
            self._deadlock = DeadlockResolver(self.config.deadlock, self.config.dt)
        self._yielder, self._road = None, None  # a car on a road: brake and wait for who it cannot pass
        roads = [b for b in self.problem.barriers if isinstance(b, RoadEdgeBarrier)]
        if self.config.yielding is not None and isinstance(self.problem.cost, LaneTrackingCost) and roads:
            self._yielder, self._road = Yielder(self.config.yielding), roads[0]
        # the whole step in one compiled call where it applies (see _whole_step)
        self._whole = (
            type(self.model) in (SingleIntegrator, KinematicBicycle) and self.config.latency <= 0
            and self._yielder is None and not self.problem.n_user and self.config.caution is None
        )  # fmt: skip
        self._state_shape = (self.model.nx,)
        self._caution_constants = () if self.config.caution is None else bound_constants(self.config.caution)
        c = self.config  # the unseen bet's constants: (ego x, ego y, now) written each step; then R and the bound's
        self._unseen_constants = np.zeros(15) if c.caution is None else np.array(
            [0.0, 0.0, 0.0, c.latency + c.horizon * c.dt, c.latency, c.caution.walking_speed,
             c.caution.trust_exponent, _quantile(c.confidence), c.safety_radius, *self._caution_constants])  # fmt: skip
        # a bicycle's unseen bet, radii and speed bound in one compiled call (_caution_pass), into
        # arrays kept for each number of pedestrians
        self._fused_caution = c.caution is not None and c.caution.occlusion and type(self.model) is KinematicBicycle
        self._caution_buffers: dict[int, tuple] = {}
        self._capped: tuple | None = None  # (cost, its reference capped, the cost capped): caution's last
        self._ease_step = 0.0 if c.caution is None else c.caution.ease * c.dt  # the speed rows' most lowering a step
        self._warm_up()
        self.reset()

    def _warm_up(self) -> None:
        """Load the compiled kernels now (numba), so the first step's deadline measures solving."""
        p = self.problem
        x = np.zeros(self.model.nx)
        p.set_stage(x, [[1e3, 1e3]], None, [0.0])
        p.build(p.initial_guess())
        p.compiled_steps(p.initial_guess().copy(), 1, 1.0, PRIMAL_TOL, MERIT_WEIGHT)  # loads the compiled SQP loop
        if self._whole:  # and the whole step's
            one = np.zeros((1, 2))
            p.whole_step(x, one + 1e3, one, np.zeros(1), p.initial_guess(), np.zeros(self.model.nu), 1, 1.0,
                         PRIMAL_TOL, MERIT_WEIGHT, 1, FEAS_TOL)  # fmt: skip
            p._whole_args = None
            whole_step_kernel_loaded()
        if self.config.caution is not None:  # and caution's
            caution_bound(self.config.caution, x[:2], np.array([1.0, 0.0]), np.ones((1, 2)), np.zeros(1), np.ones(1))
            under_speed_cap(np.zeros((1, 2)), 0.0, 1.0, -1.0, 1.0)
            shift_under_speed_cap(np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2)), 0.0, 1.0, -1.0, 1.0)
            if self._fused_caution:  # then it compiles nothing more: other dtypes and layouts are converted
                one, cov = np.ones((1, 2)), np.zeros((1, 4, 4))
                _caution_step(self._unseen_constants.copy(), 0.0, 0.0, 0.0, 1.0, 0.0, np.zeros(1), np.zeros((1, 4)),
                              cov, np.ones(1), one, one, np.zeros(1), cov, self._buffers(1)[0])  # fmt: skip
                if _caution_step.signatures:
                    _caution_step.disable_compile()
        p._qp_structs = None  # no warm start from this stand-in problem
        p.set_stage(x, np.zeros((0, 2)), None, [])

    def reset(self) -> None:
        if self._deadlock is not None:
            self._deadlock.reset()
        if self._yielder is not None:
            self._yielder.reset()
        self._plan: NDArray[np.float64] | None = None
        self._last_control = np.zeros(self.model.nu)
        self._issued: deque[tuple[float, NDArray[np.float64]]] = deque()  # (time sent, command)
        self._clock = 0.0  # time of the next step when the caller gives none (one step per dt)

    def compensate_latency(
        self, state: ArrayLike, pedestrians: ArrayLike, velocities: ArrayLike | None, time: float | None = None
    ):
        """Predict ego (under the commands still in flight) and pedestrians (constant velocity)
        ahead by the configured latency, so the plan starts where the vehicle will be when it acts."""
        peds = np.asarray(pedestrians, dtype=float) if np.size(pedestrians) else np.zeros((0, 2))
        n_p = peds.shape[0] if peds.ndim == 2 else 0
        peds, vels, _ = as_pedestrians(pedestrians, velocities, np.zeros(n_p))
        now = self._now(time)
        return self._compensate(self.model.check_state(state), peds, vels, velocities is not None, now)

    def _now(self, t: float | None) -> float:
        if t is None:
            return self._clock
        try:
            finite = math.isfinite(as_number("time", t))
        except ValueError:
            finite = False
        if not finite:
            raise ValueError(f"time must be a finite number of seconds (or None), got {t!r}")
        if self._issued and t < self._issued[-1][0] - 1e-9:
            raise ValueError(f"time must not go back: got {t!r} after a step at {self._issued[-1][0]!r} (call reset())")
        return float(t)

    def _compensate(self, x, peds, vels, moving: bool, now: float):
        """State at now + latency: a command sent at t_i acts from t_i + latency (as the plant
        applies it), so the commands sent in the last ``latency`` seconds, and the one acting now,
        are integrated piece by piece. Without a ``time`` the controller counts one step per dt."""
        lat = self.config.latency
        if lat <= 0:
            return x, peds
        u = np.zeros(self.model.nu)  # acting now: the last command that took effect by now
        pending = []
        for t_i, c in self._issued:
            if t_i + lat <= now + 1e-9:
                u = c
            else:
                pending.append((t_i + lat - now, c))
        t = 0.0
        for t_on, c in pending:
            if t_on > t + 1e-9:
                x = self.model.step(x, u, t_on - t)
                t = t_on
            u = c
        if lat > t + 1e-9:
            x = self.model.step(x, u, lat - t)
        if moving:
            peds = peds + vels * lat
        return x, peds

    def _sent(self, now: float, command: NDArray[np.float64]) -> None:
        """Remember a command sent at ``now`` (the controller's own array, never changed in place);
        forget those no longer acting or pending."""
        self._issued.append((now, command))
        lat = self.config.latency
        while len(self._issued) > 1 and self._issued[1][0] + lat <= now + 1e-9:
            self._issued.popleft()  # a newer command has taken effect
        self._clock = now + self.config.dt

    def step(
        self,
        state: ArrayLike,
        pedestrians: ArrayLike,
        velocities: ArrayLike | None,
        trusts: ArrayLike,
        time: float | None = None,
        covariances: ArrayLike | None = None,
        last_seen: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
    ) -> MpcSolution:
        """One MPC step from ego ``state`` with pedestrians (N_p, 2), velocities (N_p, 2) and
        trusts (N_p,) in [0, 1]. ``time`` (s): when the state was measured and the command will be
        sent; it places the commands still in flight for the latency compensation, so a caller
        that runs faster or slower than dt should give it (default: one call per dt).
        ``covariances`` (N_p, 4, 4) of each pedestrian's estimated (x, y, v_x, v_y), or (N_p, 2, 2)
        of its position: R grows for that pedestrian by its uncertainty along the line of
        approach, predicted over the latency and the horizon, so that R holds from the true
        position with probability ``config.confidence`` (:func:`uncertainty_margins`)."""
        t0 = _wall()
        if self._whole and covariances is None:  # the common step in one compiled call
            done = self._whole_step(state, pedestrians, velocities, trusts, time, t0)
            if done is not None:
                return done
        peds, vels, tr = as_pedestrians(pedestrians, velocities, trusts)  # refuse bad input first
        now = self._clock if time is None else self._now(time)
        x = self.model.check_state(state)
        if self.config.latency > 0:
            x, peds = self._compensate(x, peds, vels, velocities is not None, now)
        p = self.problem
        margins = None
        radii = None  # each pedestrian's R and margin, for the layers above the MPC (made once)
        bound = None  # a bicycle's caution: (speed bound, whose, metres ahead), found with the unseen bet
        if covariances is not None:
            c = self.config
            lead = c.latency + c.horizon * c.dt
            margins = uncertainty_margins(x[:2], peds, covariances, lead, c.confidence)
            if last_seen is not None and c.caution is not None and c.caution.occlusion and len(peds):
                if self._fused_caution:
                    peds, vels, margins, covariances, radii, bound = self._caution_pass(
                        x, peds, vels, tr, margins, covariances, last_seen, now
                    )
                else:
                    peds, vels, margins, covariances = self._unseen(
                        x, peds, vels, tr, margins, covariances, last_seen, now
                    )
        detour, tracked = None, p.cost
        if self._deadlock is not None:  # the route layer may move the goal the cost tracks
            radii = self._radii(len(peds), margins)
            speed = float(np.hypot(*self._last_control[:2]))
            waypoint = self._deadlock.goal(x[:2], speed, np.asarray(tracked.goal, dtype=float), peds, radii)
            detour = self._deadlock.note
            if waypoint is not None:
                p.cost = replace(tracked, goal=(float(waypoint[0]), float(waypoint[1])))
        # the yielding layer may stop the car short of someone (with caution, also someone it remembers)
        held_stop = None
        if self._yielder is not None and self.config.caution is not None and self._yielder.passing:
            # whom it waited for and did not find again: passed around where she would be, trusted
            # least (unseen), her sighting's uncertainty carried as her margin (module yielding)
            road = self._road
            seen_at = None if last_seen is None else np.asarray(last_seen[2], dtype=float)
            z = _quantile(self.config.confidence)
            g_pos, g_vel, g_sigma = self._yielder.remembered(now, x[:2], float(x[2]), road.start, road.normal,
                                                             road.room, self.config.safety_radius, peds,
                                                             seen_at, z)  # fmt: skip
            if len(g_pos):
                n0, m = len(peds), len(g_pos)
                if last_seen is not None:  # their sightings: where they would be now, as of now
                    ls_x, ls_p, ls_t = (np.asarray(a, dtype=float) for a in last_seen)
                    g_cov = np.zeros((m, 4, 4))
                    g_cov[:, 0, 0] = g_cov[:, 1, 1] = g_sigma**2
                    last_seen = (np.vstack([ls_x, np.hstack([g_pos, g_vel])]), np.concatenate([ls_p, g_cov]),
                                 np.append(ls_t, np.full(m, now)))  # fmt: skip
                peds, vels, tr = np.vstack([peds, g_pos]), np.vstack([vels, g_vel]), np.append(tr, np.zeros(m))
                margins = np.append(np.zeros(n0) if margins is None else margins, z * g_sigma)
                if covariances is not None:
                    cv = np.asarray(covariances, dtype=float)
                    covariances = np.concatenate([cv, np.zeros((m, *cv.shape[1:]))])
                radii, bound = None, None  # made anew with them
        if self._yielder is not None and (len(peds) or (self.config.caution is not None and self._yielder.remembers)):
            road, lane = self._road, p.cost
            if radii is None:  # (else the route layer's, made this step from the same margins)
                radii = self._radii(len(peds), margins)
            # with caution, the velocity's uncertainty too (caution off: the paper's controller)
            cov = None
            if self.config.caution is not None and covariances is not None:  # position-only covariances: no velocity
                cv = covariances
                cov = cv if (cv.ndim == 3 and cv.shape[1] == 4 if type(cv) is np.ndarray else
                             np.ndim(cv) == 3 and np.shape(cv)[1] == 4) else None  # fmt: skip
            held = (now, self.config.safety_radius, float(x[2])) if self.config.caution is not None else (None,) * 3
            sightings = last_seen if self.config.caution is not None and last_seen is not None else None
            stop = self._yielder.decide(x[:2], float(x[3]), np.asarray(lane.start, dtype=float),
                                        np.asarray(lane.goal, dtype=float), road.start, road.normal, road.room,
                                        peds, vels, radii, cov, _quantile(self.config.confidence),
                                        *held, sightings=sightings)  # fmt: skip
            if stop is not None:
                held_stop = stop
                ref = lane.reference
                # (copied without re-running their checks: a finite stop on the lane past its start, a
                # positive finite cap)
                capped = _revised(ref, v_max=max(min(ref.v_max, stop.speed_cap), 1e-3))
                p.cost = _revised(lane, goal=(float(stop.stop[0]), float(stop.stop[1])), reference=capped)
                detour = stop.note
        if self.config.caution is not None:  # caution: the speed bound of who might step out
            detour = self._caution(x, peds, tr, margins, radii, detour, bound)
            if held_stop is not None and type(self.model) is KinematicBicycle:
                # a yield is a stop: its cap bounds the speed rows too (lowered by at most ``ease``
                # per step), so no barrier's push (an unseen bystander's growing region) creeps the
                # car past it into the way of whom it waits for
                ease = self.config.caution.ease * self.config.dt
                p.speed_cap = min(p.speed_cap, max(held_stop.speed_cap, float(x[3]) - ease))
        try:
            p.set_checked_stage(x, peds, vels, tr, self._last_control, margins)
        finally:
            p.cost = tracked
        shifted = None
        capped = p.speed_cap < math.inf  # caution: start the SQP inside its speed rows (its merit counts CBF rows only)
        if self._plan is not None:  # the previous plan shifted by one step, its last input held
            shifted = np.empty(self._plan.shape)
            if capped and type(self.model) is KinematicBicycle:  # and capped, in one call
                u0, m = np.empty(shifted.shape), self.model
                shift_under_speed_cap(self._plan, shifted, u0, float(x[3]), min(m.speed_max, p.speed_cap),
                                      float(m.accel_min), self.config.dt)  # fmt: skip
                capped = False
            else:
                shift_plan(self._plan, shifted)
                u0 = shifted
        else:
            u0 = p.initial_guess()
        if capped:
            u0 = self._under_speed_cap(u0, float(x[3]))
        # deterministic: the solver's iteration budget alone bounds the step (no wall clock)
        deadline = None if self.config.deterministic else max(self.config.step_deadline - (_wall() - t0), 0.0)
        res: SolveResult = self.solver.solve(p, u0, deadline=deadline)
        plan, status, source = res.inputs, res.status, "solver"  # res.inputs: a fresh array, the controller's own
        fv, viol, message = res.first_row_violation, res.cbf_violation, res.message
        if status is not SolveStatus.OPTIMAL:
            # checked, ranked fallbacks: the solver's plan competes with the shifted previous plan
            # and braking to rest; ties keep the solver's plan
            cands = [("solver", res.inputs)] if np.isfinite(res.inputs).all() else []
            if shifted is not None:
                cands.append(("previous_plan", np.clip(shifted, p.ulo, p.uhi)))
            if p.speed_cap < math.inf and type(self.model) is KinematicBicycle:
                # an unconverged plan may break the speed rows (the SQP's merit counts CBF rows
                # only): none speeds the car past the cap or its speed now (braking is a candidate)
                top = max(p.speed_cap, float(x[3]))
                held = [(name, u, self._under_speed_cap(u, float(x[3]), top)) for name, u in cands]
                lowered = {name for name, u, h in held if not np.array_equal(u, h)}
                cands = [(name, h) for name, _, h in held]
            else:
                top, lowered = math.inf, set()
            cands.append(("braking", p.braking_plan()))
            scored = []
            for i, (name, u) in enumerate(cands):
                chk = p.evaluate(u)
                scored.append((rank_key(chk), i, name, u, chk.first_row, chk.worst))
            _, _, source, plan, fv, viol = min(scored, key=lambda r: (r[0], r[1]))
            if source != "solver":
                status = SolveStatus.FALLBACK
                message = f"{source} applied (violation {viol:.3g}) instead of the solver's plan: " + (
                    f"{res.status.value}: {res.message}" if res.message else res.status.value
                )
            if source in lowered:
                note = f"its accelerations lowered to keep the speed under {top:.3g} m/s"
                message = f"{message}; {note}" if message else note
        predicted = self.model.rollout(x, plan, self.config.dt)
        broken = self.model.state_limit_violation(predicted)
        state_violation, repaired = broken, False
        if broken > STATE_TOL:  # never applied unflagged: repaired, or braking, whichever ranks first
            plan, source, status, fv, viol, state_violation, predicted, note = self._repair(
                x, plan, source, status, fv, viol, broken
            )
            repaired = True
            message = f"{message}; {note}" if message else note
        decided = p.decided_violation() if p.n_decided else 0.0  # the same at every plan
        if decided > FEAS_TOL:
            note = f"CBF rows fixed by the current state (no input changes them) violated by {decided:.3g}"
            message = f"{message}; {note}" if message else note
        first = plan[0].copy()
        self._plan = plan.copy()
        self._last_control = first
        self._sent(now, first)
        return MpcSolution(
            control=first.copy(),
            inputs=plan.copy(),
            predicted_states=predicted,
            status=status,
            fallback=source != "solver",
            slack_used=viol > FEAS_TOL,
            cbf_violation=viol,
            iterations=res.iterations,
            solve_time=_wall() - t0,
            message=message,
            source=source,
            first_row_violation=fv,
            decided_violation=decided,
            recovered=res.recovered,
            deadline_hit=res.deadline_hit,
            state_violation=state_violation,
            state_repaired=repaired,
            detour=detour,
        )

    def _whole_step(self, state, pedestrians, velocities, trusts, time, t0: float) -> MpcSolution | None:
        """:meth:`step` in one compiled call (:meth:`SqpSolver.solve_whole_step`) for the common
        case: float64 arrays as the general path would make them, a previous plan, the route layer
        idle, and a solve that converges to a plan passing its check. The same result as the
        general path, which runs where this returns None: a whole step in Python costs more in
        cold caches, as in a vehicle's loop between perception's frames, than its arithmetic."""
        prev = self._plan
        if (
            prev is None
            or type(self.solver) is not SqpSolver
            or type(state) is not np.ndarray
            or type(pedestrians) is not np.ndarray
            or type(trusts) is not np.ndarray
            or state.shape != self._state_shape
            or pedestrians.ndim != 2
            or trusts.ndim != 1
        ):
            return None
        if velocities is None:  # standing pedestrians, as the general path reads None
            velocities = np.zeros(pedestrians.shape)
        if (
            type(velocities) is not np.ndarray
            or pedestrians.shape != velocities.shape
            or pedestrians.shape[1] != 2
            or trusts.shape[0] != pedestrians.shape[0]
        ):  # dtypes, dimensions and layouts: the compiled call takes float64 C arrays only
            return None
        now = self._clock if time is None else self._now(time)
        dl, last = self._deadlock, self._last_control
        if dl is not None and not dl.idle(math.hypot(last[0], last[1])):
            return None
        c = self.config
        deadline = None if c.deterministic else max(c.step_deadline - (_wall() - t0), 0.0)
        out = self.solver.solve_whole_step(self.problem, state, pedestrians, velocities, trusts, prev, last, deadline)
        if out is None:
            return None
        iterations, _, first_row, worst, limit, decided, plan, predicted = out  # plan: fresh, the controller's own
        first = plan[0].copy()
        self._plan = plan
        self._last_control = first
        issued = self._issued  # _sent with no latency: the newest command is the one acting
        issued.append((now, first))
        if len(issued) > 1:
            issued.popleft()
        self._clock = now + c.dt
        return MpcSolution(
            control=first.copy(),
            inputs=plan.copy(),
            predicted_states=predicted,
            status=SolveStatus.OPTIMAL,
            fallback=False,
            slack_used=False,
            cbf_violation=worst,
            iterations=iterations,
            solve_time=_wall() - t0,
            first_row_violation=first_row,
            decided_violation=decided,
            state_violation=limit,
            detour=None if dl is None else dl.note,
        )

    def _caution(self, x, peds, tr, margins, radii, detour: str | None, found=None) -> str | None:
        """Set this step's caution (:mod:`~trustnav.control.caution`): the reference speed the cost
        tracks capped, and the bicycle's speed rows bounded (``problem.speed_cap``, lowered from the
        present speed by at most ``ease`` per step). Returns the step's note. ``found``: the bound
        :meth:`_caution_pass` found this step, (bound, index, metres ahead) (None: found here)."""
        p = self.problem
        p.speed_cap = math.inf
        if found is not None:  # (a bicycle's)
            found, j, ahead = found
            if j < 0:
                return detour
            return self._capped_to(found, float(x[3]), True, detour, float(tr[j]), ahead)
        if not len(peds):
            return detour
        bicycle = type(self.model) is KinematicBicycle
        if bicycle:
            yaw = float(x[2])
            hx, hy = math.cos(yaw), math.sin(yaw)
            speed = float(x[3])
        else:  # a planar point: toward the goal its cost tracks
            goal = getattr(p.cost, "goal", None)
            if goal is None:
                return detour
            heading = np.asarray(goal, dtype=float) - x[:2]
            n = float(np.hypot(*heading))
            if n < 1e-9:
                return detour
            heading = heading / n
            hx, hy = float(heading[0]), float(heading[1])
            speed = float(np.hypot(*self._last_control[:2]))
        if radii is None:  # (else the radii the yielding layer made this step: the same)
            radii = self._radii(len(peds), margins)
        # caution_bound's compiled pass, without its wrapper's checks (the step's arrays are checked)
        found, j, _, ahead = _least_bound(float(x[0]), float(x[1]), hx, hy, np.ascontiguousarray(peds),
                                          np.ascontiguousarray(tr), radii, *self._caution_constants)  # fmt: skip
        if j < 0:
            return detour
        return self._capped_to(found, speed, bicycle, detour, float(tr[j]), ahead)

    def _capped_to(self, found: float, speed: float, bicycle: bool, detour: str | None, trust: float, ahead: float):
        """:meth:`_caution`'s bound ``found`` (m/s), set by a pedestrian of ``trust`` ``ahead`` metres
        ahead, applied at the car's ``speed``; returns the step's note."""
        p = self.problem
        # the speed rows and the reference the cost tracks get the same bound (a reference above
        # the rows would pull the SQP's merit against them), lowered by at most ``ease`` per step
        bound = max(found, speed - self._ease_step) if bicycle else found
        cost = p.cost
        ref = getattr(cost, "reference", None)
        if ref is not None and hasattr(ref, "v_max"):
            v_max = max(min(ref.v_max, bound), 1e-3)
            if v_max != ref.v_max:  # (a bound above the reference's speed leaves the cost as it is)
                last = self._capped  # (the tracked cost, its reference capped, the cost capped): the last step's
                if last is not None and last[0] is cost and type(last[1]) is BoundedProportionalReference:
                    # the same cost capped anew: the controller's own copy of its reference (which derives
                    # nothing from v_max, and which no one else holds) takes the new cap in place
                    if last[1].v_max != v_max:
                        object.__setattr__(last[1], "v_max", v_max)
                elif last is None or last[0] is not cost or last[1].v_max != v_max:
                    capped = _revised(ref, v_max=v_max)
                    last = self._capped = (cost, capped, _revised(cost, reference=capped))
                p.cost = last[2]
        if bicycle:
            p.speed_cap = bound
        return detour or caution_note(found, trust, ahead)

    def _unseen(self, x, peds, vels, tr, margins, covariances, last_seen, now: float):
        """Pedestrians seen last ``tau`` > 0 s ago: the region on trust's bet that each keeps to her
        last seen velocity (:func:`~trustnav.control.caution.unseen_regions`: her estimate then,
        propagated at that velocity, its margin plus the reach ``rho``) where its margin is below
        the tracker's; her position, velocity, margin and covariance replaced by it there."""
        n = len(peds)
        try:
            states, covs, times = last_seen
            if type(states) is not np.ndarray or type(covs) is not np.ndarray or type(times) is not np.ndarray:
                states, covs, times = (np.asarray(a, dtype=float) for a in last_seen)
        except (TypeError, ValueError):
            states = covs = times = np.zeros(0)
        cov = covariances if type(covariances) is np.ndarray else np.asarray(covariances, dtype=float)
        used = -1
        if states.shape == (n, 4) and covs.shape == (n, 4, 4) and times.shape == (n,) and cov.shape == (n, 4, 4):
            k = self._unseen_constants  # in one compiled pass
            k[0], k[1], k[2] = x[0], x[1], now
            out = np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty((n, 4, 4))
            c_ = np.ascontiguousarray
            used = _unseen_step(c_(k), c_(times, dtype=float), c_(states, dtype=float), c_(covs, dtype=float),
                                c_(tr, dtype=float), c_(peds, dtype=float), c_(vels, dtype=float),
                                c_(margins, dtype=float), c_(cov, dtype=float), *out)  # fmt: skip
        shapes = (states.shape, covs.shape, times.shape)
        if used < 0:
            raise ValueError(f"last_seen must be finite (states ({n}, 4), covariances ({n}, 4, 4), times ({n},)) "
                             f"beside 4 x 4 covariances, got shapes {shapes}")  # fmt: skip
        if used:  # the bet where its margin is below the tracker's (in copies: the caller's arrays stay)
            peds, vels, margins, cov = out
        return peds, vels, margins, cov

    def _buffers(self, n: int) -> tuple:
        """The array :meth:`_caution_pass` writes for ``n`` pedestrians, and its views: positions,
        velocities, margins, covariances and radii (made once for each ``n``)."""
        out = self._caution_buffers.get(n)
        if out is None:
            flat = np.empty(22 * n)
            out = self._caution_buffers[n] = (
                flat, flat[: 2 * n].reshape(n, 2), flat[2 * n : 4 * n].reshape(n, 2), flat[4 * n : 5 * n],
                flat[5 * n : 21 * n].reshape(n, 4, 4), flat[21 * n :],
            )  # fmt: skip
        return out

    def _caution_pass(self, x, peds, vels, tr, margins, covariances, last_seen, now: float):
        """A bicycle's :meth:`_unseen` and the speed bound of :meth:`_caution` in one compiled call
        (:func:`~trustnav.control.caution._caution_step`): the step's pedestrians, velocities,
        margins, covariances and radii (R plus margin) after the unseen bet, in the controller's
        arrays (rewritten at the next step: the problem's, and the layers', for this step only), and
        the speed bound (bound, index, metres ahead; index -1: none)."""
        n = len(peds)
        out = self._caution_buffers.get(n) or self._buffers(n)
        px, py, yaw, _ = x.tolist()  # (Python floats: numba reads them faster than numpy's)
        hx, hy, k = math.cos(yaw), math.sin(yaw), self._unseen_constants
        used = -1
        try:  # float64 C arrays, as the step makes them and a caller gives them
            states, covs, times = last_seen
            used, found, j, _, ahead = _caution_step(k, px, py, now, hx, hy, times, states, covs, tr, peds, vels,
                                                     margins, covariances, out[0])  # fmt: skip
        except (TypeError, ValueError):
            pass
        if used < 0:  # other types or layouts converted (the kernel compiles no variant); shapes checked
            try:
                states, covs, times = (np.asarray(a, dtype=float) for a in last_seen)
            except (TypeError, ValueError):
                states = covs = times = np.zeros(0)
            cov = np.asarray(covariances, dtype=float)
            if states.shape == (n, 4) and covs.shape == (n, 4, 4) and times.shape == (n,) and cov.shape == (n, 4, 4):
                arrays = (times, states, covs, tr, peds, vels, margins, cov)
                args = (np.ascontiguousarray(a, dtype=float) for a in arrays)
                used, found, j, _, ahead = _caution_step(k, px, py, now, hx, hy, *args, out[0])
            if used < 0:
                shapes = (states.shape, covs.shape, times.shape)
                raise ValueError(f"last_seen must be finite (states ({n}, 4), covariances ({n}, 4, 4), times ({n},)) "
                                 f"beside 4 x 4 covariances, got shapes {shapes}")  # fmt: skip
        return out[1], out[2], out[3], out[4], out[5], (found, j, ahead)

    def _under_speed_cap(self, u: NDArray[np.float64], v0: float, cap: float | None = None) -> NDArray[np.float64]:
        """``u`` with its accelerations lowered where needed so that the bicycle's speed stays
        within the step's speed rows (``cap``, default ``problem.speed_cap``, widened as the model
        widens them)."""
        m = self.model
        u = np.array(u, dtype=float)  # a fresh C array (the kernel writes it)
        top = self.problem.speed_cap if cap is None else cap
        under_speed_cap(u, float(v0), min(m.speed_max, top), float(m.accel_min), self.config.dt)
        return u

    def _radii(self, n: int, margins: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """Each pedestrian's R plus its uncertainty margin, as the route layers see them."""
        r = self.config.safety_radius
        return np.full(n, r) if margins is None else r + margins

    def _repair(self, x, plan, source, status, fv, viol, broken):
        """A plan that breaks the model's hard state limits (the bicycle's v >= speed_min) by
        ``broken``: the model's repair of it and braking to rest, checked exactly against the CBF
        rows and ranked (plans that still break a limit last, then :func:`rank_key`)."""
        p, dt = self.problem, self.config.dt
        fixed = self.model.repair_plan(x, plan, dt)
        cands = ([("repaired", fixed)] if fixed is not None else []) + [("braking", p.braking_plan())]
        scored = []
        for i, (name, u) in enumerate(cands):
            states = self.model.rollout(x, u, dt)
            sv = self.model.state_limit_violation(states)
            chk = p.evaluate(u)
            scored.append(((sv > STATE_TOL, *rank_key(chk)), i, name, u, chk, states, sv))
        _, _, name, u, chk, states, sv = min(scored, key=lambda r: (r[0], r[1]))
        what = "the shifted previous plan" if source == "previous_plan" else f"the {source} plan"
        done = "repaired (braking stops at rest)" if name == "repaired" else "braking to rest applied"
        note = f"{what} broke the model's state limits (v below its minimum) by {broken:.3g}: {done}"
        if name == "braking":
            source, status = "braking", SolveStatus.FALLBACK
        return u, source, status, chk.first_row, chk.worst, sv, states, note
