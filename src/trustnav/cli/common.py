"""What every command shares: the range of every number an option takes (:data:`BOUNDS`, checked
with a one-line error naming the option), the one-line parser error."""

from __future__ import annotations

import argparse
import math
import sys

from trustnav.schema import Integer, Invalid, Number

__all__ = ["BOUNDS", "Parser", "add_attention", "add_removed", "check_bounds", "one_line", "span"]

#: option -> its rule (trustnav.schema): the documented range of every number an option takes. Rates
#: and the CARLA timeout are bounded so that no run takes hours.
BOUNDS: dict[str, Number | Integer] = {
    "seed": Integer(0, whole_floats=True),
    "rate": Number(0, 60, lo_open=True, unit=" frames per second"),
    "control_rate": Number(1, 200, unit=" steps per second"),
    "fps": Number(0, 240, lo_open=True, unit=" frames per second"),
    "max_frames": Integer(1, whole_floats=True),
    "max_seconds": Number(0, lo_open=True, unit=" s"),
    "open_timeout": Number(0, 600, lo_open=True, unit=" s"),
    "port": Integer(1, 65535, whole_floats=True),
    "timeout": Number(0, 600, lo_open=True, unit=" s"),
    "workers": Integer(1, 256, whole_floats=True),
    "batch": Integer(1, 10000, whole_floats=True),
    "camera_height": Number(0.2, 20, unit=" m"),
    "fov": Number(10, 170, unit=" degrees"),
    "pitch": Number(-45, 45, unit=" degrees"),
    "safety_radius": Number(0, 20, lo_open=True, unit=" m"),
    "horizon": Integer(1, 100, unit=" steps", whole_floats=True),
    "v_max": Number(0, 30, lo_open=True, unit=" m/s"),
    "duration": Number(0, 600, lo_open=True, unit=" s"),
    "carla_fov": Number(10, 170, unit=" degrees"),
    "search_seconds": Number(0, 10, lo_open=True, unit=" s"),
    "perception_latency": Number(0, 5, unit=" s"),  # sim.driving.world.MAX_PERCEPTION_LATENCY (lazy imports)
    "near_range": Number(0, 30, unit=" m"),  # SensingSpec.near_range's
    "near_clutter": Number(0, 20, unit=" objects per 10 m of sidewalk"),  # SensingSpec.near_clutter's
}


def add_attention(parser: argparse.ArgumentParser) -> None:
    """``--attentive`` / ``--distracted``: every pedestrian of the scenario one way (dest ``attentive``)."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--attentive", dest="attentive", action="store_const", const=True, default=None,
                   help="every pedestrian attentive")  # fmt: skip
    g.add_argument("--distracted", dest="attentive", action="store_const", const=False,
                   help="every pedestrian distracted")  # fmt: skip


def add_removed(parser: argparse.ArgumentParser, removed: dict[str, str]) -> None:
    """Options that were removed, hidden from ``--help``: each given is one parser error line naming it
    and saying why and what replaced it (``removed``: option -> that reason, as a phrase)."""

    class Removed(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):  # type: ignore[no-untyped-def]
            option = self.option_strings[0]
            parser.error(f"{option} was removed: {removed[option]}")

    for option in removed:
        parser.add_argument(option, nargs="?", action=Removed, help=argparse.SUPPRESS)


def span(dest: str) -> str:
    """The range of an option as its help text and its error give it: 'in (0, 60] frames per second'."""
    rule = BOUNDS[dest]
    if isinstance(rule, Number) and math.isfinite(rule.lo) and math.isfinite(rule.hi):
        return rule.bounds
    return rule.expected


def check_bounds(args: argparse.Namespace, *dests: str) -> None:
    """Raise ValueError naming the option (``--seed must be an integer >= 0, got -1``) for the first
    of ``dests`` whose value (None: not given) lies outside :data:`BOUNDS`."""
    for dest in dests:
        value = getattr(args, dest, None)
        if value is None:
            continue
        try:
            BOUNDS[dest](value)
        except Invalid:
            shown = f"{value:g}" if isinstance(value, float) else repr(value) if isinstance(value, str) else value
            raise ValueError(f"--{dest.replace('_', '-')} must be {span(dest)}, got {shown}") from None


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (exit code 2, no usage dump) that names the option."""

    def error(self, message: str):  # type: ignore[override]
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
