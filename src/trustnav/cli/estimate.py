"""`trustnav estimate INPUTS`: perception + trust on images, folders of frames, videos or a live source
(:func:`trustnav.perception.estimate.estimate_sequences`); this module writes the annotated frames and
tracks.csv/json (:class:`trustnav.outputs.TrackTable`), atomically (:class:`trustnav.outputs.OutputFolder`)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from dataclasses import replace

from trustnav.cli.common import add_removed, check_bounds, span
from trustnav.outputs import OutputFolder, no_interrupts

ESTIMATE_OUTPUTS = ("frames", "annotated*.mp4", "tracks.csv", "tracks.json", "rejected.json")
#: Options that were removed, and why (a one-line error if given).
REMOVED_OPTIONS = {
    "--no-body-search": "the HOG body-shape search it skipped was retired in issue 35 (the YOLOX-Nano person "
    "detector, the default, finds the people it found on the labelled sets)",
    "--proposer": "BlazePose's tiled person search was retired in issue 35; people are proposed by the YOLOX-Nano "
    "person detector (choose its file with --detector-model FILE)",
    "--scan-frames": "it shared out BlazePose's tiled search, retired in issue 35; for a faster run use --realtime",
    "--sharpen": "it sharpened the frame for BlazePose's tiled search, retired in issue 35; the YOLOX-Nano "
    "person detector needs no sharpening",
}


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
    e.add_argument("--realtime", action="store_true",
                   help="real-time perception (same as --perception realtime): the detector on every frame, "
                   "landmarks refitted a few times a second and carried between (docs/perception.md)")  # fmt: skip
    e.add_argument("--detector-model", metavar="FILE",
                   help="the YOLOX-Nano ONNX file (default: ../shared/models/yolox/ of a checkout, "
                   "$TRUSTNAV_YOLOX_MODEL, the user cache, else downloaded once; a FILE given is never "
                   "downloaded)")  # fmt: skip
    e.add_argument("--perception", choices=["offline", "realtime"], default=None,
                   help="offline (default for files): every box of every frame fitted; realtime (= --realtime, "
                   "the default for live input): the detector on every frame, landmarks staggered "
                   "(docs/perception.md)")  # fmt: skip
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
    add_removed(e, REMOVED_OPTIONS)
    e.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from trustnav.perception.detector import resolve_model
    from trustnav.perception.estimate import estimate_sequences
    from trustnav.perception.face import FACE_FIELDS, OFFLINE_SHIFT_FITS, FaceConfig, FaceEyeContact
    from trustnav.perception.frames import frame_count, plan_sequences
    from trustnav.perception.live import LiveSource, is_live_source
    from trustnav.perception.localisation import FixedCameraGround
    from trustnav.perception.looking import LookingModel
    from trustnav.perception.optional_backends import make_backend
    from trustnav.progress import Progress
    from trustnav.trust.params import TRUST_LAWS
    from trustnav.viz.annotate import EstimateOutput, gui_available, show
    from trustnav.viz.report import estimate_summary

    # everything that can be refused is refused before the output folder is touched
    check_bounds(args, "fps", "camera_height", "fov", "pitch")
    ground = None
    if args.camera_height is not None:
        ground = FixedCameraGround(args.camera_height, 70.0 if args.fov is None else args.fov, args.pitch or 0.0)
    elif args.fov is not None or args.pitch is not None:
        raise ValueError("--fov and --pitch place people on the ground only with --camera-height")
    check_bounds(args, "max_frames", "max_seconds", "open_timeout")
    if args.show and not gui_available():
        raise ValueError("--show needs an OpenCV that can open windows; this one is headless "
                         "(opencv-python-headless): write the annotated output with --mp4 instead")  # fmt: skip
    if args.realtime:
        args.perception = "realtime"
    elif args.perception is None:  # live input runs in real time unless --perception offline is given
        live = any(is_live_source(str(i)) for i in args.inputs)
        args.perception = "realtime" if live and args.backend == "mediapipe" else "offline"
    if args.perception == "realtime" and args.backend != "mediapipe":
        raise ValueError("--realtime runs on the mediapipe backend")
    if args.backend == "mediapipe":
        args.detector_model = str(resolve_model(args.detector_model))  # a missing file: refused here
    elif args.detector_model is not None:
        raise ValueError("--detector-model applies to the mediapipe backend only")
    sequences = plan_sequences(args.inputs, one_sequence=args.one_sequence)
    eye = LookingModel.from_file(args.looking_weights)
    face = None
    # offline, a small face is fitted on a few shifted crops (FaceConfig.shift_fits); real time, once
    face_config = FaceConfig(shift_fits=OFFLINE_SHIFT_FITS if args.perception == "offline" else 1)
    if args.face:  # eye contact from the face too, fused with LOOKING (graphs loaded once, shared)
        face_config = replace(face_config, fov_deg=70.0 if args.fov is None else args.fov)
        face = FaceEyeContact(face_config)
    folder = OutputFolder(args.out, args.overwrite, ESTIMATE_OUTPUTS)
    earlier = folder.has_earlier_outputs()
    live_source = None
    if sequences[0].kind == "live":  # opened before anything is written: a bad source fails cleanly
        live_source = LiveSource(sequences[0].source, open_timeout=args.open_timeout, read_timeout=args.open_timeout)
    # written beside --out, moved into place at the end (removed if the run fails); the live source closed in any case
    with folder, contextlib.closing(live_source) if live_source is not None else contextlib.nullcontext():
        mediapipe = {"detector_model": args.detector_model} if args.backend == "mediapipe" else {}
        backend = make_backend(args.backend, video=True, realtime=args.perception == "realtime", **mediapipe)
        extra = (() if face is None else FACE_FIELDS) + (() if ground is None else ground.FIELDS)
        output = EstimateOutput(folder.path, sequences, args.mp4, extra, not args.no_images,
                                hasattr(backend, "last_rejections"))  # fmt: skip
        is_live = sequences[0].kind == "live"
        total = None if is_live else frame_count([f for s in sequences for f in s.files])
        bar = Progress(total and min(total, args.max_frames or total), "estimate", "frame")
        frames = estimate_sequences(sequences, backend, eye, face=face, face_config=face_config,
                                    trust=TRUST_LAWS[args.trust], fps=args.fps, ground=ground,
                                    max_frames=args.max_frames, max_seconds=args.max_seconds, live=live_source,
                                    max_gap=args.open_timeout,
                                    on_stream_end=lambda msg: bar.write(f"trustnav: {msg}; stopping"))  # fmt: skip
        read = skipped = 0
        completed = interrupted = False  # completed: every sequence read to its end (the bar shows 100 %)
        seq = None
        try:
            for f in frames:
                res = f.result
                if f.sequence is not seq:
                    seq = f.sequence
                    bar.describe(seq.label[-30:])
                if res.error is not None:
                    skipped += 1
                    bar.write(f"trustnav: skipped frame {res.name}: {res.error}")
                bar.update(1)
                if res.error is None:
                    read += 1
                    img = output.add(f, draw=args.show)
                    if args.show and show(img, seq.label):
                        raise KeyboardInterrupt  # q or Esc in the window: stop as Ctrl-C does
            completed = True
        except KeyboardInterrupt:
            interrupted = True
        finally:
            with no_interrupts():  # the records are saved whatever happens; a second Ctrl-C must not cut this short
                frames.close()  # a live source closed, its dropped frames counted
                bar.close(finished=completed)
                output.close()
                if hasattr(backend, "close"):
                    backend.close()
        rows, dropped = output.rows, (live_source.dropped if is_live else None)
        if interrupted:
            if not rows:  # else the records so far are kept: in --out if it held no earlier outputs, else beside it
                folder.discard()
                print(f"trustnav: interrupted after {read} frames; no records, {folder.out} left as it was",
                      file=sys.stderr)  # fmt: skip
                return 130
            kept, note = folder.keep(earlier)
            lost = f" ({dropped} live frames dropped)" if is_live else ""
            print(f"trustnav: interrupted after {read} frames{lost}; kept {len(rows)} records in "
                  f"{kept / 'tracks.csv'} and tracks.json{note}", file=sys.stderr)  # fmt: skip
            return 130
        if read == 0:
            folder.discard()  # no header-only tables that would block a rerun
            print(f"trustnav: error: none of the {skipped} input frames could be read (see above); "
                  f"nothing to estimate", file=sys.stderr)  # fmt: skip
            return 1
    lines = estimate_summary(read, len(sequences), rows, skipped, dropped, output.rejected, ground, folder.out)
    print("\n".join(lines))
    return 0
