"""`trustnav drive CASE`: end-to-end trust-aware driving (paper Section IV, Cases I and II): figures,
MP4, metrics.json; the camera, control and perception options shared with ``compare``."""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

from trustnav.cli.common import add_attention, check_bounds, span
from trustnav.outputs import OutputFolder
from trustnav.viz.report import drive_summary

DRIVE_OUTPUTS = ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames", "metrics.json",
                 "attentive", "distracted")  # fmt: skip

#: The lowest camera rate at which ``drive --perception realtime`` is allowed (frames/s).
REALTIME_MIN_RATE = 10.0


def add_parser(sub: argparse._SubParsersAction) -> None:
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
                   f"{span('search_seconds')} (the 2-core machine takes ~0.5; default: the search on its own "
                   "thread, as fast as the machine allows)")  # fmt: skip
    add_attention(d)
    d.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {span('seed')} (default 0)")
    d.add_argument("--rate", type=float, help="camera rate = trust-estimation rate, "
                   f"{span('rate')} (default: scenario, 1)")  # fmt: skip
    d.add_argument("--control-rate", type=float,
                   help=f"controller rate, {span('control_rate')} (default: scenario, 20)")  # fmt: skip
    scenario_options(d)
    d.add_argument("--out", help="output directory (default out/<case or file stem>, out/<...>-keypoints)")
    d.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    d.add_argument("--no-video", action="store_true", help="skip drive.mp4")
    d.add_argument("--world", choices=["sim", "carla"], default="sim",
                   help="sim: own world (default); carla: a CARLA server (extra trustnav[carla])")  # fmt: skip
    d.add_argument("--host", default="localhost", help="CARLA server host (--world carla)")
    d.add_argument("--port", type=int, default=2000, help=f"CARLA server port, {span('port')} (--world carla)")
    d.add_argument("--timeout", type=float, default=10.0,
                   help=f"CARLA connection timeout, {span('timeout')} (default 10; --world carla)")  # fmt: skip
    d.add_argument("--town", help="CARLA map to load, e.g. Town03 (default: the scenario's [carla] town, else "
                   "the running world; --world carla)")  # fmt: skip
    d.add_argument("--carla-fov", type=float, help=f"CARLA camera field of view, {span('carla_fov')} "
                   "(default: [carla] fov_deg, else the camera's; --world carla)")  # fmt: skip
    d.add_argument("--attentive-walker", help="CARLA walker blueprint id or index for attentive pedestrians "
                   "(--world carla)")  # fmt: skip
    d.add_argument("--distracted-walker", help="CARLA walker blueprint id or index for distracted pedestrians "
                   "(--world carla)")  # fmt: skip
    d.set_defaults(func=run)


def scenario_options(d: argparse.ArgumentParser) -> None:
    """The camera and control options of ``drive`` and ``compare`` (each overrides the scenario's)."""
    c = d.add_argument_group("camera (default: the scenario's)")
    c.add_argument("--fov", type=float, help=f"horizontal field of view, {span('fov')}")
    c.add_argument("--camera-height", type=float, help=f"camera height above the ground, {span('camera_height')}")
    c.add_argument("--pitch", type=float, help=f"camera pitch, > 0 looking down, {span('pitch')}")
    k = d.add_argument_group("control (default: the scenario's)")
    k.add_argument("--safety-radius", type=float, help=f"the margin R, {span('safety_radius')}")
    k.add_argument("--horizon", type=int, help=f"MPC horizon N_h, {span('horizon')}")
    k.add_argument("--v-max", type=float, help=f"speed bound of the reference, {span('v_max')}")
    k.add_argument("--duration", type=float, help=f"time limit of an episode, {span('duration')}")
    k.add_argument("--caution", choices=("on", "off"),
                   help="trust-aware speed bound near pedestrians who might step out (default: the scenario's "
                   "[control] caution; off: the paper's controller; docs/controller.md)")  # fmt: skip
    p = d.add_argument_group("perception (default: the scenario's)")
    p.add_argument("--perception-latency", type=float, metavar="S",
                   help=f"seconds from a frame's capture to its people reaching the controller's estimates, "
                   f"{span('perception_latency')} (default: the scenario's [sensing] perception_latency, 0; "
                   "the 2-core machine's real-time perception takes ~0.1-0.4 s, docs/perception.md)")  # fmt: skip
    p.add_argument("--near-range", type=float, metavar="M",
                   help=f"a near-field sensor around the car's front (radars or ultrasonics: positions, no "
                   f"traits; it follows the people the camera found) to M metres, {span('near_range')} (default: "
                   "the scenario's [sensing] near_range, 0: none, the camera alone; docs/drive.md)")  # fmt: skip
    p.add_argument("--near-clutter", type=float, metavar="N",
                   help=f"objects (poles, bins) per 10 m of sidewalk that the near-field sensor returns as it "
                   f"returns a person, {span('near_clutter')} (default: the scenario's [sensing] near_clutter, "
                   "0: people only)")  # fmt: skip


