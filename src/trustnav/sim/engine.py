"""One episode engine: an :class:`Environment` protocol, a :class:`Controller` protocol and one runner.

Every closed-loop episode of trustnav (the paper's scenarios, random worlds, the drive on
trustnav's own world or on CARLA, the Gymnasium environment) is an environment stepped by a
controller through :class:`Rollout`; :func:`run` is the loop. An environment is what the runner
steps: it returns the controller's :class:`Observation` and runs the plant; the drive's is a
physical world (``trustnav.sim.driving.episode.World``: trustnav's own or CARLA) seen through the
car's camera and perception. An environment keeps its own rates: the runner calls ``observe`` once
per control period (``environment.period`` seconds; one with a camera captures a frame there when
one is due), the controller decides, and ``advance(command, period)`` runs the plant (its own
sub-steps, actuation latency, moving pedestrians). ``record()`` is the instant the result keeps,
``done()`` the termination reason.

:class:`EpisodeResult` is the one result type: per instant times, ego states, pedestrian
positions and trusts; per control step the controller's statistics; the termination reason;
:meth:`EpisodeResult.to_record` is the flat record (:data:`RECORD_FIELDS`) every campaign family
shares. Safety is measured on the barrier `h_quad`: ``breach`` when some distance < R.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import MpcConfig, MpcController, MpcSolution, make_solver

__all__ = [
    "RECORD_FIELDS",
    "SIMULATION_DEADLINE",
    "STEP_MS_EDGES",
    "Controller",
    "Decision",
    "Environment",
    "EpisodeResult",
    "FunctionController",
    "MpcPolicy",
    "Observation",
    "Rollout",
    "Sample",
    "StepStats",
    "make_mpc",
    "make_solver",
    "run",
    "step_histogram",
]

#: Controller step deadline (s, wall clock) of simulated episodes: simulated time is not wall time,
#: so a long deadline keeps an episode a pure function of (scenario, parameters, seed).
SIMULATION_DEADLINE = 10.0
#: Edges (ms) of the step-time histogram of a record: 20 log bins per decade, 0.01 ms-100 s.
STEP_MS_EDGES = 10.0 ** np.linspace(-2.0, 5.0, 141)

#: The fields of :meth:`EpisodeResult.to_record`, the same for every kind of episode.
RECORD_FIELDS = (
    "steps",  # control steps run
    "reached_goal",
    "time_to_goal",  # s (simulated), null if not reached
    "min_distance",  # m, closest ego-pedestrian distance over the episode
    "breach",  # min_distance < R: the margin of `h_quad` was violated
    "safety_radius",  # R (m)
    "relaxed_steps",  # steps whose plan used slack on a `cbf_imp` row (no hard-feasible plan found)
    "relaxed_checked",  # relaxed steps re-checked independently
    "relaxed_but_feasible",  # ... of which the independent check found a plan meeting every row
    "fallback_steps",
    "recovered_steps",
    "deadline_steps",
    "failed_steps",  # solver status FAILED
    "horizon",  # N_h
    "n_p",  # pedestrians
    "ped_min_distance",  # per pedestrian (m), null if never known to the controller
    "ped_trust",  # per pedestrian: the trust in force at its closest approach
    "step_ms_median",  # wall-clock time of the controller's step, ms
    "step_ms_p99",
    "step_ms_max",
    "step_ms_hist",  # {bin index: count} on STEP_MS_EDGES
)


@dataclass(frozen=True)
class Observation:
    """The controller's input at ``time``: the ego state and the pedestrians known to it
    (positions and velocities (M, 2), trusts (M,)), as the environment's sensing gives them; with
    estimated states, ``covariances`` (M, 4, 4) of each one's (x, y, v_x, v_y) (None: exact).
    (What perception saw of one track at one instant is a ``trustnav.trust.Sighting``.)"""

    time: float
    ego: NDArray[np.float64]
    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]
    trusts: NDArray[np.float64]
    covariances: NDArray[np.float64] | None = None
    #: with estimated states, each one's (x, y, v_x, v_y) (M, 4) and covariance (M, 4, 4) at the
    #: last frame that observed it, and that frame's time (M,) (None: not known)
    last_seen: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None


@dataclass(frozen=True)
class Sample:
    """One recorded instant: ego state, true pedestrian positions (N, 2; NaN where a pedestrian
    is not in the world yet) and the trusts in force (N,)."""

    time: float
    ego: NDArray[np.float64]
    pedestrians: NDArray[np.float64]
    trusts: NDArray[np.float64]


@dataclass(frozen=True)
class StepStats:
    """How a controller decided one step (all False / NaN for a controller that does not say)."""

    status: str = "none"  # a SolveStatus value for the MPC
    relaxed: bool = False
    fallback: bool = False
    recovered: bool = False
    deadline_hit: bool = False
    solve_time: float = math.nan  # s, as the controller measured it
    plan: NDArray[np.float64] | None = None  # predicted states (N_h + 1, n_x)
    relaxed_feasible: bool | None = None  # independent check of a relaxed step (None: not checked)
    route: str | None = None  # the route layer's note (going around a group, yielding), None: nothing


@dataclass(frozen=True)
class Decision:
    """A controller's command for the next control period and how it was found."""

    control: NDArray[np.float64]
    stats: StepStats = field(default_factory=StepStats)


