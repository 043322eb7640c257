"""Frames per second of the perception pipeline on the shared data, split by stage.

Runs the full pipeline (MediaPipe backend, eye contact + phone traits, OC-SORT tracking) on the
640x480 sequences (walk_a, phone_a) in video mode, and on the street images (still mode), and
prints a Markdown table: frames, people per frame, median milliseconds per stage (detection,
landmarks, traits, tracking) and overall frames per second.

    python benchmarks/bench_perception.py                  # both modes on the sequences
    python benchmarks/bench_perception.py --json out.json
    python benchmarks/bench_perception.py --realtime --json rt.json   # issue 20: reference vs real time

``--realtime`` (issue 35) streams walk_a (640x480, 45 frames) at ``--stream-fps`` (15) and prints one
row per mode, also as JSON (``--json F``): ``name``, ``mode`` (``offline``: every frame through the
offline pipeline, as ``trustnav estimate``; ``realtime``: the real-time backend behind a
:class:`~trustnav.perception.streaming.StreamingPerceiver` fed at the camera's clock, newest frame
first), ``fps`` (frames processed per second of wall time), ``throughput_fps`` (real time: frames per
second when handed over as fast as it takes them), ``stream_fps``, ``dropped`` (share of the frames
not processed), ``latency_ms_p95`` (capture to that frame's people and tracks), ``recall_labelled``
(share of walk_a's labelled people >= 80 px tall found, IoU >= 0.5, on the labelled frames, a dropped
frame finding nobody), ``false_boxes`` and ``duplicates`` there (the labelled evaluation's rules),
``first_detection_s`` (worst delay, in stream seconds, from the offline run's first box of a person
>= 80 px to the real-time run's, over people followed >= 0.5 s; one never found counts to the end),
``recall_vs_offline``, ``traits_hz_median`` (median over tracks followed >= 1 s of the rate at which
the track's traits were judged afresh, not carried) and ``load`` (1-minute load average during the
run). ``--repeat N`` streams
N times; ``--config SPEC ...`` streams several real-time settings in turn (``default`` or
RealtimeConfig fields, ``max_fits=2,pipelined=0``: a row each, ``config`` naming it).
``recall_every_frame``, ``first_detection_every_frame_s`` and ``traits_hz_every_frame`` are the same
figures for the real-time backend handed every frame (the throughput pass, nothing dropped): what the
design gives where the machine keeps up.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from trustnav.perception.frames import iter_frames
from trustnav.perception.looking import LookingModel
from trustnav.perception.mediapipe_backend import MediaPipeConfig, MediaPipePoseBackend
from trustnav.perception.pipeline import PerceptionPipeline
from trustnav.perception.tracking import PersonTracker
from trustnav.trust import SECONDS_TRUST, TrustEstimator

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
sys.path.insert(0, str(Path(__file__).resolve().parent))  # trust_eval, beside this file


def run(
    name: str,
    paths: list[Path],
    video: bool,
    workers: int,
    model: LookingModel,
) -> dict:
    frames = [f.frame for f in iter_frames(paths) if f.frame is not None]
    config = MediaPipeConfig(workers=workers)
    backend = MediaPipePoseBackend(config, video=video)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=10.0), model)
    pipeline(frames[0])  # warm-up (graph start-up), then start again
    backend.reset()
    pipeline.tracker = PersonTracker(fps=10.0)
    stages: dict[str, list[float]] = {k: [] for k in ("detection", "landmarks", "traits", "tracking")}
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
        "frames": len(frames),
        "people_per_frame": float(np.mean(people)),
        **{f"{k}_ms": 1e3 * float(np.median(v)) for k, v in stages.items()},
        "total_ms": 1e3 * float(np.median(totals)),
        "fps": 1.0 / float(np.mean(totals)),
    }


def _people(out: list, estimator: TrustEstimator | None = None, t: float = 0.0) -> list[dict]:
    """A frame's people as compared: box, per-frame cues and, with ``estimator`` (the trust
    estimate fed frame by frame, as ``trustnav estimate`` does), each track's trait values and
    trust after this frame."""
    traits = {}
    if estimator is not None:
        tracks = estimator.add_frame(PerceptionPipeline.sightings(out, t), t)
        traits = {i: (st.eye, st.smartphone, st.trust) for i, st in tracks.items()}
    nan3 = (math.nan, math.nan, math.nan)
    return [{"id": tp.track_id, "bbox": tp.person.bbox, "eye": tp.eye_contact, "phone": tp.phone,
             "carried": bool(tp.person.extra.get("carried")),
             **dict(zip(("eye_trait", "phone_trait", "trust"), traits.get(tp.track_id, nan3), strict=True))}
            for tp in out]  # fmt: skip


def run_reference(
    frames: list,
    fps: float,
    model: LookingModel,
    realtime: bool = False,
    config: dict | None = None,
) -> tuple[list[list[dict]], float]:
    """Every frame through the offline pipeline (or, ``realtime``, the real-time backend
    handed the frames as fast as it takes them: its throughput); per frame its people, and the
    frames per second."""
    if realtime:
        from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend

        backend: MediaPipePoseBackend = RealtimePoseBackend(realtime=RealtimeConfig(**(config or {})))
    else:
        backend = MediaPipePoseBackend(video=True)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    pipeline(frames[0])  # warm-up, then start again
    backend.reset()
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    t0 = time.perf_counter()
    trust = TrustEstimator(SECONDS_TRUST)
    out = [_people(pipeline(f, time=i / fps), trust, i / fps) for i, f in enumerate(frames)]
    seconds = time.perf_counter() - t0
    backend.close()
    return out, len(frames) / seconds


def compare(
    reference: list[list[dict]],
    realtime: list[list[dict] | None],
    fps: float,
    settle_s: float = 0.5,
    clear_only: bool = False,
) -> dict:
    """recall_vs_reference, first_detection_s and traits_within_0_1 (see the module docstring).

    first_detection_s counts the people the reference follows for at least ``settle_s`` and finds
    at least ``settle_s`` before the clip ends (a box the reference shows for a frame or two, or a
    person entering in the last frames, cannot be judged); one never found by the real-time mode
    counts from its first detection to the end of the clip; ``clear_only``: only people from the first
    frame the reference shows them >= CLEAR_PX tall (the labelled evaluation's people; a far crowd's
    30-60 px people are not counted). ``first_detection_people`` says how many
    were counted, ``never_found`` how many of those the real-time mode never reported."""
    from trustnav.perception.types import box_iou

    total = hit = agree = both = agree_traits = both_traits = agree_trust = clear = clear_hit = 0
    first_ref: dict[int, int] = {}
    first_rt: dict[int, int] = {}
    frames_of: dict[int, int] = {}
    for k, (ref, rt) in enumerate(zip(reference, realtime, strict=True)):
        for p in ref:
            total += 1
            is_clear = p["bbox"][3] - p["bbox"][1] >= CLEAR_PX
            clear += is_clear
            if is_clear or not clear_only:
                first_ref.setdefault(p["id"], k)
                frames_of[p["id"]] = frames_of.get(p["id"], 0) + 1
            best = max(rt or [], key=lambda q: box_iou(p["bbox"], q["bbox"]), default=None)
            if best is None or box_iou(p["bbox"], best["bbox"]) < 0.5:
                continue
            hit += 1
            clear_hit += is_clear
            first_rt.setdefault(p["id"], k)
            pairs = [(p["eye"], best["eye"]), (p["phone"], best["phone"])]
            if all(np.isfinite(a) and np.isfinite(b) for a, b in pairs):
                both += 1
                agree += all(abs(a - b) <= 0.1 for a, b in pairs)
            pairs = [(p.get("eye_trait", math.nan), best.get("eye_trait", math.nan)),
                     (p.get("phone_trait", math.nan), best.get("phone_trait", math.nan))]  # fmt: skip
            if all(np.isfinite(a) and np.isfinite(b) for a, b in pairs):
                both_traits += 1
                agree_traits += all(abs(a - b) <= 0.1 for a, b in pairs)
                agree_trust += abs(p["trust"] - best["trust"]) <= 0.1
    settle = max(1, round(settle_s * fps))
    counted = [i for i, k in first_ref.items() if frames_of[i] >= settle and k <= len(reference) - settle]
    delays = [(first_rt.get(i, len(reference)) - first_ref[i]) / fps for i in counted]
    return {"recall_vs_reference": hit / total if total else float("nan"),
            "recall_clear": clear_hit / clear if clear else float("nan"),
            "first_detection_s": max(delays, default=0.0),
            "first_detection_people": len(counted),
            "never_found": sum(i not in first_rt for i in counted),
            "traits_within_0_1": agree / both if both else float("nan"),
            "trust_traits_within_0_1": agree_traits / both_traits if both_traits else float("nan"),
            "trust_within_0_1": agree_trust / both_traits if both_traits else float("nan")}  # fmt: skip


#: Box height (px) from which a person counts as clearly visible (``recall_clear``): the size from
#: which the labelled evaluation (trust_eval.py) counts people.
CLEAR_PX = 80.0


def labelled_scores(per_frame: list[list[dict] | None], names: list[str]) -> dict:
    """``recall_labelled`` (share of walk_a's labelled people >= CLEAR_PX tall found, IoU >= 0.5, on
    the labelled frames; a dropped frame finds nobody) and ``false_boxes`` there, by the labelled
    evaluation's own rules (benchmarks/trust_eval.py)."""
    import trust_eval

    labels = trust_eval.load_labels("walk_a")
    for frame in labels["frames"].values():  # the people >= CLEAR_PX tall; the others are ignore regions
        small = [p for p in frame["people"] if p["bbox"][3] - p["bbox"][1] < CLEAR_PX]
        frame["people"] = [p for p in frame["people"] if p not in small]
        frame["ignore"] = [*frame.get("ignore", []), *(p["bbox"] for p in small)]
    records = [{"frame": names[k], "bbox": [float(v) for v in p["bbox"]], "track_id": p["id"]}
               for k, people in enumerate(per_frame) for p in people or []]  # fmt: skip
    r = trust_eval.evaluate(labels, records)
    return {"recall_labelled": r["recall"], "labelled_people": r["people"], "false_boxes": r["false_boxes"],
            "duplicates": r["duplicates"]}  # fmt: skip


