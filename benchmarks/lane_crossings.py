"""Random lane crossings: does the car stay on the road, keep R and get through, whoever crosses?

Samples ``--runs`` variants of ``examples/scenarios/lane-crossing.toml`` (seeded): the crosser
starts on either sidewalk, 3.5-6 m from the road's line, 5-35 m ahead of the car, steps out after
0-3 s and crosses at 0.5-1.8 m/s, attentive or distracted; the car starts at 0-8 m/s; in half of
the runs a second pedestrian stands on a kerb near the crossing. Keypoint sensing, perceived
pedestrian states (the default drive). Prints the runs that left the road, came within R or did not
reach the goal, the medians of time to goal and time spent yielding, and the crosser's identity
switches and the coverage of her track's 90 % region (:func:`tracking`). Of the runs within R it
counts those that could have stopped R short of the crosser's path, braking at the vehicle's limit
after one control step and the actuation latency, (a) from the moment she stepped out (as if the
car knew at once) and (b) from the moment a sensor could have shown it (:func:`shown_at`: the camera,
or the near-field sensor where there is one). It also
lists the runs whose car stopped turned off its lane, and those whose car, after braking to a stop,
moved with her ahead within R of its heading line (:func:`stop_and_go`).

    python benchmarks/lane_crossings.py               # 100 runs, ~2 min on 2 cores
    python benchmarks/lane_crossings.py --runs 20 --state true
    python benchmarks/lane_crossings.py --rate 10      # the camera at 10 frames/s
    python benchmarks/lane_crossings.py --caution off  # without the trust-aware speed bound
    python benchmarks/lane_crossings.py --seed 1       # 100 other worlds
    python benchmarks/lane_crossings.py --only 22 70 --set caution_unseen_frames=1
    python benchmarks/lane_crossings.py --set caution_occlusion=false  # the tracker's regions alone
    python benchmarks/lane_crossings.py --wait --rate 10   # the scenario's own attentive crossing, seeds 0-4
    python benchmarks/lane_crossings.py --near-range 10    # with a near-field sensor around the car's front
    python benchmarks/lane_crossings.py --near-range 10 --near-clutter 1   # it also returns poles, bins: 1 per 10 m

``--wait`` drives the scenario file itself, the crosser attentive (``trustnav drive
examples/scenarios/lane-crossing.toml --attentive --sensing keypoints --seed S``), with perceived and
with true states, and prints each seed's time to goal: how long the car waits for a crosser it can no
longer see (issue 34, item 5).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np

from trustnav.sim.driving import load_drive_scenario, run_drive
from trustnav.sim.driving.behaviour import BehaviourSpec
from trustnav.sim.driving.sensing import NearField

ROOT = Path(__file__).resolve().parents[1]


def variant(base, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    """One random crossing on ``base``'s road (module docstring)."""
    road_x = 34.25  # the road's line near the crossing (x = 34.65 at y = 140, 33.85 at y = 60)
    side = rng.choice([-1.0, 1.0])
    y = float(base.ego_start[1] - rng.uniform(5.0, 35.0))
    start = (road_x + side * rng.uniform(3.5, 6.0), y)
    speed = float(rng.uniform(0.5, 1.8))
    far = (road_x - side * 6.0, y)
    attentive = bool(rng.random() < 0.5)
    crosser = dataclasses.replace(
        base.pedestrians[0],
        position=start,
        velocity=(0.0, 0.0),
        attentive=attentive,
        pose="walking" if attentive else "distracted",
        look_at_camera=attentive,
        body_yaw_deg=180.0 if side > 0 else 0.0,
        alternative=(),
        behaviour=BehaviourSpec(waypoints=(far,), speed=speed, start_time=float(rng.uniform(0.0, 3.0))),
    )
    peds = [crosser]
    if rng.random() < 0.5:
        kerb = (road_x + rng.choice([-1.0, 1.0]) * rng.uniform(3.2, 4.5), y + float(rng.uniform(-8.0, 8.0)))
        peds.append(dataclasses.replace(base.pedestrians[0], name="bystander", position=kerb, velocity=(0.0, 0.0),
                                        attentive=True, pose="attentive", body_yaw_deg=90.0, alternative=(),
                                        behaviour=None))  # fmt: skip
    return dataclasses.replace(base, pedestrians=tuple(peds), ego_speed=float(rng.uniform(0.0, 8.0)),
                               variants=())  # fmt: skip


#: How far (m) she must be from her standing place for one frame to show that she moved: the keypoint
#: sensor's p95 error of one placement (0.53 m, docs/perceived.md); nearer, the move is within the noise.
MEASURABLE = 0.5


