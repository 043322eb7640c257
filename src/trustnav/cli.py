"""`trustnav ...` entry points (thin: parse, call sim/viz, write files).

Output rule (every command but ``sweep``, which resumes into its folder on purpose): a folder that
already holds files is never written into silently. ``--overwrite`` replaces trustnav's own
outputs there (files of other names are left alone); default folders are named after the run
(scenario and solver, case and sensing) so two different runs never share one; ``demo`` replaces
its own default folder ``out/demo``, since it is run again and again.

Nothing lost, nothing mixed: a command writes into a temporary sibling of its folder
(:class:`OutputFolder`) and moves the outputs into place only when the run is done, so an
interruption (Ctrl-C, SIGTERM) or a failure leaves the earlier outputs as they were and nothing that
blocks a rerun. Every number an option takes is checked against the range its help text gives
(:data:`BOUNDS`), with a one-line error naming the option.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import itertools
import json
import math
import os
import secrets
import shutil
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from trustnav.schema import Integer, Invalid, Number

__all__ = ["BOUNDS", "OutputFolder", "main"]

ESTIMATE_OUTPUTS = ("frames", "annotated*.mp4", "tracks.csv", "tracks.json", "rejected.json")
SCENARIO_OUTPUTS = ("paper-*.png", "metrics.json")
DRIVE_OUTPUTS = ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames", "metrics.json",
                 "attentive", "distracted")  # fmt: skip

#: The lowest camera rate at which ``drive --perception realtime`` is allowed (frames/s).
REALTIME_MIN_RATE = 10.0

#: option -> its rule (trustnav.schema): the documented range of every number an option takes. Rates
#: and the CARLA timeout are bounded so that no run takes hours.
BOUNDS: dict[str, Number | Integer] = {
    "seed": Integer(0, whole_floats=True),
    "rate": Number(0, 60, lo_open=True, unit=" frames per second"),
    "control_rate": Number(1, 200, unit=" steps per second"),
    "fps": Number(0, 240, lo_open=True, unit=" frames per second"),
    "scan_frames": Integer(1, 100, whole_floats=True),
    "sharpen": Number(0, 3),
    "max_frames": Integer(1, whole_floats=True),
    "max_seconds": Number(0, lo_open=True, unit=" s"),
    "open_timeout": Number(0, 600, lo_open=True, unit=" s"),
    "port": Integer(1, 65535, whole_floats=True),
    "timeout": Number(0, 600, lo_open=True, unit=" s"),
    "workers": Integer(1, 256, whole_floats=True),
    "batch": Integer(1, 10000, whole_floats=True),
    "camera_height": Number(0.2, 20, unit=" m"),
    "fov": Number(10, 170, unit=" degrees"),
    "pitch": Number(-45, 45, unit=" degrees"),
    "safety_radius": Number(0, 20, lo_open=True, unit=" m"),
    "horizon": Integer(1, 100, unit=" steps", whole_floats=True),
    "v_max": Number(0, 30, lo_open=True, unit=" m/s"),
    "duration": Number(0, 600, lo_open=True, unit=" s"),
    "carla_fov": Number(10, 170, unit=" degrees"),
    "search_seconds": Number(0, 10, lo_open=True, unit=" s"),
    "perception_latency": Number(0, 5, unit=" s"),  # sim.driving.world.MAX_PERCEPTION_LATENCY (lazy imports)
}


def _range(dest: str) -> str:
    """The range of an option as its help text and its error give it: 'in (0, 60] frames per second'."""
    rule = BOUNDS[dest]
    if isinstance(rule, Number) and math.isfinite(rule.lo) and math.isfinite(rule.hi):
        return rule.bounds
    return rule.expected


def check_bounds(args: argparse.Namespace, *dests: str) -> None:
    """Raise ValueError naming the option (``--seed must be an integer >= 0, got -1``) for the first
    of ``dests`` whose value (None: not given) lies outside :data:`BOUNDS`."""
    for dest in dests:
        value = getattr(args, dest, None)
        if value is None:
            continue
        try:
            BOUNDS[dest](value)
        except Invalid:
            shown = f"{value:g}" if isinstance(value, float) else repr(value) if isinstance(value, str) else value
            raise ValueError(f"--{dest.replace('_', '-')} must be {_range(dest)}, got {shown}") from None


# -- output folders written whole or not at all ----------------------------------------------------

_PARTIAL = ".trustnav-{pid}-{token}.partial"


@contextlib.contextmanager
def _no_interrupts() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait (are ignored) while files are moved into place: a move is never cut short."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


class OutputFolder:
    """An output folder written whole or not at all.

    Refuses (ValueError, before anything is written) an ``out`` that is a file, or a folder that holds
    files unless ``overwrite``. The command writes into :attr:`path`, a temporary sibling of ``out``
    (``.<name>.trustnav-<pid>-<token>.partial``); :meth:`commit` moves the finished outputs into ``out``
    (trustnav's earlier ``outputs`` there, glob patterns, are replaced; files of other names are left
    alone), :meth:`discard` removes them. As a context manager it commits on a normal exit and discards
    on any exception (Ctrl-C included): an interrupted or failed run leaves ``out`` as it was and
    nothing that blocks a rerun. Temporary folders left by a killed run (its process gone) are removed
    the next time the same ``out`` is written.
    """

    def __init__(self, out: str | Path, overwrite: bool, outputs: tuple[str, ...]) -> None:
        self.out = Path(out)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"--out {self.out} is a file, expected a folder (new or empty) for the outputs")
        if self.out.is_dir() and any(self.out.iterdir()) and not overwrite:
            raise ValueError(
                f"--out {self.out} is not empty (outputs of an earlier run?): pass --overwrite to replace "
                "trustnav's outputs there, or choose a new folder"
            )
        self.outputs = outputs
        self._path: Path | None = None
        self.state = "new"  # -> open -> committed | discarded | kept aside

    @property
    def path(self) -> Path:
        """Where the command writes (the temporary folder, until :meth:`commit`)."""
        if self._path is None:
            raise RuntimeError("OutputFolder.path before open()")
        return self._path

    def has_earlier_outputs(self) -> bool:
        """Whether ``out`` holds outputs of an earlier run (what :meth:`commit` would replace)."""
        return self.out.is_dir() and any(any(self.out.glob(p)) for p in self.outputs)

    def final(self, path: Path) -> Path:
        """Where ``path`` (under :attr:`path`) will be once committed."""
        return self.out / Path(path).relative_to(self.path)

    def open(self) -> Path:
        real = self.out.resolve()
        real.parent.mkdir(parents=True, exist_ok=True)
        for stale in real.parent.glob(f".{glob.escape(real.name)}{_PARTIAL.format(pid='*', token='*')}"):
            pid = stale.name[len(real.name) + 1 :].split("-")[1]
            if pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(stale, ignore_errors=True)
        self._path = real.parent / f".{real.name}{_PARTIAL.format(pid=os.getpid(), token=secrets.token_hex(4))}"
        self._path.mkdir()
        self.state = "open"
        return self._path

    def commit(self) -> Path:
        """Move the outputs into ``out`` (Ctrl-C waits until they are all there); returns ``out``."""
        tmp = self.path
        with _no_interrupts():
            if not self.out.exists():
                tmp.rename(self.out.resolve())
            else:
                for pattern in self.outputs:
                    for old in self.out.glob(pattern):
                        _remove(old)
                for entry in sorted(tmp.iterdir()):
                    target = self.out / entry.name
                    if target.exists() or target.is_symlink():
                        _remove(target)
                    shutil.move(entry, target)
                tmp.rmdir()
        self.state = "committed"
        return self.out

    def discard(self) -> None:
        """Remove what the run wrote; ``out`` stays as it was."""
        if self._path is not None:
            with _no_interrupts():
                shutil.rmtree(self._path, ignore_errors=True)
        self.state = "discarded"

    def keep_aside(self, suffix: str = "interrupted") -> Path:
        """Keep what the run wrote beside ``out`` (``<out>.interrupted``, ``-2``... if taken), leaving
        ``out`` as it was; returns that folder."""
        real = self.out.resolve()
        where, k = real.with_name(f"{real.name}.{suffix}"), 2
        while where.exists():
            where, k = real.with_name(f"{real.name}.{suffix}-{k}"), k + 1
        with _no_interrupts():
            self.path.rename(where)
        self.state = "kept aside"
        return self.out.with_name(where.name)

    def __enter__(self) -> OutputFolder:
        self.open()
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if self.state == "open":
            if exc_type is None:
                self.commit()
            else:
                self.discard()


def _scenario(args: argparse.Namespace) -> int:
    from trustnav.sim.engine import make_solver
    from trustnav.sim.paper import run_scenario
    from trustnav.viz.paper_plots import plot_scenario

    make_solver(args.solver)  # refuse an unknown solver before anything is written
    default = f"out/{args.name}" if args.solver == "sqp" else f"out/{args.name}-{args.solver}"
    folder = OutputFolder(args.out or default, args.overwrite, SCENARIO_OUTPUTS)
    result = run_scenario(args.name, solver=args.solver)
    with folder:
        fig = folder.final(plot_scenario(result, folder.path))
        (folder.path / "metrics.json").write_text(json.dumps(result.metrics, indent=2))
    print(f"{args.name} ({args.solver}): wrote {fig} and {folder.out / 'metrics.json'}")
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


class _RecordSink:
    """tracks.csv written and flushed frame by frame; tracks.json written on close (also after an
    interruption), so an interrupted run keeps every record it produced."""

    FIELDS = ("frame", "track_id", "bbox", "eye_contact", "phone", "fluctuation", "smartphone_trait", "eye_trait",
              "pose_trait", "score", "trust", "sequence")  # fmt: skip

    def __init__(self, out: Path, extra: tuple[str, ...] = ()) -> None:
        import csv

        self.out = out
        self.rows: list[dict] = []
        self._fh = open(out / "tracks.csv", "w", newline="")  # closed in close()
        self._csv = csv.DictWriter(self._fh, fieldnames=(*self.FIELDS, *extra))
        self._csv.writeheader()
        self._fh.flush()

    def add(self, records: list[dict]) -> None:
        self.rows.extend(records)
        self._csv.writerows({**r, "bbox": " ".join(f"{v:g}" for v in r["bbox"])} for r in records)
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
        tmp = self.out / "tracks.json.part"
        tmp.write_text(json.dumps(self.rows, indent=1))
        tmp.replace(self.out / "tracks.json")


def _safe_name(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label) or "input"


class _Annotations:
    """Where annotated frames go, one name per input frame: ``frames/<stem>.png`` (a folder's
    frames under ``frames/<folder>/`` when there are several sequences), ``annotated.mp4`` (or
    ``annotated_<input>.mp4`` per video sequence when there are several)."""

    def __init__(self, out: Path, sequences: list, mp4: bool) -> None:
        self.out = out
        self.mp4 = mp4
        self.n_videos = sum(s.has_video or mp4 for s in sequences)
        self.nested = len(sequences) > 1
        self.used: set[Path] = set()
        self.writer = None
        self.size: tuple[int, int] | None = None
        self.seq = None

    def _unique(self, candidates: list[Path]) -> Path:
        for c in candidates:
            if c not in self.used:
                break
        else:
            base, k = candidates[-1], 2
            while (c := base.with_name(f"{base.stem}-{k}{base.suffix}")) in self.used:
                k += 1
        self.used.add(c)
        return c

    def start(self, seq, fps: float) -> None:
        self.close()
        self.seq, self.fps = seq, fps

    def add(self, name: str, img) -> None:
        import cv2

        seq = self.seq
        if seq.has_video or self.mp4:
            if self.writer is None:
                name_mp4 = "annotated.mp4" if self.n_videos == 1 else f"annotated_{_safe_name(seq.label)}.mp4"
                path = self._unique([self.out / name_mp4])
                self.size = (img.shape[1], img.shape[0])
                self.writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self.size)
            if (img.shape[1], img.shape[0]) != self.size:
                img = cv2.resize(img, self.size)
            self.writer.write(img)
            return
        folder = self.out / "frames"
        if self.nested and seq.kind == "folder":
            folder = folder / _safe_name(seq.label)
        stem = Path(name).stem
        path = self._unique([folder / f"{stem}.png", folder / f"{_safe_name(seq.label)}.png"])
        path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), img):
            raise OSError(f"cannot write {path}")

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()
            self.writer = None


def _raise_interrupt(signum, frame) -> None:  # SIGTERM (e.g. `timeout`) handled as Ctrl-C
    raise KeyboardInterrupt


def _estimate(args: argparse.Namespace) -> int:
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
        return _estimate_run(args, sequences, eye, face, ground, live_source)
    finally:
        if live_source is not None:
            live_source.close()  # also when the run failed before reading it


def _estimate_run(args: argparse.Namespace, sequences, eye, face, ground, live_source) -> int:
    """The estimate command's input loop and tables (arguments already checked, inputs planned)."""
    from trustnav.perception.face import FACE_FIELDS
    from trustnav.perception.frames import frame_count, iter_sequence, source_fps
    from trustnav.perception.live import frames_due
    from trustnav.perception.optional_backends import make_backend
    from trustnav.perception.phone import phone_label
    from trustnav.perception.pipeline import PerceptionPipeline, estimate
    from trustnav.perception.tracking import PersonTracker
    from trustnav.progress import Progress
    from trustnav.trust.estimator import TrustEstimator
    from trustnav.trust.params import MOVING_AVERAGE_TRUST, PAPER_TRUST, SECONDS_TRUST
    from trustnav.viz.annotate import annotate

    folder = OutputFolder(args.out, args.overwrite, ESTIMATE_OUTPUTS)
    earlier = folder.has_earlier_outputs()
    with folder:  # written beside --out, moved into place at the end (removed if the run fails)
        out = folder.path
        kwargs = {}
        if args.backend == "mediapipe":
            kwargs = {"scan_frames": args.scan_frames, "sharpen": args.sharpen, "body_search": not args.no_body_search,
                      "proposer": args.proposer, "detector_model": args.detector_model}  # fmt: skip
        backend = make_backend(args.backend, video=True, realtime=args.perception == "realtime", **kwargs)
        face_fields = () if face is None else FACE_FIELDS  # --face: eye_contact_face, face_confidence
        sink = _RecordSink(out, face_fields + (() if ground is None else ground.FIELDS))
        images = _Annotations(out, sequences, args.mp4)
        counts = {"read": 0, "skipped": 0, "dropped": 0}
        rejected: list[dict] = []  # proposals the landmark model or the geometry gate turned down
        interrupted = False
        is_live = sequences[0].kind == "live"
        total = None if is_live else frame_count([f for s in sequences for f in s.files])
        if total is not None and args.max_frames is not None:
            total = min(total, args.max_frames)
        bar = Progress(total, "estimate", "frame")

        def report(res) -> None:
            counts["skipped"] += 1
            bar.write(f"trustnav: skipped frame {res.name}: {res.error}")

        main_thread = threading.current_thread() is threading.main_thread()
        old_term = signal.signal(signal.SIGTERM, _raise_interrupt) if main_thread else None
        completed = False  # every sequence read to its end: the bar shows the run complete
        try:
            for seq in sequences:
                live = live_source if seq.kind == "live" else None
                if live is not None:
                    fps = live.fps or args.fps
                    items = live.frames(args.max_frames, args.max_seconds)
                else:
                    fps = source_fps(list(seq.files), args.fps) if seq.has_video else args.fps
                    items = itertools.islice(iter_sequence(seq.files), args.max_frames)
                if hasattr(backend, "reset"):
                    backend.reset()  # nothing followed from the previous sequence
                if face is None:
                    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), eye)
                else:
                    from trustnav.perception.cues import default_cues, with_face

                    cues = with_face(default_cues(eye), face)
                    pipeline = PerceptionPipeline(backend, PersonTracker(fps=fps), cues=cues)
                images.start(seq, fps)
                bar.describe(seq.label[-30:])
                law = {"seconds": SECONDS_TRUST, "paper": PAPER_TRUST, "moving-average": MOVING_AVERAGE_TRUST}
                trust = TrustEstimator(law[args.trust])
                t_first, written = None, 0  # live: capture time of the first frame, video frames written
                most = max(1, round(fps * args.open_timeout))  # a jump in a stream's clock writes no more
                try:
                    for res in estimate(items, pipeline, trust, fps, report, seq.label):
                        bar.update(1)
                        if res.error is not None:
                            continue
                        counts["read"] += 1
                        labels = [phone_label(tp.phone) for tp in res.people]
                        if ground is not None:  # where each person stands, from the camera's height
                            h, w = res.rgb.shape[:2]
                            for rec, tp in zip(res.records, res.people, strict=True):
                                rec.update(ground.fields(tp.person, w, h))
                            labels = [lab if r["distance_m"] is None else f"{lab} {r['distance_m']:.1f} m"
                                      for lab, r in zip(labels, res.records, strict=True)]  # fmt: skip
                        sink.add(res.records)
                        rejected.extend({"sequence": seq.label, "frame": res.name, **r.as_dict()}
                                        for r in getattr(backend, "last_rejections", []))  # fmt: skip
                        if not args.no_images or args.show:
                            img = annotate(res.rgb, res.records, [tp.person.keypoints for tp in res.people],
                                           labels)  # fmt: skip
                            if not args.no_images:
                                repeat = 1
                                if live is not None:  # the video plays in real time at the rate achieved
                                    t_first = res.time if t_first is None else t_first
                                    repeat = frames_due(res.time, t_first, fps, written, most)
                                for _ in range(repeat):
                                    images.add(res.name, img)
                                written += repeat
                            if args.show and _show(img, seq.label):
                                raise KeyboardInterrupt  # q or Esc in the window: stop as Ctrl-C does
                except TimeoutError as exc:  # a live stream that stopped sending: the end of that stream
                    bar.write(f"trustnav: {exc}; stopping")
                finally:
                    if live is not None:
                        counts["dropped"] += live.dropped
                        live.close()
            completed = True
        except KeyboardInterrupt:
            interrupted = True
        finally:
            # the records are saved whatever happens; a second Ctrl-C must not cut this short
            old_int = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
            try:
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
        rows = sink.rows
        if interrupted:
            # the records so far are kept: in --out when it held no earlier outputs, else beside it
            if not rows:
                folder.discard()
                print(f"trustnav: interrupted after {counts['read']} frames; no records, {folder.out} left as it was",
                      file=sys.stderr)  # fmt: skip
                return 130
            if earlier:
                kept = folder.keep_aside()
                note = f" ({folder.out} keeps the earlier outputs)"
            else:
                kept, note = folder.commit(), ""
            dropped = f" ({counts['dropped']} live frames dropped)" if is_live else ""
            print(f"trustnav: interrupted after {counts['read']} frames{dropped}; kept {len(rows)} records in "
                  f"{kept / 'tracks.csv'} and tracks.json{note}", file=sys.stderr)  # fmt: skip
            return 130
        if counts["read"] == 0:
            folder.discard()  # no header-only tables that would block a rerun
            print(f"trustnav: error: none of the {counts['skipped']} input frames could be read (see above); "
                  f"nothing to estimate", file=sys.stderr)  # fmt: skip
            return 1
    out = folder.out
    tracks = len({(r["sequence"], r["track_id"]) for r in rows})
    dropped = f", {counts['dropped']} live frames dropped (slower than the camera)" if is_live else ""
    print(f"estimate: {counts['read']} frames in {len(sequences)} sequence{'s' * (len(sequences) > 1)}, "
          f"{len(rows)} records, {tracks} tracks, {counts['skipped']} frames skipped{dropped}; "
          f"wrote {out}")  # fmt: skip
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


