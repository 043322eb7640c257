"""How perception latency changes the drive: seconds from a frame's capture to its people reaching
the controller's estimates (``SensingSpec.perception_latency``; ``trustnav drive --perception-latency``).

For each scenario (Case I, Case II both variants, the lane crossing of examples/scenarios, both
variants), each latency and each seed, one keypoint-sensing drive at ``--rate`` frames/s with
perceived pedestrian states (pure functions of scenario, latency and seed), and a Markdown table:
per row the closest approach to each pedestrian (min over seeds), margin violations and relaxed
steps (summed over seeds), goal time (median), and whether the distracted pedestrian was passed wider
than the attentive one (Case I).

    python benchmarks/latency_study.py                       # latencies 0 0.1 0.3 0.5 1, seeds 0-4
    python benchmarks/latency_study.py --latency 0 0.5 --seeds 20 --json out.json
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from trustnav.sim.driving import load_drive_scenario, run_drive

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = {
    "case-1": ("case-1", None),
    "case-2 attentive": ("case-2", True),
    "case-2 distracted": ("case-2", False),
    "lane-crossing attentive": (str(ROOT / "examples" / "scenarios" / "lane-crossing.toml"), True),
    "lane-crossing distracted": (str(ROOT / "examples" / "scenarios" / "lane-crossing.toml"), False),
}


def run(name: str, latency: float, seeds: int, rate: float) -> dict:
    path, attentive = SCENARIOS[name]
    sc = load_drive_scenario(path)
    sc = replace(sc, sensing=replace(sc.sensing, perception_latency=latency))
    runs = [run_drive(sc, sensing="keypoints", seed=s, attentive=attentive, capture_rate=rate).metrics()
            for s in range(seeds)]  # fmt: skip
    mins = np.array([[p["min_distance"] for p in m["pedestrians"]] for m in runs])
    goals = [m["time_to_goal"] for m in runs if m["time_to_goal"] is not None]
    row = {
        "scenario": name,
        "latency_s": latency,
        "seeds": seeds,
        "min_distance": [round(float(v), 3) for v in mins.min(axis=0)],
        "margin_violations": int(sum(m["margin_violations"] for m in runs)),
        "relaxed_steps": int(sum(m["relaxed_steps"] for m in runs)),
        "fallback_steps": int(sum(m["fallback_steps"] for m in runs)),
        "reached_goal": int(sum(m["reached_goal"] for m in runs)),
        "time_to_goal_median": round(float(np.median(goals)), 2) if goals else None,
    }
    if mins.shape[1] == 2:  # Case I: attentive, distracted
        row["distracted_wider"] = int(np.sum(mins[:, 1] > mins[:, 0]))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--latency", type=float, nargs="+", default=[0.0, 0.1, 0.3, 0.5, 1.0], help="seconds, each")
    ap.add_argument("--seeds", type=int, default=5, help="seeds 0..N-1 per row")
    ap.add_argument("--rate", type=float, default=10.0, help="camera frames per second")
    ap.add_argument("--json", help="write the rows to this file")
    args = ap.parse_args()
    if any(not (math.isfinite(v) and 0.0 <= v <= 5.0) for v in args.latency):
        ap.error(f"--latency: seconds in [0, 5], got {args.latency}")
    if args.seeds < 1:
        ap.error(f"--seeds: an integer >= 1, got {args.seeds}")
    if not (math.isfinite(args.rate) and 0.0 < args.rate <= 60.0):
        ap.error(f"--rate: frames per second in (0, 60], got {args.rate}")
    rows = [run(name, lat, args.seeds, args.rate) for name in SCENARIOS for lat in args.latency]
    cols = ["scenario", "latency_s", "min_distance", "distracted_wider", "margin_violations", "relaxed_steps",
            "fallback_steps", "reached_goal", "time_to_goal_median"]  # fmt: skip
    print(f"keypoint sensing, {args.rate:g} frames/s, perceived states, seeds 0-{args.seeds - 1}; "
          "min_distance: closest approach per pedestrian, min over seeds (m)")  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c, "")
            cells.append(" / ".join(f"{x:.2f}" for x in v) if isinstance(v, list) else str(v))
        print("| " + " | ".join(cells) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
