"""`trustnav ...`: one module per command, each thin (parse, call the library, report); docs/cli.md.

Output rule (all but ``sweep``, which resumes): a folder holding files is never written into silently
(``--overwrite`` replaces trustnav's own outputs; ``demo`` replaces its default ``out/demo``); every
command writes through :class:`trustnav.outputs.OutputFolder`, numbers are checked against
:data:`trustnav.cli.common.BOUNDS`."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from trustnav.cli import compare, demo, drive, estimate, scenario, sweep
from trustnav.cli.common import BOUNDS, Parser, one_line

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
    # SIGTERM (`timeout`, `kill`) handled as Ctrl-C: the default SIGINT handler raises KeyboardInterrupt
    old_term = signal.signal(signal.SIGTERM, signal.default_int_handler) if main_thread else None
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