def _drive_runs(
    case: object,
    sensing: str,
    attentive: bool | None,
    seed: int,
    rate: float | None,
    out: Path,
    video: bool = True,
    control_rate: float | None = None,
    run_variant: object = None,
    label: str = "",
    state: str = "perceived",
    perception: str = "offline",
    search_seconds: float | None = None,
) -> list[tuple[str, dict, Path]]:
    """Run a driving case (a preset name, a scenario file or a DriveScenario; Case II: both variants
    unless one is asked for) and write its outputs.

    ``run_variant(scenario, attentive, progress) -> DriveResult`` drives one variant (default:
    trustnav's own world, :func:`trustnav.sim.driving.run_drive`; the CARLA bridge gives its own);
    ``label`` tags the world in titles ("CARLA")."""
    from trustnav.progress import step_reporter
    from trustnav.sim.driving import load_drive_scenario, make_render_sensing, run_drive
    from trustnav.viz.drive_plots import plot_distance, plot_top_view, write_drive_outputs

    def own_world(sc, att, progress):  # type: ignore[no-untyped-def]
        renderer = pipeline = None
        if sensing == "render":
            renderer, pipeline = make_render_sensing(sc, rate, realtime=perception == "realtime",
                                                     search_seconds=search_seconds)  # fmt: skip
        try:
            return run_drive(sc, sensing=sensing, seed=seed, attentive=att, capture_rate=rate,
                             control_rate=control_rate, renderer=renderer, pipeline=pipeline,
                             progress=progress, state=state)  # fmt: skip
        finally:
            if renderer is not None:
                renderer.close()
            if pipeline is not None and hasattr(pipeline.backend, "close"):
                pipeline.backend.close()

    drive_one = run_variant or own_world
    sc = case if hasattr(case, "pedestrians") else load_drive_scenario(case)  # type: ignore[arg-type]
    case = sc.name
    if attentive is not None:
        variants: list[tuple[str, bool | None]] = [("attentive" if attentive else "distracted", attentive)]
    elif sc.variants:
        variants = [(v, v == "attentive") for v in sc.variants]
    else:
        variants = [("", None)]
    done, results = [], []
    where_tag = f"{label}, " if label else ""
    for tag, att in variants:
        where = out / tag if len(variants) > 1 else out
        desc = f"{case}{' ' + tag if tag else ''} ({where_tag}{sensing})"
        with step_reporter(desc, sc.duration) as progress:  # the bar opens once the world has opened
            result = drive_one(sc, att, progress)  # type: ignore[operator]
        metrics = result.metrics()
        where.mkdir(parents=True, exist_ok=True)
        write_drive_outputs(result, where, video=video)
        (where / "metrics.json").write_text(json.dumps(metrics, indent=2))
        done.append((tag or case, metrics, where))
        results.append(result)
    if len(results) > 1:
        plot_distance(results, out / "distance.png")
        plot_top_view(results, out / "top_view.png", title=f"{sc.title} [{where_tag}{sensing} sensing]")
        (out / "metrics.json").write_text(json.dumps({tag: m for tag, m, _ in done}, indent=2))
    return done


