"""`trustnav demo`: paper Case I end to end in render sensing beside the same drive with equal trust
(:func:`trustnav.sim.driving.demo.run_demo`, written once by
:func:`trustnav.viz.drive_plots.write_demo_outputs`); prints the headline numbers and where the outputs are."""

from __future__ import annotations

import argparse

from trustnav.cli.common import check_bounds, span
from trustnav.cli.drive import DRIVE_OUTPUTS
from trustnav.outputs import OutputFolder
from trustnav.viz.report import demo_headline, drive_summary


def add_parser(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser("demo", help="paper Case I end to end in render mode, beside the same drive with equal "
                       "trust; prints the headline numbers and where the outputs are")  # fmt: skip
    m.add_argument("--out", help="output directory (default out/demo, replaced on every run)")
    m.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    m.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {span('seed')} (default 0)")
    m.set_defaults(func=run)


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
        bars = {"trust-aware": "(render)", "constant trust 1": f"equal trust {story.DEMO_EQUAL_TRUST:g} (render)"}
        with labelled_reporter("case-1") as progress:  # the bars of the drives as `drive` names them
            demo = story.run_demo(args.seed, progress=lambda label, t, d: progress(bars.get(label, label), t, d))
        write_demo_outputs(demo, folder.path)
    runs = demo.runs()
    print(f"demo (paper Case I, camera -> perception -> trust -> MPC, {time.perf_counter() - t0:.0f} s): wrote")
    for name in ("drive.mp4", "top_view.png", "trust.png", "distance.png", "frames/", "metrics.json"):
        print(f"  {folder.out / name}")
    print("\n".join(drive_summary([("case-1", runs["trust-aware"], folder.out)]) + demo_headline(runs)))
    return 0
