"""Where the 90 % regions are too wide or too narrow: per person, raw placement against track, and
what the tracker's walking model and the frames' correlation contribute (issue 34 item 4).

Drives the Cases (keypoint sensing, or ``--render`` through rendered frames and the detector, on
varied worlds as ``perceived_drive.py --vary``), records each frame's people as the tracker got
them, then replays the localiser and the world tracker on those frames, open loop (the car's path
is the recorded one), under ablations of the tracker:

* ``as is``: the sensing's configuration (the drive's own regions; its coverage is the drive's);
* ``standing only``: no walking model (``switch_rate`` 0, ``initial_standing`` 1): the walking
  component's share of a standing person's region removed;
* ``independent frames``: ``error_shared`` 0 (every frame a new placement);
* ``standing shuffle / 10``: the standing model's random walk ``standing_psd`` a tenth of the
  default (0.0005 m^2/s): what the stander's shuffle adds to her region.

Per person (pedestrian index) and per run it prints: frames, the truth inside the 90 % region of
the track and of the raw placement, their errors along and across the line of sight in units of
their own sigma (rms; 1 for a calibrated region; "along q90": the 90 % quantile of the track's
|along error| over 1.645, 1 where the core of the errors is calibrated whatever their tail), and the
track's median walking probability.

    python benchmarks/region_breakdown.py --case case-2 --rate 10 --seeds 20
    python benchmarks/region_breakdown.py --case case-1 --rate 10 --render --seeds 3
    python benchmarks/region_breakdown.py --case case-1 --rate 10 --render --seeds 3 --save r.pkl
    python benchmarks/region_breakdown.py --case case-1 --load r.pkl   # replay only, no driving
    python benchmarks/region_breakdown.py --case case-1 --load r.pkl --set lateral_sigma=0.02 error_shared=0.5

``--save`` writes the recorded drives (pickle: the frames' people, cameras and the truth), so that a
model change is replayed on the same frames in seconds (``replay`` with ``dataclasses.replace`` of
the localiser's and tracker's configurations) instead of re-rendering them (a rendered drive at 10
frames/s takes minutes). A replay is open loop: the car's path is the recorded drive's.
``--set KEY=VALUE ...`` replays a candidate: each key a field of ``LocaliserConfig`` or
``WorldTrackerConfig``, over the sensing's own (every ablation on top of it).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pickle
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from perceived_drive import _frame_errors, coverage_interval, varied
from trustnav.perception.localisation import GroundLocaliser, LocaliserConfig, chi2_90
from trustnav.perception.world_tracking import WorldTracker, WorldTrackerConfig
from trustnav.sim.driving import frame_path
from trustnav.sim.driving.episode import run_drive, street_of
from trustnav.sim.driving.world import load_drive_scenario


@contextmanager
def recording(frames: list):
    """Records (time, camera, people, pedestrian index, to_world) of every frame the perceived
    path tracks (instrumentation only: the drive is unchanged)."""
    original = frame_path.PerceivedPath.track

    def track(self, frame):
        frames.append((frame.time, frame.camera, [s.person for s in frame.people],
                       [s.index for s in frame.people], frame.to_scenario))  # fmt: skip
        return original(self, frame)

    frame_path.PerceivedPath.track = track
    try:
        yield frames
    finally:
        frame_path.PerceivedPath.track = original


def drive(case: str, seed: int, att, rate: float | None, render: bool) -> dict:
    """One recorded drive: its frames and the truth at each frame's time."""
    sc = load_drive_scenario(case)
    frames: list = []
    kw = {}
    if render:
        from trustnav.sim.driving.sensing import make_render_sensing

        sc = varied(sc, seed)
        kw["renderer"], kw["pipeline"] = make_render_sensing(sc, capture_rate=rate)
    try:
        with recording(frames):
            r = run_drive(sc, sensing="render" if render else "keypoints", seed=seed, attentive=att,
                          capture_rate=rate, **kw)  # fmt: skip
    finally:
        if render:
            kw["renderer"].close()
            kw["pipeline"].backend.close()
    truth = {
        round(f.time, 6): [None if v.position is None else np.array(v.position) for v in f.views] for f in r.frames
    }
    inside = [e[2] for e in _frame_errors(r)]  # the drive's own figure, for the replay to reproduce
    metrics = r.metrics()  # the drive's claims (closest approaches, goal), for --claims
    metrics.pop("per_frame", None)
    return {"scenario": sc, "att": att, "seed": seed, "frames": frames, "truth": truth, "keypoints": not render,
            "inside": inside, "metrics": metrics}  # fmt: skip


def set_value(text: str) -> float | bool:
    """A ``--set`` value: true / false for a switch (``pixel_bias``, ``separate_scales``), else a number
    (ValueError)."""
    flag = {"true": True, "false": False}
    return flag[text.lower()] if text.lower() in flag else float(text)


