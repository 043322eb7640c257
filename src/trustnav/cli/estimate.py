"""`trustnav estimate INPUTS`: perception + trust on images, folders of frames, videos or a live source
(:func:`trustnav.perception.estimate.estimate_sequences`); this module writes the annotated frames and
tracks.csv/json (:class:`trustnav.outputs.TrackTable`), atomically (:class:`trustnav.outputs.OutputFolder`)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

from trustnav.cli.common import check_bounds, raise_interrupt, span
from trustnav.outputs import OutputFolder, TrackTable

ESTIMATE_OUTPUTS = ("frames", "annotated*.mp4", "tracks.csv", "tracks.json", "rejected.json")


def add_parser(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser(
        "estimate",
        help="perception + trust on images, folders of frames or videos: annotated frames, tracks.csv/json",
    )
    e.add_argument("inputs", nargs="+",
                   help="images, folders of frames (natural order) or videos, each its own sequence; or one live "
                   "input: a camera index (0) or a stream URL (rtsp://..., http://..., file://...), read "
                   "newest-frame-first (frames perception has no time for are dropped and counted)")  # fmt: skip
    e.add_argument("--out", required=True, help="output directory (new or empty)")
    e.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    e.add_argument("--one-sequence", action="store_true",
                   help="run all inputs as one sequence (one tracker and trust state), in the order given")  # fmt: skip
    e.add_argument("--fps", type=float, default=10.0,
                   help=f"rate of image sequences, {span('fps')} (default 10; videos: their own)")  # fmt: skip
    e.add_argument("--backend", choices=["mediapipe", "openpifpaf", "yolo"], default="mediapipe")
    e.add_argument(
        "--scan-frames",
        type=int,
        default=1,
        help=f"mediapipe: share the tiled search over N frames, {span('scan_frames')} (faster, fewer found)",
    )
    e.add_argument("--realtime", action="store_true",
                   help="real-time perception (same as --perception realtime): the detector on every frame, "
                   "landmarks refitted a few times a second and carried between (docs/perception.md)")  # fmt: skip
    e.add_argument("--proposer", choices=["detector", "blazepose"], default="detector",
                   help="mediapipe: who proposes people: the YOLOX-Nano person detector (default) or, as before, "
                   "BlazePose's face detector over tiles with the segmentation and HOG searches")  # fmt: skip
    e.add_argument("--detector-model", metavar="FILE",
                   help="the YOLOX-Nano ONNX file (default: ../shared/models/yolox/ of a checkout, "
                   "$TRUSTNAV_YOLOX_MODEL, the user cache, else downloaded once; a FILE given is never "
                   "downloaded)")  # fmt: skip
    e.add_argument("--perception", choices=["offline", "realtime"], default=None,
                   help="offline (default for files): every box of every frame fitted; realtime (= --realtime, "
                   "the default for live input): the detector on every frame, landmarks staggered "
                   "(docs/perception.md)")  # fmt: skip
    e.add_argument(
        "--sharpen",
        type=float,
        default=0.0,
        help=f"mediapipe: unsharp mask for the person search, {span('sharpen')} (default 0, off); 0.7 finds "
        "more people on soft or compressed video (MP4 at ~36 dB)",
    )
    e.add_argument("--no-body-search", action="store_true",
                   help="mediapipe: skip the HOG body-shape search for the people the pose detector misses (seen "
                   "from behind, on compressed video); faster, finds fewer (docs/perception.md)")  # fmt: skip
    e.add_argument("--max-frames", type=int, help=f"stop after N frames, {span('max_frames')} (any input)")
    e.add_argument("--max-seconds", type=float,
                   help=f"live input: stop after S seconds, {span('max_seconds')} (default: when the stream ends "
                   "or on Ctrl-C)")  # fmt: skip
    e.add_argument("--open-timeout", type=float, default=5.0,
                   help=f"live input: seconds to wait for the source to open and for each frame, "
                   f"{span('open_timeout')} (default 5)")  # fmt: skip
    e.add_argument(
        "--show",
        action="store_true",
        help="show the annotated frames in a window (q or Esc stops; needs an OpenCV with a GUI)",
    )
    e.add_argument("--looking-weights", help="LOOKING eye-contact weights (default: ../shared, cache, download)")
    e.add_argument("--face", action="store_true",
                   help="add the face's own eye-contact reading (eye_contact_face, face_confidence) to the tables "
                   "(the face is always fused with LOOKING on people >= 100 px tall)")  # fmt: skip
    e.add_argument("--trust", choices=["seconds", "paper", "moving-average"], default="seconds",
                   help="seconds: SECONDS_TRUST, the same trust after the same seconds at any frame rate (default); "
                   "paper: PAPER_TRUST, a step per frame, rises only; moving-average: MOVING_AVERAGE_TRUST",
                   )  # fmt: skip
    e.add_argument("--no-images", action="store_true", help="write only tracks.csv/json")
    e.add_argument("--camera-height", type=float,
                   help=f"the camera's height above flat ground, {span('camera_height')}: places each person on "
                   "the ground (ahead_m, left_m, their sd, distance_m in the tables; the "
                   "distance on the frames); without it no positions are written")  # fmt: skip
    e.add_argument("--fov", type=float, help=f"horizontal field of view, {span('fov')} (default 70; "
                   "with --camera-height)")  # fmt: skip
    e.add_argument("--pitch", type=float, help=f"camera pitch, > 0 looking down, {span('pitch')} (default 0; "
                   "with --camera-height)")  # fmt: skip
    e.add_argument("--mp4", action="store_true",
                   help="image inputs too: an annotated MP4 per sequence instead of PNG frames")  # fmt: skip
    e.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from trustnav.perception.frames import plan_sequences
    from trustnav.perception.looking import LookingModel

    # everything that can be refused is refused before the output folder is touched
    check_bounds(args, "fps", "scan_frames", "sharpen", "camera_height", "fov", "pitch")
    ground = None
    if args.camera_height is not None:
        from trustnav.perception.localisation import FixedCameraGround

        ground = FixedCameraGround(args.camera_height, 70.0 if args.fov is None else args.fov, args.pitch or 0.0)
    elif args.fov is not None or args.pitch is not None:
        raise ValueError("--fov and --pitch place people on the ground only with --camera-height")
    check_bounds(args, "max_frames", "max_seconds", "open_timeout")
    if args.show and not _gui_available():
        raise ValueError("--show needs an OpenCV that can open windows; this one is headless "
                         "(opencv-python-headless): write the annotated output with --mp4 instead")  # fmt: skip
    if args.realtime:
        args.perception = "realtime"
    elif args.perception is None:  # live input runs in real time unless --perception offline is given
        from trustnav.perception.live import is_live_source

        live = any(is_live_source(str(i)) for i in args.inputs)
        mediapipe = args.backend == "mediapipe" and args.proposer == "detector"
        args.perception = "realtime" if live and mediapipe else "offline"
    if args.perception == "realtime" and (args.backend != "mediapipe" or args.proposer != "detector"):
        raise ValueError("--realtime runs on the mediapipe backend with the detector as proposer")
    legacy = args.sharpen or args.scan_frames != 1 or args.no_body_search
    if legacy and (args.backend != "mediapipe" or args.proposer != "blazepose"):
        raise ValueError("--sharpen, --scan-frames and --no-body-search apply to --proposer blazepose (mediapipe) only")
    if args.backend == "mediapipe" and args.proposer == "detector":
        from trustnav.perception.detector import resolve_model

        args.detector_model = str(resolve_model(args.detector_model))  # a missing file: refused here
    elif args.detector_model is not None:
        raise ValueError("--detector-model applies to --proposer detector (mediapipe backend) only")
    sequences = plan_sequences(args.inputs, one_sequence=args.one_sequence)
    eye = LookingModel.from_file(args.looking_weights)
    face = None
    if args.face:  # eye contact from the face too, fused with LOOKING (graphs loaded once, shared)
        from trustnav.perception.face import FaceConfig, FaceEyeContact

        face = FaceEyeContact(FaceConfig(fov_deg=70.0 if args.fov is None else args.fov))
    live_source = None
    if sequences[0].kind == "live":  # opened before anything is written: a bad source fails cleanly
        from trustnav.perception.live import LiveSource

        live_source = LiveSource(sequences[0].source, open_timeout=args.open_timeout, read_timeout=args.open_timeout)
    try:
        return _write_run(args, sequences, eye, face, ground, live_source)
    finally:
        if live_source is not None:
            live_source.close()  # also when the run failed before reading it


def _gui_available() -> bool:
    """Whether this OpenCV can open windows (the headless build trustnav depends on cannot)."""
    import cv2

    try:
        cv2.namedWindow("trustnav-probe", cv2.WINDOW_NORMAL)
        cv2.destroyWindow("trustnav-probe")
    except cv2.error:
        return False
    return True


def _show(img, title: str) -> bool:
    """Show an annotated frame; True when the user pressed q or Esc."""
    import cv2

    cv2.imshow(f"trustnav estimate: {title}", img)
    return (cv2.waitKey(1) & 0xFF) in (ord("q"), 27)


def _write_run(args: argparse.Namespace, sequences, eye, face, ground, live_source) -> int:  # type: ignore[no-untyped-def]
    """Run :func:`estimate_sequences` (arguments checked, inputs planned), writing tables and pictures."""
    from trustnav.perception.estimate import estimate_sequences
    from trustnav.perception.face import FACE_FIELDS
    from trustnav.perception.frames import frame_count
    from trustnav.perception.live import frames_due
    from trustnav.perception.optional_backends import make_backend
    from trustnav.progress import Progress
    from trustnav.trust.params import MOVING_AVERAGE_TRUST, PAPER_TRUST, SECONDS_TRUST
    from trustnav.viz.annotate import AnnotatedOutput, annotate

    folder = OutputFolder(args.out, args.overwrite, ESTIMATE_OUTPUTS)
    earlier = folder.has_earlier_outputs()
    with folder:  # written beside --out, moved into place at the end (removed if the run fails)
        out = folder.path
        kwargs = {}
        if args.backend == "mediapipe":
            kwargs = {"scan_frames": args.scan_frames, "sharpen": args.sharpen, "body_search": not args.no_body_search,
                      "proposer": args.proposer, "detector_model": args.detector_model}  # fmt: skip
        backend = make_backend(args.backend, video=True, realtime=args.perception == "realtime", **kwargs)
        sink = TrackTable(out, (() if face is None else FACE_FIELDS) + (() if ground is None else ground.FIELDS))
        images = AnnotatedOutput(out, sequences, args.mp4)
        read = skipped = 0
        rejected: list[dict] = []  # proposals the landmark model or the geometry gate turned down
        is_live = sequences[0].kind == "live"
        total = None if is_live else frame_count([f for s in sequences for f in s.files])
        if total is not None and args.max_frames is not None:
            total = min(total, args.max_frames)
        bar = Progress(total, "estimate", "frame")
        cues = None
        if face is not None:  # eye contact from the face too, fused with LOOKING
            from trustnav.perception.cues import default_cues, with_face

            cues = lambda: with_face(default_cues(eye), face)  # noqa: E731
        law = {"seconds": SECONDS_TRUST, "paper": PAPER_TRUST, "moving-average": MOVING_AVERAGE_TRUST}[args.trust]
        frames = estimate_sequences(sequences, backend, eye, cues=cues, trust=law, fps=args.fps, ground=ground,
                                    max_frames=args.max_frames, max_seconds=args.max_seconds, live=live_source,
                                    on_stream_end=lambda msg: bar.write(f"trustnav: {msg}; stopping"))  # fmt: skip
        main_thread = threading.current_thread() is threading.main_thread()
        old_term = signal.signal(signal.SIGTERM, raise_interrupt) if main_thread else None
        completed = interrupted = False  # completed: every sequence read to its end (the bar shows 100 %)
        seq, t_first, written = None, None, 0  # live: capture time of the first frame, video frames written
        try:
            for f in frames:
                res = f.result
                if f.sequence is not seq:
                    seq, t_first, written = f.sequence, None, 0
                    images.start(seq, f.fps)
                    bar.describe(seq.label[-30:])
                if res.error is not None:
                    skipped += 1
                    bar.write(f"trustnav: skipped frame {res.name}: {res.error}")
                bar.update(1)
                if res.error is not None:
                    continue
                read += 1
                sink.add(res.records)
                rejected.extend(f.rejected)
                if not args.no_images or args.show:
                    img = annotate(res.rgb, res.records, [tp.person.keypoints for tp in res.people], f.labels)
                    if not args.no_images:
                        repeat = 1
                        if seq.kind == "live":  # the video plays in real time at the rate achieved
                            t_first = res.time if t_first is None else t_first
                            most = max(1, round(f.fps * args.open_timeout))  # a jump in a stream's clock
                            repeat = frames_due(res.time, t_first, f.fps, written, most)
                        for _ in range(repeat):
                            images.add(res.name, img)
                        written += repeat
                    if args.show and _show(img, seq.label):
                        raise KeyboardInterrupt  # q or Esc in the window: stop as Ctrl-C does
            completed = True
        except KeyboardInterrupt:
            interrupted = True
        finally:
            # the records are saved whatever happens; a second Ctrl-C must not cut this short
            old_int = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
            try:
                frames.close()  # a live source closed, its dropped frames counted
                bar.close(finished=completed)
                images.close()
                sink.close()
                if hasattr(backend, "last_rejections"):
                    (out / "rejected.json").write_text(json.dumps(rejected, indent=1))
                if hasattr(backend, "close"):
                    backend.close()
            finally:
                if main_thread:
                    signal.signal(signal.SIGINT, old_int)
                    signal.signal(signal.SIGTERM, old_term)
        rows, dropped = sink.rows, (live_source.dropped if is_live else 0)
        if interrupted:
            # the records so far are kept: in --out when it held no earlier outputs, else beside it
            if not rows:
                folder.discard()
                print(f"trustnav: interrupted after {read} frames; no records, {folder.out} left as it was",
                      file=sys.stderr)  # fmt: skip
                return 130
            kept, note = (folder.keep_aside(), f" ({folder.out} keeps the earlier outputs)") if earlier else (
                folder.commit(), "")  # fmt: skip
            lost = f" ({dropped} live frames dropped)" if is_live else ""
            print(f"trustnav: interrupted after {read} frames{lost}; kept {len(rows)} records in "
                  f"{kept / 'tracks.csv'} and tracks.json{note}", file=sys.stderr)  # fmt: skip
            return 130
        if read == 0:
            folder.discard()  # no header-only tables that would block a rerun
            print(f"trustnav: error: none of the {skipped} input frames could be read (see above); "
                  f"nothing to estimate", file=sys.stderr)  # fmt: skip
            return 1
    tracks = len({(r["sequence"], r["track_id"]) for r in rows})
    lost = f", {dropped} live frames dropped (slower than the camera)" if is_live else ""
    print(f"estimate: {read} frames in {len(sequences)} sequence{'s' * (len(sequences) > 1)}, {len(rows)} records, "
          f"{tracks} tracks, {skipped} frames skipped{lost}; wrote {folder.out}")  # fmt: skip
    if rejected:
        gate = sum("landmark model" not in r["reason"] for r in rejected)
        print(f"  {len(rejected)} detector boxes rejected ({gate} by the geometry gate, {len(rejected) - gate} not "
              f"confirmed by the landmark model): rejected.json")  # fmt: skip
    if ground is None:
        print("  no ground positions: give --camera-height (and --fov, --pitch) to place people on the ground")
    else:
        placed = sum(r.get("distance_m") is not None for r in rows)
        print(f"  {placed} of {len(rows)} records placed on the ground (ahead_m, left_m with sd; camera "
              f"{ground.height:g} m up, {ground.fov_deg:g} deg, pitch {ground.pitch_deg:g} deg)")  # fmt: skip
    return 0
