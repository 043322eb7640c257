"""Run trustnav's trust estimator and MPC in the CARLA simulator, as the paper did (Section IV).

Optional extra ``trustnav[carla]`` (the ``carla`` 0.9.16 client); ``trustnav drive case-1|case-2
--world carla [--host H --port P --timeout S]``. The CARLA server is one more
:class:`trustnav.sim.driving.episode.World` behind the drive loop of ``trustnav drive``.

* :mod:`.frames`: scenario <-> CARLA coordinates (CARLA is left-handed), camera buffer decoding;
* :mod:`.control`: (steer rad, accel m/s^2) -> ``VehicleControl`` steer / throttle / brake;
* :mod:`.posing`: trustnav's poses as walker bone offsets;
* :mod:`.session`: connect, synchronous mode, spawn, and always restore / destroy;
* :mod:`.world`: :class:`CarlaWorld` and :func:`run_carla_drive_episode`;
* :mod:`.command`: the command line.

Nothing here imports ``carla`` at import time; :func:`load_carla` does, with a clear error.
See docs/carla.md.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "CarlaOptions",
    "CarlaSession",
    "CarlaWorld",
    "MapFrame",
    "PedalMap",
    "load_carla",
    "run_carla_drive_episode",
]

_WHERE = {
    "CarlaOptions": "session",
    "CarlaSession": "session",
    "load_carla": "session",
    "CarlaWorld": "world",
    "run_carla_drive_episode": "world",
    "MapFrame": "frames",
    "PedalMap": "control",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f"trustnav.carla_bridge.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'trustnav.carla_bridge' has no attribute {name!r}")
