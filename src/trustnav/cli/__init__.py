"""`trustnav ...` entry points, one module per command, each thin: parse, call the library, report.

Output rule (every command but ``sweep``, which resumes into its folder on purpose): a folder that
already holds files is never written into silently. ``--overwrite`` replaces trustnav's own
outputs there (files of other names are left alone); default folders are named after the run
(scenario and solver, case and sensing) so two different runs never share one; ``demo`` replaces
its own default folder ``out/demo``, since it is run again and again. Nothing lost, nothing mixed:
every command writes through :class:`trustnav.outputs.OutputFolder`. Every number an option takes is
checked against the range its help text gives (:data:`trustnav.cli.common.BOUNDS`).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from trustnav.cli import compare, demo, drive, estimate, scenario, sweep
from trustnav.cli.common import BOUNDS, Parser, one_line, raise_interrupt

__all__ = ["BOUNDS", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``trustnav`` parser: a sub-command per module, in the order of ``trustnav --help``."""
    version = getattr(sys.modules.get("trustnav"), "__version__", "unknown")  # loaded with this package
    p = Parser(prog="trustnav", description="Trust-aware safe navigation (MPC-CBF with pedestrian trust).")
    p.add_argument("--version", action="version", version=f"trustnav {version}")
    sub = p.add_subparsers(dest="command", required=True)
    for command in (scenario, estimate, drive, compare, sweep, demo):
        command.add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run ``trustnav`` with ``argv`` (default: the command line); returns the exit code (0, 1 nothing
    to do, 2 a refused input, 130 interrupted; CARLA failures their own)."""
    args = build_parser().parse_args(argv)
    main_thread = threading.current_thread() is threading.main_thread()
    old_term = signal.signal(signal.SIGTERM, raise_interrupt) if main_thread else None  # `timeout`, `kill`
    try:
        return int(args.func(args) or 0)
    except (ValueError, ImportError) as exc:
        for line in getattr(exc, "errors", None) or (one_line(exc),):  # SchemaError: one line per error
            print(f"trustnav: error: {one_line(line)}", file=sys.stderr)
        return 2
    except OSError as exc:  # missing files, unwritable --out, full disk: one line, no traceback
        where = f": {exc.filename}" if exc.filename and str(exc.filename) not in str(exc.strerror) else ""
        text = f"{exc.strerror}{where}" if exc.strerror else one_line(exc)
        print(f"trustnav: error: {text}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("trustnav: interrupted; earlier outputs are as they were", file=sys.stderr)
        return 130
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, old_term)
