"""Calibrate the keypoint sensing mode's noise against the detector on rendered frames.

One pedestrian is placed at a grid of positions ahead of the drive's camera (case-1's camera and
street: ego heading -pi/2 along the road, the pedestrian 8-30 m ahead, -5..+5 m to the side, on the
road and on the 0.13 m kerb), in the poses of the Cases (attentive, distracted, walking) at random
sway times and body yaws 0/90/180/270 deg +- 20 deg. Each placement is rendered with PyBullet and
run through the project's perception pipeline (the person detector, BlazePose's landmarks on its
boxes; a fresh tracker per image, the backend in image mode keeps no state), the detected person is
matched to the true one by box overlap, and per COCO joint the residual detected - projected true
joint is measured in units of the person's projected height H (true head top to sole, pixels),
separately for u and v: mean and standard deviation, and the robust median and 1.4826 * MAD, near
(< 15 m) and far. Also: detection rate against distance, the bottom of the detector's box and
BlazePose's heel / foot-index landmarks against the true sole pixel, and the spread of H (and of the
person's apparent height in metres); left/right swaps; and a pixel model per joint (bias = offset px +
slope x H, sigma = sqrt(s0^2 + (s1 x H)^2), fitted across distances), the form a keypoint noise
model can copy.

The same placements also go through the keypoint sensor (KeypointSensor.person, the scenario's
noise) so that the two sit side by side.

    python benchmarks/calibrate_keypoints.py --quick                 # 36 images, ~20 s on 2 cores
    python benchmarks/calibrate_keypoints.py --json benchmarks/data/keypoint_calibration.json  # 384, ~5 min
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.geometry import CameraPose
from trustnav.perception.tracking import PersonTracker
from trustnav.perception.types import COCO_KEYPOINTS, Person, box_iou
from trustnav.sim.driving import body
from trustnav.sim.driving.sensing import KeypointSensor, make_render_sensing, projected_box
from trustnav.sim.driving.world import DriveScenario, load_drive_scenario, street_of

POSE_LOOKS = {"attentive": body.ATTENTIVE_LOOK, "distracted": body.DISTRACTED_LOOK, "walking": body.WALKER_LOOK}
PED_Y = 101.0  # the pedestrians' line of case-1 (m); the ego is placed behind it
NEAR_FAR = 15.0  # m: near below, far at or above
MAD_K = 1.4826
BLAZE_HEELS = (29, 30)
BLAZE_TOES = (31, 32)
ROAD_OFFSETS = (-5.0, -4.0, -2.25, -0.75, 0.75, 2.25, 4.0, 5.0)  # lateral, m, + = image right
CALIB_DISTANCES = (8.0, 11.0, 14.0, 17.0, 20.0, 23.0, 26.0, 30.0)
QUICK_DISTANCES = (8.0, 15.0, 22.0, 30.0)
QUICK_OFFSETS = (-4.0, -0.75, 4.0)


@dataclass(frozen=True)
class Placement:
    """One pedestrian relative to the camera: ``distance`` m ahead along the optical axis,
    ``lateral`` m to the image's right; pose, body yaw (deg), sway time and phase; the ego's
    sideways offset from the road's centre line (m)."""

    distance: float
    lateral: float
    pose: str
    yaw_deg: float
    t: float
    phase: float
    ego_offset: float


@dataclass
class Scene:
    """A placement made concrete: camera, body, and the true pixels of the person."""

    placement: Placement
    camera: CameraPose
    skeleton: body.Skeleton
    appearance: body.Appearance
    position: NDArray[np.float64]  # (2,) world x, y of the person (below the pelvis)
    ground: float  # height of the surface under the feet (m): 0 road, kerb on the sidewalk
    joints_uv: NDArray[np.float64]  # (17, 2) projected true joints
    sole_uv: NDArray[np.float64]  # (2,) projected ground point under the person
    head_uv: NDArray[np.float64]  # (2,) projected head top
    height_px: float  # H = sole v - head-top v
    range_m: float  # horizontal distance from the camera (m)
    depth_m: float  # depth of the sole point along the optical axis (m)
    in_view: bool  # every point of the body inside the image (2 px margin)

    @property
    def sidewalk(self) -> bool:
        return self.ground > 0.0


