"""``trustnav drive case-1|case-2 --world carla [--host H --port P --timeout S]``.

Runs the case (Case II: attentive and distracted unless one is asked for) on a CARLA server and
writes the same outputs as ``trustnav drive`` (figures, annotated frames, MP4, metrics.json with
``"world": "carla"``). Exit codes: 0 done; 2 bad input, ``carla`` not installed or no server
(one line on stderr, no traceback); 1 a CARLA error during the run; 130 interrupted (Ctrl-C or
SIGTERM). In every case the session restores the world's settings and destroys what it spawned.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from trustnav.carla_bridge.session import CarlaError, CarlaNotInstalled, CarlaOptions, CarlaUnavailable, load_carla

__all__ = ["run_carla_drive"]


def run_carla_drive(args: argparse.Namespace) -> int:
    """The ``--world carla`` branch of ``trustnav drive``; returns the exit code."""
    try:
        carla = load_carla()
    except CarlaNotInstalled as exc:
        return _fail(str(exc), 2)
    from trustnav.sim.driving import DRIVE_SCENARIOS, load_drive_scenario

    if args.case not in DRIVE_SCENARIOS:
        return _fail(f"unknown case {args.case!r}: expected one of {', '.join(DRIVE_SCENARIOS)}", 2)
    for name, value in (("--rate", args.rate), ("--control-rate", args.control_rate)):
        if value is not None and not value > 0:
            return _fail(f"{name} must be a positive number, got {value}", 2)
    try:
        options = CarlaOptions(host=args.host, port=args.port, timeout=args.timeout)
    except ValueError as exc:
        return _fail(str(exc), 2)
    sc = load_drive_scenario(args.case)
    if args.attentive is not None:
        variants: list[tuple[str, bool | None]] = [("attentive" if args.attentive else "distracted", args.attentive)]
    elif sc.variants:
        variants = [(v, v == "attentive") for v in sc.variants]
    else:
        variants = [("", None)]
    out = Path(args.out or f"out/{args.case}-carla")
    done: list[tuple[str, dict[str, Any], Path]] = []
    results = []
    for tag, att in variants:
        try:
            result = _run_variant(carla, sc, options, args, att)
        except CarlaUnavailable as exc:
            return _fail(str(exc), 2)
        except CarlaError as exc:
            return _fail(f"CARLA: {exc} (settings restored, spawned actors destroyed)", 1)
        except KeyboardInterrupt:
            return _fail("interrupted; CARLA settings restored and spawned actors destroyed", 130)
        where = out / tag if len(variants) > 1 else out
        where.mkdir(parents=True, exist_ok=True)
        from trustnav.viz.drive_plots import write_drive_outputs

        metrics = result.metrics()
        write_drive_outputs(result, where, video=not args.no_video)
        (where / "metrics.json").write_text(json.dumps(metrics, indent=2))
        done.append((tag or args.case, metrics, where))
        results.append(result)
    if len(results) > 1:
        from trustnav.viz.drive_plots import plot_distance, plot_top_view

        plot_distance(results, out / "distance.png")
        plot_top_view(results, out / "top_view.png", title=f"{sc.title} [CARLA, {args.sensing} sensing]")
        (out / "metrics.json").write_text(json.dumps({tag: m for tag, m, _ in done}, indent=2))
    print(f"drive {args.case} on CARLA at {options.address} ({args.sensing} sensing): wrote {out}/")
    for tag, m, where in done:
        ttg = "not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s"
        print(f"  {tag}: goal {ttg}  margin violations {m['margin_violations']}  relaxed steps "
              f"{m['relaxed_steps']}  fallback steps {m['fallback_steps']}  -> {where}")  # fmt: skip
        for p in m["pedestrians"]:
            print(f"      {p['name']:<11} min distance {p['min_distance']:.2f} m  final trust "
                  f"{p['final_trust']:.2f}  frames seen {p['frames_seen']}")  # fmt: skip
    return 0


def _run_variant(carla: Any, sc: Any, options: CarlaOptions, args: argparse.Namespace, attentive: bool | None) -> Any:
    from tqdm import tqdm

    from trustnav.carla_bridge.world import run_carla_drive_episode

    pipeline = _pipeline(sc, args.rate) if args.sensing == "render" else None
    bars: list[Any] = []  # the progress bar, made once the session is open

    def report(session: Any) -> None:
        print(f"CARLA {session.server_version} at {options.address}, map {session.map_name}, "
              f"synchronous, {session.delta:g} s per tick", file=sys.stderr)  # fmt: skip

    def progress(t: float, duration: float) -> None:
        if not bars:
            tag = {None: "", True: " attentive", False: " distracted"}[attentive]
            bars.append(tqdm(total=duration, desc=f"{args.case}{tag} (CARLA, {args.sensing})", unit="s",
                             bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} s sim [{elapsed}]"))  # fmt: skip
        bars[0].update(t - bars[0].n)

    try:
        return run_carla_drive_episode(
            carla, sc, options, sensing=args.sensing, seed=args.seed, attentive=attentive,
            capture_rate=args.rate, control_rate=args.control_rate, pipeline=pipeline, progress=progress,
            on_session=report,
        )  # fmt: skip
    finally:
        for bar in bars:
            bar.close()
        if pipeline is not None and hasattr(pipeline.backend, "close"):
            pipeline.backend.close()


def _pipeline(sc: Any, rate: float | None) -> Any:
    """trustnav.perception on CARLA's frames, as render sensing runs it on trustnav's renders."""
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker
    from trustnav.sim.driving.sensing import looking_model

    fps = float(rate or sc.camera.rate)
    return PerceptionPipeline(MediaPipePoseBackend(video=fps >= 5.0), PersonTracker(fps=fps), looking_model())


def _fail(message: str, code: int) -> int:
    print(f"trustnav: error: {message}", file=sys.stderr)
    return code
