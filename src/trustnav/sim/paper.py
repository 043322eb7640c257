"""The paper's three numerical scenarios (Section III), closed loop, single integrator.

Scenario parameters live in TOML files next to this module (``scenarios/paper-*.toml``); this
module only loads them, runs episodes and computes metrics.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import (
    BoundedProportionalReference,
    MpcConfig,
    SingleIntegrator,
    SolveStatus,
    VelocityTrackingCost,
)
from trustnav.control.barrier import TIMINGS
from trustnav.schema import (
    Dotted,
    InFile,
    Integer,
    Number,
    OneOf,
    Pair,
    SchemaError,
    Seq,
    Text,
    check_fields,
    load,
    load_each,
)
from trustnav.sim.engine import SIMULATION_DEADLINE, EpisodeResult, Observation, Sample, make_mpc, run
from trustnav.trust import GammaParams

__all__ = [
    "SCENARIOS",
    "Episode",
    "PaperEnvironment",
    "PaperScenario",
    "Pedestrian",
    "ScenarioResult",
    "episode_metrics",
    "load_scenario",
    "run_episode",
    "run_scenario",
]

SCENARIOS = ("paper-1", "paper-2", "paper-3")


#: The rules of a scenario file's keys (trustnav.schema); numbers are kept as floats.
POSITIVE = Number(lo=0, lo_open=True, cast=True)
XY = Pair()


@dataclass(frozen=True)
class Pedestrian:
    """A pedestrian of a scenario: start position (m), constant velocity (m/s), trust in [0, 1]."""

    position: Annotated[tuple[float, float], XY]
    velocity: Annotated[tuple[float, float], XY] = (0.0, 0.0)
    trust: Annotated[float, Number(0.0, 1.0, cast=True)] = 1.0

    def __post_init__(self) -> None:
        check_fields(self, Dotted("pedestrian"))


@dataclass(frozen=True)
class PaperScenario:
    """One numerical scenario: world, agents, MPC and reference parameters."""

    name: Annotated[str, Text(empty=True)]
    title: Annotated[str, Text(empty=True)]
    ego_start: Annotated[tuple[float, float], XY]
    goal: Annotated[tuple[float, float], XY]
    pedestrians: tuple[Pedestrian, ...]
    horizons: Annotated[tuple[int, ...], Seq(Integer(1), min_len=1)] = (7,)
    trust_sweep: Annotated[tuple[float, ...], Seq(Number(0.0, 1.0, cast=True))] = ()
    control_equal_trust: bool = False
    compare_timings: bool = False
    dt: Annotated[float, POSITIVE] = 0.05
    safety_radius: Annotated[float, POSITIVE] = 3.0
    gamma: GammaParams = field(default_factory=GammaParams)
    timing: Annotated[str, OneOf(*TIMINGS)] = "paper"
    reference_gain: Annotated[float, POSITIVE] = 1.5
    reference_v_max: Annotated[float, POSITIVE] = 10.0
    reference_mode: Annotated[str, OneOf("rollout", "hold")] = "rollout"
    u_max: Annotated[float, POSITIVE] = 20.0
    max_steps: Annotated[int, Integer(1)] = 1000
    goal_tolerance: Annotated[float, POSITIVE] = 0.25
    world_size: Annotated[tuple[float, float], XY] = (50.0, 50.0)
    notes: Annotated[str, Text(empty=True)] = ""

    def __post_init__(self) -> None:
        try:
            check_fields(self)
        except SchemaError as exc:
            raise SchemaError(f"scenario {self.name}: {e}" for e in exc.errors) from None
        if not isinstance(self.pedestrians, tuple) or not self.pedestrians:
            raise ValueError(f"scenario {self.name}: needs at least one pedestrian")
        if not all(isinstance(p, Pedestrian) for p in self.pedestrians):
            raise ValueError(f"scenario {self.name}: pedestrians must be Pedestrian objects")
        if not isinstance(self.gamma, GammaParams):
            raise ValueError(f"scenario {self.name}: gamma must be GammaParams, got {self.gamma!r}")

    def config(self, horizon: int | None = None, timing: str | None = None) -> MpcConfig:
        return MpcConfig(
            horizon=horizon or self.horizons[0],
            dt=self.dt,
            safety_radius=self.safety_radius,
            gamma=self.gamma,
            timing=timing or self.timing,  # type: ignore[arg-type]
            # simulated time is not wall time: a long step deadline keeps an episode a pure
            # function of the scenario, whatever the machine's load
            deadline=SIMULATION_DEADLINE,
            deadlock=None,  # the paper's plain controller: no route layer around wedges
        )

    def cost(self) -> VelocityTrackingCost:
        ref = BoundedProportionalReference(self.reference_gain, self.reference_v_max, self.reference_mode)  # type: ignore[arg-type]
        return VelocityTrackingCost(goal=self.goal, reference=ref)


def _pedestrians(v: Any, place: InFile) -> tuple[Pedestrian, ...]:
    if not isinstance(v, list) or not v:
        raise SchemaError(f"{place.file} needs [[pedestrian]] tables, each with position = [x, y] (and optionally "
                          "velocity, trust)")  # fmt: skip
    return load_each(Pedestrian, v, [InFile(place.file, f"pedestrian {i + 1}") for i in range(len(v))])


def _scenario_from_dict(d: dict[str, Any], source: str) -> PaperScenario:
    """A scenario from its TOML document; every error names ``source`` (the file or preset)."""
    place = InFile(source)
    return load(PaperScenario, d, place, convert={"pedestrians": lambda v, _: _pedestrians(v, place)},
                rename={"pedestrian": "pedestrians"})  # fmt: skip


def load_scenario(name_or_path: str | Path) -> PaperScenario:
    """Load ``paper-1|paper-2|paper-3`` (shipped) or a TOML file of the same form."""
    path = Path(name_or_path)
    if path.suffix == ".toml" and path.is_file():
        text = path.read_text()
    elif str(name_or_path) in SCENARIOS:
        text = resources.files("trustnav.sim").joinpath(f"scenarios/{name_or_path}.toml").read_text()
    else:
        raise ValueError(f"unknown scenario {name_or_path!r}: expected one of {SCENARIOS} or a .toml file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"scenario file {name_or_path}: not valid TOML ({exc})") from None
    return _scenario_from_dict(data, str(name_or_path))


@dataclass
class Episode:
    """A closed-loop run: ego path (T+1, 2), pedestrian paths (T+1, N_p, 2), per-step solver data;
    ``result``: the engine's :class:`~trustnav.sim.engine.EpisodeResult` it was read from."""

    scenario: str
    horizon: int
    trusts: NDArray[np.float64]
    ego: NDArray[np.float64]
    pedestrians: NDArray[np.float64]
    statuses: list[SolveStatus]
    fallbacks: int
    slack_steps: int
    solve_times: NDArray[np.float64]
    reached_goal: bool
    timing: str
    result: EpisodeResult | None = None

    @property
    def distances(self) -> NDArray[np.float64]:
        """Ego-pedestrian distance per step (T+1, N_p)."""
        return np.linalg.norm(self.ego[:, None, :] - self.pedestrians, axis=2)