@runtime_checkable
class Environment(Protocol):
    """What the runner steps: the controller's observations, the plant, the records. ``period``:
    the control period (s); ``name``: a short tag ("paper", "sim", "carla", ...)."""

    name: str
    period: float

    def reset(self, seed: int | None = None) -> None:
        """Back to t = 0; randomness from ``seed`` (None: the environment's own seed)."""
        ...

    def observe(self) -> Observation:
        """What the controller may use now (captures a camera frame where one is due)."""
        ...

    def advance(self, command: ArrayLike, duration: float) -> Any:
        """Apply ``command`` and run the plant ``duration`` seconds."""
        ...

    def done(self) -> str | None:
        """Why the episode ends now ("goal", "time", "max_steps", ...), or None."""
        ...

    def record(self) -> Sample:
        """The current instant."""
        ...


@runtime_checkable
class Controller(Protocol):
    """Anything that maps an observation (the controller's input) to a decision."""

    def step(self, observation: Observation) -> Decision: ...


class FunctionController:
    """A plain function ``f(observation) -> command`` as a :class:`Controller` (no statistics)."""

    def __init__(self, fn: Callable[[Observation], ArrayLike]) -> None:
        self.fn = fn

    def step(self, observation: Observation) -> Decision:
        return Decision(self.fn(observation))  # checked by the runner (Rollout.apply)


class MpcPolicy:
    """:class:`~trustnav.control.MpcController` as a :class:`Controller`.

    ``timed``: pass the observation's time to the controller (it then places the commands still in
    flight under its actuation latency); else the controller is called without a time.
    """

    def __init__(self, controller: MpcController, timed: bool = False) -> None:
        self.controller = controller
        self.timed = timed
        self.last_solution: MpcSolution | None = None

    @property
    def config(self) -> MpcConfig:
        return self.controller.config

    @property
    def horizon(self) -> int:
        return int(self.config.horizon)

    @property
    def safety_radius(self) -> float:
        return float(self.config.safety_radius)

    def step(self, observation: Observation) -> Decision:
        o = observation
        extra: dict[str, object] = {"covariances": o.covariances}
        if o.last_seen is not None:  # a controller that keeps an unseen pedestrian from her last sighting
            extra["last_seen"] = o.last_seen
        when = o.time if self.timed else None
        sol = self.controller.step(o.ego, o.positions, o.velocities, o.trusts, time=when, **extra)
        self.last_solution = sol
        stats = StepStats(
            status=sol.status.value,
            relaxed=bool(sol.slack_used),
            fallback=bool(sol.fallback),
            recovered=bool(sol.recovered),
            deadline_hit=bool(sol.deadline_hit),
            solve_time=float(sol.solve_time),
            plan=sol.predicted_states,
            route=sol.detour,
        )
        return Decision(sol.control, stats)


def make_mpc(
    model: Any, cost: Any, config: MpcConfig, solver: str = "sqp", timed: bool = False, barriers: Any = ()
) -> MpcPolicy:
    """The one place episodes build their MPC: ``config`` (dt, R, deadline, ...) comes from the
    scenario; ``solver`` by name (:func:`trustnav.control.make_solver`); ``barriers``: the
    scenario's own (the road's edges)."""
    return MpcPolicy(MpcController(model, cost, config, make_solver(solver), barriers=barriers), timed=timed)


def step_histogram(ms: ArrayLike) -> dict[str, int]:
    """Sparse histogram of step times (ms) on :data:`STEP_MS_EDGES` (mergeable across records)."""
    idx = np.clip(
        np.searchsorted(STEP_MS_EDGES, np.asarray(ms, dtype=float), side="right") - 1, 0, len(STEP_MS_EDGES) - 2
    )
    vals, counts = np.unique(idx, return_counts=True)
    return {str(int(v)): int(c) for v, c in zip(vals, counts, strict=True)}


