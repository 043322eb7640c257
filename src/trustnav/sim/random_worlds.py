"""Random closed-loop worlds for reliability studies of the controller (seeded, documented).

Two families, each a pure function of (spec, seed):

* single integrator (Section III's model): ego from the origin toward a goal 30-45 m away in a
  random direction; 1-10 pedestrians near the straight path (static, wandering, crossing the
  path, or walking toward the ego); in half of the episodes 1-3 more pedestrians stand at R + 0.1
  within 45 deg ahead of the ego at t = 0 (the hard case: rows bind from the first step). Trusts
  uniform in [0, 1]; N_h, the reference bound and the trust preset drawn from the spec's lists.
* kinematic bicycle (Section IV's model): a straight road (0, 0) -> (100, 0), initial speed
  4-10 m/s, 1-6 pedestrians near the lane (static on the kerb, on the lane edge, or crossing),
  and in a third of the episodes a pedestrian that steps onto the lane ahead part-way through.

:class:`RandomEnvironment` is a sampled world on the episode engine (:mod:`trustnav.sim.engine`);
:func:`run_world` runs one episode with the world's MPC and returns a record;
:func:`hard_feasible_exists` is the independent check used for relaxed steps.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize

from trustnav.control import (
    BoundedProportionalReference,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcProblem,
    SingleIntegrator,
    VelocityTrackingCost,
)
from trustnav.sim.engine import Decision, EpisodeResult, MpcPolicy, Observation, Sample, make_mpc, run
from trustnav.trust import PAPER_GAMMA_CARLA, PAPER_GAMMA_NUMERICAL

__all__ = [
    "RandomEnvironment",
    "RandomWorld",
    "RandomWorldSpec",
    "hard_feasible_exists",
    "run_world",
    "run_world_result",
    "sample_world",
    "world_record",
]

Family = Literal["single_integrator", "bicycle"]


@dataclass(frozen=True)
class RandomWorldSpec:
    """Distribution of random worlds (see the module docstring)."""

    family: Family = "single_integrator"
    horizons: tuple[int, ...] = (4, 7, 15)
    v_max: tuple[float, ...] = (10.0, 18.0)
    max_pedestrians: int = 10
    close_start_share: float = 0.5  # share of episodes with pedestrians at R + 0.1 ahead at t = 0
    max_steps: int = 600

    def __post_init__(self) -> None:
        if self.family not in ("single_integrator", "bicycle"):
            raise ValueError(f"family must be 'single_integrator' or 'bicycle', got {self.family!r}")
        if not self.horizons or any(not isinstance(h, int) or h < 1 for h in self.horizons):
            raise ValueError(f"horizons must be integers >= 1, got {self.horizons!r}")
        if not self.v_max or any(not v > 0 for v in self.v_max):
            raise ValueError(f"v_max must be positive speeds, got {self.v_max!r}")
        if not isinstance(self.max_pedestrians, int) or self.max_pedestrians < 1:
            raise ValueError(f"max_pedestrians must be an integer >= 1, got {self.max_pedestrians!r}")
        if not 0 <= self.close_start_share <= 1:
            raise ValueError(f"close_start_share must lie in [0, 1], got {self.close_start_share!r}")
        if not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise ValueError(f"max_steps must be an integer >= 1, got {self.max_steps!r}")


@dataclass(frozen=True)
class RandomWorld:
    """One sampled world: ego start, goal, pedestrians (with an appearance step each), trusts."""

    family: Family
    seed: int
    config: MpcConfig
    start: NDArray[np.float64]  # ego state
    goal: NDArray[np.float64]
    pedestrians: NDArray[np.float64]  # (N, 2) initial positions
    velocities: NDArray[np.float64]  # (N, 2)
    trusts: NDArray[np.float64]  # (N,)
    appear: NDArray[np.int64]  # (N,) step at which each pedestrian is first known to the controller
    v_max: float
    kinds: tuple[str, ...] = field(default=())
    max_steps: int = 600


def _si_world(spec: RandomWorldSpec, seed: int, rng: np.random.Generator) -> RandomWorld:
    n_h = int(rng.choice(spec.horizons))
    v_max = float(rng.choice(spec.v_max))
    cfg = MpcConfig(horizon=n_h, dt=0.05, safety_radius=3.0, gamma=PAPER_GAMMA_NUMERICAL)
    r = cfg.safety_radius
    heading = rng.uniform(-math.pi, math.pi)
    axis = np.array([math.cos(heading), math.sin(heading)])
    normal = np.array([-axis[1], axis[0]])
    length = rng.uniform(30.0, 45.0)
    goal = axis * length
    peds, vels, kinds = [], [], []
    for _ in range(int(rng.integers(1, spec.max_pedestrians + 1))):
        for _try in range(50):
            s = rng.uniform(0.15, 0.9) * length
            off = rng.normal(0.0, 4.0)
            p = axis * s + normal * off
            if np.linalg.norm(p) > r + 0.5 and np.linalg.norm(p - goal) > r + 0.5:
                break
        kind = str(rng.choice(["static", "wander", "crossing", "toward"], p=[0.4, 0.2, 0.25, 0.15]))
        speed = rng.uniform(0.5, 2.0)
        if kind == "static":
            v = np.zeros(2)
        elif kind == "wander":
            a = rng.uniform(-math.pi, math.pi)
            v = speed * np.array([math.cos(a), math.sin(a)])
        elif kind == "crossing":
            v = -np.sign(off or 1.0) * speed * normal
        else:
            v = -speed * axis
        peds.append(p)
        vels.append(v)
        kinds.append(kind)
    if rng.uniform() < spec.close_start_share:
        for _ in range(int(rng.integers(1, 4))):
            a = heading + rng.uniform(-math.pi / 4, math.pi / 4)
            peds.append((r + 0.1) * np.array([math.cos(a), math.sin(a)]))
            vels.append(np.zeros(2))
            kinds.append("close")
    n = len(peds)
    return RandomWorld(
        family="single_integrator", seed=seed, config=cfg, start=np.zeros(2), goal=goal,
        pedestrians=np.array(peds), velocities=np.array(vels), trusts=rng.uniform(0, 1, n),
        appear=np.zeros(n, dtype=np.int64), v_max=v_max, kinds=tuple(kinds), max_steps=spec.max_steps,
    )  # fmt: skip


def _bicycle_world(spec: RandomWorldSpec, seed: int, rng: np.random.Generator) -> RandomWorld:
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA, latency=0.1)
    v0 = rng.uniform(4.0, 10.0)
    peds, vels, kinds, appear = [], [], [], []
    for _ in range(int(rng.integers(1, min(6, spec.max_pedestrians) + 1))):
        kind = str(rng.choice(["kerb", "edge", "crossing"], p=[0.5, 0.25, 0.25]))
        x = rng.uniform(15.0, 85.0)
        side = rng.choice([-1.0, 1.0])
        if kind == "kerb":
            p, v = np.array([x, side * rng.uniform(3.5, 6.0)]), np.zeros(2)
        elif kind == "edge":
            p, v = np.array([x, side * rng.uniform(2.0, 3.5)]), np.zeros(2)
        else:
            p, v = np.array([x, side * rng.uniform(4.0, 7.0)]), np.array([0.0, -side * rng.uniform(0.5, 1.5)])
        peds.append(p)
        vels.append(v)
        kinds.append(kind)
        appear.append(0)
    if rng.uniform() < 1 / 3:  # a pedestrian steps out ahead part-way through (may be unavoidable)
        step = int(rng.integers(10, 60))
        peds.append(np.array([np.nan, rng.uniform(-1.5, 1.5)]))  # x set at appearance: ahead of the car
        vels.append(np.zeros(2))
        kinds.append(f"sudden@{rng.uniform(4.0, 15.0):.2f}")
        appear.append(step)
    n = len(peds)
    return RandomWorld(
        family="bicycle", seed=seed, config=cfg, start=np.array([0.0, 0.0, 0.0, v0]), goal=np.array([100.0, 0.0]),
        pedestrians=np.array(peds), velocities=np.array(vels), trusts=rng.uniform(0, 1, n),
        appear=np.array(appear, dtype=np.int64), v_max=8.0, kinds=tuple(kinds), max_steps=min(spec.max_steps, 400),
    )  # fmt: skip


def sample_world(spec: RandomWorldSpec, seed: int) -> RandomWorld:
    """The world of ``seed`` under ``spec`` (same seed, same world)."""
    rng = np.random.default_rng(seed)
    return _si_world(spec, seed, rng) if spec.family == "single_integrator" else _bicycle_world(spec, seed, rng)


def _model(world: RandomWorld) -> Any:
    return SingleIntegrator() if world.family == "single_integrator" else KinematicBicycle()


def _policy(world: RandomWorld) -> MpcPolicy:
    """The world's MPC (its ``config``: N_h, dt, R, gamma, latency, deadline)."""
    if world.family == "single_integrator":
        cost = VelocityTrackingCost(goal=tuple(world.goal), reference=BoundedProportionalReference(1.5, world.v_max))
    else:
        cost = LaneTrackingCost(start=(0.0, 0.0), goal=tuple(world.goal),
                                reference=BoundedProportionalReference(0.5, world.v_max))  # fmt: skip
    return make_mpc(_model(world), cost, world.config)