def placements(
    distances: Sequence[float],
    offsets: Sequence[float],
    poses: Sequence[str],
    repeats: int,
    rng: np.random.Generator,
    ego_jitter: float = 0.4,
) -> list[Placement]:
    """The grid (distance x lateral x pose x repeats); body yaws cycle through 0/90/180/270 deg
    (+- 20 deg), sway time, phase and the ego's lateral offset are random."""
    out = []
    k = 0
    for d in distances:
        for lat in offsets:
            for pose in poses:
                for _ in range(repeats):
                    yaw = 90.0 * (k % 4) + rng.uniform(-20.0, 20.0)
                    k += 1
                    out.append(
                        Placement(
                            distance=float(d),
                            lateral=float(lat),
                            pose=pose,
                            yaw_deg=float(yaw),
                            t=float(rng.uniform(0.0, 10.0)),
                            phase=float(rng.uniform(0.0, 1.0)),
                            ego_offset=float(rng.uniform(-ego_jitter, ego_jitter)),
                        )
                    )
    return out


def head_top(skeleton: body.Skeleton) -> NDArray[np.float64]:
    """The head-top point the sensing's boxes use (Skeleton.points)."""
    assert skeleton.head_centre is not None and skeleton.head_rot is not None
    return skeleton.head_centre + skeleton.head_rot[:, 2] * 0.13 * skeleton.height / 1.75


def make_scene(scenario: DriveScenario, p: Placement) -> Scene:
    """Camera (case-1's, ego heading -pi/2 on the road) and the posed body for a placement."""
    street = street_of(scenario)
    yaw = -0.5 * math.pi
    road_x = float(street.start[0])
    ego = np.array([road_x + p.ego_offset, PED_Y + p.distance + scenario.camera.forward])
    camera = scenario.camera.pose(ego, yaw)
    right = camera.right[:2]
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    xy = camera.position[:2] + p.distance * fwd + p.lateral * right
    ground = float(street.ground_height(xy))
    look = POSE_LOOKS[p.pose]
    target = None if p.pose == "distracted" else camera.position
    sk = body.pedestrian_skeleton(p.pose, (xy[0], xy[1], ground), math.radians(p.yaw_deg), p.t, look, look_at=target,
                                  phase=p.phase)  # fmt: skip
    return scene_of(camera, sk, look, xy, ground, p)


def scene_of(
    camera: CameraPose,
    sk: body.Skeleton,
    look: body.Appearance,
    xy: NDArray[np.float64],
    ground: float,
    p: Placement,
) -> Scene:
    joints_uv, _ = camera.project(sk.joints)
    (sole_uv, head_uv), depth = camera.project(np.array([[xy[0], xy[1], ground], head_top(sk)]))
    pts_uv, pts_depth = camera.project(sk.points())
    w, h = camera.spec.width, camera.spec.height
    with np.errstate(invalid="ignore"):
        inside = bool(
            np.all(pts_depth > 0.5)
            and np.all((pts_uv[:, 0] >= 2) & (pts_uv[:, 0] <= w - 3) & (pts_uv[:, 1] >= 2) & (pts_uv[:, 1] <= h - 3))
            and 2 <= sole_uv[1] <= h - 3
        )
    return Scene(
        placement=p,
        camera=camera,
        skeleton=sk,
        appearance=look,
        position=np.asarray(xy, dtype=float),
        ground=ground,
        joints_uv=joints_uv,
        sole_uv=sole_uv,
        head_uv=head_uv,
        height_px=float(sole_uv[1] - head_uv[1]),
        range_m=float(np.hypot(*(np.asarray(xy) - camera.position[:2]))),
        depth_m=float(depth[0]),
        in_view=inside,
    )


