"""`trustnav demo`: paper Case I end to end in render sensing beside the same drive with equal trust
(:func:`trustnav.sim.driving.demo.run_demo`, written once by
:func:`trustnav.viz.drive_plots.write_demo_outputs`); prints the headline numbers and where the outputs are."""

from __future__ import annotations

import argparse

from trustnav.cli.common import check_bounds, span
from trustnav.cli.drive import DRIVE_OUTPUTS, drive_summary
from trustnav.outputs import OutputFolder


def add_parser(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser("demo", help="paper Case I end to end in render mode, beside the same drive with equal "
                       "trust; prints the headline numbers and where the outputs are")  # fmt: skip
    m.add_argument("--out", help="output directory (default out/demo, replaced on every run)")
    m.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    m.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {span('seed')} (default 0)")
    m.set_defaults(func=run)


def headline(runs: dict[str, dict]) -> None:
    """The demo's numbers: per pedestrian the closest approach and the final trust, the time to
    goal and the bend, for the trust-aware run, the equal-trust run and keypoint sensing."""
    given = runs["equal_trust"]["trust_given_to_controller"]
    cols = [("trust-aware", runs["trust-aware"]), (f"equal trust {given:g} (trust-blind)",
            runs["equal_trust"]), ("trust-aware, keypoint sensing", runs["keypoints_sensing"])]  # fmt: skip
    m0 = runs["trust-aware"]
    print(f"headline (Case I, R = {m0.get('safety_radius', 2.5):g} m): closest approach (final trust) per pedestrian")
    print((f"  {'':<22}" + "".join(f"{name:<32}" for name, _ in cols)).rstrip())
    for j, p in enumerate(m0["pedestrians"]):
        cells = []
        for name, m in cols:
            q = m["pedestrians"][j]
            trust = f"{given:.2f} fixed" if name.startswith("equal") else f"{q['final_trust']:.2f}"
            cells.append(f"{q['min_distance']:.2f} m (trust {trust})")
        print((f"  {p['name']:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())
    ttg = ["not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s" for _, m in cols]
    rows = [("time to goal", ttg), ("bend off the lane", [f"{m['max_lateral_offset']:.2f} m" for _, m in cols]),
            ("margin violations", [str(m["margin_violations"]) for _, m in cols])]  # fmt: skip
    for head, cells in rows:
        print((f"  {head:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())


def run(args: argparse.Namespace) -> int:
    import time

    from trustnav.progress import labelled_reporter
    from trustnav.sim.driving import demo as story
    from trustnav.viz.drive_plots import write_demo_outputs

    # the demo is run again and again: its own default folder is replaced (trustnav's outputs only);
    # a folder the user names follows the rule of every command
    check_bounds(args, "seed")
    folder = OutputFolder(args.out or "out/demo", args.overwrite or args.out is None, DRIVE_OUTPUTS)
    t0 = time.perf_counter()
    with folder:  # written beside the folder, moved into place at the end: Ctrl-C keeps the earlier demo
        with labelled_reporter("case-1", leave=False) as progress:
            demo = story.run_demo(args.seed, progress=progress)
        write_demo_outputs(demo, folder.path)
    runs = demo.runs()
    print(f"demo (paper Case I, camera -> perception -> trust -> MPC, {time.perf_counter() - t0:.0f} s): wrote")
    for name in ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames/", "metrics.json"):
        print(f"  {folder.out / name}")
    drive_summary([("case-1", runs["trust-aware"], folder.out)], folder.out)
    headline(runs)
    return 0