def _room_from(sc, r, t: float) -> float:  # type: ignore[no-untyped-def]
    """How far short of R from the crosser's path the car could stop, braking at the vehicle's limit
    after one control step and the actuation latency from time ``t`` (negative: it could not)."""
    k = min(int(np.searchsorted(r.times, t - 1e-9)), len(r.times) - 1)
    _, y, _, v = r.ego[k]
    ahead = y - sc.pedestrians[0].position[1]  # the car drives toward -y
    react = sc.vehicle.latency + 1.0 / sc.control.rate
    stop = v * react + v * v / (2.0 * abs(sc.vehicle.accel_min))
    return float(ahead - sc.control.safety_radius - stop)


def shown_at(sc, r) -> float | None:  # type: ignore[no-untyped-def]
    """When a sensor could first have shown the controller that the crosser stepped out: the first
    camera frame captured at or after her step-out that observed her at least ``MEASURABLE`` from her
    standing place, plus the perception latency (``FrameReport.known_at``); with a near-field sensor
    (``[sensing] near_range``), also its first scan at or after her step-out that the car was slow
    enough to take with her inside its field and that far from her standing place (its returns lie
    within ``near_sigma`` of her), plus the same latency; the earlier of the two. None if neither did."""
    start = np.asarray(sc.pedestrians[0].position, dtype=float)
    t0 = sc.pedestrians[0].behaviour.start_time
    shown = None
    for f in r.frames:
        v = f.views[0]
        if f.time >= t0 - 1e-9 and v.observed and v.position is not None:
            if float(np.hypot(*(np.asarray(v.position) - start))) >= MEASURABLE:
                shown = float(f.known_at)
                break
    near = NearField.of(sc.sensing)
    if near is None:
        return shown
    scans = 0  # the drive's scan slots: one each 1 / rate s, taken only while the car is slow
    lag = sc.sensing.perception_latency
    for t, ego, her in zip(r.times, r.ego, r.pedestrians[:, 0], strict=True):
        if shown is not None and t + lag >= shown:
            break
        if t + 1e-9 < scans / near.rate:
            continue
        scans += 1
        if t >= t0 - 1e-9 and ego[3] <= near.max_speed and near.covers(ego, her):
            if float(np.hypot(*(her - start))) >= MEASURABLE:
                return float(t) + lag
    return shown


#: chi^2 with 2 degrees of freedom, 90 %: the truth inside the 90 % region of a 2-D estimate.
CHI2_90 = 4.605


def tracking(r) -> tuple[int, int, int]:  # type: ignore[no-untyped-def]
    """The crosser's identity switches (her world track changing between the frames that observed
    her), the frames that observed her, and of those the frames whose track's 90 % region held her
    true position."""
    switches, seen, covered, last = 0, 0, 0, None
    for f in r.frames:
        v = f.views[0]
        if not v.observed or v.track_id is None:
            continue
        seen += 1
        switches += last is not None and v.track_id != last
        last = v.track_id
        if v.estimate is not None and v.estimate_cov is not None and v.position is not None:
            d = np.asarray(v.position) - np.asarray(v.estimate)[:2]
            covered += float(d @ np.linalg.solve(np.asarray(v.estimate_cov)[:2, :2], d)) <= CHI2_90
    return switches, seen, covered


#: How slow (m/s) a car counts as stopped, and how far (deg) off its lane's heading it counts as turned.
STOPPED, TURNED = 0.3, 10.0
#: How far ahead (m) a crosser on the car's heading line counts as in its way once it has stopped.
NEAR = 10.0


def stop_and_go(sc, r) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """The car's largest turn (deg) off its lane's heading while stopped, and its fastest speed (m/s)
    while the crosser is ahead of it, within ``NEAR`` m and within R of the line it heads along, after
    it has braked to a stop (a car that restarts or creeps toward her: 0 if none)."""
    lane = np.asarray(sc.goal, dtype=float) - np.asarray(sc.ego_start, dtype=float)
    psi = float(np.arctan2(lane[1], lane[0]))
    yaw, v = r.ego[:, 2], r.ego[:, 3]
    off = np.degrees(np.abs((yaw - psi + np.pi) % (2 * np.pi) - np.pi))
    stopped = v < STOPPED
    turned = float(off[stopped].max()) if stopped.any() else 0.0
    rel = r.pedestrians[:, 0, :] - r.ego[:, :2]
    fwd = rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw)
    side = np.abs(rel[:, 1] * np.cos(yaw) - rel[:, 0] * np.sin(yaw))
    after = np.cumsum(stopped & (np.cumsum(~stopped) > 0)) > 0  # stopped after moving
    toward = after & (fwd > 0) & (fwd < NEAR) & (side < sc.control.safety_radius) & (v >= STOPPED)
    return turned, float(v[toward].max()) if toward.any() else 0.0


