"""`trustnav ...` entry points (thin: parse, call sim/viz, write files)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["main"]


def _scenario(args: argparse.Namespace) -> int:
    from trustnav.sim.paper import run_scenario
    from trustnav.viz.paper_plots import plot_scenario

    out = Path(args.out or f"out/{args.name}")
    out.mkdir(parents=True, exist_ok=True)
    result = run_scenario(args.name, solver=args.solver)
    fig = plot_scenario(result, out)
    (out / "metrics.json").write_text(json.dumps(result.metrics, indent=2))
    print(f"{args.name}: wrote {fig} and {out / 'metrics.json'}")
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="trustnav", description="Trust-aware safe navigation (MPC-CBF with pedestrian trust)."
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser(
        "scenario", help="run one of the paper's numerical scenarios and write its figure + metrics.json"
    )
    s.add_argument("name", choices=["paper-1", "paper-2", "paper-3"])
    s.add_argument("--out", help="output directory (default out/<name>)")
    s.add_argument(
        "--solver", choices=["sqp", "slsqp"], default="sqp", help="sqp: fast default; slsqp: paper-style reference"
    )
    s.set_defaults(func=_scenario)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"trustnav: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
