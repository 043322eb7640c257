"""Frames per second of the perception pipeline on the shared data, split by stage.

Runs the full pipeline (MediaPipe backend, eye contact + phone traits, OC-SORT tracking) on the
640x480 sequences (walk_a, phone_a) in video mode, and on the street images (still mode), and
prints a Markdown table: frames, people per frame, median milliseconds per stage (detection,
landmarks, traits, tracking) and overall frames per second. ``--scan-frames N`` shares the tiled
search over N frames of a video (people already found are followed from their landmarks).

    python benchmarks/bench_perception.py                  # both modes on the sequences
    python benchmarks/bench_perception.py --json out.json
    python benchmarks/bench_perception.py --realtime --json rt.json   # issue 20: reference vs real time

``--realtime`` measures, per input and in the same run, the offline **reference** (every frame
through the full pipeline, as ``trustnav estimate`` does) and the **realtime** mode
(:class:`~trustnav.perception.realtime.RealtimePoseBackend` behind a
:class:`~trustnav.perception.streaming.StreamingPerceiver`, frames handed over at the stream's
rate ``--stream-fps``, the newest frame taken, older ones dropped; or, per ``--max-latency`` S, frames
waiting while younger than S seconds). Rows (``--json``): ``name``, ``max_latency_s`` (0: newest only),
``mode`` (reference | realtime), ``fps`` (frames processed per second of wall time; for the
realtime mode also ``throughput_fps``, frames per second when handed over as fast as it takes
them), ``recall_vs_reference`` (share of the reference's person-frames the realtime mode also
reports, box IoU >= 0.5; a dropped frame reports nobody; ``recall_clear``: the same over the reference's
people >= 80 px tall), ``first_detection_s`` (worst delay, in
stream seconds, from a person's first reference detection to the realtime mode's, over the people
the reference follows for >= 0.5 s and finds >= 0.5 s before the end; ``never_found`` of them the
realtime mode never reports, counted to the end of the clip), ``traits_within_0_1``
(share of the person-frames found by both whose eye contact and phone use agree within 0.1),
``latency_ms_p95``, ``dropped`` and the load average during the run; the reference's row gives
``traits_frame_to_frame``, the same agreement between a track's consecutive reference frames (how
steady the per-frame values are to begin with) and ``reference_new_share``, the share of its
person-frames whose track it did not report on the frame before (people it finds anew, which any
search that hands over a frame or more later misses unless a carried box covers them); ``--search-seconds``
adds in-step rows (the search in the frame loop, handed over after that much stream time; no frame
dropped, nothing load-dependent), one per ``--landmark-every``; ``trust_traits_within_0_1`` and
``trust_within_0_1``, the same agreement for the eye-contact and smartphone trait values and the
trust that a seconds-based ``TrustEstimator`` fed frame by frame gives each track (what the
controller uses). The inputs: walk_a (640x480)
and walk_a enlarged to 1280x720 (a dash-cam-sized stand-in: the shared data have no 1280x720 clip).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
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


def run(
    name: str, paths: list[Path], video: bool, scan_frames: int, workers: int, model: LookingModel, body: bool = True
) -> dict:
    frames = [f.frame for f in iter_frames(paths) if f.frame is not None]
    config = MediaPipeConfig(scan_frames=scan_frames, workers=workers, body_search=body)
    backend = MediaPipePoseBackend(config, video=video)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=10.0), model)
    pipeline(frames[0])  # warm-up (graph start-up), then start again
    backend.reset()
    pipeline.tracker = PersonTracker(fps=10.0)
    stages: dict[str, list[float]] = {
        k: [] for k in ("detection", "landmarks", "segmentation", "body", "traits", "tracking")
    }
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
        "body_search": body,
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
        tracks = estimator.update(PerceptionPipeline.observations(out, t), t)
        traits = {i: (st.eye, st.smartphone, st.trust) for i, st in tracks.items()}
    nan3 = (math.nan, math.nan, math.nan)
    return [{"id": tp.track_id, "bbox": tp.person.bbox, "eye": tp.eye_contact, "phone": tp.phone,
             **dict(zip(("eye_trait", "phone_trait", "trust"), traits.get(tp.track_id, nan3), strict=True))}
            for tp in out]  # fmt: skip


def run_reference(frames: list, fps: float, model: LookingModel, body: bool = True) -> tuple[list[list[dict]], float]:
    """Every frame through the offline pipeline; per frame its people, and the frames per second."""
    backend = MediaPipePoseBackend(MediaPipeConfig(body_search=body), video=True)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    pipeline(frames[0])  # warm-up, then start again
    backend.reset()
    pipeline.tracker = PersonTracker(fps=fps)
    t0 = time.perf_counter()
    trust = TrustEstimator(SECONDS_TRUST)
    out = [_people(pipeline(f, time=i / fps), trust, i / fps) for i, f in enumerate(frames)]
    seconds = time.perf_counter() - t0
    backend.close()
    return out, len(frames) / seconds


def run_realtime(
    frames: list, fps: float, model: LookingModel, max_latency: float | None = None, body: bool = True
) -> dict:
    """The realtime mode: a throughput pass (frames handed over as fast as it takes them), then a
    stream at ``fps`` through the StreamingPerceiver (newest frame first, drops counted)."""
    from trustnav.perception.realtime import RealtimePoseBackend
    from trustnav.perception.streaming import StreamingPerceiver

    backend = RealtimePoseBackend(MediaPipeConfig(body_search=body))
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    t0 = time.perf_counter()
    for i, f in enumerate(frames):
        pipeline(f, time=i / fps)
    throughput = len(frames) / (time.perf_counter() - t0)
    backend.reset()
    pipeline.tracker = PersonTracker(fps=fps)
    per_frame: list[list[dict] | None] = [None] * len(frames)
    trust = TrustEstimator(SECONDS_TRUST)  # results arrive in capture order
    with StreamingPerceiver(pipeline, mode="realtime", max_latency=max_latency) as stream:
        start = time.perf_counter()
        for i, f in enumerate(frames):
            time.sleep(max(0.0, start + i / fps - time.perf_counter()))  # the camera's clock
            stream.submit(f, i / fps)
            for r in stream.poll():
                per_frame[r.index] = _people(r.people, trust, r.capture_time)
        results = stream.drain(timeout=30.0)
        for r in results:
            per_frame[r.index] = _people(r.people, trust, r.capture_time)
        wall = time.perf_counter() - start
        stats = stream.stats
    backend.close()
    processed = sum(p is not None for p in per_frame)
    return {"per_frame": per_frame, "fps": processed / wall, "throughput_fps": throughput,
            "latency_ms_p95": 1e3 * stats["latency_p95_s"], "dropped": stats["dropped"],
            "searches": backend.stats["searches"], "search_mean_s": backend.stats["search_mean_s"]}  # fmt: skip


def run_in_step(
    frames: list, fps: float, model: LookingModel, search_seconds: float, body: bool = True, landmark_every: int = 2
) -> dict:
    """The real-time design with its search in step with the frames (``RealtimeConfig.search_frames``):
    every frame processed, the search's findings handed over ``search_seconds`` of stream time after
    the frame it searched, each followed person fitted on one frame in ``landmark_every``. What it
    misses against the reference is the design's (search latency, following, carrying), not the
    machine's: no frame is dropped and nothing depends on load."""
    from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend, modelled_search_frames

    k = modelled_search_frames(fps, search_seconds)
    realtime = RealtimeConfig(search_frames=k, landmark_every=landmark_every)
    backend = RealtimePoseBackend(MediaPipeConfig(body_search=body), realtime=realtime)
    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), model)
    trust = TrustEstimator(SECONDS_TRUST)
    t0 = time.perf_counter()
    per_frame = [_people(pipeline(f, time=i / fps), trust, i / fps) for i, f in enumerate(frames)]
    wall = time.perf_counter() - t0
    backend.close()
    return {"per_frame": per_frame, "compute_fps": len(frames) / wall, "search_frames": k}