def brake_room(sc, r) -> tuple[float, float | None]:  # type: ignore[no-untyped-def]
    """The braking room (:func:`_room_from`) (a) from the moment she stepped out (the car knew at
    once) and (b) from the moment a sensor could have shown it (:func:`shown_at`; None: never)."""
    shown = shown_at(sc, r)
    return _room_from(sc, r, sc.pedestrians[0].behaviour.start_time), (
        None if shown is None else _room_from(sc, r, shown)
    )


def wait(base, rate: float | None, seeds: int) -> None:  # type: ignore[no-untyped-def]
    """The scenario's own crossing, the crosser attentive, seeds 0..seeds-1: time to goal, closest
    approach and seconds yielded, with perceived and with true states (module docstring)."""
    print(f"(1-minute load average {os.getloadavg()[0]:.1f})")
    for state in ("perceived", "true"):
        out = []
        for s in range(seeds):
            m = run_drive(base, sensing="keypoints", seed=s, attentive=True, capture_rate=rate, state=state).metrics()
            out.append(f"{m['time_to_goal']} s ({min(p['min_distance'] for p in m['pedestrians']):.2f} m, "
                       f"yield {m['yield_s']} s, {m['margin_violations']} within R)")  # fmt: skip
        print(f"attentive lane crossing, {state} states, {rate or base.camera.rate:g} frames/s, seeds 0-{seeds - 1}: "
              + "; ".join(out))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--state", choices=["perceived", "true"], default="perceived")
    ap.add_argument("--rate", type=float, help="camera frames per second (default: the scenario's, 1)")
    ap.add_argument("--caution", choices=["on", "off"], help="the trust-aware speed bound (default: on)")
    ap.add_argument("--set", nargs="*", default=[], help="[control] options, e.g. caution_pass_speed=3")
    ap.add_argument("--only", type=int, nargs="+", help="drive only these runs (their worlds as in the full set)")
    ap.add_argument("--json", help="write every run's summary to this file")
    ap.add_argument(
        "--near-range",
        type=float,
        help="[sensing] near_range, m: a near-field sensor (default: the file's, none)",
    )
    ap.add_argument(
        "--near-max-speed",
        type=float,
        help="[sensing] near_max_speed, m/s: it scans up to this speed (default: 3; inf: at any speed)",
    )
    ap.add_argument(
        "--near-clutter",
        type=float,
        help="[sensing] near_clutter: objects per 10 m of sidewalk it returns (default: 0)",
    )
    ap.add_argument("--wait", action="store_true", help="the scenario's own attentive crossing, seeds 0-4 (--runs)")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error(f"--runs {args.runs}: expected a whole number of runs >= 1")
    if args.rate is not None and not (math.isfinite(args.rate) and args.rate > 0):
        ap.error(f"--rate {args.rate}: expected camera frames per second > 0")
    base = load_drive_scenario(ROOT / "examples" / "scenarios" / "lane-crossing.toml")
    if args.near_range is not None and not 0 <= args.near_range <= 30:
        ap.error(f"--near-range {args.near_range:g}: expected metres in [0, 30]")
    if args.near_max_speed is not None and not args.near_max_speed >= 0:  # the park-assist gate; inf: any speed
        ap.error(f"--near-max-speed {args.near_max_speed:g}: expected m/s >= 0 (inf: at any speed)")
    if args.near_clutter is not None and not 0 <= args.near_clutter <= 20:
        ap.error(f"--near-clutter {args.near_clutter:g}: expected objects per 10 m of sidewalk in [0, 20]")
    near = {"near_range": args.near_range, "near_max_speed": args.near_max_speed, "near_clutter": args.near_clutter}
    base = base.with_options(sensing=near)
    if args.wait:
        wait(base, args.rate, min(args.runs, 5))
        return
    sets: dict[str, float | bool] = {}
    for kv in args.set:  # checked once, before any drive: a bad option is one line naming it
        key, eq, value = kv.partition("=")
        try:
            flag = {"true": True, "false": False}.get(value.lower())
            sets[key] = flag if flag is not None else float(value) if eq else float("nan")
            dataclasses.replace(base.control, **sets)
        except (TypeError, ValueError) as exc:  # SchemaError is a ValueError
            ap.error(f"--set {kv!r}: {exc} (expected [control] OPTION=NUMBER, or true/false)")
    rng = np.random.default_rng(args.seed)
    rows = []
    for k in range(args.runs):
        sc = variant(base, rng)
        if args.only is not None and k not in args.only:
            continue
        if args.caution is not None:
            sc = dataclasses.replace(sc, control=dataclasses.replace(sc.control, caution=args.caution == "on"))
        if sets:
            sc = dataclasses.replace(sc, control=dataclasses.replace(sc.control, **sets))
        r = run_drive(sc, sensing="keypoints", seed=k, state=args.state, capture_rate=args.rate)
        m = r.metrics()
        room_a, room_b = brake_room(sc, r)
        shown = shown_at(sc, r)
        switches, seen, covered = tracking(r)
        turned, toward = stop_and_go(sc, r)
        rows.append({
            "run": k, "attentive": sc.pedestrians[0].attentive, "ego_speed": round(sc.ego_speed, 2),
            "reached_goal": m["reached_goal"], "time_to_goal": m["time_to_goal"],
            "road_departure_max": m["road_departure_max"], "margin_violations": m["margin_violations"],
            "closest_m": min(p["min_distance"] for p in m["pedestrians"]), "yield_s": m["yield_s"],
            "relaxed_steps": m["relaxed_steps"], "brake_room_m": round(room_a, 2),
            "brake_room_shown_m": None if room_b is None else round(room_b, 2),
            "steps_out_s": round(sc.pedestrians[0].behaviour.start_time, 2),
            "shown_s": None if shown is None else round(shown, 2), "crosser_speed": sc.pedestrians[0].behaviour.speed,
            "id_switches": switches, "frames_observed": seen, "frames_covered": covered,
            "stopped_turned_deg": round(turned, 1), "toward_her_mps": round(toward, 2),
        })  # fmt: skip
    off = [r for r in rows if r["road_departure_max"] > 0]
    inside = [r for r in rows if r["margin_violations"] > 0]
    stuck = [r for r in rows if not r["reached_goal"]]
    ttg = [r["time_to_goal"] for r in rows if r["time_to_goal"] is not None]
    rate = args.rate or base.camera.rate
    print(f"(1-minute load average {os.getloadavg()[0]:.1f})")
    print(f"{len(rows)} random lane crossings ({args.state} states, keypoint sensing at {rate:g} frames/s, "
          f"seed {args.seed})")  # fmt: skip
    avoidable = [r for r in inside if r["brake_room_m"] >= 0]
    shown = [r for r in inside if r["brake_room_shown_m"] is not None and r["brake_room_shown_m"] >= 0]
    print(f"  off the road: {len(off)}  within R: {len(inside)}  goal not reached: {len(stuck)}")
    print(f"  of those within R, could have stopped R short braking at the limit (a) from her step-out: "
          f"{len(avoidable)}, (b) from when a sensor could show it: {len(shown)}")  # fmt: skip
    print(f"  closest approach {min(r['closest_m'] for r in rows):.2f} m (R = {base.control.safety_radius} m)")
    yielded = [r["yield_s"] for r in rows]
    ttg = ttg or [float("nan")]  # none reached the goal (--only)
    print(f"  time to goal median {np.median(ttg):.1f} s, p90 {np.percentile(ttg, 90):.1f} s; yielded in "
          f"{sum(y > 0 for y in yielded)} runs, median {np.median(yielded):.1f} s")  # fmt: skip
    seen = sum(r["frames_observed"] for r in rows)
    print(f"  the crosser's track: {sum(r['id_switches'] for r in rows)} identity switches in "
          f"{sum(r['id_switches'] > 0 for r in rows)} runs; her 90 % region held her in "
          f"{sum(r['frames_covered'] for r in rows) / max(seen, 1):.3f} of {seen} frames observing her")  # fmt: skip
    turned = [r for r in rows if r["stopped_turned_deg"] > TURNED]
    toward = [r for r in rows if r["toward_her_mps"] > 0]
    print(f"  stopped turned more than {TURNED:g} deg off the lane: {len(turned)} runs "
          f"{[r['run'] for r in turned]}; moved toward her (within {NEAR:g} m ahead, R of its heading "
          f"line) after stopping: {len(toward)} runs {[(r['run'], r['toward_her_mps']) for r in toward]}")  # fmt: skip
    for r in off + inside + stuck:
        print("  ", json.dumps(r))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
