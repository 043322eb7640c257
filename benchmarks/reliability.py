"""Controller reliability over thousands of random closed-loop episodes: the campaign
``examples/campaigns/reliability.yaml`` run by :mod:`trustnav.campaigns` (``trustnav sweep``).

The worlds are those of :mod:`trustnav.sim.random_worlds` (distribution documented there and in
docs/campaigns.md), run with the default controller (step deadline 10 s, so that an episode is a
pure function of its seed; the wall step time is reported separately), every step whose plan
violates a CBF row re-checked with an independent multi-start SLSQP on the hard problem. Prints,
per family: episodes, relaxed episodes and steps, how many relaxed steps the independent check
could solve (goal 0), margin breaches (all, and in episodes where a safe plan existed at every
step: goal 0), fallbacks, recoveries, deadline hits and the wall step time median / p99 / p99.9
(log-histogram bin edges) / max, and the wall time.

    python benchmarks/reliability.py --quick                     # 300 + 30 episodes
    python benchmarks/reliability.py --out out/reliability       # 10,000 + 300 (resumes)
    trustnav sweep examples/campaigns/reliability.yaml --out out/reliability   # the same
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import yaml

from trustnav.campaigns import RecordStore, run_campaign, spec_from_dict
from trustnav.campaigns.summary import write_summary

SPEC = Path(__file__).resolve().parents[1] / "examples" / "campaigns" / "reliability.yaml"
KEYS = (
    "episodes",
    "failed",
    "steps",
    "reached_goal",
    "stopped_for_good",
    "infeasible_episodes",
    "infeasible_steps",
    "relaxed_steps_checked",
    "relaxed_steps_independently_feasible",
    "violations",
    "breach_episodes_with_safe_plan_at_every_step",
    "min_distance_min",
    "breach_continuous_episodes",
    "min_distance_continuous_min",
    "fallback_steps",
    "recovered_steps",
    "deadline_steps",
    "solver_failed_steps",
    "step_ms",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--si", type=int, help="single-integrator episodes (default: the spec's 10,000)")
    ap.add_argument("--bicycle", type=int, help="bicycle episodes (default: the spec's 300)")
    ap.add_argument("--quick", action="store_true", help="300 + 30 episodes")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scheduler", help="a running Dask scheduler instead of a LocalCluster")
    ap.add_argument("--no-check", action="store_true", help="skip the independent check of relaxed steps")
    ap.add_argument("--out", default="out/reliability", help="campaign directory (records, summary; resumes)")
    ap.add_argument("--json", help="also write the per-family figures here")
    args = ap.parse_args()
    doc: dict[str, Any] = yaml.safe_load(SPEC.read_text())
    counts = {"single_integrator": args.si, "bicycle": args.bicycle}
    if args.quick:
        counts = {"single_integrator": 300, "bicycle": 30}
    for sweep in doc["sweeps"]:
        n = sweep["seeds"] if counts[sweep["name"]] is None else counts[sweep["name"]]  # 0 skips the family
        sweep["seeds"] = {"start": args.seed, "count": n}
    doc["sweeps"] = [s for s in doc["sweeps"] if s["seeds"]["count"] > 0]
    doc["record"]["check_relaxed"] = not args.no_check
    spec = spec_from_dict(doc)
    t0 = time.perf_counter()
    rep = run_campaign(spec, args.out, scheduler=args.scheduler, workers=args.workers)
    summary = write_summary(spec, RecordStore(Path(args.out) / "records.jsonl").latest().values(), args.out)
    wall = time.perf_counter() - t0
    out: dict[str, Any] = {}
    for name, s in summary["sweeps"].items():
        fig = {k: s[k] for k in KEYS}
        fig["by_horizon"] = {
            h: {k: g[k] for k in ("episodes", "violations", "infeasible_episodes", "infeasible_steps")}
            for h, g in summary["by_horizon"][name].items()
        }
        out[name] = fig
        print(f"\n## {name}: {s['episodes']} episodes, {s['steps']} steps")
        for k, v in fig.items():
            if k not in ("episodes", "steps"):
                print(f"  {k}: {v:.3f}" if isinstance(v, float) else f"  {k}: {v}")
    print(f"\nran {rep.ran} episodes ({rep.skipped} already recorded) on {rep.workers} workers: {wall:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({**out, "wall_s": wall, "workers": rep.workers}, indent=2) + "\n")


if __name__ == "__main__":
    main()
