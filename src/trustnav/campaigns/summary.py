"""Safety statistics of a campaign: per sweep point, per sweep, per horizon; JSON and Markdown.

Rates are shares of episodes that ran (``status: ok``) with Wilson 95 % intervals; a breach is an
episode whose closest approach is below R (the margin of `h_quad`); an infeasible (relaxed) step
is one whose plan needed slack on a `cbf_imp` row. Minimum distances are split by the trust
(`agg_trust`) of the pedestrian they belong to: low [0, 1/3), mid [1/3, 2/3), high [2/3, 1].
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from trustnav.campaigns.episodes import STEP_MS_EDGES
from trustnav.campaigns.spec import CampaignSpec

__all__ = ["TRUST_BANDS", "markdown_table", "summarise", "summarise_records", "wilson", "write_summary"]

TRUST_BANDS = (("low", 0.0, 1.0 / 3.0), ("mid", 1.0 / 3.0, 2.0 / 3.0), ("high", 2.0 / 3.0, 1.0 + 1e-9))


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float] | None:
    """Wilson score interval of a binomial share k / n (None when n = 0)."""
    if n <= 0:
        return None
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def _q(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def _hist_quantile(counts: np.ndarray, q: float) -> float | None:
    """Upper edge (ms) of the histogram bin holding quantile q (conservative)."""
    total = counts.sum()
    if total == 0:
        return None
    i = int(np.searchsorted(np.cumsum(counts), q * total))
    return float(STEP_MS_EDGES[min(i + 1, len(STEP_MS_EDGES) - 1)])


def _tail(hist: np.ndarray, top: float | None) -> dict[str, float | None]:
    """Step-time median and tail from the merged histogram (never above the exact max)."""
    out: dict[str, float | None] = {}
    for name, q in (("median", 0.5), ("p99", 0.99), ("p999", 0.999)):
        v = _hist_quantile(hist, q)
        out[name] = None if v is None else (min(v, top) if top is not None else v)
    out["max"] = top
    return out


def summarise_records(recs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The statistics of a set of records (one point, one sweep, or any group)."""
    ok = [r for r in recs if r.get("status") == "ok"]
    n, n_ok = len(recs), len(ok)
    breach = sum(bool(r["breach"]) for r in ok)
    relaxed_eps = sum((r["relaxed_steps"] or 0) > 0 for r in ok)
    steps = sum(r["steps"] or 0 for r in ok)
    relaxed = sum(r["relaxed_steps"] or 0 for r in ok)
    fallback = sum(r["fallback_steps"] or 0 for r in ok)
    reached = sum(bool(r["reached_goal"]) for r in ok)
    ttg = [r["time_to_goal"] for r in ok if r.get("time_to_goal") is not None]
    md = [r["min_distance"] for r in ok if r.get("min_distance") is not None]
    bands: dict[str, list[float]] = {b: [] for b, _, _ in TRUST_BANDS}
    for r in ok:
        for t, d in zip(r.get("ped_trust") or [], r.get("ped_min_distance") or [], strict=False):
            if t is None or d is None:
                continue
            for b, lo, hi in TRUST_BANDS:
                if lo <= t < hi:
                    bands[b].append(d)
    checked = sum(r.get("relaxed_checked") or 0 for r in ok)
    feasible = sum(r.get("relaxed_but_feasible") or 0 for r in ok)
    # a safe plan existed at every step: every relaxed step was checked and found feasible (none: trivially)
    safe_everywhere = [
        r
        for r in ok
        if (r.get("relaxed_checked") or 0) == (r.get("relaxed_steps") or 0) == (r.get("relaxed_but_feasible") or 0)
    ]
    unchecked = [r for r in ok if (r.get("relaxed_checked") or 0) < (r.get("relaxed_steps") or 0)]
    hist = np.zeros(len(STEP_MS_EDGES) - 1)
    for r in ok:
        for k, c in (r.get("step_ms_hist") or {}).items():
            hist[int(k)] += c
    maxes = [r["step_ms_max"] for r in ok if r.get("step_ms_max") is not None]
    errors: dict[str, int] = defaultdict(int)
    for r in recs:
        if r.get("status") != "ok":
            errors[str(r.get("error"))[:200]] += 1

    def rate(k: int) -> float | None:
        return k / n_ok if n_ok else None

    return {
        "episodes": n,
        "ok": n_ok,
        "failed": n - n_ok,
        "violations": breach,
        "violation_rate": rate(breach),
        "violation_ci95": wilson(breach, n_ok),
        "infeasible_steps": relaxed,
        "infeasible_episodes": relaxed_eps,
        "infeasible_episode_rate": rate(relaxed_eps),
        "infeasible_episode_ci95": wilson(relaxed_eps, n_ok),
        "steps": steps,
        "infeasible_step_rate": relaxed / steps if steps else None,
        "fallback_steps": fallback,
        "fallback_step_rate": fallback / steps if steps else None,
        "recovered_steps": sum(r.get("recovered_steps") or 0 for r in ok),
        "deadline_steps": sum(r.get("deadline_steps") or 0 for r in ok),
        "solver_failed_steps": sum(r.get("failed_steps") or 0 for r in ok),
        "reached_goal": reached,
        "reached_goal_rate": rate(reached),
        "stopped_for_good": sum(bool(r.get("stopped_for_good")) for r in ok),
        "time_to_goal_median": _q(ttg, 50),
        "min_distance_median": _q(md, 50),
        "min_distance_p05": _q(md, 5),
        "min_distance_min": min(md) if md else None,
        "min_distance_by_trust": {
            b: {"n": len(v), "median": _q(v, 50), "p05": _q(v, 5), "min": min(v) if v else None}
            for b, v in bands.items()
        },
        "relaxed_steps_checked": checked,
        "relaxed_steps_independently_feasible": feasible,
        "breach_episodes_with_safe_plan_at_every_step": sum(bool(r["breach"]) for r in safe_everywhere),
        "breach_episodes_unchecked": sum(bool(r["breach"]) for r in unchecked),  # relaxed steps not checked
        # random families: the plant's path between control steps (record.min_distance_continuous)
        "breach_continuous_episodes": sum(bool(r.get("breach_continuous")) for r in ok),
        "min_distance_continuous_min": min(mc)
        if (mc := [r["min_distance_continuous"] for r in ok if r.get("min_distance_continuous") is not None])
        else None,
        "step_ms": _tail(hist, max(maxes) if maxes else None),
        "errors": dict(sorted(errors.items(), key=lambda kv: -kv[1])[:5]),
    }