class PaperEnvironment:
    """A paper scenario as an engine :class:`~trustnav.sim.engine.Environment`: the single integrator
    ego applies each input exactly for ``dt`` (no latency), pedestrians move at constant velocity
    and their trusts are fixed; it ends at the goal (``goal_tolerance``) or after ``max_steps``."""

    name = "paper"
    command_size = 2  # the single integrator's velocity

    def __init__(self, scenario: PaperScenario, trusts: ArrayLike | None = None) -> None:
        self.scenario = scenario
        self.period = scenario.dt
        self.model = SingleIntegrator(u_max=scenario.u_max)
        tr = [p.trust for p in scenario.pedestrians] if trusts is None else trusts
        self.trusts = np.array(tr, dtype=float)
        self.velocities = np.array([p.velocity for p in scenario.pedestrians], dtype=float)
        self.goal = np.array(scenario.goal, dtype=float)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Back to the start (the scenario has no randomness; ``seed`` is ignored)."""
        self.step_index = 0
        self.ego = np.array(self.scenario.ego_start, dtype=float)
        self.positions = np.array([p.position for p in self.scenario.pedestrians], dtype=float)

    @property
    def time(self) -> float:
        return self.step_index * self.period

    def observe(self) -> Observation:
        return Observation(self.time, self.ego.copy(), self.positions.copy(), self.velocities.copy(),
                           self.trusts.copy())  # fmt: skip

    def advance(self, command: ArrayLike, duration: float) -> None:
        self.ego = self.model.step(self.ego, np.asarray(command, dtype=float), duration)
        self.positions = self.positions + self.velocities * duration
        self.step_index += 1

    def done(self) -> str | None:
        if self.step_index > 0 and np.linalg.norm(self.ego - self.goal) <= self.scenario.goal_tolerance:
            return "goal"
        return "max_steps" if self.step_index >= self.scenario.max_steps else None

    def record(self) -> Sample:
        return Sample(self.time, self.ego.copy(), self.positions.copy(), self.trusts.copy())


def run_episode(
    scenario: PaperScenario,
    horizon: int | None = None,
    trusts: list[float] | NDArray[np.float64] | None = None,
    solver: str = "sqp",
    timing: str | None = None,
) -> Episode:
    """Closed loop on the engine: each step solve `proposed`, apply u(t) exactly (no latency), move
    pedestrians (:class:`PaperEnvironment` with the scenario's MPC)."""
    cfg = scenario.config(horizon, timing)
    policy = make_mpc(SingleIntegrator(u_max=scenario.u_max), scenario.cost(), cfg, solver)
    world = PaperEnvironment(scenario, trusts)
    res = run(world, policy)
    return Episode(
        scenario=scenario.name,
        horizon=cfg.horizon,
        trusts=world.trusts,
        ego=res.ego,
        pedestrians=res.pedestrians,
        statuses=[SolveStatus(s) for s in res.statuses],
        fallbacks=res.count("fallback"),
        slack_steps=res.count("relaxed"),
        solve_times=res.solve_times,
        reached_goal=res.reached_goal,
        timing=cfg.timing,
        result=res,
    )


def episode_metrics(ep: Episode, radius: float) -> dict[str, Any]:
    """The keys scripts rely on: min_distance (per pedestrian), steps_to_goal, margin_violations,
    solver_failures; plus slack_steps and timing information."""
    d = ep.distances
    return {
        "min_distance": [float(v) for v in d.min(axis=0)],
        "steps_to_goal": (len(ep.ego) - 1) if ep.reached_goal else None,
        "margin_violations": int(np.sum(np.any(d < radius - 1e-6, axis=1))),
        "solver_failures": int(sum(s is SolveStatus.FAILED for s in ep.statuses)),
        "fallback_steps": int(ep.fallbacks),
        "slack_steps": int(ep.slack_steps),
        "trusts": [float(t) for t in ep.trusts],
        "horizon": ep.horizon,
        "timing": ep.timing,
        "median_solve_ms": float(np.median(ep.solve_times) * 1e3) if ep.solve_times.size else math.nan,
    }


def with_overrides(scenario: PaperScenario, **kw: Any) -> PaperScenario:
    """A copy of the scenario with some fields replaced (for studies and tests)."""
    return replace(scenario, **kw)


@dataclass
class ScenarioResult:
    """Everything a scenario run produced: the metrics document and the episodes to plot."""

    scenario: PaperScenario
    metrics: dict[str, Any]
    episodes: list[Episode]  # main runs, in the order of `runs` (or the single run)
    control: Episode | None = None  # Scenario II equal-trust control
    variant_episodes: dict[str, list[Episode]] = field(default_factory=dict)


def _ordering(ep: Episode) -> dict[str, Any]:
    """Scenario III: share of steps where the distance to the least trusted pedestrian is at least
    the distance to the most trusted one, and the first step where it fails."""
    d = ep.distances
    lo, hi = int(np.argmin(ep.trusts)), int(np.argmax(ep.trusts))
    ok = d[:, lo] >= d[:, hi] - 1e-9
    bad = np.flatnonzero(~ok)
    return {
        "low_trust_farther_share": float(ok.mean()),
        "low_trust_farther_first_failure": int(bad[0]) if bad.size else None,
    }


def run_scenario(scenario: PaperScenario | str, solver: str = "sqp") -> ScenarioResult:
    """Run a paper scenario the way the paper reports it and return metrics + episodes.

    paper-1: one run per value of ``trust_sweep`` (``runs``, each with ``trust``);
    paper-2: the main run plus ``control_equal_trust`` (all trusts 1.0);
    paper-3: one run per horizon (``runs``, each with ``horizon``), and with ``compare_timings``
    the same for both CBF timings under ``timings``.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    r = sc.safety_radius
    head: dict[str, Any] = {"scenario": sc.name, "title": sc.title, "solver": solver, "timing": sc.timing,
                            "reference": {"gain": sc.reference_gain, "v_max": sc.reference_v_max,
                                          "mode": sc.reference_mode}}  # fmt: skip
    if sc.trust_sweep:
        eps = [run_episode(sc, trusts=[t] * len(sc.pedestrians), solver=solver) for t in sc.trust_sweep]
        runs = [{"trust": t, **episode_metrics(ep, r)} for t, ep in zip(sc.trust_sweep, eps, strict=True)]
        return ScenarioResult(sc, {**head, "runs": runs}, eps)
    if len(sc.horizons) > 1:
        timings = ("paper", "authors_code") if sc.compare_timings else (sc.timing,)
        by_timing: dict[str, list[Episode]] = {
            tm: [run_episode(sc, horizon=h, solver=solver, timing=tm) for h in sc.horizons] for tm in timings
        }

        def runs_of(eps: list[Episode]) -> list[dict[str, Any]]:
            return [{"horizon": ep.horizon, **episode_metrics(ep, r), **_ordering(ep)} for ep in eps]

        doc = {**head, "runs": runs_of(by_timing[sc.timing])}
        if sc.compare_timings:
            doc["timings"] = {tm: runs_of(eps) for tm, eps in by_timing.items()}
        return ScenarioResult(sc, doc, by_timing[sc.timing], variant_episodes=by_timing)
    ep = run_episode(sc, solver=solver)
    doc = {**head, **episode_metrics(ep, r)}
    control = None
    if sc.control_equal_trust:
        control = run_episode(sc, trusts=[1.0] * len(sc.pedestrians), solver=solver)
        doc["control_equal_trust"] = episode_metrics(control, r)
    return ScenarioResult(sc, doc, [ep], control=control)
