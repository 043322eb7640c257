"""The CARLA side of ``trustnav drive case-1|case-2 --world carla [--host H --port P --timeout S]``.

:func:`carla_runner` checks the ``carla`` package and the options and returns the function that
drives one variant of a case on the server; ``trustnav.cli`` runs the variants and writes the outputs
(the same output-folder checks, figures, frames, MP4 and metrics.json, with ``"world": "carla"``,
as ``trustnav drive``). Failures raise :class:`CarlaCommandError` with the CLI's exit code: 2 bad
input, ``carla`` not installed or no server; 1 a CARLA error during the run; 130 interrupted
(Ctrl-C or SIGTERM). In every case the session restores the world's settings and destroys what it
spawned.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from trustnav.carla_bridge.session import CarlaError, CarlaNotInstalled, CarlaOptions, CarlaUnavailable, load_carla

__all__ = ["CarlaCommandError", "carla_runner"]

Progress = Callable[[float, float], None]


class CarlaCommandError(Exception):
    """A ``--world carla`` failure: ``message`` for one stderr line and the exit ``code``."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def carla_runner(
    args: argparse.Namespace, route: dict[str, Any] | None = None
) -> tuple[str, Callable[[Any, bool | None, Progress | None], Any]]:
    """(where: "H:P", run_variant(scenario, attentive, progress) -> DriveResult) for ``args``;
    ``route``: further :class:`CarlaOptions` (town, fov_deg, walkers: the scenario's ``[carla]``
    section with the command line's options applied)."""
    try:
        carla = load_carla()
    except CarlaNotInstalled as exc:
        raise CarlaCommandError(str(exc), 2) from None
    try:
        options = CarlaOptions(host=args.host, port=args.port, timeout=args.timeout, **(route or {}))
    except ValueError as exc:
        raise CarlaCommandError(str(exc), 2) from None

    def run_variant(sc: Any, attentive: bool | None, progress: Progress | None) -> Any:
        try:
            return _run_variant(carla, sc, options, args, attentive, progress)
        except CarlaUnavailable as exc:
            raise CarlaCommandError(str(exc), 2) from None
        except CarlaError as exc:
            raise CarlaCommandError(f"CARLA: {exc} (settings restored, spawned actors destroyed)", 1) from None
        except KeyboardInterrupt:
            raise CarlaCommandError("interrupted; CARLA settings restored and spawned actors destroyed", 130) from None

    return options.address, run_variant


def _run_variant(
    carla: Any, sc: Any, options: CarlaOptions, args: argparse.Namespace, attentive: bool | None,
    progress: Progress | None,
) -> Any:  # fmt: skip
    from trustnav.carla_bridge.world import run_carla_drive_episode

    pipeline = None
    if args.sensing == "render":
        from trustnav.sim.driving.sensing import make_render_pipeline

        realtime = getattr(args, "perception", "offline") == "realtime"
        pipeline = make_render_pipeline(sc, args.rate, realtime=realtime,
                                        search_seconds=getattr(args, "search_seconds", None))  # fmt: skip

    def report(session: Any) -> None:
        print(f"CARLA {session.server_version} at {options.address}, map {session.map_name}, "
              f"synchronous, {session.delta:g} s per tick", file=sys.stderr)  # fmt: skip

    try:
        return run_carla_drive_episode(
            carla, sc, options, sensing=args.sensing, seed=args.seed, attentive=attentive,
            capture_rate=args.rate, control_rate=args.control_rate, pipeline=pipeline, progress=progress,
            on_session=report, state=getattr(args, "state", "perceived"),
        )  # fmt: skip
    finally:
        if pipeline is not None and hasattr(pipeline.backend, "close"):
            pipeline.backend.close()
