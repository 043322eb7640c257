"""Monocular ground-plane localisation on rendered frames: error against distance and coverage.

One pedestrian at known positions 5-30 m ahead of the drive's camera (case-1's camera and street,
-5..+5 m to the side, on the road and on the 0.13 m kerb; attentive, distracted and walking poses,
body yaws 0/90/180/270 deg +- 20 deg) is rendered, run through the perception pipeline (BlazePose,
a fresh tracker per image), matched to the truth by box overlap (for scoring only) and placed on
the ground by ``trustnav.perception.localisation.GroundLocaliser`` (default config, the street's
ground height). The same bodies also go through the keypoint sensing mode (``KeypointSensor.person``,
the scenario's noise) and the same localiser, side by side.

Printed per distance bin (true horizontal distance from the camera; 5-10, ..., 25-30 m) and
overall: detections, median and p95 of the position error (m), range error bias (estimated minus
true distance, median, m), lateral error median (m, across the line of sight), and the interval
coverage (share of estimates whose truth lies inside the 90 % region, Mahalanobis^2 <= 4.605).
With ``--calibration`` a third mode adds the calibrated keypoint noise model of
``benchmarks/calibrate_keypoints.py`` (its pixel model: per joint a bias offset_px + slope x H and a
sigma sqrt(s0^2 + (s1 x H)^2), left/right swaps) to the table (the figure shows the two modes).

    python benchmarks/localisation_eval.py --quick                   # ~70 images, ~40 s on 2 cores
    python benchmarks/localisation_eval.py --json benchmarks/data/localisation.json  # ~5 min, docs/img/localisation.png
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from calibrate_keypoints import POSE_LOOKS, Detector, Scene, jsonable, make_scene, match, placements
from trustnav.perception.localisation import GroundLocaliser
from trustnav.perception.types import Person
from trustnav.sim.driving.sensing import KeypointSensor
from trustnav.sim.driving.world import load_drive_scenario, street_of

ROOT = Path(__file__).resolve().parents[1]
FIGURE = ROOT / "docs" / "img" / "localisation.png"
BINS = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
CHI2_90 = 4.605
OFFSETS = (-5.0, -4.0, -2.25, -0.75, 0.75, 2.25, 4.0, 5.0)
DISTANCES = tuple(np.round(np.arange(5.5, 30.0, 1.5), 2))  # forward, m: 5.5, 7, ..., 29.5
QUICK_DISTANCES = (6.0, 9.0, 12.0, 16.0, 19.0, 23.0, 26.0, 29.0)
QUICK_OFFSETS = (-4.0, 0.75, 4.0)
MODES = ("render", "keypoints", "model")
FIGURE_MODES = ("render", "keypoints")  # the calibrated model of --calibration is printed, not drawn
MODE_LABELS = {
    "render": "rendered frames (BlazePose)",
    "keypoints": "keypoints mode (KeypointSensor)",
    "model": "keypoints, calibrated noise model",
}


class CalibratedNoise:
    """Keypoints from the calibration (calibrate_keypoints.py JSON) on the true projected joints:
    per joint and axis a bias offset_px + slope x H and Gaussian noise of sigma sqrt(s0^2 + (s1 x H)^2)
    px (H: the person's projected height), the left/right joints swapped with the measured
    probability; the box from the calibrated box-bottom / box-top offsets."""

    def __init__(self, doc: dict[str, Any], rng: np.random.Generator) -> None:
        from calibrate_keypoints import SWAP

        det = doc["detector"]
        pm = det["pixel_model"]
        names = list(pm)[:17]
        self.offset = np.array([[pm[n][a]["offset_px"] for a in "uv"] for n in names])
        self.slope = np.array([[pm[n][a]["slope"] for a in "uv"] for n in names])
        self.s0 = np.array([[pm[n][a]["sigma_px"] for a in "uv"] for n in names])
        self.s1 = np.array([[pm[n][a]["sigma_share"] for a in "uv"] for n in names])
        self.swap_p = float(det.get("lr_swapped") or 0.0)
        self.swap = SWAP
        sc = det["scalars"]["all"]
        self.box = {k: (sc[k]["median"], sc[k]["rsd"]) for k in ("box_bottom", "box_top")}
        self.rng = rng

    def person(self, scene: Scene, template: Person | None) -> Person | None:
        if template is None:  # not in view for the keypoint sensor: not for the model either
            return None
        hpx = scene.height_px
        sigma = np.sqrt(self.s0**2 + (self.s1 * hpx) ** 2)
        kp = scene.joints_uv + self.offset + self.slope * hpx + sigma * self.rng.normal(size=sigma.shape)
        if self.rng.random() < self.swap_p:
            kp[5:] = kp[self.swap[5:]]
        b0, bs = self.box["box_bottom"]
        t0, ts = self.box["box_top"]
        bottom = scene.sole_uv[1] + hpx * (b0 + bs * self.rng.normal())
        top = scene.head_uv[1] + hpx * (t0 + ts * self.rng.normal())
        box = np.array([kp[:, 0].min(), top, kp[:, 0].max() + 1.0, max(bottom, top + 2.0)])
        return Person(bbox=box, keypoints=kp, confidences=template.confidences, score=0.9)


def score(est: Any, scene: Scene) -> dict[str, Any]:
    """Errors of one estimate against the truth (None: no estimate)."""
    cam = scene.camera.position[:2]
    truth = scene.position
    rec: dict[str, Any] = {
        "range": scene.range_m,
        "distance": scene.placement.distance,
        "lateral": scene.placement.lateral,
        "pose": scene.placement.pose,
        "sidewalk": scene.sidewalk,
    }
    if est is None:
        return {**rec, "located": False}
    d = np.asarray(est.position, dtype=float) - truth
    los = (truth - cam) / np.linalg.norm(truth - cam)  # line of sight over the ground
    cov = np.asarray(est.covariance, dtype=float)
    m2 = float(d @ np.linalg.solve(cov, d))
    sd_range = float(math.sqrt(los @ cov @ los))
    return {
        **rec,
        "located": True,
        "error": float(np.hypot(*d)),
        "range_error": float(est.distance - scene.range_m),
        "lateral_error": float(abs(d @ np.array([-los[1], los[0]]))),
        "mahalanobis2": m2,
        "inside90": m2 <= CHI2_90,
        "sd_range": sd_range,
        "sd_major": float(math.sqrt(np.linalg.eigvalsh(0.5 * (cov + cov.T)).max())),
    }


def summary(recs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    seen = [r for r in recs if r.get("seen")]
    loc = [r for r in seen if r["located"]]
    out: dict[str, Any] = {"images": len(recs), "detected": len(seen), "located": len(loc)}
    if not loc:
        return out
    e = np.array([r["error"] for r in loc])
    re = np.array([r["range_error"] for r in loc])
    out.update(
        error_median=float(np.median(e)),
        error_p95=float(np.percentile(e, 95)),
        error_max=float(e.max()),
        range_bias=float(np.median(re)),
        range_mean=float(re.mean()),
        range_abs_median=float(np.median(np.abs(re))),
        lateral_median=float(np.median([r["lateral_error"] for r in loc])),
        coverage=float(np.mean([r["inside90"] for r in loc])),
        mahalanobis2_median=float(np.median([r["mahalanobis2"] for r in loc])),
        sd_range_median=float(np.median([r["sd_range"] for r in loc])),
    )
    return out


def binned(recs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    out = {}
    for lo, hi in itertools.pairwise(BINS):
        out[f"{lo:g}-{hi:g}"] = summary([r for r in recs if lo <= r["range"] < hi or (hi == BINS[-1] == r["range"])])
    out["all"] = summary(recs)
    return out


def print_table(results: dict[str, dict[str, Any]]) -> None:
    print("\n## Localisation error against distance (m; true horizontal distance from the camera)\n")
    print("| mode | distance (m) | images | detected | located | error median | error p95 | range bias (median) | "
          "lateral median | coverage (90 % region) | M^2 median (1.39 nominal) | range sd (median) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for mode, rows in results.items():
        for b, s in rows.items():
            if s.get("located", 0) == 0:
                print(f"| {mode} | {b} | {s['images']} | {s['detected']} | 0 | - | - | - | - | - | - | - |")
                continue
            print(f"| {mode} | {b} | {s['images']} | {s['detected']} | {s['located']} | {s['error_median']:.2f} | "
                  f"{s['error_p95']:.2f} | {s['range_bias']:+.2f} | {s['lateral_median']:.2f} | "
                  f"{s['coverage']:.2f} | {s['mahalanobis2_median']:.2f} | {s['sd_range_median']:.2f} |")  # fmt: skip


def draw(results: dict[str, dict[str, Any]], recs: dict[str, list[dict[str, Any]]], path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    colours = {"render": "#c0392b", "keypoints": "#2471a3", "model": "#7d8a2e"}
    fig = Figure(figsize=(11.0, 4.2), dpi=120)
    FigureCanvasAgg(fig)
    ax, bx = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1.0]})
    centres = [0.5 * (lo + hi) for lo, hi in itertools.pairwise(BINS)]
    keys = [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(BINS)]
    offsets = np.linspace(-0.3, 0.3, len(FIGURE_MODES))
    shown = [m for m in results if m in FIGURE_MODES]
    top = max(2.0, 1.4 * max(results[m][b].get("error_p95", 0.0) for m in shown for b in keys))
    for k, mode in enumerate(shown):
        c = colours[mode]
        pts = [r for r in recs[mode] if r.get("seen") and r["located"]]
        err = np.array([r["error"] for r in pts])
        ax.scatter([r["range"] for r in pts], np.minimum(err, top), s=5, color=c, alpha=0.25, lw=0)
        med = [results[mode][b].get("error_median", np.nan) for b in keys]
        p95 = [results[mode][b].get("error_p95", np.nan) for b in keys]
        ax.plot(centres, med, "-o", color=c, label=MODE_LABELS[mode])
        ax.plot(centres, p95, "--^", color=c, alpha=0.8)
        cov = [results[mode][b].get("coverage", np.nan) for b in keys]
        bx.plot(np.array(centres) + offsets[k], cov, "-o", color=c, label=MODE_LABELS[mode])
    ax.set_xlabel("true distance from the camera (m)")
    ax.set_ylabel("position error (m)")
    ax.set_xlim(BINS[0], BINS[-1])
    ax.set_ylim(0.0, top)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(
        f"Localisation error: median (solid), p95 (dashed), frames (dots; > {top:.1f} m at the top)", fontsize=10
    )
    bx.axhspan(0.8, 0.98, color="0.85", zorder=0, label="required 0.80-0.98")
    bx.axhline(0.9, color="0.3", lw=1, ls=":", label="nominal 0.90")
    bx.set_xlabel("true distance from the camera (bin)")
    bx.set_ylabel("interval coverage (share inside 90 % region)")
    bx.set_xticks(centres, [f"{k} m" for k in keys])
    low = min([results[m][b].get("coverage", 1.0) for m in shown for b in keys] + [0.55])
    bx.set_ylim(low - 0.05, 1.02)
    bx.grid(alpha=0.3, axis="y")
    bx.legend(fontsize=7, loc="lower left")
    bx.set_title("Coverage of the 90 % region", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="8 distances x 3 offsets x 3 poses (~70 images)")
    ap.add_argument("--repeats", type=int, default=1, help="images per (distance, offset, pose)")
    ap.add_argument("--seed", type=int, default=0, help="seed of placements and keypoint noise")
    ap.add_argument("--scenario", default="case-1", help="street and camera (default case-1)")
    ap.add_argument("--json", type=Path, help="write the tables to this file")
    ap.add_argument("--figure", type=Path, help=f"figure (PNG); default {FIGURE.relative_to(ROOT)} without --quick")
    ap.add_argument("--samples", action="store_true", help="also write every image's errors to the JSON")
    ap.add_argument("--calibration", type=Path, help="calibrate_keypoints.py JSON: add the calibrated noise model")
    ap.add_argument("--pitch-sigma", type=float, help="the localiser's pitch uncertainty (deg; default the scenario's)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    scenario = load_drive_scenario(args.scenario)
    street = street_of(scenario)
    if args.quick:
        grid = placements(QUICK_DISTANCES, QUICK_OFFSETS, tuple(POSE_LOOKS), max(1, args.repeats), rng)
    else:
        grid = placements(DISTANCES, OFFSETS, tuple(POSE_LOOKS), max(1, args.repeats), rng)
    # the scenario's localiser: its camera's pitch is known as the drive knows it (--pitch-sigma to change)
    # (rendered frames: the detector's feet bias modelled; keypoint sensing: none drawn)
    localisers = {}
    for mode in MODES:
        config = scenario.sensing.localiser(keypoints=mode != "render")
        if args.pitch_sigma is not None:
            config = replace(config, pitch_sigma_deg=args.pitch_sigma)
        localisers[mode] = GroundLocaliser(config)
    config = localisers["render"].config
    model = None
    if args.calibration:
        model = CalibratedNoise(json.loads(args.calibration.read_text()), np.random.default_rng(args.seed + 2))
    modes = [m for m in MODES if m != "model" or model is not None]
    recs: dict[str, list[dict[str, Any]]] = {m: [] for m in modes}
    print(f"{len(grid)} placements ({args.scenario} camera, seed {args.seed})", file=sys.stderr)
    t0 = time.perf_counter()
    det = Detector(scenario)
    sensor = KeypointSensor(scenario.sensing, np.random.default_rng(args.seed + 1), eye_model=det.pipeline.eye_model)
    skipped = 0
    try:
        for i, p in enumerate(grid):
            scene = make_scene(scenario, p)
            if not scene.in_view:
                skipped += 1
                continue
            people, _ = det(scene)
            person, _fp = match(people, scene)
            kp = sensor.person(scene.camera, scene.skeleton)
            found = {"render": person, "keypoints": kp}
            if model is not None:
                found["model"] = model.person(scene, kp)
            for mode in modes:
                who = found[mode]
                loc = localisers[mode]
                est = None if who is None else loc.locate(who, scene.camera, ground_height=street.ground_height)
                recs[mode].append({**score(est, scene), "seen": who is not None})
            if (i + 1) % 25 == 0:
                print(f"  {i + 1}/{len(grid)} images, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    finally:
        det.close()
    elapsed = time.perf_counter() - t0
    results = {m: binned(recs[m]) for m in modes}
    by_pose = {m: {pose: summary([r for r in recs[m] if r["pose"] == pose]) for pose in POSE_LOOKS} for m in modes}
    print(f"\n{len(grid)} placements, {skipped} partly out of view (skipped); {elapsed:.0f} s")
    print_table(results)
    for m in modes:
        a = results[m]["all"]
        if a.get("located"):
            print(f"- {m}: overall median {a['error_median']:.2f} m, p95 {a['error_p95']:.2f} m, coverage "
                  f"{a['coverage']:.2f} ({a['located']} estimates of {a['detected']} detections, {a['images']} "
                  f"images)")  # fmt: skip
    print("\n## By pose (body heights: attentive 1.76 m, distracted 1.72 m, walking 1.70 m)\n")
    print("| mode | pose | located | error median | error p95 | range bias (median) | coverage |")
    print("|---|---|---|---|---|---|---|")
    for m in modes:
        for pose, st in by_pose[m].items():
            if st.get("located"):
                print(f"| {m} | {pose} | {st['located']} | {st['error_median']:.2f} | {st['error_p95']:.2f} | "
                      f"{st['range_bias']:+.2f} | {st['coverage']:.2f} |")  # fmt: skip
    figure = args.figure or (None if args.quick else FIGURE)
    if figure is not None:
        draw(results, recs, figure)
        print(f"\nwrote {figure}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        doc = {
            "description": "GroundLocaliser on one pedestrian at known positions; errors in metres, bins by true "
            "horizontal distance from the camera; coverage = share with Mahalanobis^2 <= 4.605",
            "scenario": args.scenario,
            "seed": args.seed,
            "quick": args.quick,
            "placements": len(grid),
            "out_of_view": skipped,
            "localiser_config": config.__dict__,
            "results": results,
            "by_pose": by_pose,
            "seconds": elapsed,
        }
        if args.samples:
            doc["samples"] = {m: [compact(r) for r in recs[m]] for m in modes}
        args.json.write_text(json.dumps(jsonable(doc), indent=1))
        print(f"wrote {args.json}")


def compact(r: dict[str, Any]) -> dict[str, Any]:
    keys = ("range", "lateral", "pose", "sidewalk", "seen", "located", "error", "range_error", "lateral_error",
            "mahalanobis2", "sd_range")  # fmt: skip
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items() if k in keys}


if __name__ == "__main__":
    main()
