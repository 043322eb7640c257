"""How well the rendered sensor places people the image's edge cuts (issue 34: rendered Case II world 705).

A person whose box the image's edge cuts (beside the camera as the car passes, or so near that the
feet fall below the image) is seen in part: the landmark model guesses at the rest from a region
the image's border crops. On rendered drives those placements were the least honest of all (truth
inside the 90 % region in 0.70 of 57 such frames against 0.90 of the rest, errors of 2-3 sigma
along the line of sight; a walker found again cut off beside the stopped car was placed 0.33 m off
with a sigma of 0.04 m and passed at 2.28 m).

One pedestrian is placed ahead of case-1's camera, on a random draw of places where the image cuts
her: at its left or right edge (2.5-12 m ahead, her centre 0.6 m inside to 0.4 m outside the
edge's ray), or below it (2-4.3 m ahead: the feet out of the image), and, as a control, whole in the
image 4.5-12 m ahead; random pose (the Cases' three), body yaw, sway. Each image is rendered and
run through the render sensing's pipeline, the detection matched to her by box overlap and placed by
the render sensing's localiser; its error is whitened by its own sigma along and across the line of
sight. For each ``cut_range_share`` of a grid (``LocaliserConfig``: the range's sigma of a body the
image's edge cuts, as a share of its distance, added along the line of sight), without and with a
``cut_body_sigma`` (where the cut body's centre is, isotropic), the script prints the truth's share
inside the 90 % region and the whitened rms of the cut placements, on two disjoint draws (``--seed``
and ``--seed + 1``): the share is chosen on the first (the smallest whose coverage reaches 0.90
with the body's sigma) and judged on the second.

    python benchmarks/cut_bodies.py                 # 2 x 160 images, ~4 min on 2 cores
    python benchmarks/cut_bodies.py --images 40     # quick look
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibrate_keypoints import Detector, Placement, make_scene, match
from trustnav.perception.localisation import GroundLocaliser, LocaliserConfig, chi2_90, cut_by_image
from trustnav.sim.driving.world import load_drive_scenario, street_of

SHARES = (0.0, 0.05, 0.1, 0.12, 0.15, 0.2, 0.25)
BODY = (0.0, 0.05)  # cut_body_sigma, m
POSES = ("attentive", "distracted", "walking")


def draw(n: int, rng: np.random.Generator, half_fov: float) -> list[tuple[str, Placement]]:
    """``n`` placements: a third cut by the left or right edge, a third by the bottom, a third whole."""
    out = []
    for k in range(n):
        kind = ("side", "bottom", "whole")[k % 3]
        if kind == "side":
            d = float(rng.uniform(2.5, 12.0))
            lateral = float(rng.choice([-1.0, 1.0])) * (d * math.tan(half_fov) + float(rng.uniform(-0.6, 0.4)))
        elif kind == "bottom":
            d = float(rng.uniform(2.0, 4.3))
            lateral = float(rng.uniform(-0.5, 0.5)) * d * math.tan(half_fov)
        else:
            d = float(rng.uniform(4.5, 12.0))
            lateral = float(rng.uniform(-0.6, 0.6)) * d * math.tan(half_fov)
        p = Placement(distance=d, lateral=lateral, pose=str(rng.choice(POSES)), yaw_deg=float(rng.uniform(0, 360)),
                      t=float(rng.uniform(0.0, 10.0)), phase=float(rng.uniform(0.0, 1.0)),
                      ego_offset=float(rng.uniform(-0.4, 0.4)))  # fmt: skip
        out.append((kind, p))
    return out


def detections(scenario, grid: list[tuple[str, Placement]]) -> list[tuple[str, object, object]]:
    """(kind, scene, detected person) of every placement whose person was detected."""
    det = Detector(scenario)
    out = []
    t0 = time.perf_counter()
    try:
        for i, (kind, p) in enumerate(grid):
            scene = make_scene(scenario, p)
            people, _ = det(scene)
            person, _ = match(people, scene)
            if person is not None:
                out.append((kind, scene, person))
            if (i + 1) % 40 == 0:
                print(f"  {i + 1}/{len(grid)} images, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    finally:
        det.close()
    return out


def whitened(scenario, found, share: float, body: float) -> np.ndarray:
    """Per detection: (cut, inside the 90 % region, along / sigma, across / sigma, error m, range m)."""
    cfg = dataclasses.replace(scenario.sensing.localiser(False), cut_range_share=share, cut_body_sigma=body)
    loc = GroundLocaliser(cfg)
    ground = street_of(scenario).ground_height
    rows = []
    for _kind, scene, person in found:
        e = loc.locate(person, scene.camera, ground)
        if e is None:
            continue
        w, h = scene.camera.spec.width, scene.camera.spec.height
        d = e.position - scene.position
        u = (scene.position - scene.camera.position[:2]) / scene.range_m
        n = np.array([-u[1], u[0]])
        cov = e.covariance
        rows.append((cut_by_image(person.bbox, w, h), float(d @ np.linalg.solve(cov, d)) <= chi2_90,
                     d @ u / math.sqrt(u @ cov @ u), d @ n / math.sqrt(n @ cov @ n), float(np.hypot(*d)),
                     scene.range_m))  # fmt: skip
    return np.array(rows, dtype=float).reshape(-1, 6)


def table(name: str, scenario, found) -> dict[tuple[float, float], float]:
    print(f"{name}: {len(found)} detections")
    coverage = {}
    for b, s in itertools.product(BODY, SHARES):
        r = whitened(scenario, found, s, b)
        c, whole = r[r[:, 0] == 1], r[r[:, 0] == 0]
        coverage[s, b] = float(c[:, 1].mean()) if len(c) else math.nan
        print(f"  cut_range_share {s:4.2f}, cut_body_sigma {b:4.2f}: cut by the edge {len(c):3d}: inside "
              f"{coverage[s, b]:.3f}, rms along "
              f"{np.sqrt(np.mean(c[:, 2] ** 2)):.2f} across {np.sqrt(np.mean(c[:, 3] ** 2)):.2f}, error median "
              f"{np.median(c[:, 4]):.2f} m;  whole {len(whole):3d}: inside {whole[:, 1].mean():.3f}")  # fmt: skip
    return coverage


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=160, help="placements per draw (default 160)")
    ap.add_argument("--seed", type=int, default=0, help="the fit's draw; the judged one is seed + 1")
    args = ap.parse_args(argv)
    if args.images < 3:
        ap.error(f"--images {args.images}: expected at least 3 (a third of each kind)")
    scenario = load_drive_scenario("case-1")
    half = math.radians(0.5 * scenario.camera.fov_deg)
    fit = table(f"fit draw (seed {args.seed})", scenario,
                detections(scenario, draw(args.images, np.random.default_rng([args.seed, 705]), half)))  # fmt: skip
    chosen = next((s for s in SHARES if fit[s, BODY[-1]] >= 0.90), SHARES[-1])
    print(
        f"chosen: cut_range_share {chosen} with cut_body_sigma {BODY[-1]} (the smallest share whose cut "
        f"placements' coverage reaches 0.90; the localiser's defaults: {LocaliserConfig().cut_range_share}, "
        f"{LocaliserConfig().cut_body_sigma})"
    )
    table(f"judged draw (seed {args.seed + 1})", scenario,
          detections(scenario, draw(args.images, np.random.default_rng([args.seed + 1, 705]), half)))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