def replay(rec: dict, ablation: dict, localiser: dict | None = None) -> dict[int, list[tuple]]:
    """Localiser and tracker over the recorded frames: per pedestrian index, per frame that updated
    its track, (track inside, raw inside, track along, track across, raw along, raw across, walking
    probability), errors whitened by each one's own sigma along and across the line of sight.
    ``ablation``: tracker fields replaced; ``localiser``: localiser fields replaced."""
    sc = rec["scenario"]
    loc = GroundLocaliser(dataclasses.replace(sc.sensing.localiser(rec["keypoints"]), **(localiser or {})))
    trk = WorldTracker(dataclasses.replace(sc.sensing.tracker(rec["keypoints"]), **ablation))
    ground = street_of(sc).ground_height
    out: dict[int, list[tuple]] = {}
    for t, camera, people, index, to_world in rec["frames"]:
        ests = [loc.locate(p, camera, ground) for p in people]
        if to_world is not None:
            ests = [None if e is None else e.mapped(to_world) for e in ests]
        ids = trk.add_frame(t, ests, [p.bbox for p in people], camera, to_world)
        truth = rec["truth"].get(round(t, 6))
        if truth is None:
            continue
        states = {s.track_id: s for s in trk.predict(t)}
        walking = {k.track_id: float(k.probabilities[1]) for k in trk.tracks}
        for j, tid, e in zip(index, ids, ests, strict=True):
            if j is None or tid is None or tid not in states or truth[j] is None or e is None:
                continue
            u = truth[j] - camera.position[:2]
            u = u / np.hypot(*u)
            w = np.array([-u[1], u[0]])
            row = []
            for mean, cov in ((states[tid].mean[:2], states[tid].covariance[:2, :2]), (e.position, e.covariance)):
                d = mean - truth[j]
                row.append((float(d @ np.linalg.solve(cov, d)) <= chi2_90, d @ u / math.sqrt(u @ cov @ u),
                            d @ w / math.sqrt(w @ cov @ w)))  # fmt: skip
            (ti, ta, tc), (ri, ra, rc) = row
            out.setdefault(j, []).append((ti, ri, ta, tc, ra, rc, walking[tid]))
    return out


def people_classes(recs: list[dict], rows: dict) -> dict[str, list]:
    """The replay's rows (keyed by run and pedestrian index) grouped by what the person does:
    standing (velocity 0 in the scenario) or moving."""
    sc = recs[0]["scenario"]
    out: dict[str, list] = {}
    for key in rows:
        moving = any(sc.pedestrians[key[1]].velocity)
        out.setdefault("moving people" if moving else "standers", []).append(key)
    return out


def claims(recs: list[dict]) -> None:
    """The recorded (closed-loop) drives' own claims: per world, the closest approach to the
    attentive and the distracted pedestrian (Case I: its two people; Case II: its two runs' one),
    whether the distracted one was passed wider, and the runs with a true distance below R."""
    worlds: dict[int, dict] = {}
    below: list[str] = []  # the runs (seed/run) with a true distance below R
    for rec in recs:
        m = rec.get("metrics")
        if m is None:
            print("claims: a recording of an older --save without the drives' metrics")
            return
        run = {True: "attentive", False: "distracted", None: "both"}[rec["att"]]
        if m["margin_violations"] > 0:
            below.append(f"{rec['seed']}/{run}")
        w = worlds.setdefault(rec["seed"], {})
        for p in m["pedestrians"]:
            key = "attentive" if (p["attentive"] if rec["att"] is None else rec["att"]) else "distracted"
            w[key] = p["min_distance"]
    pairs = [(w["attentive"], w["distracted"]) for w in worlds.values() if len(w) == 2]
    wider = sum(d > a for a, d in pairs)
    gaps = " ".join(f"{s}:{w['distracted'] - w['attentive']:+.2f}" for s, w in sorted(worlds.items()) if len(w) == 2)
    closest = min(min(w.values()) for w in worlds.values())
    print(f"claims (recorded drives): distracted passed wider in {wider} of {len(pairs)} worlds; runs below R "
          f"{len(below)} of {len(recs)}{' (' + ' '.join(below) + ')' if below else ''}; closest {closest:.2f} m; "
          f"gaps {gaps}")  # fmt: skip


def _inside(b: np.ndarray) -> str:
    """Replay rows (inside track, inside raw, along / across of track and raw in sigmas, ...) as one
    summary: frames, truth inside, rms errors and the track's along q90 (1 where its core is calibrated)."""
    rms = np.sqrt(np.mean(b[:, 2:6] ** 2, axis=0))
    core = np.quantile(np.abs(b[:, 2]), 0.9) / 1.645
    track = f"track inside {b[:, 0].mean():.3f} (along {rms[0]:.2f}, across {rms[1]:.2f}; along q90 {core:.2f})"
    return f"{len(b)} frames, {track}, raw inside {b[:, 1].mean():.3f} (along {rms[2]:.2f}, across {rms[3]:.2f})"


