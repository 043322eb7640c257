"""Trust sets speed: step-outs and kerbs (issue 34).

Variants of ``examples/scenarios/step-out.toml`` (the car at 8 m/s on the one-lane street, the
camera at 1 frame/s, perceived pedestrian states, keypoint sensing by default), one per seed:

* **step-out**: a pedestrian texting at the kerb (0.1-0.9 m beyond it, 92-106 m along the map)
  steps straight across the lane at 1.4 m/s when a car that did not slow would be 14-20 m from her;
* **stays**: the same kerb, the pedestrian attentive (looking at the car) or texting, and staying;
  beside a **free road** (nobody near it).

For each, with the trust-aware caution (the default) and without it (``caution = false``, the
paper's controller), prints the true closest approach, the runs below R and below 1 m, the road
departure, the time to the goal and the median solve time.

    python benchmarks/step_out.py                      # 10 seeds, ~3 min on 2 cores
    python benchmarks/step_out.py --seeds 20 --rate 10
    python benchmarks/step_out.py --sensing render --seeds 1 --only step-out
    python benchmarks/step_out.py --near-range 10        # with a near-field sensor around the car's front
    python benchmarks/step_out.py --near-range 10 --near-clutter 1  # it also returns poles, bins: 1 per 10 m
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from trustnav.sim.driving import load_drive_scenario, run_drive
from trustnav.sim.driving.behaviour import BehaviourSpec
from trustnav.sim.driving.episode import drive_metrics

ROOT = Path(__file__).resolve().parents[1]
ROAD_X, KERB = 34.25, 3.0  # the road's line near y = 100 and its half width


def step_out(base, seed: int, pose: str = "texting", stays: bool = False, free: bool = False):  # type: ignore[no-untyped-def]
    """The seed's variant (module docstring): kerb offset, place and the step-out's distance
    drawn from ``seed``."""
    rng = np.random.default_rng(1000 + seed)
    y = float(rng.uniform(92.0, 106.0))
    x = ROAD_X + KERB + float(rng.uniform(0.1, 0.9))
    distance = float(rng.uniform(14.0, 20.0))
    start = (base.ego_start[1] - y - distance) / 8.0  # a car that kept 8 m/s is `distance` from her
    p = base.pedestrians[0]
    attentive = pose == "attentive"
    ped = dataclasses.replace(
        p,
        position=(70.0 if free else x, y),
        velocity=(0.0, 0.0) if stays else (-1.4, 0.0),
        attentive=attentive,
        pose="attentive" if attentive else "distracted",
        look_at_camera=attentive,
        alternative=(),
        behaviour=None if stays else BehaviourSpec(start_time=max(start, 0.0), moving_pose="texting_walk"),
    )
    return dataclasses.replace(base, pedestrians=(ped,), variants=()), distance


def run(args: argparse.Namespace) -> dict:
    base = load_drive_scenario(ROOT / "examples/scenarios/step-out.toml")
    # None: the file's (no near-field sensor, no clutter)
    base = base.with_options(sensing={"near_range": args.near_range, "near_clutter": args.near_clutter})
    renderer = pipeline = None
    if args.sensing == "render":
        from trustnav.sim.driving import make_render_sensing

        renderer, pipeline = make_render_sensing(base, args.rate)
    kinds = {
        "step-out": dict(),
        "attentive stays": dict(pose="attentive", stays=True),
        "texting stays": dict(stays=True),
        "free road": dict(stays=True, free=True),
    }
    if args.only:
        kinds = {k: v for k, v in kinds.items() if k == args.only}
    overrides = {k: float(v) for k, v in (kv.split("=") for kv in args.set)}
    out: dict = {"rate": args.rate, "sensing": args.sensing, "rows": []}
    for kind, kw in kinds.items():
        for caution in {"both": (True, False), "on": (True,), "off": (False,)}[args.caution]:
            rows = []
            for seed in range(args.seeds):
                sc, distance = step_out(base, seed, **kw)
                sc = dataclasses.replace(sc, control=dataclasses.replace(sc.control, caution=caution, **overrides))
                r = run_drive(sc, args.sensing, seed=seed, capture_rate=args.rate, renderer=renderer, pipeline=pipeline)
                m = drive_metrics(r)
                ped = m["pedestrians"][0]
                rows.append(dict(seed=seed, distance=round(distance, 2), min_distance=ped["min_distance"],
                                 trust=ped["final_trust"], goal=m["time_to_goal"],
                                 road=m["road_departure_max"], violations=m["margin_violations"],
                                 solve_ms=m["solve_ms_median"]))  # fmt: skip
            out["rows"].append(dict(kind=kind, caution=caution, runs=rows))
            d = np.array([r["min_distance"] for r in rows])
            goals = [r["goal"] for r in rows if r["goal"] is not None]
            print(
                f"{kind:16s} caution={'on ' if caution else 'off'}  closest min {d.min():5.2f} m"
                f" median {np.median(d):5.2f} m"
                f"  >= R {int(np.sum(d >= 2.5))}/{len(d)}  < 1 m {int(np.sum(d < 1.0))}"
                f"  off road {sum(r['road'] > 0 for r in rows)}  goal {len(goals)}/{len(rows)}"
                f" median {np.median(goals) if goals else float('nan'):5.2f} s"
                f"  solve median {np.median([r['solve_ms'] for r in rows]):.3f} ms  (load {os.getloadavg()[0]:.1f})",
                flush=True,
            )
    return out


def figure(path: Path, seed: int = 0) -> None:
    """Speed and distance over time on ``examples/scenarios/step-out.toml``: trust-aware with and
    without caution, and the controller handed constant trust 0 and 1 (``trustnav compare``)."""
    from trustnav.sim.driving.compare import ConstantTrustEnvironment
    from trustnav.sim.driving.episode import DriveEnvironment, drive
    from trustnav.viz.style import legend, new_figure, styled

    base = load_drive_scenario(ROOT / "examples/scenarios/step-out.toml")
    runs = []
    modes = (("trust-aware, caution", True, None), ("trust-aware, no caution (the paper's)", False, None),
             ("constant trust 0", True, 0.0), ("constant trust 1", True, 1.0))  # fmt: skip
    for label, caution, trust in modes:
        sc = dataclasses.replace(base, control=dataclasses.replace(base.control, caution=caution))
        sim = DriveEnvironment(sc, seed=seed)
        r = drive(sim if trust is None else ConstantTrustEnvironment(sim, trust), "keypoints")  # type: ignore[arg-type]
        m = drive_metrics(r)
        runs.append((label, r, m))
        print(f"{label:40s} closest {m['pedestrians'][0]['min_distance']:.2f} m  goal {m['time_to_goal']} s")
    step = base.pedestrians[0].behaviour.start_time  # type: ignore[union-attr]
    with styled():
        fig, (ax, bx) = new_figure((7.0, 6.0), 2, 1, sharex=True)
        for (label, r, m), style in zip(runs, ("-", ":", "--", "-."), strict=True):
            ax.plot(r.times, r.ego[:, 3], style, label=f"{label}: {m['pedestrians'][0]['min_distance']:.2f} m")
            bx.plot(r.times, r.distances[:, 0], style)
        for a in (ax, bx):
            a.axvline(step, color="grey", lw=0.8)
        ax.text(step, 0.3, " she steps out", color="grey")
        bx.axhline(base.control.safety_radius, color="red", lw=0.8)
        ax.set_ylabel("car speed (m/s)")
        bx.set_ylabel("distance to her (m)")
        bx.set_xlabel("time (s)")
        bx.set_ylim(0, 20)
        # above the plot: inside, it hid the runs' later speeds
        legend(ax, loc="lower center", bbox_to_anchor=(0.5, 1.02), ncol=2, title="run: closest approach to her")
        fig.savefig(path)
    print(f"wrote {path}")


def solve_time(repeats: int = 5) -> None:
    """The controller's median step time with and without caution, drives interleaved (on, off,
    on, ...) so that the machine's load falls on both alike; seed 0 of each kind."""
    base = load_drive_scenario(ROOT / "examples/scenarios/step-out.toml")
    for kind, kw in (("step-out", {}), ("texting stays", dict(stays=True)),
                     ("attentive stays", dict(pose="attentive", stays=True))):  # fmt: skip
        sc, _ = step_out(base, 0, **kw)
        ms: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(repeats):
            for caution in (True, False):
                s = dataclasses.replace(sc, control=dataclasses.replace(sc.control, caution=caution))
                ms[caution].append(drive_metrics(run_drive(s, "keypoints", seed=0))["solve_ms_median"])
        on, off = float(np.median(ms[True])), float(np.median(ms[False]))
        print(f"{kind:16s} median step {on:.3f} ms with caution, {off:.3f} ms without: x{on / off:.2f}"
              f"  (load {os.getloadavg()[0]:.1f})", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--rate", type=float, default=1.0)
    ap.add_argument("--sensing", default="keypoints", choices=("keypoints", "render"))
    ap.add_argument("--only", default=None, choices=("step-out", "attentive stays", "texting stays", "free road"))
    ap.add_argument("--caution", default="both", choices=("both", "on", "off"))
    ap.add_argument("--set", nargs="*", default=[], help="[control] options, e.g. caution_pass_speed=4")
    ap.add_argument("--json", type=Path, default=None, help="write every run's numbers here")
    ap.add_argument("--figure", type=Path, default=None, help="only draw speed over time (seed 0) to this PNG")
    ap.add_argument("--solve-time", action="store_true", help="only the median step time, caution on and off")
    ap.add_argument(
        "--near-range",
        type=float,
        help="[sensing] near_range, m: a near-field sensor (default: the file's, none)",
    )
    ap.add_argument(
        "--near-clutter",
        type=float,
        help="[sensing] near_clutter: objects per 10 m of sidewalk it returns (default: 0)",
    )
    args = ap.parse_args()
    if args.near_range is not None and not 0 <= args.near_range <= 30:
        ap.error(f"--near-range {args.near_range:g}: expected metres in [0, 30]")
    if args.near_clutter is not None and not 0 <= args.near_clutter <= 20:
        ap.error(f"--near-clutter {args.near_clutter:g}: expected objects per 10 m of sidewalk in [0, 20]")
    if args.seeds < 1:
        ap.error(f"--seeds {args.seeds}: expected a whole number of seeds >= 1")
    if not (math.isfinite(args.rate) and args.rate > 0):
        ap.error(f"--rate {args.rate}: expected camera frames per second > 0")
    if args.solve_time:
        solve_time()
        return
    if args.figure:
        figure(args.figure)
        return
    t0 = time.time()
    out = run(args)
    print(f"{time.time() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
