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


def _drive_runs(
    case: str,
    sensing: str,
    attentive: bool | None,
    seed: int,
    rate: float | None,
    out: Path,
    video: bool = True,
    control_rate: float | None = None,
) -> list[tuple[str, dict, Path]]:
    """Run a driving case (Case II: both variants unless one is asked for) and write its outputs."""
    from tqdm import tqdm

    from trustnav.sim.driving import load_drive_scenario, make_render_sensing, run_drive
    from trustnav.viz.drive_plots import plot_distance, plot_top_view, write_drive_outputs

    sc = load_drive_scenario(case)
    if attentive is not None:
        variants: list[tuple[str, bool | None]] = [("attentive" if attentive else "distracted", attentive)]
    elif sc.variants:
        variants = [(v, v == "attentive") for v in sc.variants]
    else:
        variants = [("", None)]
    done, results = [], []
    for tag, att in variants:
        where = out / tag if len(variants) > 1 else out
        renderer = pipeline = None
        if sensing == "render":
            renderer, pipeline = make_render_sensing(sc, rate)
        desc = f"{case}{' ' + tag if tag else ''} ({sensing})"
        try:
            with tqdm(total=sc.duration, desc=desc, unit="s", bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} s sim "
                      "[{elapsed}]") as bar:  # fmt: skip
                result = run_drive(sc, sensing=sensing, seed=seed, attentive=att, capture_rate=rate,
                                   control_rate=control_rate, renderer=renderer, pipeline=pipeline,
                                   progress=lambda t, _d, bar=bar: bar.update(t - bar.n))  # fmt: skip
                bar.total = bar.n
                bar.refresh()
        finally:
            if renderer is not None:
                renderer.close()
            if pipeline is not None and hasattr(pipeline.backend, "close"):
                pipeline.backend.close()
        metrics = result.metrics()
        where.mkdir(parents=True, exist_ok=True)
        write_drive_outputs(result, where, video=video)
        (where / "metrics.json").write_text(json.dumps(metrics, indent=2))
        done.append((tag or case, metrics, where))
        results.append(result)
    if len(results) > 1:
        plot_distance(results, out / "distance.png")
        plot_top_view(results, out / "top_view.png", title=f"{sc.title} [{sensing} sensing]")
        (out / "metrics.json").write_text(json.dumps({tag: m for tag, m, _ in done}, indent=2))
    return done


def _drive_summary(done: list[tuple[str, dict, Path]], out: Path) -> None:
    for tag, m, where in done:
        ttg = "not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s"
        extra = f"  detection recall {m['detection_recall']:.2f}" if m.get("detection_recall") is not None else ""
        print(f"  {tag}: goal {ttg}  margin violations {m['margin_violations']}  relaxed steps "
              f"{m['relaxed_steps']}  fallback steps {m['fallback_steps']}  solve {m['solve_ms_median']:.2f} ms "
              f"(p95 {m['solve_ms_p95']:.2f}){extra}  -> {where}")  # fmt: skip
        for p in m["pedestrians"]:
            kind = "attentive" if p["attentive"] else "distracted"
            print(f"      {p['name']:<11} ({kind:<10}) min distance {p['min_distance']:.2f} m  "
                  f"final trust {p['final_trust']:.2f}  frames seen {p['frames_seen']}")  # fmt: skip


