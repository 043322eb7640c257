"""Controller reliability over thousands of random closed-loop episodes (seeded, reproducible).

Runs the worlds of :mod:`trustnav.sim.random_worlds` (the distribution is documented there and in
docs/reliability.md) with the default controller, re-checks every step whose plan violates a CBF
row with an independent multi-start SLSQP on the hard problem, and prints: episodes, relaxed
episodes and steps, how many relaxed steps the independent check could solve (goal 0), margin
breaches (all, and in episodes where a safe plan existed at every step: goal 0), fallbacks,
recoveries, deadline hits and the step time median / p99 / max (wall clock, which includes the
time the process was preempted, and CPU time of the stepping thread).

    python benchmarks/reliability.py --quick            # 300 + 30 episodes, ~1 min
    python benchmarks/reliability.py                    # 10,000 single-integrator + 300 bicycle
    python benchmarks/reliability.py --json out/rel.json --workers 2
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time
from typing import Any

import numpy as np

from trustnav.sim.random_worlds import RandomWorldSpec, run_world, sample_world


def _one(job: tuple[str, int, bool]) -> dict[str, Any]:
    family, seed, check = job
    rec = run_world(sample_world(RandomWorldSpec(family=family), seed), check_relaxed=check, keep_step_times=True)
    rec["step_ms"] = np.asarray(rec["step_ms"], dtype=np.float32)
    rec["step_cpu_ms"] = np.asarray(rec["step_cpu_ms"], dtype=np.float32)
    return rec


def summarise(recs: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures the study reports, for one family."""
    times = np.concatenate([r["step_ms"] for r in recs])
    cpu = np.concatenate([r["step_cpu_ms"] for r in recs])
    small = [r for r in recs if r["n_p"] <= 10 and r["horizon"] <= 20]
    safe_everywhere = [r for r in recs if r["relaxed_checked"] == r["relaxed_but_feasible"]]
    return {
        "episodes": len(recs),
        "steps": int(sum(r["steps"] for r in recs)),
        "reached_goal": int(sum(r["reached_goal"] for r in recs)),
        "relaxed_episodes": int(sum(r["relaxed_steps"] > 0 for r in recs)),
        "relaxed_steps": int(sum(r["relaxed_steps"] for r in recs)),
        "relaxed_steps_checked": int(sum(r["relaxed_checked"] for r in recs)),
        "relaxed_steps_independently_feasible": int(sum(r["relaxed_but_feasible"] for r in recs)),
        "breach_episodes": int(sum(r["breach"] for r in recs)),
        "breach_episodes_with_safe_plan_at_every_step": int(sum(r["breach"] for r in safe_everywhere)),
        "min_distance_min": float(min(r["min_distance"] for r in recs)),
        "fallback_steps": int(sum(r["fallback_steps"] for r in recs)),
        "recovered_steps": int(sum(r["recovered_steps"] for r in recs)),
        "deadline_steps": int(sum(r["deadline_steps"] for r in recs)),
        "failed_steps": int(sum(r["failed_steps"] for r in recs)),
        "step_ms_median": float(np.median(times)),
        "step_ms_p99": float(np.percentile(times, 99)),
        "step_ms_max": float(times.max()),
        "step_ms_max_np10_nh20": float(max(r["step_ms_max"] for r in small)) if small else None,
        "step_cpu_ms_median": float(np.median(cpu)),
        "step_cpu_ms_p99": float(np.percentile(cpu, 99)),
        "step_cpu_ms_max": float(cpu.max()),
        "step_cpu_ms_max_np10_nh20": float(max(r["step_cpu_ms_max"] for r in small)) if small else None,
        "breach_seeds": [r["seed"] for r in recs if r["breach"]][:50],
        "relaxed_but_feasible_seeds": [r["seed"] for r in recs if r["relaxed_but_feasible"]][:50],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--si", type=int, default=10_000, help="single-integrator episodes")
    ap.add_argument("--bicycle", type=int, default=300, help="bicycle episodes")
    ap.add_argument("--quick", action="store_true", help="300 + 30 episodes")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-check", action="store_true", help="skip the independent check of relaxed steps")
    ap.add_argument("--json", help="write the summary here")
    args = ap.parse_args()
    n_si, n_bi = (300, 30) if args.quick else (args.si, args.bicycle)
    out: dict[str, Any] = {}
    for family, n in (("single_integrator", n_si), ("bicycle", n_bi)):
        if n <= 0:
            continue
        jobs = [(family, args.seed + i, not args.no_check) for i in range(n)]
        t0 = time.perf_counter()
        if args.workers > 1:
            with mp.get_context("spawn").Pool(args.workers) as pool:
                recs = list(pool.imap_unordered(_one, jobs, chunksize=8))
        else:
            recs = [_one(j) for j in jobs]
        s = summarise(sorted(recs, key=lambda r: r["seed"]))
        s["wall_s"] = time.perf_counter() - t0
        out[family] = s
        head = f"{s['episodes']} episodes, {s['steps']} steps ({s['wall_s']:.0f} s, {args.workers} workers)"
        print(f"\n## {family}: {head}")
        for k, v in s.items():
            if k not in ("episodes", "steps", "wall_s"):
                print(f"  {k}: {v:.3f}" if isinstance(v, float) else f"  {k}: {v}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
