"""Frames per second of the perception pipeline on the shared data, split by stage.

Runs the full pipeline (MediaPipe backend, eye contact + phone traits, OC-SORT tracking) on the
640x480 sequences (walk_a, phone_a) in video mode, and on the street images (still mode), and
prints a Markdown table: frames, people per frame, median milliseconds per stage (detection,
landmarks, traits, tracking) and overall frames per second. ``--scan-frames N`` shares the tiled
search over N frames of a video (people already found are followed from their landmarks).

    python benchmarks/bench_perception.py                  # both modes on the sequences
    python benchmarks/bench_perception.py --json out.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from trustnav.perception.frames import iter_frames
from trustnav.perception.looking import LookingModel
from trustnav.perception.mediapipe_backend import MediaPipeConfig, MediaPipePoseBackend
from trustnav.perception.pipeline import PerceptionPipeline
from trustnav.perception.tracking import PersonTracker

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def run(name: str, paths: list[Path], video: bool, scan_frames: int, workers: int, model: LookingModel) -> dict:
    frames = [f.frame for f in iter_frames(paths) if f.frame is not None]
    backend = MediaPipePoseBackend(MediaPipeConfig(scan_frames=scan_frames, workers=workers), video=video)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=10.0), model)
    pipeline(frames[0])  # warm-up (graph start-up), then start again
    backend.reset()
    pipeline.tracker = PersonTracker(fps=10.0)
    stages: dict[str, list[float]] = {"detection": [], "landmarks": [], "traits": [], "tracking": []}
    totals, people = [], []
    for frame in frames:
        t0 = time.perf_counter()
        out = pipeline(frame)
        totals.append(time.perf_counter() - t0)
        people.append(len(out))
        for k in stages:
            stages[k].append(pipeline.last_timing.get(k, 0.0))
    backend.close()
    h, w = frames[0].shape[:2]
    return {
        "input": name,
        "size": f"{w}x{h}",
        "mode": "video" if video else "still",
        "scan_frames": scan_frames,
        "frames": len(frames),
        "people_per_frame": float(np.mean(people)),
        **{f"{k}_ms": 1e3 * float(np.median(v)) for k, v in stages.items()},
        "total_ms": 1e3 * float(np.median(totals)),
        "fps": 1.0 / float(np.mean(totals)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan-frames", type=int, nargs="+", default=[1, 4])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-street", action="store_true", help="sequences only")
    ap.add_argument("--json", help="write the rows to this file")
    args = ap.parse_args()
    if not SHARED.is_dir():
        raise SystemExit(f"needs the shared data at {SHARED}")
    model = LookingModel.from_file()
    rows = []
    for scan in args.scan_frames:
        for seq in ("walk_a", "phone_a"):
            paths = sorted((SHARED / "data" / "sequences" / seq).glob("*.png"))
            rows.append(run(seq, paths, True, scan, args.workers, model))
    if not args.skip_street:
        streets = sorted((SHARED / "data" / "street_images").glob("street_*.png"))
        rows.append(run("street_*.png", streets, False, 1, args.workers, model))
        rows.append(run("crossing.jpg", [SHARED / "data" / "street_images" / "crossing.jpg"] * 3, False, 1,
                        args.workers, model))  # fmt: skip
    cols = ["input", "size", "mode", "scan_frames", "frames", "people_per_frame", "detection_ms", "landmarks_ms",
            "traits_ms", "tracking_ms", "total_ms", "fps"]  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