class Detector:
    """Renderer + perception pipeline of the render sensing mode, one unrelated image at a time:
    the backend runs in image mode (no state between frames) and the tracker is new per image."""

    def __init__(self, scenario: DriveScenario) -> None:
        self.renderer, self.pipeline = make_render_sensing(scenario)
        self.fps = float(scenario.camera.rate)

    def __call__(self, scene: Scene) -> tuple[list[Any], NDArray[np.uint8]]:
        frame = self.renderer.render(scene.camera, [(scene.skeleton, scene.appearance)])
        reset = getattr(self.pipeline.backend, "reset", None)
        if reset is not None:
            reset()
        self.pipeline.tracker = PersonTracker(fps=self.fps)
        return self.pipeline(frame), frame

    def close(self) -> None:
        self.renderer.close()
        self.pipeline.backend.close()


def match(people: Sequence[Any], scene: Scene, min_iou: float = 0.1) -> tuple[Person | None, int]:
    """The detected person overlapping the true projected box most (IoU >= min_iou) and the number
    of other detections (false positives)."""
    truth = projected_box(scene.camera, scene.skeleton)
    if truth is None or not people:
        return None, len(people)
    iou = [box_iou(tp.person.bbox, truth) for tp in people]
    k = int(np.argmax(iou))
    if iou[k] < min_iou:
        return None, len(people)
    return people[k].person, len(people) - 1


SWAP = np.array([0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15])  # COCO left <-> right


def view_class(scene: Scene) -> str:
    """'front', 'profile' or 'back': where the body faces relative to the camera."""
    to_cam = scene.camera.position[:2] - scene.position
    a = math.atan2(to_cam[1], to_cam[0]) - math.radians(scene.placement.yaw_deg)
    a = abs(math.degrees(math.atan2(math.sin(a), math.cos(a))))
    return "front" if a < 45.0 else "back" if a > 135.0 else "profile"


def residual_record(person: Person, scene: Scene, source: str) -> dict[str, Any]:
    """Residuals of one detection in units of H (detected - true)."""
    hpx = scene.height_px
    res = (person.keypoints - scene.joints_uv) / hpx
    box = person.bbox
    sensor_box = projected_box(scene.camera, scene.skeleton)
    rec: dict[str, Any] = {
        "source": source,
        "range": scene.range_m,
        "distance": scene.placement.distance,
        "lateral": scene.placement.lateral,
        "pose": scene.placement.pose,
        "sidewalk": scene.sidewalk,
        "height_px": hpx,
        "apparent_height_m": hpx * scene.depth_m / scene.camera.focal_px,
        "body_height_m": scene.skeleton.height,
        "sensor_box_height_px": None if sensor_box is None else float(sensor_box[3] - sensor_box[1]),
        "du": res[:, 0],
        "dv": res[:, 1],
        "conf": np.asarray(person.confidences, dtype=float),
        "box_bottom": (box[3] - scene.sole_uv[1]) / hpx,
        "box_top": (box[1] - scene.head_uv[1]) / hpx,
        "box_height": (box[3] - box[1]) / hpx,
        "box_centre_u": (0.5 * (box[0] + box[2]) - scene.sole_uv[0]) / hpx,
    }
    # keypoint body height (eyes/ears to ankles) as the localiser's height prior would see it
    top, ank = [1, 2, 3, 4], [15, 16]
    det_span = person.keypoints[ank, 1].mean() - person.keypoints[top, 1].mean()
    true_span = scene.joints_uv[ank, 1].mean() - scene.joints_uv[top, 1].mean()
    rec["span_ratio"] = float(det_span / true_span)
    # left/right confusion of the body joints (a person seen from behind or in profile)
    direct = np.nanmean(np.hypot(*(person.keypoints[5:] - scene.joints_uv[5:]).T))
    swapped = np.nanmean(np.hypot(*(person.keypoints[SWAP[5:]] - scene.joints_uv[5:]).T))
    rec["lr_swapped"] = bool(swapped < 0.5 * direct and direct > 0.02 * hpx)
    if rec["lr_swapped"]:
        fixed = (person.keypoints[SWAP] - scene.joints_uv) / hpx
        rec["du_fixed"], rec["dv_fixed"] = fixed[:, 0], fixed[:, 1]
    else:
        rec["du_fixed"], rec["dv_fixed"] = rec["du"], rec["dv"]
    rec["view"] = view_class(scene)
    lm = person.extra.get("blazepose")
    if lm is not None:
        rec["heel_v"] = float((lm[list(BLAZE_HEELS), 1].mean() - scene.sole_uv[1]) / hpx)
        rec["toe_v"] = float((lm[list(BLAZE_TOES), 1].mean() - scene.sole_uv[1]) / hpx)
        rec["foot_v"] = float((lm[[*BLAZE_HEELS, *BLAZE_TOES], 1].max() - scene.sole_uv[1]) / hpx)
    return rec


