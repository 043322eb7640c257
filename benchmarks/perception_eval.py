"""Prints the perception figures the tests assert, against the hand-made ground truth.

Ground truth: ``tests/data/perception_truth.json`` (boxes and paths drawn by hand on the shared
images). Prints: pedestrians found per street image and false boxes; eye contact of the people
facing the camera and in profile on crossing.jpg, and of the people crossing in street_2 (with
BlazePose's own visibility as confidences for comparison); per hand-followed walk_a pedestrian,
frames detected and the share carrying its most frequent track ID; the phone user of phone_a
against the walk_a pedestrians without a phone (final smartphone trait and trust).

    python benchmarks/perception_eval.py        # ~1 min on 2 cores
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from trustnav.cli import main as cli
from trustnav.perception.confidence import BLAZEPOSE_TO_COCO
from trustnav.perception.frames import iter_frames
from trustnav.perception.looking import LookingModel, normalise_keypoints
from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
from trustnav.perception.types import box_iou

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TRUTH = json.loads((ROOT / "tests" / "data" / "perception_truth.json").read_text())


def inside(p, box) -> bool:
    return box[0] <= p[0] <= box[2] and box[1] <= p[1] <= box[3]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """No options: ``--help`` prints what the script measures and exits."""
    parser = argparse.ArgumentParser(
        prog="perception_eval.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"Reads the shared images and sequences under {SHARED} and the ground truth in tests/data.",
    )
    return parser.parse_args(argv)


def main() -> None:
    if not SHARED.is_dir():
        raise SystemExit(f"needs the shared data at {SHARED}")
    model = LookingModel.from_file()
    street = SHARED / "data" / "street_images"
    found = total = false = 0
    people = {}
    print("## Street images: clearly visible pedestrians found (box IoU > 0.4), false boxes")
    with MediaPipePoseBackend() as backend:
        for name, clear in TRUTH["clear"].items():
            frame = next(iter_frames([street / name])).frame
            people[name] = (frame.shape[1], backend(frame))
            boxes = [p.bbox for p in people[name][1]]
            hit = [any(box_iou(b, gt) > 0.4 for b in boxes) for gt in clear]
            bad = [b for b in boxes if not any(inside(((b[0] + b[2]) / 2, (b[1] + b[3]) / 2), gt)
                                               for gt in clear + TRUTH["other"][name])]  # fmt: skip
            missed = [TRUTH["clear_names"][name][i] for i, h in enumerate(hit) if not h]
            print(f"- {name}: {sum(hit)}/{len(clear)} found, {len(bad)} false boxes; missed: {missed or 'none'}")
            found, total, false = found + sum(hit), total + len(clear), false + len(bad)
    print(f"- total: {found}/{total} = {found / total:.0%}, false boxes {false}")

    def eye(name: str, index: int) -> tuple[float, float]:
        width, ps = people[name]
        p = max(ps, key=lambda q: box_iou(q.bbox, TRUTH["clear"][name][index]))
        vis = np.clip(p.extra["blazepose"][list(BLAZEPOSE_TO_COCO), 3], 0, 1)
        ours = model.predict(normalise_keypoints(p.keypoints, p.confidences, width)[None])[0]
        naive = model.predict(normalise_keypoints(p.keypoints, vis, width)[None])[0]
        return float(ours), float(naive)

    print("\n## Eye contact (occlusion-aware confidences; BlazePose visibility in brackets)")
    groups = [("crossing.jpg", "crossing_facing", "facing the camera"),
              ("crossing.jpg", "crossing_profile", "in profile"),
              ("street_2.png", "street_2_crossing", "crossing the road in profile")]  # fmt: skip
    for name, key, what in groups:
        for i in TRUTH[key]:
            ours, naive = eye(name, i)
            print(f"- {name}, {what}: {TRUTH['clear_names'][name][i]}: {ours:.3f} ({naive:.3f})")

    seq = SHARED / "data" / "sequences"
    with tempfile.TemporaryDirectory() as tmp:
        rows = {}
        for s in ("walk_a", "phone_a"):
            cli(["estimate", str(seq / s), "--out", f"{tmp}/{s}", "--no-images"])
            rows[s] = json.loads(Path(f"{tmp}/{s}/tracks.json").read_text())
    frames = sorted(p.name for p in (seq / "walk_a").glob("*.png"))
    print("\n## walk_a: hand-followed pedestrians (frames detected, share with the most frequent ID)")
    final = {}
    for name, keys in TRUTH["walk_a"].items():
        ids = []
        for k in range(keys[0][0], keys[-1][0] + 1):
            pt = (np.interp(k, [f for f, _, _ in keys], [x for _, x, _ in keys]),
                  np.interp(k, [f for f, _, _ in keys], [y for _, _, y in keys]))  # fmt: skip
            hits = [r for r in rows["walk_a"] if r["frame"] == frames[k] and inside(pt, r["bbox"])]
            if hits:
                ids.append(min(hits, key=lambda r: r["bbox"][2] - r["bbox"][0])["track_id"])
        major = max(set(ids), key=ids.count)
        final[name] = [r for r in rows["walk_a"] if r["track_id"] == major][-1]
        span = keys[-1][0] - keys[0][0] + 1
        print(f"- {name}: detected {len(ids)}/{span}, one ID for {ids.count(major) / len(ids):.2f}")
    last = sorted({r["frame"] for r in rows["phone_a"]})[-1]
    woman = next(r for r in rows["phone_a"] if r["frame"] == last and inside(TRUTH["phone_a_user_last_frame_point"],
                                                                             r["bbox"]))  # fmt: skip
    n = sum(r["track_id"] == woman["track_id"] for r in rows["phone_a"])
    print("\n## Smartphone trait and trust at the end of the track")
    print(f"- phone_a, woman with the phone ({n} frames): smartphone trait {woman['smartphone_trait']:.3f}, "
          f"trust {woman['trust']:.3f}")  # fmt: skip
    for name in TRUTH["walk_a_no_phone"]:
        r = final[name]
        print(f"- walk_a, {name}: smartphone trait {r['smartphone_trait']:.3f}, trust {r['trust']:.3f}")


if __name__ == "__main__":
    parse_args()
    main()
