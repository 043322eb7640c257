"""`trustnav compare SCENARIO`: what trust buys, trust-aware beside constant trust 0 and 1
(:func:`trustnav.sim.driving.compare.compare_trust`): one figure, a table."""

from __future__ import annotations

import argparse
from pathlib import Path

from trustnav.cli.common import add_attention, span
from trustnav.cli.drive import drive_scenario, scenario_options
from trustnav.outputs import OutputFolder
from trustnav.viz.report import comparison_table

COMPARE_OUTPUTS = ("compare.png", "metrics.json", "table.csv")


def add_parser(sub: argparse._SubParsersAction) -> None:
    q = sub.add_parser("compare", help="what trust buys: a scenario driven trust-aware and with constant trust 0 "
                       "and 1 (both ends of gamma): one figure of paths and distances, a table")  # fmt: skip
    q.add_argument("case", help="case-1, case-2 or a scenario file (.toml)")
    q.add_argument("--sensing", choices=["keypoints", "render"], default="keypoints",
                   help="keypoints: projected joints (default, fast); render: frames + perception")  # fmt: skip
    q.add_argument("--state", choices=["perceived", "true"], default="perceived",
                   help="the controller's pedestrians: perceived (default) or true (the world's)")  # fmt: skip
    add_attention(q)
    q.add_argument("--seed", type=int, default=0, help=f"seed of sensing noise, {span('seed')} (default 0)")
    q.add_argument("--rate", type=float, help=f"camera rate, {span('rate')} (default: scenario)")
    q.add_argument("--control-rate", type=float, help=f"controller rate, {span('control_rate')} (default: scenario)")
    scenario_options(q)
    q.add_argument("--out", help="output directory (default out/compare-<case or file stem>-<sensing>)")
    q.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    q.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``trustnav compare SCENARIO``: trust-aware beside constant trust 0 and 1 (one figure, a table)."""
    from trustnav.progress import labelled_reporter
    from trustnav.sim.driving.compare import compare_trust, comparison_rows
    from trustnav.viz.drive_plots import write_comparison_outputs

    sc = drive_scenario(args)
    stem = args.case if args.case in ("case-1", "case-2") else Path(args.case).stem
    folder = OutputFolder(args.out or f"out/compare-{stem}-{args.sensing}", args.overwrite, COMPARE_OUTPUTS)
    with labelled_reporter(sc.name, leave=False) as progress:
        comp = compare_trust(sc, sensing=args.sensing, seed=args.seed, attentive=args.attentive, capture_rate=args.rate,
                             control_rate=args.control_rate, state=args.state, progress=progress)  # fmt: skip
    rows = comparison_rows(comp)
    with folder:
        write_comparison_outputs(comp, rows, folder.path, args.state)
    out = folder.out
    print(f"compare {sc.name} ({args.sensing} sensing, seed {args.seed}): wrote {out / 'compare.png'}, "
          f"{out / 'table.csv'}, {out / 'metrics.json'}")  # fmt: skip
    print("\n".join(comparison_table(rows, sc.control.safety_radius)))
    return 0