ABLATIONS = {
    "as is": {},
    "standing only": {"switch_rate": 0.0, "initial_standing": 1.0},
    "independent frames": {"error_shared": 0.0},
    "standing shuffle / 10": {"standing_psd": 0.0005},
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="case-1", help="scenario (default case-1)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds (default 5)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--rate", type=float, help="camera frames per second (default: the scenario's)")
    ap.add_argument("--render", action="store_true", help="rendered frames on varied worlds (slow)")
    ap.add_argument("--save", type=Path, help="write the recorded drives to this file (pickle) for --load")
    ap.add_argument("--load", type=Path, nargs="+",
                    help="replay drives recorded by --save (one or several files, pooled), not driving")  # fmt: skip
    ap.add_argument(
        "--ablations",
        choices=("all", "none"),
        default="all",
        help="'none': replay only the sensing's configuration ('as is'; default all, see above)",
    )
    ap.add_argument(
        "--claims",
        action="store_true",
        help="also print the recorded drives' own claims (closest approaches, distracted passed wider)",
    )
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="replay with these LocaliserConfig / WorldTrackerConfig fields replaced")  # fmt: skip
    args = ap.parse_args(argv)
    loc_set, trk_set = {}, {}
    loc_fields = {f.name for f in dataclasses.fields(LocaliserConfig)}
    trk_fields = {f.name for f in dataclasses.fields(WorldTrackerConfig)}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            number = set_value(value)
        except ValueError:
            ap.error(f"--set {item!r}: expected KEY=NUMBER (or true / false)")
        if key in loc_fields:
            loc_set[key] = number
        elif key in trk_fields:
            trk_set[key] = int(number) if key == "confirm_hits" else number
        else:
            ap.error(f"--set {item!r}: {key!r} is no field of LocaliserConfig or WorldTrackerConfig")
    try:
        LocaliserConfig(**loc_set)
        WorldTrackerConfig(**trk_set)
    except (TypeError, ValueError) as exc:
        ap.error(f"--set: {exc}")
    if not 1 <= args.seeds <= 200:
        ap.error(f"--seeds must be in [1, 200], got {args.seeds}")
    t0 = time.perf_counter()
    if args.rate is not None and not 0 < args.rate <= 60:
        ap.error(f"--rate must be in (0, 60] frames per second, got {args.rate}")
    try:
        sc = load_drive_scenario(args.case)
    except (ValueError, FileNotFoundError) as exc:
        ap.error(f"--case {args.case!r}: {exc}")
    if args.load is not None:
        recs = []
        for path in args.load:
            try:
                with path.open("rb") as fh:
                    recs += pickle.load(fh)
            except (OSError, pickle.UnpicklingError, EOFError) as exc:
                ap.error(f"--load {str(path)!r}: not a recording of --save ({exc})")
    else:
        recs = [
            drive(args.case, seed, att, args.rate, args.render)
            for seed in range(args.first_seed, args.first_seed + args.seeds)
            for att in ([True, False] if sc.variants else [None])
        ]
    if args.save is not None:
        with args.save.open("wb") as fh:
            pickle.dump(recs, fh)
    if args.load is not None:  # what the recordings hold
        seeds = sorted({rec.get("seed", -1) for rec in recs})
        args.render = not all(rec["keypoints"] for rec in recs)
        args.first_seed, args.seeds = seeds[0], len(seeds)
        args.case = recs[0]["scenario"].name
    print(f"{args.case}, {'render' if args.render else 'keypoints'}, {args.rate or 'scenario'} frames/s, seeds "
          f"{args.first_seed}-{args.first_seed + args.seeds - 1}"
          + (f" ({args.seeds} recorded)" if args.load is not None else "")
          + f"; drives {time.perf_counter() - t0:.0f} s, "
          f"load {os.getloadavg()[0]:.1f}" + (f"; replayed with {' '.join(args.set)}" if args.set else ""))  # fmt: skip
    if args.claims:
        claims(recs)
    for name, ablation in ABLATIONS.items() if args.ablations == "all" else [("as is", {})]:
        rows: dict[tuple, list] = {}
        worlds: dict[int, list] = {}  # the track's inside per frame, per seed (world)
        for rec in recs:
            for j, r in replay(rec, {**trk_set, **ablation}, loc_set).items():
                rows.setdefault(
                    ("run " + {True: "attentive", False: "distracted", None: "both"}[rec["att"]], j), []
                ).extend(r)
                worlds.setdefault(rec.get("seed", -1), []).extend((0.0, 0.0, row[0]) for row in r)
        every = np.array([r for rs in rows.values() for r in rs], dtype=float).reshape(-1, 7)
        ci = coverage_interval([{"errors": e} for e in worlds.values()]) if len(every) else [math.nan] * 2
        print(
            f"{name}: track inside {every[:, 0].mean():.3f} (90 % interval over the {len(worlds)} worlds "
            f"{ci[0]:.3f}-{ci[1]:.3f}), raw inside {every[:, 1].mean():.3f} ({len(every)} frames)"
        )
        for label, keys in people_classes(recs, rows).items():
            b = np.array([r for k in keys for r in rows[k]], dtype=float).reshape(-1, 7)
            if len(b):
                print(f"  {label}: {_inside(b)}")
        for key in sorted(rows):
            b = np.array(rows[key], dtype=float)
            print(f"  {key[0]}, pedestrian {key[1]}: {_inside(b)}, walking probability median {np.median(b[:, 6]):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
