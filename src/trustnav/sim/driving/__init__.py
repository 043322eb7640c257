"""A small offline driving world for the paper's CARLA Cases I and II (Section IV).

Camera frames -> perception -> trust -> kinematic-bicycle MPC -> car, on a straight road in the
paper's map coordinates (metres, x/y ground, z up, yaw 0 = +x, counter-clockwise). Scenarios are
TOML data (``sim/scenarios/case-1.toml``, ``case-2.toml``); :func:`run_drive` runs one episode
(pure: scenario, parameters, seed -> :class:`DriveResult`); ``gym_env`` wraps the world as a
Gymnasium environment.

The world's parts import lazily so that ``body`` / ``camera`` / ``render`` can be used on their own.
"""

from __future__ import annotations

from typing import Any

__all__ = [
    "DRIVE_SCENARIOS",
    "DriveEnvironment",
    "DriveResult",
    "DriveScenario",
    "SimWorld",
    "World",
    "drive",
    "drive_controller",
    "drive_metrics",
    "load_drive_scenario",
    "make_render_pipeline",
    "make_render_sensing",
    "run_drive",
]

_WHERE = {
    "DRIVE_SCENARIOS": "world",
    "DriveScenario": "world",
    "load_drive_scenario": "world",
    "DriveResult": "episode",
    "DriveEnvironment": "episode",
    "World": "episode",
    "SimWorld": "episode",
    "drive": "episode",
    "drive_controller": "episode",
    "drive_metrics": "episode",
    "run_drive": "episode",
    "make_render_pipeline": "sensing",
    "make_render_sensing": "sensing",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f"trustnav.sim.driving.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'trustnav.sim.driving' has no attribute {name!r}")