def hard_feasible_exists(problem: MpcProblem, plans: list[NDArray[np.float64]], seed: int = 0) -> bool:
    """Independent check: does a plan meet every hard row of the problem's current stage?

    Multi-start scipy SLSQP on the plain numpy constraints (finite differences; none of the SQP
    code path): minimise the distance to each start subject to all rows, from the given plans,
    braking, and two random starts. True as soon as one result meets every row within 1e-6.
    """
    rng = np.random.default_rng(seed)
    lo, hi = problem.lo, problem.hi
    starts = [np.asarray(u, dtype=float).ravel() for u in plans]
    starts += [problem.braking_plan().ravel()]
    starts += [rng.uniform(lo, hi) for _ in range(2)]
    bounds = list(zip(lo, hi, strict=True))
    rows = problem.decision_rows_np
    cons = [{"type": "ineq", "fun": rows}]
    for x0 in starts:
        x0 = np.clip(x0, lo, hi)
        if rows(x0).min() >= -1e-6:
            return True
        res = minimize(lambda u, a=x0: float(np.sum((u - a) ** 2)), x0, method="SLSQP", bounds=bounds,
                       constraints=cons, options={"maxiter": 60, "ftol": 1e-9})  # fmt: skip
        if np.all(np.isfinite(res.x)) and rows(res.x).min() >= -1e-6:
            return True
    return False


