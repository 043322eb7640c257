"""One episode runner for every family: (family, parameters, seed) -> record.

Each family calls the same code as the command line (no copies), and every episode runs on the one
episode engine (:mod:`trustnav.sim.engine`): ``paper`` runs :func:`trustnav.sim.paper.run_episode`
on a shipped scenario with overrides; ``random_si`` and ``random_bicycle`` sample
:func:`trustnav.sim.random_worlds.sample_world` and run :func:`~trustnav.sim.random_worlds.run_world`
(the reliability study's generator and record); ``drive`` runs :func:`trustnav.sim.driving.run_drive`
with ``keypoints`` sensing.

Every episode is a pure function of (family, parameters, seed): the controller's wall-clock step
deadline is set long (``deadline``, default :data:`~trustnav.sim.engine.SIMULATION_DEADLINE`) so that
the machine's speed cannot change a plan; the wall step time is measured and reported separately
(``step_ms_*``, the controller's step on the engine's clock for every family).

The record (one JSON line) has the campaign fields ``key sweep point point_id family params seed
status error traceback wall_s cpu_s`` (wall and process CPU time of the episode) and the outcome
fields of :data:`OUTCOME_FIELDS`: the engine's :meth:`~trustnav.sim.engine.EpisodeResult.to_record`,
one shape for every family; plus the family's own metrics: the random families keep every field of
``run_world``'s record; ``paper`` and ``drive`` keep their ``metrics.json`` entries under ``extra``.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from trustnav.campaigns.spec import EpisodeTask
from trustnav.control import MpcConfig
from trustnav.sim.engine import RECORD_FIELDS, SIMULATION_DEADLINE, STEP_MS_EDGES, step_histogram
from trustnav.sim.paper import PaperScenario, episode_metrics, load_scenario, run_episode, with_overrides

__all__ = ["DEFAULT_DEADLINE", "OUTCOME_FIELDS", "STEP_MS_EDGES", "run_batch", "run_episode_task", "step_histogram"]

#: Controller step deadline (s, wall clock) of campaign episodes unless a spec sets ``deadline``.
DEFAULT_DEADLINE = SIMULATION_DEADLINE
#: The outcome fields of every record: the engine's one record shape.
OUTCOME_FIELDS = RECORD_FIELDS


def _gamma(base: Any, p: Mapping[str, Any]) -> Any:
    """gamma(trust) of `weight` with the swept gamma_ini / delta / lam (validated by GammaParams)."""
    from trustnav.trust import GammaParams

    kw = {k: p[k] for k in ("gamma_ini", "delta", "lam") if k in p}
    return GammaParams(**{**base.__dict__, **kw}) if kw else base


# ---------------------------------------------------------------------------------------------- random worlds


def _random(task: EpisodeTask) -> dict[str, Any]:
    from trustnav.sim.random_worlds import RandomWorldSpec, run_world, sample_world

    p = task.params
    family = "single_integrator" if task.family == "random_si" else "bicycle"
    dist = {k: p[k] for k in ("max_pedestrians", "close_start_share", "max_steps") if k in p}
    world = sample_world(RandomWorldSpec(family=family, **dist), task.seed)
    cfg = replace(
        world.config,
        horizon=p.get("horizon", world.config.horizon),
        timing=p.get("timing", world.config.timing),
        gamma=_gamma(world.config.gamma, p),
        deadline=p.get("deadline", DEFAULT_DEADLINE),
    )
    trusts = world.trusts
    if "trust" in p:
        trusts = np.full_like(trusts, p["trust"])
    elif "trust_range" in p:
        lo, hi = p["trust_range"]
        trusts = lo + (hi - lo) * trusts  # the sampled trusts are uniform in [0, 1]
    world = replace(world, config=cfg, trusts=trusts, v_max=float(p.get("v_max", world.v_max)))
    return run_world(world, check_relaxed=task.record.check_relaxed, keep_step_times=task.record.step_times)


# ---------------------------------------------------------------------------------------------- paper scenarios


@dataclass(frozen=True)
class _DeadlineScenario(PaperScenario):
    """A paper scenario whose controller has the given step deadline (s; None: dt/2 wall clock)."""

    deadline: float | None = DEFAULT_DEADLINE

    def config(self, horizon: int | None = None, timing: str | None = None) -> MpcConfig:
        return replace(super().config(horizon, timing), deadline=self.deadline)


def _paper(task: EpisodeTask) -> dict[str, Any]:
    p = task.params
    sc = load_scenario(p["scenario"])
    kw: dict[str, Any] = {"gamma": _gamma(sc.gamma, p)}
    for k in ("reference_v_max", "reference_gain"):
        if k in p:
            kw[k] = p[k]
    if p.get("position_jitter", 0.0) > 0:
        rng = np.random.default_rng(task.seed)
        kw["pedestrians"] = tuple(
            replace(q, position=tuple(float(c) for c in np.add(q.position, rng.normal(0.0, p["position_jitter"], 2))))
            for q in sc.pedestrians
        )
    sc = with_overrides(sc, **kw)
    sc = _DeadlineScenario(
        **{f.name: getattr(sc, f.name) for f in fields(sc)}, deadline=p.get("deadline", DEFAULT_DEADLINE)
    )
    n = len(sc.pedestrians)
    if "trusts" in p:
        if len(p["trusts"]) != n:
            raise ValueError(f"trusts: scenario {sc.name} has {n} pedestrians, got {len(p['trusts'])} trusts")
        trusts = list(p["trusts"])
    elif "trust" in p:
        trusts = [p["trust"]] * n
    else:
        trusts = [q.trust for q in sc.pedestrians]
    ep = run_episode(sc, horizon=p.get("horizon"), trusts=trusts, solver=p.get("solver", "sqp"), timing=p.get("timing"))
    assert ep.result is not None
    m = episode_metrics(ep, sc.safety_radius)
    return {**ep.result.to_record(), "extra": {k: v for k, v in m.items() if k != "median_solve_ms"}}


# ---------------------------------------------------------------------------------------------- driving world


def _drive(task: EpisodeTask) -> dict[str, Any]:
    from trustnav.sim.driving import drive_metrics, load_drive_scenario, run_drive

    p = task.params
    sc = load_drive_scenario(p["scenario"])
    ctl = {k: p[k] for k in ("horizon", "safety_radius", "deadline", "confidence") if k in p}
    sens_keys = (
        "pixel_noise",
        "dropout",
        "miss_rate",
        "position_noise",
        "velocity_noise",
        "pitch_sigma_deg",
        "perception_latency",
    )
    sens = {k: p[k] for k in sens_keys if k in p}
    sc = replace(
        sc,
        control=replace(sc.control, gamma=_gamma(sc.control.gamma, p), **ctl),
        sensing=replace(sc.sensing, **sens),
    )
    r = run_drive(
        sc,
        sensing="keypoints",
        seed=task.seed,
        attentive=p.get("attentive"),
        capture_rate=p.get("capture_rate"),
        control_rate=p.get("control_rate"),
        state=p.get("state", "perceived"),
    )
    assert r.episode is not None
    m = drive_metrics(r)
    extra = {k: v for k, v in m.items() if k not in ("per_frame", "solve_ms_median", "solve_ms_p95")}
    return {**r.episode.to_record(), "extra": extra}


_RUNNERS = {"paper": _paper, "random_si": _random, "random_bicycle": _random, "drive": _drive}


def _clean(v: Any) -> Any:
    """JSON-safe: non-finite floats -> null, numpy scalars and arrays -> Python."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return [_clean(x) for x in v.tolist()]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def record_head(task: EpisodeTask) -> dict[str, Any]:
    """The fields every record of ``task`` starts with (what identifies the episode)."""
    return {
        "key": task.key,
        "sweep": task.sweep,
        "point": task.point,
        "point_id": task.point_id,
        "family": task.family,
        "params": dict(task.params),
        "seed": task.seed,
    }


def run_episode_task(task: EpisodeTask) -> dict[str, Any]:
    """Run one episode; never raises: an error becomes a record with ``status: failed``."""
    head = record_head(task)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        body = _RUNNERS[task.family](task)
        status, error, tb = "ok", None, None
    except Exception as exc:  # an episode's failure is data, never the campaign's end
        body = {}
        status, error = "failed", f"{type(exc).__name__}: {exc}"
        tb = traceback.format_exc()[-4000:]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rec = {**head, "status": status, "error": error, "traceback": tb, "wall_s": wall, "cpu_s": cpu}
    rec.update({k: body.get(k) for k in OUTCOME_FIELDS})
    rec.update({k: v for k, v in body.items() if k not in rec})
    return _clean(rec)


def run_batch(tasks: Sequence[EpisodeTask]) -> list[dict[str, Any]]:
    """A Dask task: the episodes of one batch, in order."""
    return [run_episode_task(t) for t in tasks]