def summarise(spec: CampaignSpec, records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """summary.json: per point (``points``), per sweep (``sweeps``), per sweep and horizon
    (``by_horizon``, from the horizon each episode ran with) for the records of the spec's keys."""
    keys = {t.key for t in spec.tasks()}
    by_point: dict[tuple[str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in records:
        if r["key"] in keys:
            by_point[(r["sweep"], r["point_id"])].append(r)
    points, sweeps, by_h = [], {}, {}
    for s in spec.sweeps:
        allrec: list[Mapping[str, Any]] = []
        for p in s.points(spec.seed, spec.record):
            recs = sorted(by_point.get((s.name, p.point_id), []), key=lambda r: r["seed"])
            allrec += recs
            head = {"sweep": s.name, "point": p.index, "point_id": p.point_id, "family": s.family}
            points.append({**head, "params": dict(p.params), "planned": len(s.seeds), **summarise_records(recs)})
        sweeps[s.name] = {"family": s.family, **summarise_records(allrec)}
        groups: dict[int, list[Mapping[str, Any]]] = defaultdict(list)
        for r in allrec:
            if r.get("horizon") is not None:
                groups[int(r["horizon"])].append(r)
        by_h[s.name] = {str(h): summarise_records(g) for h, g in sorted(groups.items())}
    return {"campaign": spec.name, "points": points, "sweeps": sweeps, "by_horizon": by_h}


def _fmt(v: Any, digits: int = 2) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def _pct(k: int, n: int) -> str:
    return f"{k} ({100 * k / n:.1f} %)" if n else f"{k}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """summary.md: one row per point, then sweep totals with the step-time tail."""
    lines = [f"# Campaign `{summary['campaign']}`", ""]
    lines += [
        "Per point: episodes (failed), margin violations (episodes with min distance < R), infeasible "
        "(episodes with a relaxed step) and relaxed steps, fallback steps, goal reached, median time to "
        "goal (s), median min distance (m) overall and by trust band (low < 1/3 <= mid < 2/3 <= high).",
        "",
        "| sweep | params | episodes (failed) | violations | infeasible eps | relaxed steps | fallback steps "
        "| goal | t goal | min d | min d low / mid / high trust |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in summary["points"]:
        params = ", ".join(f"{k}={v}" for k, v in p["params"].items()) or "-"
        b = p["min_distance_by_trust"]
        bands = " / ".join(_fmt(b[k]["median"]) for k in ("low", "mid", "high"))
        lines.append(
            f"| {p['sweep']} | {params} | {p['episodes']} ({p['failed']}) | {_pct(p['violations'], p['ok'])} "
            f"| {_pct(p['infeasible_episodes'], p['ok'])} | {p['infeasible_steps']} | {p['fallback_steps']} "
            f"| {_pct(p['reached_goal'], p['ok'])} | {_fmt(p['time_to_goal_median'])} "
            f"| {_fmt(p['min_distance_median'])} | {bands} |"
        )
    lines += [
        "",
        "## Sweeps",
        "",
        "| sweep | family | episodes (failed) | steps | violations | infeasible eps | relaxed steps (checked / "
        "independently feasible) | breaches with a safe plan at every step | fallback steps "
        "| step ms median / p99 / p99.9 / max |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary["sweeps"].items():
        t = s["step_ms"]
        lines.append(
            f"| {name} | {s['family']} | {s['episodes']} ({s['failed']}) | {s['steps']} "
            f"| {_pct(s['violations'], s['ok'])} | {_pct(s['infeasible_episodes'], s['ok'])} "
            f"| {s['infeasible_steps']} ({s['relaxed_steps_checked']} / {s['relaxed_steps_independently_feasible']}) "
            f"| {s['breach_episodes_with_safe_plan_at_every_step']}"
            f"{f' ({u} unchecked)' if (u := s['breach_episodes_unchecked']) else ''} | {s['fallback_steps']} "
            f"| {_fmt(t['median'], 3)} / {_fmt(t['p99'], 2)} / {_fmt(t['p999'], 2)} / {_fmt(t['max'], 1)} |"
        )
    errs = {e: c for s in summary["sweeps"].values() for e, c in s["errors"].items()}
    if errs:
        lines += ["", "## Failed episodes (most frequent errors)", ""]
        lines += [f"- {c} x {e.replace('|', '/')}" for e, c in errs.items()]
    lines += [
        "",
        "Step times: wall clock per control step for the random families, solver time for `paper` and "
        "`drive`; medians and tails from a log histogram (bin upper edges), max exact.",
    ]
    return "\n".join(lines) + "\n"


def write_summary(spec: CampaignSpec, records: Iterable[Mapping[str, Any]], out: str | Path) -> dict[str, Any]:
    """Write ``summary.json`` and ``summary.md`` under ``out``; return the summary."""
    out = Path(out)
    summary = summarise(spec, records)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (out / "summary.md").write_text(markdown_table(summary))
    return summary