def _drive_summary(done: list[tuple[str, dict, Path]], out: Path) -> None:
    for tag, m, where in done:
        ttg = "not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s"
        extra = f"  detection recall {m['detection_recall']:.2f}" if m.get("detection_recall") is not None else ""
        if m.get("perception_ms_median") is not None:
            extra += f"  perception {m['perception_ms_median']:.0f} ms (p95 {m['perception_ms_p95']:.0f})"
        if m.get("road_departure_max"):
            extra += f"  off the road by up to {m['road_departure_max']:.2f} m"
        if m.get("yield_s"):
            extra += f"  yielded {m['yield_s']:.1f} s"
        print(f"  {tag}: goal {ttg}  margin violations {m['margin_violations']}  relaxed steps "
              f"{m['relaxed_steps']}  fallback steps {m['fallback_steps']}  solve {m['solve_ms_median']:.2f} ms "
              f"(p95 {m['solve_ms_p95']:.2f}){extra}  -> {where}")  # fmt: skip
        for p in m["pedestrians"]:
            kind = "attentive" if p["attentive"] else "distracted"
            who = p["name"] if kind in p["name"] else f"{p['name']} ({kind})"  # not "attentive (attentive)"
            loc = ""
            if p.get("localisation_error_median") is not None:
                loc = (f"  located to {p['localisation_error_median']:.2f} m (p95 {p['localisation_error_p95']:.2f}), "
                       f"truth in the 90 % region {p['interval_coverage']:.0%}")  # fmt: skip
            print(f"      {who:<24} min distance {p['min_distance']:.2f} m  "
                  f"final trust {p['final_trust']:.2f}  frames seen {p['frames_seen']}{loc}")  # fmt: skip
        if m.get("state") == "perceived":
            print(f"      pedestrians perceived by the camera (--state true: the world's); "
                  f"identity switches {m.get('id_switches', 0)}")  # fmt: skip