def _drive(args: argparse.Namespace) -> int:
    from trustnav.sim.driving import DRIVE_SCENARIOS

    if args.world == "carla":
        from trustnav.carla_bridge.command import run_carla_drive

        return run_carla_drive(args)

    if args.case not in DRIVE_SCENARIOS:
        raise ValueError(f"unknown case {args.case!r}: expected one of {', '.join(DRIVE_SCENARIOS)}")
    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"--rate must be a positive number of frames per second, got {args.rate}")
    if args.control_rate is not None and not args.control_rate > 0:
        raise ValueError(f"--control-rate must be a positive number of steps per second, got {args.control_rate}")
    out = Path(args.out or f"out/{args.case}")
    done = _drive_runs(args.case, args.sensing, args.attentive, args.seed, args.rate, out, video=not args.no_video,
                       control_rate=args.control_rate)  # fmt: skip
    files = "top_view.png, trust.png, distance.png, drive.mp4, frames/, metrics.json"
    if args.no_video:
        files = files.replace("drive.mp4, ", "")
    if len(done) > 1:
        runs = ", ".join(f"{tag}/" for tag, _, _ in done)
        files = f"top_view.png, distance.png, metrics.json comparing the runs; per run in {runs}: {files}"
    print(f"drive {args.case} ({args.sensing} sensing): wrote {out}/ ({files})")
    _drive_summary(done, out)
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from trustnav.campaigns.command import run_sweep_command

    return run_sweep_command(args)


def _demo(args: argparse.Namespace) -> int:
    import time

    out = Path(args.out)
    t0 = time.perf_counter()
    done = _drive_runs("case-1", "render", None, args.seed, None, out)
    print(f"demo (paper Case I, camera -> perception -> trust -> MPC, {time.perf_counter() - t0:.0f} s): wrote")
    for name in ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames/", "metrics.json"):
        print(f"  {out / name}")
    _drive_summary(done, out)
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (exit code 2, no usage dump)."""

    def error(self, message: str):  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="trustnav", description="Trust-aware safe navigation (MPC-CBF with pedestrian trust).")
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
    d = sub.add_parser(
        "drive",
        help="end-to-end trust-aware driving (paper Section IV, Cases I and II): figures, MP4, metrics.json",
    )
    d.add_argument("case", help="case-1 (attentive + distracted standing) or case-2 (one walking pedestrian)")
    d.add_argument("--sensing", choices=["render", "keypoints"], default="render",
                   help="render: rendered frames + perception (default); keypoints: projected joints")  # fmt: skip
    g = d.add_mutually_exclusive_group()
    g.add_argument("--attentive", dest="attentive", action="store_const", const=True, default=None,
                   help="every pedestrian attentive")  # fmt: skip
    g.add_argument("--distracted", dest="attentive", action="store_const", const=False,
                   help="every pedestrian distracted")  # fmt: skip
    d.add_argument("--seed", type=int, default=0, help="seed of sensing noise (default 0)")
    d.add_argument("--rate", type=float, help="camera frames per second = trust-estimation rate (default: scenario, 1)")
    d.add_argument("--control-rate", type=float, help="controller steps per second (default: scenario, 20)")
    d.add_argument("--out", help="output directory (default out/<case>)")
    d.add_argument("--no-video", action="store_true", help="skip drive.mp4")
    d.add_argument("--world", choices=["sim", "carla"], default="sim",
                   help="sim: own world (default); carla: a CARLA server (extra trustnav[carla])")  # fmt: skip
    d.add_argument("--host", default="localhost", help="CARLA server host (--world carla)")
    d.add_argument("--port", type=int, default=2000, help="CARLA server port (--world carla)")
    d.add_argument("--timeout", type=float, default=10.0, help="CARLA connection timeout in seconds (--world carla)")
    d.set_defaults(func=_drive)
    w = sub.add_parser("sweep", help="a campaign of closed-loop episodes on Dask (records, summary, plots)")
    w.add_argument("spec", help="campaign spec (YAML or TOML)")
    w.add_argument("--out", required=True, help="output directory (records are appended; a rerun resumes)")
    w.add_argument("--scheduler", help="address of a running Dask scheduler (default: a LocalCluster)")
    w.add_argument("--workers", type=int, help="LocalCluster workers (default: the machine's cores)")
    w.set_defaults(func=_sweep)
    m = sub.add_parser("demo", help="paper Case I end to end in render mode; prints where the outputs are")
    m.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    m.add_argument("--seed", type=int, default=0)
    m.set_defaults(func=_demo)
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