def traits_hz(per_frame: list[list[dict] | None], fps: float, min_s: float = 1.0) -> float:
    """Median over tracks followed for >= ``min_s`` of the rate (per second of stream) at which the
    track's traits were judged afresh (its keypoints fitted on that frame, not carried)."""
    fresh: dict[int, int] = {}
    span: dict[int, list[int]] = {}
    for k, people in enumerate(per_frame):
        for p in people or []:
            span.setdefault(p["id"], [k, k])[1] = k
            fresh[p["id"]] = fresh.get(p["id"], 0) + (not p.get("carried", False))
    rates = [fresh[i] * fps / (b - a + 1) for i, (a, b) in span.items() if (b - a + 1) / fps >= min_s]
    return float(np.median(rates)) if rates else float("nan")


def run_stream(frames: list, fps: float, model: LookingModel, realtime: bool, config: dict | None = None) -> dict:
    """walk_a streamed at ``fps`` through the StreamingPerceiver (newest frame first, drops counted):
    the real-time backend (``config``: RealtimeConfig fields), or (``realtime`` False) the offline one,
    which cannot keep up."""
    from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend
    from trustnav.perception.streaming import StreamingPerceiver

    if realtime:
        backend: MediaPipePoseBackend = RealtimePoseBackend(realtime=RealtimeConfig(**(config or {})))
    else:
        backend = MediaPipePoseBackend(video=True)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    pipeline(frames[0], time=0.0)  # warm-up (graph start-up), then start again
    backend.reset()
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    per_frame: list[list[dict] | None] = [None] * len(frames)

    def keep(r) -> None:
        per_frame[r.index] = [{"id": tp.track_id, "bbox": tp.person.bbox, "eye": tp.eye_contact, "phone": tp.phone,
                               "carried": bool(tp.person.extra.get("carried"))} for tp in r.people]  # fmt: skip

    load0 = os.getloadavg()[0]
    with StreamingPerceiver(pipeline, mode="realtime") as stream:
        start = time.perf_counter()
        for i, f in enumerate(frames):
            time.sleep(max(0.0, start + i / fps - time.perf_counter()))  # the camera's clock
            stream.submit(f, i / fps)
            for r in stream.poll():
                keep(r)
        for r in stream.drain(timeout=60.0):
            keep(r)
        wall = time.perf_counter() - start
        stats = stream.stats
    backend.close()
    processed = sum(p is not None for p in per_frame)
    return {"per_frame": per_frame, "fps": processed / wall, "latency_ms_p95": 1e3 * stats["latency_p95_s"],
            "dropped": stats["dropped"] / len(frames), "load": round((load0 + os.getloadavg()[0]) / 2, 2)}  # fmt: skip