# ---------------------------------------------------------------- statistics


def robust(x: NDArray[np.float64]) -> dict[str, float]:
    """mean, sd, median, 1.4826 * MAD, p05, p95, n of the finite values."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"n": 0}
    med = float(np.median(x))
    return {
        "n": len(x),
        "mean": float(x.mean()),
        "sd": float(x.std(ddof=1)) if len(x) > 1 else 0.0,
        "median": med,
        "rsd": float(MAD_K * np.median(np.abs(x - med))),
        "p05": float(np.percentile(x, 5)),
        "p95": float(np.percentile(x, 95)),
    }


def joint_stats(recs: Sequence[dict[str, Any]], suffix: str = "") -> dict[str, Any]:
    """Per joint, u and v: robust stats; plus pooled groups (suffix "_fixed": left/right swaps undone)."""
    if not recs:
        return {}
    du = np.stack([r["du" + suffix] for r in recs])
    dv = np.stack([r["dv" + suffix] for r in recs])
    out: dict[str, Any] = {
        name: {"u": robust(du[:, j]), "v": robust(dv[:, j])} for j, name in enumerate(COCO_KEYPOINTS)
    }
    groups = {"face": range(5), "upper": range(5, 11), "hips_knees": range(11, 15), "ankles": range(15, 17)}
    groups_all = {**groups, "all": range(17), "all_but_ankles": range(15)}
    for g, idx in groups_all.items():
        idx = list(idx)
        # pooled after removing each joint's own bias: the sigma of a per-joint-bias model
        cu = du[:, idx] - np.nanmedian(du[:, idx], axis=0)
        cv = dv[:, idx] - np.nanmedian(dv[:, idx], axis=0)
        out[f"group:{g}"] = {
            "u": robust(du[:, idx].ravel()),
            "v": robust(dv[:, idx].ravel()),
            "u_debiased": robust(cu.ravel()),
            "v_debiased": robust(cv.ravel()),
        }
    # common mode: each image's mean residual over its joints, and what is left around it
    cm_u, cm_v = np.nanmean(du, axis=1), np.nanmean(dv, axis=1)
    bias_u, bias_v = np.nanmedian(du, axis=0), np.nanmedian(dv, axis=0)
    left_u = du - bias_u - (cm_u - np.nanmedian(cm_u))[:, None]
    left_v = dv - bias_v - (cm_v - np.nanmedian(cm_v))[:, None]
    out["common_mode"] = {"u": robust(cm_u), "v": robust(cm_v)}
    out["independent_after_common_mode"] = {"u": robust(left_u.ravel()), "v": robust(left_v.ravel())}
    return out


def scalar_stats(recs: Sequence[dict[str, Any]], keys: Sequence[str]) -> dict[str, Any]:
    return {k: robust(np.array([r[k] for r in recs if r.get(k) is not None], dtype=float)) for k in keys}


SCALARS = ("box_bottom", "box_top", "box_height", "box_centre_u", "span_ratio", "heel_v", "toe_v", "foot_v",
           "height_px", "apparent_height_m")  # fmt: skip


PIXEL_GROUPS: dict[str, list[int]] = {
    **{name: [j] for j, name in enumerate(COCO_KEYPOINTS)},
    "group:face": [0, 1, 2, 3, 4],
    "group:shoulders_hips": [5, 6, 11, 12],
    "group:elbows_wrists": [7, 8, 9, 10],
    "group:knees": [13, 14],
    "group:ankles": [15, 16],
    "group:all": list(range(17)),
    "group:all_but_ankles": list(range(15)),
}


def _line(h: NDArray[np.float64], r: NDArray[np.float64]) -> tuple[float, float]:
    """r = a + b h by least squares on the inliers (within 5 robust sigma of the median)."""
    med = np.median(r)
    rsd = MAD_K * np.median(np.abs(r - med))
    keep = np.abs(r - med) <= 5.0 * rsd if rsd > 0 else np.ones(len(r), dtype=bool)
    a, b = np.linalg.lstsq(np.column_stack([np.ones(keep.sum()), h[keep]]), r[keep], rcond=None)[0]
    return float(a), float(b)


def pixel_model(recs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per joint and axis, the residual in pixels as bias = offset_px + slope * H and spread
    sigma = sqrt(sigma_px^2 + (sigma_share * H)^2) (robust sigma per distance, fitted by NNLS);
    groups pool their joints after each joint's own bias line; ``outliers``: share of residuals
    beyond 4 sigma of the model."""
    from scipy.optimize import nnls

    if len(recs) < 10:
        return {}
    h = np.array([r["height_px"] for r in recs])
    dist = np.array([r["distance"] for r in recs])
    out: dict[str, Any] = {}
    for axis in ("u", "v"):
        res = np.stack([r["d" + axis] for r in recs]) * h[:, None]  # px
        lines = [_line(h, res[:, j]) for j in range(17)]
        err = res - np.array([[a + b * hh for a, b in lines] for hh in h])
        for name, idx in PIXEL_GROUPS.items():
            e = err[:, idx]
            hs, rs = [], []
            for d in np.unique(dist):
                sel = e[dist == d].ravel()
                if len(sel) >= 5:
                    hs.append(np.median(h[dist == d]))
                    rs.append(MAD_K * np.median(np.abs(sel - np.median(sel))))
            coef, _ = nnls(np.column_stack([np.ones(len(hs)), np.square(hs)]), np.square(rs))
            s0, s1 = math.sqrt(coef[0]), math.sqrt(coef[1])
            sig = np.sqrt(s0**2 + (s1 * h[:, None]) ** 2)
            a = float(np.mean([lines[j][0] for j in idx]))
            b = float(np.mean([lines[j][1] for j in idx]))
            out.setdefault(name, {})[axis] = {
                "offset_px": a,
                "slope": b,
                "sigma_px": s0,
                "sigma_share": s1,
                "outliers": float(np.mean(np.abs(e) > 4.0 * sig)),
            }
    return out


