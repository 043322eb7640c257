"""`trustnav scenario paper-N`: one of the paper's numerical scenarios, its figure and metrics.json."""

from __future__ import annotations

import argparse
import json

from trustnav.outputs import OutputFolder
from trustnav.viz.report import scenario_summary

SCENARIO_OUTPUTS = ("paper-*.png", "metrics.json")


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser(
        "scenario", help="run one of the paper's numerical scenarios and write its figure + metrics.json"
    )
    s.add_argument("name", choices=["paper-1", "paper-2", "paper-3"])
    s.add_argument("--out", help="output directory (default out/<name>, out/<name>-<solver> for another solver)")
    s.add_argument("--overwrite", action="store_true", help="replace trustnav's outputs in a non-empty --out")
    s.add_argument("--solver", choices=["sqp", "slsqp", "slsqp-authors"], default="sqp",
                   help="sqp: fast default; slsqp: SLSQP, tuned; slsqp-authors: as the authors' code")  # fmt: skip
    s.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
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
    print("\n".join(scenario_summary(result.metrics)))
    return 0