def realtime_main(args: argparse.Namespace, model: LookingModel) -> None:
    """Rows ``offline`` (every frame through the offline pipeline, as ``trustnav estimate``) and
    ``realtime`` (walk_a streamed at ``--stream-fps`` into the real-time backend); both scored against
    walk_a's labels; first detection against the offline rows' tracks."""
    paths = sorted((SHARED / "data" / "sequences" / "walk_a").glob("*.png"))
    walk = [f.frame for f in iter_frames(paths)]
    names = [p.name for p in paths]
    fps = args.stream_fps
    rows = []
    load0 = os.getloadavg()[0]
    reference, ref_fps = run_reference(walk, fps, model)
    load = round((load0 + os.getloadavg()[0]) / 2, 2)
    rows.append({"name": "walk_a", "mode": "offline", "fps": ref_fps,
                 **labelled_scores(reference, names), "traits_hz_median": traits_hz(reference, fps),
                 "load": load})  # fmt: skip
    for _, (label, config) in itertools.product(range(args.repeat), args.config):
        load0 = os.getloadavg()[0]
        every, throughput = run_reference(walk, fps, model, realtime=True, config=config)  # every frame
        design = labelled_scores(every, names)
        first_every = compare(reference, every, fps, clear_only=True)["first_detection_s"]
        load_tp = round((load0 + os.getloadavg()[0]) / 2, 2)
        rt = run_stream(walk, fps, model, realtime=True, config=config)
        cmp = compare(reference, rt["per_frame"], fps, clear_only=True)
        rows.append({"name": "walk_a", "mode": "realtime", "config": label, "stream_fps": fps, "fps": rt["fps"],
                     "dropped": rt["dropped"], "latency_ms_p95": rt["latency_ms_p95"],
                     **labelled_scores(rt["per_frame"], names),
                     "first_detection_s": cmp["first_detection_s"], "recall_vs_offline": cmp["recall_vs_reference"],
                     "traits_hz_median": traits_hz(rt["per_frame"], fps), "load": rt["load"],
                     "throughput_fps": throughput, "load_throughput": load_tp,
                     "recall_every_frame": design["recall_labelled"],
                     "first_detection_every_frame_s": first_every,
                     "traits_hz_every_frame": traits_hz(every, fps)})  # fmt: skip
    cols = ["name", "mode", "config", "stream_fps", "fps", "throughput_fps", "dropped", "latency_ms_p95",
            "recall_labelled", "labelled_people", "false_boxes", "duplicates", "first_detection_s",
            "recall_vs_offline", "traits_hz_median", "load", "load_throughput", "recall_every_frame",
            "first_detection_every_frame_s", "traits_hz_every_frame"]  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        cells = [r.get(c, "") for c in cols]
        print("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in cells) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2, default=float))


def realtime_config(spec: str) -> tuple[str, dict]:
    """``--config``: 'default' or comma-separated RealtimeConfig fields (integers; 0/1 for booleans)."""
    from trustnav.perception.realtime import RealtimeConfig

    if spec == "default":
        return spec, {}
    fields = {f for f in RealtimeConfig.__dataclass_fields__}
    out: dict = {}
    for item in spec.split(","):
        key, _, value = item.partition("=")
        if key not in fields or not value.lstrip("-").isdigit():
            raise argparse.ArgumentTypeError(
                f"--config: expected 'default' or FIELD=INT,... of {sorted(fields)}, got {item!r}"
            )
        out[key] = bool(int(value)) if key == "pipelined" else int(value)
    try:
        RealtimeConfig(**out)  # validated now
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--config {spec!r}: {exc}") from None
    return spec, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realtime", action="store_true", help="reference vs real-time mode (issue 20 rows)")
    ap.add_argument("--stream-fps", type=float, default=15.0, help="--realtime: the stream's frame rate")
    ap.add_argument("--repeat", type=int, default=1, help="--realtime: streamed runs (the spread of the timings)")
    ap.add_argument("--config", nargs="+", type=realtime_config, default=[realtime_config("default")],
                    metavar="SPEC", help="--realtime: the real-time backends streamed, in turn, each 'default' "
                    "or RealtimeConfig fields as 'max_fits=2,pipelined=0' (ratios in one run)")  # fmt: skip
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-street", action="store_true", help="sequences only")
    ap.add_argument("--json", help="write the rows to this file")
    args = ap.parse_args()
    if not 1 <= args.repeat <= 10:
        ap.error(f"--repeat: an integer in [1, 10], got {args.repeat}")
    if not SHARED.is_dir():
        raise SystemExit(f"needs the shared data at {SHARED}")
    model = LookingModel.from_file()
    if args.realtime:
        realtime_main(args, model)
        return
    rows = []
    for seq in ("walk_a", "phone_a"):
        paths = sorted((SHARED / "data" / "sequences" / seq).glob("*.png"))
        rows.append(run(seq, paths, True, args.workers, model))
    if not args.skip_street:
        streets = sorted((SHARED / "data" / "street_images").glob("street_*.png"))
        rows.append(run("street_*.png", streets, False, args.workers, model))
        crossing = [SHARED / "data" / "street_images" / "crossing.jpg"] * 3
        rows.append(run("crossing.jpg", crossing, False, args.workers, model))
    cols = ["input", "size", "mode", "frames", "people_per_frame", "detection_ms",
            "landmarks_ms", "traits_ms", "tracking_ms", "total_ms", "fps"]  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