def summarise(recs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    near = [r for r in recs if r["range"] < NEAR_FAR]
    far = [r for r in recs if r["range"] >= NEAR_FAR]
    return {
        "n": len(recs),
        "joints": {"all": joint_stats(recs), "near": joint_stats(near), "far": joint_stats(far)},
        "joints_swaps_undone": {"all": joint_stats(recs, "_fixed")},
        "pixel_model": pixel_model(recs),
        "lr_swapped": float(np.mean([r["lr_swapped"] for r in recs])) if recs else None,
        "scalars": {
            "all": scalar_stats(recs, SCALARS),
            "near": scalar_stats(near, SCALARS),
            "far": scalar_stats(far, SCALARS),
        },
        "by_distance": {
            f"{d:g}": {
                **scalar_stats([r for r in recs if r["distance"] == d], SCALARS),
                "ankle_v": robust(np.concatenate([r["dv"][15:17] for r in recs if r["distance"] == d] or [[]])),
                "all_joints_v": robust(np.concatenate([r["dv"] for r in recs if r["distance"] == d] or [[]])),
                "all_joints_u": robust(np.concatenate([r["du"] for r in recs if r["distance"] == d] or [[]])),
            }
            for d in sorted({r["distance"] for r in recs})
        },
        "by_pose": {
            pose: {
                "ankle_v": robust(np.concatenate([r["dv"][15:17] for r in recs if r["pose"] == pose] or [[]])),
                "box_bottom": robust(np.array([r["box_bottom"] for r in recs if r["pose"] == pose])),
            }
            for pose in sorted({r["pose"] for r in recs})
        },
    }


# ---------------------------------------------------------------- run


def run(
    scenario: DriveScenario, grid: Sequence[Placement], seed: int, log: bool = True
) -> Iterator[tuple[Scene, Person | None, int, Person | None]]:
    """For each placement: the scene, the detected person (or None), false positives, and the
    keypoint sensor's person for the same body (its default noise, miss rate 0)."""
    det = Detector(scenario)
    sensor = KeypointSensor(scenario.sensing, np.random.default_rng(seed + 1), eye_model=det.pipeline.eye_model)
    t0 = time.perf_counter()
    try:
        for i, p in enumerate(grid):
            scene = make_scene(scenario, p)
            if not scene.in_view:
                yield scene, None, 0, None
                continue
            people, _ = det(scene)
            person, fp = match(people, scene)
            kp = sensor.person(scene.camera, scene.skeleton)
            if log and (i + 1) % 20 == 0:
                el = time.perf_counter() - t0
                print(f"  {i + 1}/{len(grid)} images, {el:.0f} s", file=sys.stderr, flush=True)
            yield scene, person, fp, kp
    finally:
        det.close()


def pct(x: float | None, digits: int = 1) -> str:
    return "   -" if x is None or not math.isfinite(x) else f"{100.0 * x:+.{digits}f}"


def print_tables(
    summary: dict[str, Any],
    kp_summary: dict[str, Any],
    det_rows: list[dict[str, Any]],
    by_kind: dict[str, dict[str, int]],
) -> None:
    print("\n## Detection rate against distance (person fully in view)\n")
    print("| distance ahead (m) | images | detected | rate | false positives | H (px) median | H range (px) |")
    print("|---|---|---|---|---|---|---|")
    for row in det_rows:
        print(f"| {row['distance']:g} | {row['images']} | {row['detected']} | {row['rate']:.2f} | "
              f"{row['false_positives']} | {row['height_px_median']:.0f} | "
              f"{row['height_px_min']:.0f}-{row['height_px_max']:.0f} |")  # fmt: skip
    cells = ", ".join(f"{k} {v['detected']}/{v['images']}" for k, v in by_kind.items())
    print(f"\nDetected by pose/view: {cells}")
    j = summary["joints"]
    print("\n## Detector - true joint, per COCO joint, % of H (head top to sole); bias = median, sd = 1.4826 MAD\n")
    print("| joint | u bias | u sd | v bias | v sd | u mean | u std | v mean | v std | near v bias | near v sd | "
          "far v bias | far v sd | keypoint mode v sd |")  # fmt: skip
    print("|---|" + "---|" * 13)
    for name in [*COCO_KEYPOINTS, "group:face", "group:upper", "group:hips_knees", "group:ankles", "group:all",
                 "group:all_but_ankles"]:  # fmt: skip
        a, n, f = j["all"].get(name), j["near"].get(name), j["far"].get(name)
        k = kp_summary["joints"]["all"].get(name)
        if a is None:
            continue

        def g(s: dict | None, axis: str, key: str) -> float | None:
            return None if not s or s[axis].get("n", 0) == 0 else s[axis][key]

        print(f"| {name} | {pct(g(a, 'u', 'median'))} | {pct(g(a, 'u', 'rsd'))} | {pct(g(a, 'v', 'median'))} | "
              f"{pct(g(a, 'v', 'rsd'))} | {pct(g(a, 'u', 'mean'))} | {pct(g(a, 'u', 'sd'))} | "
              f"{pct(g(a, 'v', 'mean'))} | {pct(g(a, 'v', 'sd'))} | {pct(g(n, 'v', 'median'))} | "
              f"{pct(g(n, 'v', 'rsd'))} | {pct(g(f, 'v', 'median'))} | {pct(g(f, 'v', 'rsd'))} | "
              f"{pct(g(k, 'v', 'rsd'))} |")  # fmt: skip
    for name in ("group:all", "group:all_but_ankles"):
        a = j["all"][name]
        print(f"- {name} after removing each joint's bias: u sd {pct(a['u_debiased']['rsd'])} %, "
              f"v sd {pct(a['v_debiased']['rsd'])} % (1.4826 MAD); std {pct(a['u_debiased']['sd'])} / "
              f"{pct(a['v_debiased']['sd'])} %")  # fmt: skip
    if summary.get("lr_swapped") is not None:
        fx = summary["joints_swaps_undone"]["all"]
        print(f"- left/right swapped (body joints): {100 * summary['lr_swapped']:.1f} % of detections; with the swaps "
              f"undone, all joints: u mean {pct(fx['group:all']['u']['mean'])} std {pct(fx['group:all']['u']['sd'])},"
              f" v mean {pct(fx['group:all']['v']['mean'])} std {pct(fx['group:all']['v']['sd'])}; after each "
              f"joint's bias: u std {pct(fx['group:all']['u_debiased']['sd'])}, v std "
              f"{pct(fx['group:all']['v_debiased']['sd'])} %")  # fmt: skip
    pm = summary.get("pixel_model") or {}
    if pm:
        print("\n## Pixel model per joint: bias = offset (px) + slope x H, sigma = sqrt(s0^2 + (s1 x H)^2)\n")
        print("| joint | v offset (px) | v slope (% H) | v s0 (px) | v s1 (% H) | v outliers | u offset (px) | "
              "u slope (% H) | u s0 (px) | u s1 (% H) | u outliers |")  # fmt: skip
        print("|---|" + "---|" * 10)
        for name, m in pm.items():
            v, u = m["v"], m["u"]
            print(f"| {name} | {v['offset_px']:+.2f} | {100 * v['slope']:+.2f} | {v['sigma_px']:.2f} | "
                  f"{100 * v['sigma_share']:.2f} | {100 * v['outliers']:.1f} % | {u['offset_px']:+.2f} | "
                  f"{100 * u['slope']:+.2f} | {u['sigma_px']:.2f} | {100 * u['sigma_share']:.2f} | "
                  f"{100 * u['outliers']:.1f} % |")  # fmt: skip
    cm, ind = j["all"]["common_mode"], j["all"]["independent_after_common_mode"]
    print(
        f"- common mode (per-image mean over the 17 joints): u sd {pct(cm['u']['rsd'])} %, v sd "
        f"{pct(cm['v']['rsd'])} %; left per joint: u sd {pct(ind['u']['rsd'])} %, v sd {pct(ind['v']['rsd'])} %"
    )
    print("\n## Box, feet and height against the truth (% of H unless stated; median [1.4826 MAD] (p05..p95))\n")
    print("| quantity | all | near < 15 m | far >= 15 m | keypoint mode (all) |")
    print("|---|---|---|---|---|")
    labels = {
        "box_bottom": "box bottom - sole v",
        "box_top": "box top - head-top v",
        "box_height": "box height / H (x100)",
        "box_centre_u": "box centre u - sole u",
        "heel_v": "BlazePose heels v - sole v",
        "toe_v": "BlazePose foot index v - sole v",
        "foot_v": "lowest foot landmark v - sole v",
        "span_ratio": "eyes/ears-to-ankles span, det / true (x100)",
        "height_px": "H (px, not %)",
        "apparent_height_m": "H x depth / f (m, not %)",
    }
    s = summary["scalars"]
    for key, label in labels.items():

        def cell(st: dict[str, Any], key: str = key) -> str:
            v = st.get(key)
            if not v or v.get("n", 0) == 0:
                return "-"
            if key in ("height_px", "apparent_height_m"):
                return f"{v['median']:.2f} [{v['rsd']:.2f}] ({v['p05']:.2f}..{v['p95']:.2f})"
            return f"{100 * v['median']:+.2f} [{100 * v['rsd']:.2f}] ({100 * v['p05']:+.1f}..{100 * v['p95']:+.1f})"

        print(f"| {label} | {cell(s['all'])} | {cell(s['near'])} | {cell(s['far'])} | "
              f"{cell(kp_summary['scalars']['all'])} |")  # fmt: skip
    print("\n## By distance (% of H: median [1.4826 MAD])\n")
    print("| distance (m) | n | ankles v | all joints v | all joints u | box bottom - sole | lowest foot lm - sole | "
          "span ratio |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for d, st in summary["by_distance"].items():

        def c(v: dict[str, Any]) -> str:
            return "-" if v.get("n", 0) == 0 else f"{100 * v['median']:+.2f} [{100 * v['rsd']:.2f}]"

        print(
            f"| {d} | {st['box_bottom'].get('n', 0)} | {c(st['ankle_v'])} | {c(st['all_joints_v'])} | "
            f"{c(st['all_joints_u'])} | {c(st['box_bottom'])} | {c(st['foot_v'])} | {c(st['span_ratio'])} |"
        )
    print("\n## By pose (% of H: median [1.4826 MAD])\n")
    for pose, st in summary["by_pose"].items():
        a, b = st["ankle_v"], st["box_bottom"]
        print(
            f"- {pose}: ankles v {100 * a['median']:+.2f} [{100 * a['rsd']:.2f}], box bottom - sole "
            f"{100 * b['median']:+.2f} [{100 * b['rsd']:.2f}] (n = {b['n']})"
        )


def jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else round(float(x), 5)
    if isinstance(x, np.integer):
        return int(x)
    return x


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 distances x 3 offsets x 3 poses, one each (~36 images)")
    ap.add_argument("--repeats", type=int, default=2, help="images per (distance, offset, pose) (full run)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the placements' random yaw, time, phase, ego offset")
    ap.add_argument("--scenario", default="case-1", help="street and camera (default case-1)")
    ap.add_argument("--json", type=Path, help="write the summary to this file")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    scenario = load_drive_scenario(args.scenario)
    poses = tuple(POSE_LOOKS)
    if args.quick:
        grid = placements(QUICK_DISTANCES, QUICK_OFFSETS, poses, 1, rng)
    else:
        grid = placements(CALIB_DISTANCES, ROAD_OFFSETS, poses, max(1, args.repeats), rng)
    print(f"{len(grid)} placements ({args.scenario} camera, seed {args.seed})", file=sys.stderr)
    t0 = time.perf_counter()
    det_recs, kp_recs, rows, by_kind = [], [], {}, {}
    out_of_view = 0
    for scene, person, fp, kp in run(scenario, grid, args.seed):
        d = scene.placement.distance
        if not scene.in_view:
            out_of_view += 1
            continue
        row = rows.setdefault(d, {"distance": d, "images": 0, "detected": 0, "false_positives": 0, "h": []})
        row["images"] += 1
        row["false_positives"] += fp
        row["h"].append(scene.height_px)
        kind = by_kind.setdefault(f"{scene.placement.pose}/{view_class(scene)}", [0, 0])
        kind[0] += 1
        if person is not None:
            kind[1] += 1
            row["detected"] += 1
            det_recs.append(residual_record(person, scene, "detector"))
        if kp is not None:
            kp_recs.append(residual_record(kp, scene, "keypoints"))
    elapsed = time.perf_counter() - t0
    det_rows = []
    for d in sorted(rows):
        r = rows[d]
        h = np.array(r.pop("h"))
        det_rows.append({**r, "rate": r["detected"] / max(1, r["images"]), "height_px_median": float(np.median(h)),
                         "height_px_min": float(h.min()), "height_px_max": float(h.max())})  # fmt: skip
    summary = summarise(det_recs)
    kp_summary = summarise(kp_recs)
    print(f"\n{len(grid)} placements, {out_of_view} partly out of view (skipped), {len(det_recs)} detections; "
          f"{elapsed:.0f} s")  # fmt: skip
    detection_by_kind = {k: {"images": v[0], "detected": v[1]} for k, v in sorted(by_kind.items())}
    print_tables(summary, kp_summary, det_rows, detection_by_kind)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        doc = {
            "description": "detector (YOLOX-Nano boxes, BlazePose landmarks, rendered frames) - true projected "
            "joints, in units of the person's projected height H (head top to sole, px); bias = median, "
            "rsd = 1.4826 MAD",
            "scenario": args.scenario,
            "seed": args.seed,
            "quick": args.quick,
            "placements": len(grid),
            "out_of_view": out_of_view,
            "grid": {
                "distances": sorted({p.distance for p in grid}),
                "offsets": sorted({p.lateral for p in grid}),
                "poses": list(poses),
            },
            "detection": det_rows,
            "detection_by_pose_view": detection_by_kind,
            "detector": summary,
            "keypoint_sensor": kp_summary,
            "seconds": elapsed,
        }
        args.json.write_text(json.dumps(jsonable(doc), indent=1))
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
