"""`trustnav ...` entry points (thin: parse, call sim/viz, write files)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["main"]


def _scenario(args: argparse.Namespace) -> int:
    from trustnav.sim.paper import run_scenario
    from trustnav.viz.paper_plots import plot_scenario

    out = Path(args.out or f"out/{args.name}")
    out.mkdir(parents=True, exist_ok=True)
    result = run_scenario(args.name, solver=args.solver)
    fig = plot_scenario(result, out)
    (out / "metrics.json").write_text(json.dumps(result.metrics, indent=2))
    print(f"{args.name}: wrote {fig} and {out / 'metrics.json'}")
    _summary(result.metrics)
    return 0


def _summary(m: dict) -> None:
    def line(tag: str, r: dict) -> None:
        dist = ", ".join(f"{d:.3f}" for d in r["min_distance"])
        print(f"  {tag:<28} min distance [{dist}]  steps to goal {r['steps_to_goal']}  "
              f"margin violations {r['margin_violations']}  solver failures {r['solver_failures']}")  # fmt: skip

    if "runs" in m:
        for r in m["runs"]:
            line(f"trust {r['trust']:g}" if "trust" in r else f"N_h {r['horizon']}", r)
        for timing, runs in m.get("timings", {}).items():
            if timing == m["timing"]:
                continue
            for r in runs:
                line(f"N_h {r['horizon']} ({timing})", r)
    else:
        line("trust-aware", m)
        if "control_equal_trust" in m:
            line("control (all trusts 1.0)", m["control_equal_trust"])


def _estimate(args: argparse.Namespace) -> int:
    import csv

    import cv2
    from tqdm import tqdm

    from trustnav.perception.frames import VIDEO_SUFFIXES, expand_inputs, frame_count, iter_frames, source_fps
    from trustnav.perception.looking import LookingModel
    from trustnav.perception.optional_backends import make_backend
    from trustnav.perception.phone import phone_label
    from trustnav.perception.pipeline import PerceptionPipeline, estimate
    from trustnav.perception.tracking import PersonTracker
    from trustnav.trust.estimator import TrustEstimator
    from trustnav.viz.annotate import annotate

    inputs = expand_inputs(args.inputs)  # once: folders listed, existence checked
    fps = source_fps(inputs, args.fps)
    video_in = any(p.suffix.lower() in VIDEO_SUFFIXES for p in inputs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    total = frame_count(inputs)
    kwargs = {"scan_frames": args.scan_frames} if args.backend == "mediapipe" else {}
    backend = make_backend(args.backend, video=True, **kwargs)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), LookingModel.from_file(args.looking_weights))
    writer = None
    rows: list[dict] = []
    errors = 0

    def report(res) -> None:
        nonlocal errors
        errors += 1
        tqdm.write(f"trustnav: skipped frame {res.name}: {res.error}", file=sys.stderr)

    size: tuple[int, int] | None = None
    results = estimate(iter_frames(inputs), pipeline, TrustEstimator(), fps, on_error=report)
    for res in tqdm(results, total=total, unit="frame"):
        rows.extend(res.records)
        if res.error is not None or args.no_images:
            continue
        img = annotate(
            res.rgb,
            res.records,
            [tp.person.keypoints for tp in res.people],
            [phone_label(tp.phone) for tp in res.people],
        )
        if video_in or args.mp4:
            if writer is None:
                size = (img.shape[1], img.shape[0])
                writer = cv2.VideoWriter(str(out / "annotated.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
            if (img.shape[1], img.shape[0]) != size:
                img = cv2.resize(img, size)
            writer.write(img)
        else:
            (out / "frames").mkdir(exist_ok=True)
            cv2.imwrite(str(out / "frames" / f"{Path(res.name).stem}.png"), img)
    if writer is not None:
        writer.release()
    if hasattr(backend, "close"):
        backend.close()
    fields = ["frame", "track_id", "bbox", "eye_contact", "phone", "fluctuation",
              "smartphone_trait", "eye_trait", "pose_trait", "score", "trust"]  # fmt: skip
    with open(out / "tracks.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow({**r, "bbox": " ".join(f"{v:g}" for v in r["bbox"])})
    (out / "tracks.json").write_text(json.dumps(rows, indent=1))
    tracks = len({r["track_id"] for r in rows})
    print(f"estimate: {len(rows)} records, {tracks} tracks, {errors} frames skipped; wrote {out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="trustnav", description="Trust-aware safe navigation (MPC-CBF with pedestrian trust)."
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser(
        "scenario", help="run one of the paper's numerical scenarios and write its figure + metrics.json"
    )
    s.add_argument("name", choices=["paper-1", "paper-2", "paper-3"])
    s.add_argument("--out", help="output directory (default out/<name>)")
    s.add_argument(
        "--solver", choices=["sqp", "slsqp"], default="sqp", help="sqp: fast default; slsqp: paper-style reference"
    )
    s.set_defaults(func=_scenario)
    e = sub.add_parser(
        "estimate",
        help="perception + trust on images, folders of frames or videos: annotated frames, tracks.csv/json",
    )
    e.add_argument("inputs", nargs="+", help="image files, folders of frames (natural order) or video files")
    e.add_argument("--out", required=True, help="output directory")
    e.add_argument("--fps", type=float, default=10.0, help="frame rate of image sequences (videos: their own)")
    e.add_argument("--backend", choices=["mediapipe", "openpifpaf", "yolo"], default="mediapipe")
    e.add_argument(
        "--scan-frames",
        type=int,
        default=1,
        help="mediapipe: share the tiled search over N frames (faster, fewer found)",
    )
    e.add_argument("--looking-weights", help="LOOKING eye-contact weights (default: ../shared, cache, download)")
    e.add_argument("--no-images", action="store_true", help="write only tracks.csv/json")
    e.add_argument("--mp4", action="store_true", help="write annotated.mp4 also for image inputs (not PNG frames)")
    e.set_defaults(func=_estimate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, ImportError) as exc:
        print(f"trustnav: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