def step_time_fields(ms: ArrayLike) -> dict[str, Any]:
    """``step_ms_median``, ``_p99``, ``_max`` and ``_hist`` of step times in ms (None when empty)."""
    ms = np.asarray(ms, dtype=float)
    if ms.size == 0:
        return {"step_ms_median": None, "step_ms_p99": None, "step_ms_max": None, "step_ms_hist": {}}
    return {
        "step_ms_median": float(np.median(ms)),
        "step_ms_p99": float(np.percentile(ms, 99)),
        "step_ms_max": float(ms.max()),
        "step_ms_hist": step_histogram(ms),
    }


@dataclass
class EpisodeResult:
    """One closed-loop episode of the environment named ``environment``. Per instant (T+1):
    ``times``, ``ego``, ``pedestrians`` (T+1, N, 2), ``trusts`` (T+1, N); per control step (T):
    ``stats`` and the step's wall / thread CPU time (s); ``reason`` why it ended; ``outcome``:
    measurements the environment made itself (e.g. the closest approach between control steps),
    which take precedence in :meth:`to_record`."""

    environment: str
    times: NDArray[np.float64]
    ego: NDArray[np.float64]
    pedestrians: NDArray[np.float64]
    trusts: NDArray[np.float64]
    stats: list[StepStats]
    step_wall: NDArray[np.float64]
    step_cpu: NDArray[np.float64]
    reason: str | None
    safety_radius: float | None = None
    horizon: int | None = None
    outcome: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return len(self.stats)

    @property
    def reached_goal(self) -> bool:
        return self.reason == "goal"

    @property
    def distances(self) -> NDArray[np.float64]:
        """Ego-pedestrian distance at each instant (T+1, N); NaN where a pedestrian is absent."""
        return np.linalg.norm(self.ego[:, None, :2] - self.pedestrians, axis=2)

    def count(self, flag: str) -> int:
        """Steps whose :class:`StepStats` ``flag`` is true (relaxed, fallback, recovered, deadline_hit)."""
        return int(sum(bool(getattr(s, flag)) for s in self.stats))

    @property
    def statuses(self) -> list[str]:
        return [s.status for s in self.stats]

    @property
    def solve_times(self) -> NDArray[np.float64]:
        return np.array([s.solve_time for s in self.stats], dtype=float)

    @property
    def plans(self) -> list[NDArray[np.float64] | None]:
        return [s.plan for s in self.stats]

    def ped_min_distance(self) -> list[float | None]:
        """Closest approach per pedestrian: the environment's own measure, else over the instants."""
        if "ped_min_distance" in self.outcome:
            return list(self.outcome["ped_min_distance"])
        d = self.distances
        out: list[float | None] = []
        for j in range(d.shape[1]):
            col = d[:, j][np.isfinite(d[:, j])]
            out.append(float(col.min()) if col.size else None)
        return out

    def ped_trust(self) -> list[float]:
        """Per pedestrian, the trust in force at its closest recorded approach."""
        if "ped_trust" in self.outcome:
            return [float(t) for t in self.outcome["ped_trust"]]
        d = np.where(np.isfinite(self.distances), self.distances, np.inf)
        closest = np.argmin(d, axis=0) if len(d) else np.zeros(0, dtype=int)
        return [float(self.trusts[closest[j], j]) for j in range(d.shape[1])]

    def metrics(self) -> dict[str, Any]:
        """The flat record (:meth:`to_record`)."""
        return self.to_record()

    def to_record(self) -> dict[str, Any]:
        """The fields of :data:`RECORD_FIELDS` (one shape for every kind of episode)."""
        mins = self.ped_min_distance()
        known = [m for m in mins if m is not None]
        min_d = float(min(known)) if known else math.inf
        r = self.safety_radius
        reached = self.reached_goal
        ttg = self.outcome.get("time_to_goal", float(self.times[-1] - self.times[0]) if reached else None)
        checked = [s.relaxed_feasible for s in self.stats if s.relaxed_feasible is not None]
        return {
            "steps": self.steps,
            "reached_goal": reached,
            "time_to_goal": ttg if reached else None,
            "min_distance": min_d,
            "breach": bool(r is not None and min_d < r - 1e-6),
            "safety_radius": r,
            "relaxed_steps": self.count("relaxed"),
            "relaxed_checked": len(checked),
            "relaxed_but_feasible": int(sum(checked)),
            "fallback_steps": self.count("fallback"),
            "recovered_steps": self.count("recovered"),
            "deadline_steps": self.count("deadline_hit"),
            "failed_steps": int(sum(s.status == "failed" for s in self.stats)),
            "horizon": self.horizon,
            "n_p": int(self.pedestrians.shape[1]),
            "ped_min_distance": mins,
            "ped_trust": self.ped_trust(),
            **step_time_fields(self.step_wall * 1e3),
        }


