"""The paper's Section IV claims as statistics over seeds, from a `trust_claims.yaml` campaign.

    trustnav sweep examples/campaigns/trust_claims.yaml --out out/trust_claims
    python examples/campaigns/trust_claims.py out/trust_claims

Per sweep (trust-aware, trust-blind at gamma_ini, trust-blind at gamma_ini + delta) it prints, with 95 %
intervals:

* Case I: the extra room of the distracted pedestrian, d(distracted) - d(attentive), per seed (same
  episode); the claim holds when the trust-aware interval lies above 0 and the blind ones do not;
* Case II: the extra room of the walker when distracted, d(distracted run) - d(attentive run), paired
  by seed;
* every sweep: the share of episodes inside R (a breach; Wilson interval) and the time to the goal.

Intervals of means are percentile bootstraps (10,000 resamples, seeded: the same records give the
same intervals).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from trustnav.campaigns.summary import wilson

BOOTSTRAP = 10_000


def mean_ci(values: list[float], seed: int = 0) -> tuple[float, float, float]:
    """(mean, lower, upper): the mean and its 95 % percentile-bootstrap interval."""
    x = np.asarray(values, dtype=float)
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(BOOTSTRAP, x.size))].mean(axis=1)
    return float(x.mean()), float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def load(folder: Path) -> dict[str, list[dict]]:
    """The campaign's ok records by sweep (the latest record of each key)."""
    latest: dict[str, dict] = {}
    with open(folder / "records.jsonl") as fh:
        for line in fh:
            if line.strip():
                rec = json.loads(line)
                latest[rec["key"]] = rec
    by: dict[str, list[dict]] = defaultdict(list)
    for rec in latest.values():
        if rec["status"] == "ok":
            by[rec["sweep"]].append(rec)
    return by


def _fmt(m: tuple[float, float, float], unit: str = " m") -> str:
    return f"{m[0]:+.2f}{unit} [{m[1]:+.2f}, {m[2]:+.2f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", type=Path, help="the campaign's --out folder (records.jsonl)")
    args = ap.parse_args()
    by = load(args.folder)
    if not by:
        raise SystemExit(f"{args.folder}: no ok records")
    print("claim 1 (Case I): extra room of the distracted pedestrian, d(distracted) - d(attentive), mean [95 % CI]")
    for sweep in ("case1_aware", "case1_blind0", "case1_blind1"):
        recs = by.get(sweep, [])
        if recs:
            diff = [r["ped_min_distance"][1] - r["ped_min_distance"][0] for r in recs]
            print(f"  {sweep:<14} n = {len(recs):<4} {_fmt(mean_ci(diff))}")
    print("claim 2 (Case II): extra room of the walker when distracted, paired by seed, mean [95 % CI]")
    for sweep in ("case2_aware", "case2_blind0", "case2_blind1"):
        runs: dict[int, dict[bool, float]] = defaultdict(dict)
        for r in by.get(sweep, []):
            runs[r["seed"]][bool(r["params"]["attentive"])] = r["ped_min_distance"][0]
        diff = [d[False] - d[True] for d in runs.values() if len(d) == 2]
        if diff:
            print(f"  {sweep:<14} n = {len(diff):<4} {_fmt(mean_ci(diff))}")
    print("safety and cost per sweep: episodes inside R (Wilson 95 %), time to goal (mean [95 % CI])")
    for sweep, recs in sorted(by.items()):
        breach = sum(bool(r["breach"]) for r in recs)
        lo, hi = wilson(breach, len(recs)) or (float("nan"), float("nan"))
        times = [r["time_to_goal"] for r in recs if r["time_to_goal"] is not None]
        ttg = _fmt(mean_ci(times), " s").replace("+", "") if times else "never reached"
        print(f"  {sweep:<14} n = {len(recs):<4} breaches {breach} [{lo:.3f}, {hi:.3f}]  goal {ttg}")


if __name__ == "__main__":
    main()