def drive_scenario(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The scenario of ``args.case`` (a preset name or a scenario file) with the camera, control and
    CARLA options of the command line applied; each refused with an error naming the option."""
    from trustnav.sim.driving import load_drive_scenario

    opt = lambda name: getattr(args, name, None)  # noqa: E731  (an option a caller's namespace lacks: not given)
    check_bounds(args, "seed", "rate", "control_rate", "port", "timeout", "fov", "camera_height", "pitch",
                 "safety_radius", "horizon", "v_max", "duration", "carla_fov", "perception_latency",
                 "near_range", "near_clutter")  # fmt: skip
    caution, latency, near, clutter = opt("caution"), opt("perception_latency"), opt("near_range"), opt("near_clutter")
    return load_drive_scenario(args.case).with_options(
        opt("duration"), camera={"fov_deg": opt("fov"), "up": opt("camera_height"), "pitch_deg": opt("pitch")},
        control={"safety_radius": opt("safety_radius"), "horizon": opt("horizon"), "reference_v_max": opt("v_max"),
                 "caution": None if caution is None else caution == "on"},
        carla={"town": opt("town"), "fov_deg": opt("carla_fov"), "attentive_walker": _walker(opt("attentive_walker")),
               "distracted_walker": _walker(opt("distracted_walker"))},
        sensing={"perception_latency": None if latency is None else float(latency),
                 "near_range": None if near is None else float(near),
                 "near_clutter": None if clutter is None else float(clutter)})  # fmt: skip


def _walker(v: str | None) -> int | str | None:
    """A walker given on the command line: an index (digits) or a blueprint id."""
    return int(v) if v is not None and v.isdigit() else v


def run(args: argparse.Namespace) -> int:
    from trustnav.progress import step_reporter
    from trustnav.sim.driving.variants import drive_variant, drive_variants
    from trustnav.viz.drive_plots import write_variant_outputs

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
    sc = drive_scenario(args)
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
    default = f"out/{stem}{'' if args.sensing == 'render' else '-' + args.sensing}{'-carla' * (args.world == 'carla')}"
    folder = OutputFolder(args.out or default, args.overwrite, DRIVE_OUTPUTS)
    own = functools.partial(drive_variant, sensing=args.sensing, seed=args.seed, capture_rate=args.rate,
                            control_rate=args.control_rate, state=getattr(args, "state", "perceived"),
                            perception=getattr(args, "perception", "offline"), search_seconds=search)  # fmt: skip
    world = f"{label}, " if label else ""
    with folder:  # written beside --out, moved into place at the end (removed if the run fails)
        try:
            runs = drive_variants(sc, args.attentive, run_variant or own, lambda tag: step_reporter(
                f"{sc.name}{' ' + tag if tag else ''} ({world}{args.sensing})", sc.duration))  # fmt: skip
        except errors as exc:
            folder.discard()
            print(f"trustnav: error: {exc}", file=sys.stderr)
            return int(exc.code)  # type: ignore[attr-defined]
        title = f"{sc.title} [{world}{args.sensing} sensing]"
        done = write_variant_outputs(runs, folder.path, video=not args.no_video, title=title)
    done = [(tag, m, folder.final(where)) for tag, m, where in done]
    files = f"top_view.png, trust.png, distance.png, {'' if args.no_video else 'drive.mp4, '}frames/, metrics.json"
    if len(done) > 1:
        runs = ", ".join(f"{tag}/" for tag, _, _ in done)
        files = f"top_view.png, distance.png, metrics.json comparing the runs; per run in {runs}: {files}"
    print(f"drive {sc.name}{on} ({args.sensing} sensing): wrote {folder.out}/ ({files})")
    print("\n".join(drive_summary(done)))
    return 0