#: Plant integration step of the bicycle (s): 10 x finer than the controller's sub-steps, so the
#: plant is the continuous car to within a millimetre per control period, not the controller's model.
PLANT_STEP = 0.001


def _plant(
    model: Any, x: NDArray[np.float64], applied: NDArray[np.float64], new: NDArray[np.float64], cfg: MpcConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """One control period of the plant: the input being executed for the first ``latency``
    seconds (actuation delay, at most one period), then the new one. The single integrator is
    exact in one step per input; the bicycle is integrated in :data:`PLANT_STEP` steps. Returns
    the state at the end of the period and the ego positions along it (times ``path_times``)."""
    lat = min(cfg.latency, cfg.dt)
    if isinstance(model, SingleIntegrator):
        times = [0.0, lat, cfg.dt] if 0 < lat < cfg.dt else [0.0, cfg.dt]
        pts = [x[:2].copy()]
        for t_a, t_b in itertools.pairwise(times):
            x = model.step(x, applied if t_a < lat - 1e-12 else new, t_b - t_a)
            pts.append(x[:2].copy())
        return x, np.array(pts), np.array(times)
    n = max(1, round(cfg.dt / PLANT_STEP))
    h = cfg.dt / n
    pts = np.empty((n + 1, 2))
    pts[0] = x[:2]
    for i in range(n):
        x = model.step(x, applied if i * h < lat - 1e-12 else new, h)
        pts[i + 1] = x[:2]
    return x, pts, np.linspace(0.0, cfg.dt, n + 1)


def _path_min_distance(
    path: NDArray[np.float64], times: NDArray[np.float64], peds: NDArray[np.float64], vels: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Closest approach of the ego path (piecewise linear through ``path`` at ``times``) to each
    constant-velocity pedestrian starting at ``peds``: the distance between samples, exact for the
    single integrator and to within the plant step for the bicycle."""
    q = peds[None, :, :] + times[:, None, None] * vels[None, :, :]  # (T, N, 2)
    d = path[:, None, :] - q  # relative position at each time
    a, b = d[:-1], d[1:]
    e = b - a
    den = np.sum(e * e, axis=2)
    s = np.clip(-np.sum(a * e, axis=2) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    closest = np.linalg.norm(a + s[:, :, None] * e, axis=2)
    return closest.min(axis=0)


class RandomEnvironment:
    """A :class:`RandomWorld` as an engine :class:`~trustnav.sim.engine.Environment`.

    Pedestrians move at constant velocity; a pedestrian is given to the controller from its
    appearance step on (a 'sudden' one appears at the distance in its kind ahead of the car). The
    plant (:func:`_plant`) executes the previous input for the first ``latency`` seconds of each
    period. Besides the instants it measures the closest approaches the record needs: at the
    control steps (each pedestrian over the steps it is known) and along the plant's path between
    them (``min_distance_continuous``).
    """

    def __init__(self, world: RandomWorld) -> None:
        self.spec = world
        self.name = f"random_{world.family}"
        self.period = world.config.dt
        self.model = _model(world)
        self.command_size = self.model.nu
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Back to the start (the world was sampled from its seed; ``seed`` is ignored)."""
        w = self.spec
        self.step_index = 0
        self.ego = w.start.astype(float).copy()
        self.positions = w.pedestrians.copy()
        self.applied = np.zeros(self.model.nu)  # the input being executed when a new one is issued
        self.min_continuous = math.inf
        self.ped_min = np.full(len(w.pedestrians), math.inf)  # per pedestrian, over the steps it is known

    def known(self) -> NDArray[np.bool_]:
        return self.spec.appear <= self.step_index

    def observe(self) -> Observation:
        k = self.known()
        w = self.spec
        return Observation(self.step_index * self.period, self.ego.copy(), self.positions[k],
                           w.velocities[k], w.trusts[k])  # fmt: skip

    def advance(self, command: ArrayLike, duration: float) -> None:
        w, cfg = self.spec, self.spec.config
        if abs(duration - cfg.dt) > 1e-12:
            raise ValueError(f"a random world advances by its control period {cfg.dt}, got {duration}")
        known = self.known()
        u = np.asarray(command, dtype=float)
        self.ego, path, path_t = _plant(self.model, self.ego, self.applied, u, cfg)
        self.applied = u
        if known.any():
            d_path = _path_min_distance(path, path_t, self.positions[known], w.velocities[known])
            self.min_continuous = min(self.min_continuous, float(d_path.min()))
        self.positions = self.positions + w.velocities * cfg.dt
        if known.any():
            d = np.linalg.norm(self.positions[known] - self.ego[:2], axis=1)
            self.ped_min[known] = np.minimum(self.ped_min[known], d)
        self.step_index += 1
        for j in np.flatnonzero(w.appear == self.step_index):
            if w.kinds[j].startswith("sudden@"):
                self.positions[j, 0] = self.ego[0] + float(w.kinds[j].split("@")[1])

    def done(self) -> str | None:
        tol = 0.25 if self.spec.family == "single_integrator" else 1.0
        if self.step_index > 0 and np.linalg.norm(self.ego[:2] - self.spec.goal) <= tol:
            return "goal"
        return "max_steps" if self.step_index >= self.spec.max_steps else None

    def record(self) -> Sample:
        return Sample(self.step_index * self.period, self.ego.copy(), self.positions.copy(), self.spec.trusts.copy())

    def outcome(self) -> dict[str, Any]:
        return {
            "ped_min_distance": [float(v) if math.isfinite(v) else None for v in self.ped_min],
            "ped_trust": [float(v) for v in self.spec.trusts],
            "min_distance_continuous": self.min_continuous,
        }


def run_world_result(world: RandomWorld, check_relaxed: bool = False) -> EpisodeResult:
    """The episode of ``world`` on the engine; with ``check_relaxed`` every step whose plan
    violates a CBF row is re-checked with :func:`hard_feasible_exists` on the same stage."""
    policy = _policy(world)
    checks: dict[int, bool] = {}

    def check(k: int, _obs: Observation, decision: Decision) -> None:
        if check_relaxed and decision.stats.relaxed and policy.last_solution is not None:
            checks[k] = hard_feasible_exists(policy.controller.problem, [policy.last_solution.inputs],
                                             seed=world.seed * 1000 + k)  # fmt: skip

    res = run(RandomEnvironment(world), policy, on_step=check)
    res.stats = [replace(s, relaxed_feasible=checks.get(k)) for k, s in enumerate(res.stats)]
    return res


def run_world(world: RandomWorld, check_relaxed: bool = False, keep_step_times: bool = False) -> dict[str, Any]:
    """Closed loop on one world (:class:`RandomEnvironment` on the engine); the record a
    reliability study needs: the engine's record (:meth:`~trustnav.sim.engine.EpisodeResult.to_record`)
    and the world's own fields.

    With ``check_relaxed`` every relaxed step is re-checked with :func:`hard_feasible_exists`.
    ``ped_min_distance`` / ``ped_trust``: each pedestrian's closest approach (None if never known
    to the controller) and trust. ``min_distance`` / ``breach`` are taken at the control steps,
    where the discrete-time CBF (`cbf_discrete`) guarantees h >= 0; ``min_distance_continuous`` /
    ``breach_continuous`` along the plant's path between them.
    """
    res = run_world_result(world, check_relaxed)
    return world_record(world, res, keep_step_times)


def world_record(world: RandomWorld, res: EpisodeResult, keep_step_times: bool = False) -> dict[str, Any]:
    """The reliability record of a random world's episode (see :func:`run_world`)."""
    r = world.config.safety_radius
    st = res.step_wall * 1e3  # wall clock (what a real-time loop sees, preemption included)
    ct = res.step_cpu * 1e3  # CPU time of the stepping thread
    statuses: dict[str, int] = {}
    for s in res.statuses:
        statuses[s] = statuses.get(s, 0) + 1
    min_cont = float(res.outcome["min_distance_continuous"])
    return {
        "family": world.family,
        "seed": world.seed,
        "kinds": list(world.kinds),
        "v_max": world.v_max,
        **res.to_record(),
        "min_distance_continuous": min_cont,
        "breach_continuous": bool(min_cont < r - 1e-6),
        "statuses": statuses,
        "step_ms": st.tolist() if keep_step_times else None,
        "step_ms_sum": float(st.sum()),
        "step_cpu_ms": ct.tolist() if keep_step_times else None,
        "step_cpu_ms_max": float(ct.max()),
        "final_speed": float(res.ego[-1, 3]) if world.family == "bicycle" else None,
        "stopped_for_good": _stopped_for_good(world, res),
    }


def _stopped_for_good(world: RandomWorld, res: EpisodeResult, window_s: float = 2.0) -> bool:
    """The episode ended short of the goal with the vehicle standing still (moved < 5 cm over the
    last ``window_s``): wedged, not merely slow."""
    if bool(res.to_record().get("reached_goal")):
        return False
    k = max(1, round(window_s / world.config.dt))
    if len(res.ego) <= k:
        return False
    return bool(np.hypot(*(res.ego[-1, :2] - res.ego[-1 - k, :2])) < 0.05)
