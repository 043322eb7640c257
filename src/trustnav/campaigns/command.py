"""``trustnav sweep SPEC --out DIR [--scheduler ADDRESS] [--workers N]``: run, summarise, plot."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from trustnav.campaigns.plots import write_figures
from trustnav.campaigns.records import RecordStore
from trustnav.campaigns.runner import CampaignFolderError, check_campaign_folder, run_campaign
from trustnav.campaigns.spec import CampaignSpec, load_spec
from trustnav.campaigns.summary import write_summary

__all__ = ["run_sweep_command"]


def _own_folder(spec: CampaignSpec, out: Path) -> bool:
    """Whether ``out`` is the folder of ``spec``'s campaign (its spec.json written)."""
    try:
        check_campaign_folder(spec, out)
    except CampaignFolderError:
        return False
    return (out / "spec.json").is_file()


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run the campaign of ``args.spec`` into ``args.out`` and write its summary and figures.

    Returns 0 when every episode of the spec has a record (failed episodes included: they are
    data), 130 when the run was interrupted (Ctrl-C: the records finished so far are kept and
    summarised, one line says so; a rerun resumes). Spec errors and a folder of another campaign or
    of other files raise ValueError (exit code 2 in the CLI) before anything is written.
    """
    spec = load_spec(args.spec)
    if getattr(args, "workers", None) is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if getattr(args, "batch", None) is not None and args.batch < 1:
        raise ValueError(f"--batch must be >= 1, got {args.batch}")
    out = Path(args.out)
    t0 = time.perf_counter()
    interrupted = False
    try:
        report = run_campaign(
            spec,
            out,
            scheduler=getattr(args, "scheduler", None),
            workers=getattr(args, "workers", None),
            progress=not getattr(args, "quiet", False),
            retry_failed=getattr(args, "retry_failed", False),
            batch=getattr(args, "batch", None),
        )
    except KeyboardInterrupt:
        interrupted = True
        report = None
    if interrupted and not _own_folder(spec, out):  # stopped before the folder was checked and made
        print(f"trustnav: interrupted before the first episode of {spec.name}; nothing written", file=sys.stderr)
        return 130
    keys = {t.key for t in spec.tasks()}
    records = [r for r in RecordStore(out / "records.jsonl").latest().values() if r["key"] in keys]
    summary = write_summary(spec, records, out)
    figures = write_figures(spec, records, out)
    wall = time.perf_counter() - t0
    if report is not None:
        with open(out / "runs.jsonl", "a") as fh:
            fh.write(json.dumps({"time": time.strftime("%Y-%m-%dT%H:%M:%S"), **report.__dict__}) + "\n")
        print(
            f"{spec.name}: {report.episodes} episodes, {report.skipped} already recorded, ran {report.ran} "
            f"({report.failed} failed) on {report.workers} workers in {report.wall_s:.1f} s ({wall:.1f} s in all)"
        )
    else:
        print(f"trustnav: interrupted; {len(records)} of the {len(keys)} episodes of {spec.name} are recorded in "
              f"{out / 'records.jsonl'} (summary and figures updated); rerun the same command to resume",
              file=sys.stderr)  # fmt: skip
        return 130
    for name, s in summary["sweeps"].items():
        md = s["min_distance_median"]
        print(
            f"  {name} ({s['family']}): {s['episodes']} episodes, {s['failed']} failed, "
            f"{s['violations']} margin violations, {s['infeasible_episodes']} with relaxed steps "
            f"({s['infeasible_steps']} steps), min distance median {'-' if md is None else f'{md:.2f}'} m"
        )
    print(f"wrote {out / 'records.jsonl'}, summary.json, summary.md, {len(figures)} figures in {out / 'figures'}")
    return 0