def _drive_scenario(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The scenario of ``args.case`` (a preset name or a scenario file) with the camera, control and
    CARLA options of the command line applied; each refused with an error naming the option."""
    import dataclasses

    from trustnav.sim.driving import load_drive_scenario

    opt = lambda name: getattr(args, name, None)  # noqa: E731  (an option a caller's namespace lacks: not given)
    check_bounds(args, "seed", "rate", "control_rate", "port", "timeout", "fov", "camera_height", "pitch",
                 "safety_radius", "horizon", "v_max", "duration", "carla_fov", "perception_latency")  # fmt: skip
    sc = load_drive_scenario(args.case)
    camera = {k: v for k, v in (("fov_deg", opt("fov")), ("up", opt("camera_height")), ("pitch_deg", opt("pitch")))
              if v is not None}  # fmt: skip
    control = {k: v for k, v in (("safety_radius", opt("safety_radius")), ("horizon", opt("horizon")),
               ("reference_v_max", opt("v_max")),
               ("caution", None if opt("caution") is None else opt("caution") == "on")) if v is not None}  # fmt: skip
    route = {k: v for k, v in (("town", opt("town")), ("fov_deg", opt("carla_fov")),
             ("attentive_walker", _walker_arg(opt("attentive_walker"))),
             ("distracted_walker", _walker_arg(opt("distracted_walker")))) if v is not None}  # fmt: skip
    changes: dict = {}
    if camera:
        changes["camera"] = dataclasses.replace(sc.camera, **camera)
    if control:
        changes["control"] = dataclasses.replace(sc.control, **control)
    if route:
        changes["carla"] = dataclasses.replace(sc.carla, **route)
    if opt("duration") is not None:
        changes["duration"] = float(opt("duration"))
    if opt("perception_latency") is not None:
        changes["sensing"] = dataclasses.replace(sc.sensing, perception_latency=float(opt("perception_latency")))
    return dataclasses.replace(sc, **changes) if changes else sc


def _walker_arg(v: str | None) -> int | str | None:
    """A walker given on the command line: an index (digits) or a blueprint id."""
    return int(v) if v is not None and v.isdigit() else v


def _drive(args: argparse.Namespace) -> int:
    search = getattr(args, "search_seconds", None)
    if search is not None and getattr(args, "perception", "offline") != "realtime":
        raise ValueError("--search-seconds models the real-time perceiver's search: it needs --perception realtime")
    check_bounds(args, "search_seconds")
    if getattr(args, "perception", "offline") == "realtime":
        if args.sensing != "render":
            raise ValueError("--perception realtime needs --sensing render (camera frames to perceive)")
        if args.rate is None or args.rate < REALTIME_MIN_RATE:
            raise ValueError(f"--perception realtime needs --rate >= {REALTIME_MIN_RATE:g} frames/s: what its search "
                             "finds reaches the controller a frame later, and at 5 frames/s Case I already came "
                             "within R (docs/perception.md)")  # fmt: skip
    sc = _drive_scenario(args)
    route = ("town", "carla_fov", "attentive_walker", "distracted_walker")
    if args.world != "carla" and any(getattr(args, name, None) is not None for name in route):
        raise ValueError("--town, --carla-fov, --attentive-walker and --distracted-walker need --world carla")
    run_variant, label, on = None, "", ""
    errors: tuple[type[Exception], ...] = ()  # a world's failures that carry their own exit code
    if args.world == "carla":
        from trustnav.carla_bridge.command import CarlaCommandError, carla_runner

        errors = (CarlaCommandError,)

        try:
            address, run_variant = carla_runner(args, sc.carla.options())
        except CarlaCommandError as exc:
            print(f"trustnav: error: {exc}", file=sys.stderr)
            return exc.code
        label, on = "CARLA", f" on CARLA at {address}"
    stem = args.case if args.case in ("case-1", "case-2") else Path(args.case).stem
    default = f"out/{stem}" if args.sensing == "render" else f"out/{stem}-{args.sensing}"
    if args.world == "carla":
        default += "-carla"
    folder = OutputFolder(args.out or default, args.overwrite, DRIVE_OUTPUTS)
    with folder:  # written beside --out, moved into place at the end (removed if the run fails)
        try:
            done = _drive_runs(sc, args.sensing, args.attentive, args.seed, args.rate, folder.path,
                               video=not args.no_video, control_rate=args.control_rate, run_variant=run_variant,
                               label=label, state=getattr(args, "state", "perceived"),
                               perception=getattr(args, "perception", "offline"),
                               search_seconds=getattr(args, "search_seconds", None))  # fmt: skip
        except errors as exc:
            folder.discard()
            print(f"trustnav: error: {exc}", file=sys.stderr)
            return int(exc.code)  # type: ignore[attr-defined]
    out = folder.out
    done = [(tag, m, folder.final(where)) for tag, m, where in done]
    files = "top_view.png, trust.png, distance.png, drive.mp4, frames/, metrics.json"
    if args.no_video:
        files = files.replace("drive.mp4, ", "")
    if len(done) > 1:
        runs = ", ".join(f"{tag}/" for tag, _, _ in done)
        files = f"top_view.png, distance.png, metrics.json comparing the runs; per run in {runs}: {files}"
    print(f"drive {sc.name}{on} ({args.sensing} sensing): wrote {out}/ ({files})")
    _drive_summary(done, out)
    return 0


COMPARE_OUTPUTS = ("compare.png", "metrics.json", "table.csv")


def _compare(args: argparse.Namespace) -> int:
    """``trustnav compare SCENARIO``: trust-aware beside constant trust 0 and 1 (one figure, a table)."""
    import csv

    from trustnav.progress import labelled_reporter
    from trustnav.sim.driving.compare import compare_trust, comparison_rows
    from trustnav.viz.drive_plots import plot_trust_comparison

    sc = _drive_scenario(args)
    stem = args.case if args.case in ("case-1", "case-2") else Path(args.case).stem
    folder = OutputFolder(args.out or f"out/compare-{stem}-{args.sensing}", args.overwrite, COMPARE_OUTPUTS)
    with labelled_reporter(sc.name, leave=False) as progress:
        comp = compare_trust(sc, sensing=args.sensing, seed=args.seed, attentive=args.attentive, capture_rate=args.rate,
                             control_rate=args.control_rate, state=args.state, progress=progress)  # fmt: skip
    rows = comparison_rows(comp)
    with folder:
        groups = [(v, [(r.mode, r.result) for r in runs]) for v, runs in comp.by_variant()]
        plot_trust_comparison(groups, folder.path / "compare.png")
        metrics = {"scenario": sc.name, "sensing": args.sensing, "seed": args.seed, "state": args.state,
                   "table": rows, "runs": [dict(variant=r.variant, mode=r.mode, **r.result.metrics())
                                           for r in comp.runs]}  # fmt: skip
        (folder.path / "metrics.json").write_text(json.dumps(metrics, indent=2))
        with open(folder.path / "table.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["variant", "mode", "trust_given", "gamma", "pedestrian", "attentive", "min_distance",
                        "final_trust", "time_to_goal", "max_lateral_offset", "margin_violations"])  # fmt: skip
            for r in rows:
                for p in r["pedestrians"]:
                    w.writerow([r["variant"], r["mode"], r["trust_given"], r["gamma"], p["name"], p["attentive"],
                                p["min_distance"], p["final_trust"], r["time_to_goal"], r["max_lateral_offset"],
                                r["margin_violations"]])  # fmt: skip
    out = folder.out
    print(f"compare {sc.name} ({args.sensing} sensing, seed {args.seed}): wrote {out / 'compare.png'}, "
          f"{out / 'table.csv'}, {out / 'metrics.json'}")  # fmt: skip
    _compare_table(rows, sc.control.safety_radius)
    return 0


def _compare_table(rows: list[dict], radius: float) -> None:
    """The comparison as a text table: one line per run, closest approach per pedestrian."""
    names = [p["name"] for p in rows[0]["pedestrians"]]
    head = f"  {'run':<30}{'gamma':>7}" + "".join(f"{'min d ' + n:>18}" for n in names)
    print(head + f"{'goal':>9}{'bend':>8}{'in R':>6}")
    for r in rows:
        label = f"{r['variant'] + ': ' if r['variant'] else ''}{r['mode']}"
        gamma = "est." if r["gamma"] is None else f"{r['gamma']:.2f}"
        goal = "-" if r["time_to_goal"] is None else f"{r['time_to_goal']:.1f} s"
        cells = "".join(f"{p['min_distance']:>16.2f} m" for p in r["pedestrians"])
        print(f"  {label:<30}{gamma:>7}{cells}{goal:>9}{r['max_lateral_offset']:>6.2f} m{r['margin_violations']:>6}")
    print(
        f"  (min d: closest true distance, R = {radius:g} m; gamma: the barrier rate the controller got, est. = "
        "from each pedestrian's estimated trust; bend: largest offset from the lane centre; in R: steps inside R)"
    )


def _sweep(args: argparse.Namespace) -> int:
    from trustnav.campaigns.command import run_sweep_command

    check_bounds(args, "workers", "batch")
    return run_sweep_command(args)


#: the trust every pedestrian gets in the demo's trust-blind run: one value for all, as the control
#: run of the paper's Scenario II (`trustnav scenario paper-2`)
DEMO_EQUAL_TRUST = 1.0


class _EqualTrustWorld:
    """A drive world whose controller is handed one trust for every pedestrian (trust-blind);
    perception, trust estimation and the records run as usual. The demo's comparison run: the
    same world, camera and perception, only the trusts the MPC gets differ."""

    def __init__(self, sim: object, trust: float) -> None:
        self._sim = sim
        self._trust = float(trust)

    def observe(self):  # type: ignore[no-untyped-def]
        import dataclasses

        import numpy as np

        obs = self._sim.observe()  # type: ignore[attr-defined]
        return dataclasses.replace(obs, trusts=np.full(len(obs.trusts), self._trust))

    def __getattr__(self, name: str) -> object:
        return getattr(self._sim, name)


def _demo_drive(sc, seed: int, progress=None, equal_trust: float | None = None):  # type: ignore[no-untyped-def]
    """Case I in render sensing (rendered camera + perception), trust-aware or with
    ``equal_trust`` for everybody; returns the DriveResult."""
    from trustnav.sim.driving import make_render_sensing
    from trustnav.sim.driving.episode import DriveSimulation, drive, make_sensor, prepare_scenario

    renderer, pipeline = make_render_sensing(sc)
    try:
        sim = DriveSimulation(prepare_scenario(sc), seed=seed, sensor=make_sensor("render", renderer, pipeline))
        world = sim if equal_trust is None else _EqualTrustWorld(sim, equal_trust)
        return drive(world, "render", progress=progress)  # type: ignore[arg-type]
    finally:
        renderer.close()
        if hasattr(pipeline.backend, "close"):
            pipeline.backend.close()


def _demo_comparisons(result, seed: int, where: Path) -> dict[str, dict]:  # type: ignore[no-untyped-def]
    """The demo's story: Case I again with equal trust (trust-blind, render sensing as the
    trust-aware run) and trust-aware in keypoint sensing (ideal landmarks); the top view and the
    distance plot redrawn with them beside the trust-aware run, their metrics added to
    metrics.json (``equal_trust``, ``keypoints_sensing``). Returns the three runs' metrics."""
    from trustnav.progress import step_reporter
    from trustnav.sim.driving import run_drive
    from trustnav.viz.drive_plots import plot_distance, plot_top_view

    sc = result.scenario
    with step_reporter(f"case-1 equal trust {DEMO_EQUAL_TRUST:g} (render)", sc.duration) as progress:
        equal = _demo_drive(sc, seed, progress, equal_trust=DEMO_EQUAL_TRUST)
    keypoints = run_drive(sc, sensing="keypoints", seed=seed)
    label = f"equal trust {DEMO_EQUAL_TRUST:g}"
    plot_top_view(result, where / "top_view.png", comparisons=[(label, equal)],
                  offset_only=[("trust-aware, keypoint sensing", keypoints)])  # fmt: skip
    plot_distance(result, where / "distance.png", comparisons=[(label, equal)])
    runs = {"trust-aware": result.metrics(), "equal_trust": equal.metrics(), "keypoints_sensing": keypoints.metrics()}
    runs["equal_trust"]["trust_given_to_controller"] = DEMO_EQUAL_TRUST
    metrics = dict(runs["trust-aware"], equal_trust=runs["equal_trust"], keypoints_sensing=runs["keypoints_sensing"])
    (where / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return runs


def _demo_headline(runs: dict[str, dict]) -> None:
    """The demo's numbers: per pedestrian the closest approach and the final trust, the time to
    goal and the bend, for the trust-aware run, the equal-trust run and keypoint sensing."""
    cols = [("trust-aware", runs["trust-aware"]), (f"equal trust {DEMO_EQUAL_TRUST:g} (trust-blind)",
            runs["equal_trust"]), ("trust-aware, keypoint sensing", runs["keypoints_sensing"])]  # fmt: skip
    m0 = runs["trust-aware"]
    print(f"headline (Case I, R = {m0.get('safety_radius', 2.5):g} m): closest approach (final trust) per pedestrian")
    print((f"  {'':<22}" + "".join(f"{name:<32}" for name, _ in cols)).rstrip())
    for j, p in enumerate(m0["pedestrians"]):
        cells = []
        for name, m in cols:
            q = m["pedestrians"][j]
            trust = f"{DEMO_EQUAL_TRUST:.2f} fixed" if name.startswith("equal") else f"{q['final_trust']:.2f}"
            cells.append(f"{q['min_distance']:.2f} m (trust {trust})")
        print((f"  {p['name']:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())
    ttg = ["not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s" for _, m in cols]
    rows = [("time to goal", ttg), ("bend off the lane", [f"{m['max_lateral_offset']:.2f} m" for _, m in cols]),
            ("margin violations", [str(m["margin_violations"]) for _, m in cols])]  # fmt: skip
    for head, cells in rows:
        print((f"  {head:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())


def _demo(args: argparse.Namespace) -> int:
    import time

    # the demo is run again and again: its own default folder is replaced (trustnav's outputs only);
    # a folder the user names follows the rule of every command
    check_bounds(args, "seed")
    folder = OutputFolder(args.out or "out/demo", args.overwrite or args.out is None, DRIVE_OUTPUTS)
    t0 = time.perf_counter()
    kept: list = []  # the trust-aware run, for the comparison

    def trust_aware(sc, _att, progress):  # type: ignore[no-untyped-def]
        kept.append(_demo_drive(sc, args.seed, progress))
        return kept[-1]

    runs = None
    with folder:  # written beside the folder, moved into place at the end: Ctrl-C keeps the earlier demo
        done = _drive_runs("case-1", "render", None, args.seed, None, folder.path, run_variant=trust_aware)
        if kept:
            runs = _demo_comparisons(kept[0], args.seed, folder.path)
    out = folder.out
    done = [(tag, m, folder.final(where)) for tag, m, where in done]
    print(f"demo (paper Case I, camera -> perception -> trust -> MPC, {time.perf_counter() - t0:.0f} s): wrote")
    for name in ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames/", "metrics.json"):
        print(f"  {out / name}")
    _drive_summary(done, out)
    if runs is not None:
        _demo_headline(runs)
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (exit code 2, no usage dump) that names the option."""

    def error(self, message: str):  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _scenario_options(d: argparse.ArgumentParser) -> None:
    """The camera and control options of ``drive`` and ``compare`` (each overrides the scenario's)."""
    c = d.add_argument_group("camera (default: the scenario's)")
    c.add_argument("--fov", type=float, help=f"horizontal field of view, {_range('fov')}")
    c.add_argument("--camera-height", type=float, help=f"camera height above the ground, {_range('camera_height')}")
    c.add_argument("--pitch", type=float, help=f"camera pitch, > 0 looking down, {_range('pitch')}")
    k = d.add_argument_group("control (default: the scenario's)")
    k.add_argument("--safety-radius", type=float, help=f"the margin R, {_range('safety_radius')}")
    k.add_argument("--horizon", type=int, help=f"MPC horizon N_h, {_range('horizon')}")
    k.add_argument("--v-max", type=float, help=f"speed bound of the reference, {_range('v_max')}")
    k.add_argument("--duration", type=float, help=f"time limit of an episode, {_range('duration')}")
    k.add_argument("--caution", choices=("on", "off"),
                   help="trust-aware speed bound near pedestrians who might step out (default: the scenario's "
                   "[control] caution; off: the paper's controller; docs/controller.md)")  # fmt: skip
    p = d.add_argument_group("perception (default: the scenario's)")
    p.add_argument("--perception-latency", type=float, metavar="S",
                   help=f"seconds from a frame's capture to its people reaching the controller's estimates, "
                   f"{_range('perception_latency')} (default: the scenario's [sensing] perception_latency, 0; "
                   "the 2-core machine's real-time perception takes ~0.1-0.4 s, docs/perception.md)")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="trustnav", description="Trust-aware safe navigation (MPC-CBF with pedestrian trust).")
    p.add_argument("--version", action="version", version=f"trustnav {_version()}")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser(
        "scenario", help="run one of the paper's numerical scenarios and write its figure + metrics.json"
    )
    s.add_argument("name", choices=["paper-1", "paper-2", "paper-3"])
    s.add_argument("--out", help="output directory (default out/<name>, out/<name>-<solver> for another solver)")
    s.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    s.add_argument("--solver", choices=["sqp", "slsqp", "slsqp-authors"], default="sqp",
                   help="sqp: fast default; slsqp: SLSQP, tuned; slsqp-authors: as the authors' code")  # fmt: skip
    s.set_defaults(func=_scenario)
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
                   help=f"rate of image sequences, {_range('fps')} (default 10; videos: their own)")  # fmt: skip
    e.add_argument("--backend", choices=["mediapipe", "openpifpaf", "yolo"], default="mediapipe")
    e.add_argument(
        "--scan-frames",
        type=int,
        default=1,
        help=f"mediapipe: share the tiled search over N frames, {_range('scan_frames')} (faster, fewer found)",
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
        help=f"mediapipe: unsharp mask for the person search, {_range('sharpen')} (default 0, off); 0.7 finds "
        "more people on soft or compressed video (MP4 at ~36 dB)",
    )
    e.add_argument("--no-body-search", action="store_true",
                   help="mediapipe: skip the HOG body-shape search for the people the pose detector misses (seen "
                   "from behind, on compressed video); faster, finds fewer (docs/perception.md)")  # fmt: skip
    e.add_argument("--max-frames", type=int, help=f"stop after N frames, {_range('max_frames')} (any input)")
    e.add_argument("--max-seconds", type=float,
                   help=f"live input: stop after S seconds, {_range('max_seconds')} (default: when the stream ends "
                   "or on Ctrl-C)")  # fmt: skip
    e.add_argument("--open-timeout", type=float, default=5.0,
                   help=f"live input: seconds to wait for the source to open and for each frame, "
                   f"{_range('open_timeout')} (default 5)")  # fmt: skip
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
                   help=f"the camera's height above flat ground, {_range('camera_height')}: places each person on "
                   "the ground (ahead_m, left_m, their sd, distance_m in the tables; the "
                   "distance on the frames); without it no positions are written")  # fmt: skip
    e.add_argument("--fov", type=float, help=f"horizontal field of view, {_range('fov')} (default 70; "
                   "with --camera-height)")  # fmt: skip
    e.add_argument("--pitch", type=float, help=f"camera pitch, > 0 looking down, {_range('pitch')} (default 0; "
                   "with --camera-height)")  # fmt: skip
    e.add_argument("--mp4", action="store_true",
                   help="image inputs too: an annotated MP4 per sequence instead of PNG frames")  # fmt: skip
    e.set_defaults(func=_estimate)
    d = sub.add_parser(
        "drive",
        help="end-to-end trust-aware driving (paper Section IV, Cases I and II): figures, MP4, metrics.json",
    )
    d.add_argument("case", help="case-1 (attentive + distracted standing), case-2 (one walking pedestrian) or a "
                   "scenario file (.toml, the form of sim/scenarios/case-1.toml; docs/drive.md)")  # fmt: skip
    d.add_argument("--sensing", choices=["render", "keypoints"], default="render",
                   help="render: rendered frames + perception (default); keypoints: projected joints")  # fmt: skip
    d.add_argument("--state", choices=["perceived", "true"], default="perceived",
                   help="where the controller's pedestrian positions and velocities come from: perceived "
                   "(default: the camera, localised and tracked, with uncertainty) or true (the world's)")  # fmt: skip
    d.add_argument("--perception", choices=["offline", "realtime"], default="offline",
                   help="render sensing: offline (default: every frame searched in full, deterministic) or "
                   "realtime (the search for new people beside the frame loop; results depend on machine "
                   "load; docs/perception.md)")  # fmt: skip
    d.add_argument("--search-seconds", type=float, default=None, metavar="S",
                   help="with --perception realtime: make the run deterministic, the search for new people "
                   "run in step with the frames and its findings handed over as if it took S seconds, "
                   f"{_range('search_seconds')} (the 2-core machine takes ~0.5; default: the search on its own "
                   "thread, as fast as the machine allows)")  # fmt: skip
    g = d.add_mutually_exclusive_group()
    g.add_argument("--attentive", dest="attentive", action="store_const", const=True, default=None,
                   help="every pedestrian attentive")  # fmt: skip
    g.add_argument("--distracted", dest="attentive", action="store_const", const=False,
                   help="every pedestrian distracted")  # fmt: skip
    d.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {_range('seed')} (default 0)")
    d.add_argument("--rate", type=float, help="camera rate = trust-estimation rate, "
                   f"{_range('rate')} (default: scenario, 1)")  # fmt: skip
    d.add_argument("--control-rate", type=float,
                   help=f"controller rate, {_range('control_rate')} (default: scenario, 20)")  # fmt: skip
    _scenario_options(d)
    d.add_argument("--out", help="output directory (default out/<case or file stem>, out/<...>-keypoints)")
    d.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    d.add_argument("--no-video", action="store_true", help="skip drive.mp4")
    d.add_argument("--world", choices=["sim", "carla"], default="sim",
                   help="sim: own world (default); carla: a CARLA server (extra trustnav[carla])")  # fmt: skip
    d.add_argument("--host", default="localhost", help="CARLA server host (--world carla)")
    d.add_argument("--port", type=int, default=2000, help=f"CARLA server port, {_range('port')} (--world carla)")
    d.add_argument("--timeout", type=float, default=10.0,
                   help=f"CARLA connection timeout, {_range('timeout')} (default 10; --world carla)")  # fmt: skip
    d.add_argument("--town", help="CARLA map to load, e.g. Town03 (default: the scenario's [carla] town, else "
                   "the running world; --world carla)")  # fmt: skip
    d.add_argument("--carla-fov", type=float, help=f"CARLA camera field of view, {_range('carla_fov')} "
                   "(default: [carla] fov_deg, else the camera's; --world carla)")  # fmt: skip
    d.add_argument("--attentive-walker", help="CARLA walker blueprint id or index for attentive pedestrians "
                   "(--world carla)")  # fmt: skip
    d.add_argument("--distracted-walker", help="CARLA walker blueprint id or index for distracted pedestrians "
                   "(--world carla)")  # fmt: skip
    d.set_defaults(func=_drive)
    q = sub.add_parser("compare", help="what trust buys: a scenario driven trust-aware and with constant trust 0 "
                       "and 1 (both ends of gamma): one figure of paths and distances, a table")  # fmt: skip
    q.add_argument("case", help="case-1, case-2 or a scenario file (.toml)")
    q.add_argument("--sensing", choices=["keypoints", "render"], default="keypoints",
                   help="keypoints: projected joints (default, fast); render: frames + perception")  # fmt: skip
    q.add_argument("--state", choices=["perceived", "true"], default="perceived",
                   help="the controller's pedestrians: perceived (default) or true (the world's)")  # fmt: skip
    gq = q.add_mutually_exclusive_group()
    gq.add_argument("--attentive", dest="attentive", action="store_const", const=True, default=None,
                    help="every pedestrian attentive")  # fmt: skip
    gq.add_argument("--distracted", dest="attentive", action="store_const", const=False,
                    help="every pedestrian distracted")  # fmt: skip
    q.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {_range('seed')} (default 0)")
    q.add_argument("--rate", type=float, help=f"camera rate, {_range('rate')} (default: scenario)")
    q.add_argument("--control-rate", type=float, help=f"controller rate, {_range('control_rate')} (default: scenario)")
    _scenario_options(q)
    q.add_argument("--out", help="output directory (default out/compare-<case or file stem>-<sensing>)")
    q.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    q.set_defaults(func=_compare)
    w = sub.add_parser("sweep", help="a campaign of closed-loop episodes on Dask (records, summary, plots)")
    w.add_argument("spec", help="campaign spec (YAML or TOML)")
    w.add_argument("--out", required=True, help="output directory: new, empty or this campaign's own (records are "
                   "appended; a rerun resumes; a folder of another campaign or of other files is refused)")  # fmt: skip
    w.add_argument("--scheduler", help="address of a running Dask scheduler (default: a LocalCluster)")
    w.add_argument("--workers", type=int,
                   help=f"LocalCluster workers, {_range('workers')} (default: the machine's cores)")  # fmt: skip
    w.add_argument("--batch", type=int,
                   help=f"episodes per Dask task, {_range('batch')} (default: the spec's, else auto)")  # fmt: skip
    w.add_argument("--retry-failed", action="store_true", help="run recorded failed episodes again")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    w.set_defaults(func=_sweep)
    m = sub.add_parser("demo", help="paper Case I end to end in render mode, beside the same drive with equal "
                       "trust; prints the headline numbers and where the outputs are")  # fmt: skip
    m.add_argument("--out", help="output directory (default out/demo, replaced on every run)")
    m.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    m.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {_range('seed')} (default 0)")
    m.set_defaults(func=_demo)
    return p


def _version() -> str:
    """The package's version (``trustnav.__version__``; the package is loaded with this module)."""
    return str(getattr(sys.modules.get("trustnav"), "__version__", "unknown"))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    main_thread = threading.current_thread() is threading.main_thread()
    old_term = signal.signal(signal.SIGTERM, _raise_interrupt) if main_thread else None  # `timeout`, `kill`
    try:
        return int(args.func(args) or 0)
    except (ValueError, ImportError) as exc:
        for line in getattr(exc, "errors", None) or (_one_line(exc),):  # SchemaError: one line per error
            print(f"trustnav: error: {_one_line(line)}", file=sys.stderr)
        return 2
    except OSError as exc:  # missing files, unwritable --out, full disk: one line, no traceback
        where = f": {exc.filename}" if exc.filename and str(exc.filename) not in str(exc.strerror) else ""
        text = f"{exc.strerror}{where}" if exc.strerror else _one_line(exc)
        print(f"trustnav: error: {text}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("trustnav: interrupted; earlier outputs are as they were", file=sys.stderr)
        return 130
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, old_term)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    raise SystemExit(main())