def compare(reference: list[list[dict]], realtime: list[list[dict] | None], fps: float, settle_s: float = 0.5) -> dict:
    """recall_vs_reference, first_detection_s and traits_within_0_1 (see the module docstring).

    first_detection_s counts the people the reference follows for at least ``settle_s`` and finds
    at least ``settle_s`` before the clip ends (a box the reference shows for a frame or two, or a
    person entering in the last frames, cannot be judged); one never found by the real-time mode
    counts from its first detection to the end of the clip. ``first_detection_people`` says how many
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
#: which the labelled evaluation (trust_eval.py) counts people and both proposers work.
CLEAR_PX = 80.0


def reference_new_share(reference: list[list[dict]]) -> float:
    """Share of the reference's person-frames, after the first frame, whose track the reference did
    not report on the frame before: people it finds anew (entering, or found again after a frame or
    more without them). The reference detects on every frame; a design whose search hands its
    findings over even one frame later can match these only with a box it carried, so this share
    bounds how close to 1 its ``recall_vs_reference`` can come."""
    new = total = 0
    for prev, cur in itertools.pairwise(reference):
        before = {p["id"] for p in prev}
        total += len(cur)
        new += sum(p["id"] not in before for p in cur)
    return new / total if total else float("nan")


def frame_to_frame_agreement(reference: list[list[dict]]) -> float:
    """Share of a track's consecutive reference frames whose eye-contact and phone values agree
    within 0.1: how steady the per-frame trait values are before any real-time shortcut (a bound
    on how well two modes that fit a person on different frames or regions can agree)."""
    agree = pairs = 0
    for prev, cur in itertools.pairwise(reference):
        before = {p["id"]: p for p in prev}
        for p in cur:
            q = before.get(p["id"])
            if q is None or not all(np.isfinite([p["eye"], q["eye"], p["phone"], q["phone"]])):
                continue
            pairs += 1
            agree += abs(p["eye"] - q["eye"]) <= 0.1 and abs(p["phone"] - q["phone"]) <= 0.1
    return agree / pairs if pairs else float("nan")


#: --body-search: the MediaPipeConfig.body_search settings measured.
BODY_SEARCH = {"on": [True], "off": [False], "both": [False, True]}


def realtime_main(args: argparse.Namespace, model: LookingModel) -> None:
    import cv2

    walk = [f.frame for f in iter_frames(sorted((SHARED / "data" / "sequences" / "walk_a").glob("*.png")))]
    big = [np.ascontiguousarray(cv2.resize(f, (1280, 960), interpolation=cv2.INTER_CUBIC)[120:840]) for f in walk]
    rows = []
    bodies = BODY_SEARCH[args.body_search]
    for (name, frames), body in itertools.product((("walk_a", walk), ("walk_a_1280x720", big)), bodies):
        load0 = os.getloadavg()[0]
        reference, ref_fps = run_reference(frames, args.stream_fps, model, body)
        size = f"{frames[0].shape[1]}x{frames[0].shape[0]}"
        rows.append({"name": name, "size": size, "body_search": body, "mode": "reference", "fps": ref_fps,
                     "traits_frame_to_frame": frame_to_frame_agreement(reference),
                     "reference_new_share": reference_new_share(reference),
                     "load_avg": round(load0, 2)})  # fmt: skip
        for budget in args.max_latency:
            load0 = os.getloadavg()[0]
            rt = run_realtime(frames, args.stream_fps, model, budget or None, body)
            load = round((load0 + os.getloadavg()[0]) / 2, 2)
            rows.append({"name": name, "size": size, "body_search": body, "mode": "realtime", "max_latency_s": budget,
                         "fps": rt["fps"],
                         "throughput_fps": rt["throughput_fps"],
                         **compare(reference, rt["per_frame"], args.stream_fps),
                         "latency_ms_p95": rt["latency_ms_p95"], "dropped": rt["dropped"], "load_avg": load,
                         "searches": rt["searches"], "search_mean_s": rt["search_mean_s"],
                         "stream_fps": args.stream_fps})  # fmt: skip
        for secs, every in itertools.product(args.search_seconds, args.landmark_every):
            st = run_in_step(frames, args.stream_fps, model, secs, body, every)
            rows.append({"name": name, "size": size, "body_search": body, "mode": "in-step", "search_s": secs,
                         "landmark_every": every,
                         "search_frames": st["search_frames"], "compute_fps": st["compute_fps"],
                         **compare(reference, st["per_frame"], args.stream_fps),
                         "stream_fps": args.stream_fps})  # fmt: skip
    cols = ["name", "size", "body_search", "mode", "max_latency_s", "search_s", "landmark_every", "fps",
            "throughput_fps", "compute_fps", "recall_vs_reference", "recall_clear", "reference_new_share",
            "first_detection_s", "first_detection_people", "never_found", "traits_within_0_1",
            "traits_frame_to_frame", "trust_traits_within_0_1", "trust_within_0_1", "latency_ms_p95", "dropped",
            "load_avg"]  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        cells = [r.get(c, "") for c in cols]
        print("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in cells) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realtime", action="store_true", help="reference vs real-time mode (issue 20 rows)")
    ap.add_argument("--stream-fps", type=float, default=15.0, help="--realtime: the stream's frame rate")
    ap.add_argument("--max-latency", type=float, nargs="+", default=[0.0, 0.3],
                    help="--realtime: StreamingPerceiver latency budgets to run, s (0: newest frame only)")  # fmt: skip
    ap.add_argument("--search-seconds", type=float, nargs="*", default=[],
                    help="--realtime: also the real-time design in step with the frames, its search taking "
                    "each of these stream seconds (rows in-step: no frame dropped, no load effect)")  # fmt: skip
    ap.add_argument("--landmark-every", type=int, nargs="+", default=[2],
                    help="--realtime: the in-step rows' RealtimeConfig.landmark_every, each (1: every person "
                    "fitted on every frame)")  # fmt: skip
    ap.add_argument("--scan-frames", type=int, nargs="+", default=[1, 4])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-street", action="store_true", help="sequences only")
    ap.add_argument("--body-search", choices=tuple(BODY_SEARCH), default="on",
                    help="the HOG body-shape search (MediaPipeConfig.body_search): on, off or both")  # fmt: skip
    ap.add_argument("--json", help="write the rows to this file")
    args = ap.parse_args()
    if any(not 0.0 <= b <= 10.0 for b in args.max_latency):
        ap.error(f"--max-latency: seconds in [0, 10] (0: newest frame only), got {args.max_latency}")
    if any(not 0.0 < b <= 10.0 for b in args.search_seconds):
        ap.error(f"--search-seconds: seconds in (0, 10], got {args.search_seconds}")
    if any(not 1 <= n <= 10 for n in args.landmark_every):
        ap.error(f"--landmark-every: integers in [1, 10], got {args.landmark_every}")
    if not SHARED.is_dir():
        raise SystemExit(f"needs the shared data at {SHARED}")
    model = LookingModel.from_file()
    if args.realtime:
        realtime_main(args, model)
        return
    rows = []
    bodies = BODY_SEARCH[args.body_search]
    for scan, body in itertools.product(args.scan_frames, bodies):
        for seq in ("walk_a", "phone_a"):
            paths = sorted((SHARED / "data" / "sequences" / seq).glob("*.png"))
            rows.append(run(seq, paths, True, scan, args.workers, model, body))
    if not args.skip_street:
        streets = sorted((SHARED / "data" / "street_images").glob("street_*.png"))
        for body in bodies:
            rows.append(run("street_*.png", streets, False, 1, args.workers, model, body))
            rows.append(run("crossing.jpg", [SHARED / "data" / "street_images" / "crossing.jpg"] * 3, False, 1,
                            args.workers, model, body))  # fmt: skip
    cols = ["input", "size", "mode", "scan_frames", "body_search", "frames", "people_per_frame", "detection_ms",
            "landmarks_ms", "segmentation_ms", "body_ms", "traits_ms", "tracking_ms", "total_ms", "fps"]  # fmt: skip
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
