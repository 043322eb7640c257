"""`trustnav sweep SPEC`: a campaign of closed-loop episodes on Dask (:mod:`trustnav.campaigns`)."""

from __future__ import annotations

import argparse

from trustnav.cli.common import check_bounds, span


def add_parser(sub: argparse._SubParsersAction) -> None:
    w = sub.add_parser("sweep", help="a campaign of closed-loop episodes on Dask (records, summary, plots)")
    w.add_argument("spec", help="campaign spec (YAML or TOML)")
    w.add_argument("--out", required=True, help="output directory: new, empty or this campaign's own (records are "
                   "appended; a rerun resumes; a folder of another campaign or of other files is refused)")  # fmt: skip
    w.add_argument("--scheduler", help="address of a running Dask scheduler (default: a LocalCluster)")
    w.add_argument("--workers", type=int,
                   help=f"LocalCluster workers, {span('workers')} (default: the machine's cores)")  # fmt: skip
    w.add_argument("--batch", type=int,
                   help=f"episodes per Dask task, {span('batch')} (default: the spec's, else auto)")  # fmt: skip
    w.add_argument("--retry-failed", action="store_true", help="run recorded failed episodes again")
    w.add_argument("--quiet", action="store_true", help="no progress bar")
    w.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from trustnav.campaigns.command import run_sweep_command

    check_bounds(args, "workers", "batch")
    return run_sweep_command(args)