class Rollout:
    """An episode in progress on ``environment``: the runner's bookkeeping, also driven step by step
    from outside (the Gymnasium environment). ``horizon`` and ``safety_radius`` label the result."""

    def __init__(
        self, environment: Environment, horizon: int | None = None, safety_radius: float | None = None
    ) -> None:
        self.environment = environment
        self.horizon = horizon
        self.safety_radius = safety_radius
        self.samples: list[Sample] = [environment.record()]
        self.stats: list[StepStats] = []
        self.wall: list[float] = []
        self.cpu: list[float] = []

    def observe(self) -> Observation:
        return self.environment.observe()

    def apply(self, decision: Decision, wall: float = math.nan, cpu: float = math.nan) -> None:
        """Run the environment one control period under ``decision`` and record the new instant (a
        command that is not a finite 1-D vector of the environment's input size is refused by name)."""
        command = self._checked(decision.control)
        self.stats.append(decision.stats)
        self.wall.append(wall)
        self.cpu.append(cpu)
        self.environment.advance(command, self.environment.period)
        self.samples.append(self.environment.record())

    def _checked(self, control: Any) -> NDArray[np.float64]:
        size = getattr(self.environment, "command_size", None)
        if size is None and self.stats:  # the environment does not say: the first command's size holds
            size = self._size
        try:
            command = np.asarray(control, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"controller command must be a vector of numbers, got {control!r}") from exc
        if command.ndim != 1 or command.size == 0 or (size is not None and command.size != size):
            want = f"{size} numbers" if size is not None else "a non-empty 1-D vector"
            name = self.environment.name
            raise ValueError(f"controller command must be {want} for environment {name!r}, got {control!r}")
        if not np.isfinite(command).all():
            raise ValueError(f"controller command must be finite, got {command.tolist()!r} at step {len(self.stats)}")
        self._size = command.size
        return command

    def done(self) -> str | None:
        return self.environment.done()

    def result(self, reason: str | None = None) -> EpisodeResult:
        s = self.samples
        outcome = getattr(self.environment, "outcome", None)
        return EpisodeResult(
            environment=self.environment.name,
            times=np.array([x.time for x in s], dtype=float),
            ego=np.array([x.ego for x in s], dtype=float),
            pedestrians=np.array([x.pedestrians for x in s], dtype=float),
            trusts=np.array([x.trusts for x in s], dtype=float),
            stats=list(self.stats),
            step_wall=np.array(self.wall, dtype=float),
            step_cpu=np.array(self.cpu, dtype=float),
            reason=reason if reason is not None else self.done(),
            safety_radius=self.safety_radius,
            horizon=self.horizon,
            outcome=dict(outcome()) if callable(outcome) else {},
        )


def run(
    environment: Environment,
    controller: Controller,
    *,
    seed: int | None = None,
    max_steps: int | None = None,
    on_step: Callable[[int, Observation, Decision], None] | None = None,
) -> EpisodeResult:
    """Step ``environment`` with ``controller`` until ``environment.done()`` (or ``max_steps``): per
    control period observe, decide (timed: wall clock and thread CPU), advance, record.

    ``seed``: reset the environment with it first (None: run it as it is). ``on_step(k,
    observation, decision)`` is called after step k has advanced the environment.
    """
    if seed is not None:
        environment.reset(seed)
    ro = Rollout(environment, getattr(controller, "horizon", None), getattr(controller, "safety_radius", None))
    reason = ro.done()
    while reason is None:
        if max_steps is not None and len(ro.stats) >= max_steps:
            reason = "max_steps"
            break
        obs = ro.observe()
        t0, c0 = _time.perf_counter(), _time.thread_time()
        decision = controller.step(obs)
        wall, cpu = _time.perf_counter() - t0, _time.thread_time() - c0
        ro.apply(decision, wall, cpu)
        if on_step is not None:
            on_step(len(ro.stats) - 1, obs, decision)
        reason = ro.done()
    return ro.result(reason)
