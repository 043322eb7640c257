"""A driving case's variants and the drive of one in trustnav's own world (what `trustnav drive` runs).

:func:`variants_of`: the runs a case asks for (Case II: attentive and distracted, unless one is
asked for). :func:`drive_variant`: one of them with the camera and perception of its sensing set
up and closed again (render sensing: the rendered street and the perception pipeline).
:func:`drive_variants`: every variant, each through a ``drive_one`` of the caller's (default
:func:`drive_variant`; the CARLA bridge gives its own). Pure: no files written.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

from trustnav.sim.driving.episode import DriveResult, run_drive
from trustnav.sim.driving.sensing import make_render_sensing
from trustnav.sim.driving.world import DriveScenario

__all__ = ["drive_variant", "drive_variants", "variants_of"]


def variants_of(scenario: DriveScenario, attentive: bool | None = None) -> list[tuple[str, bool | None]]:
    """(tag, attentive) per run: one behaviour when ``attentive`` is given, else the scenario's
    variants, else one run as the scenario is ("")."""
    if attentive is not None:
        return [("attentive" if attentive else "distracted", attentive)]
    if scenario.variants:
        return [(v, v == "attentive") for v in scenario.variants]
    return [("", None)]


def drive_variant(
    scenario: DriveScenario,
    attentive: bool | None,
    progress: Callable[[float, float], None] | None = None,
    *,
    sensing: str = "keypoints",
    seed: int = 0,
    capture_rate: float | None = None,
    control_rate: float | None = None,
    state: str = "perceived",
    perception: str = "offline",
    search_seconds: float | None = None,
) -> DriveResult:
    """:func:`run_drive` of one variant, render sensing's renderer and perception (``perception``
    "offline" or "realtime", ``search_seconds``: :func:`make_render_sensing`) opened and closed."""
    renderer = pipeline = None
    if sensing == "render":
        renderer, pipeline = make_render_sensing(scenario, capture_rate, realtime=perception == "realtime",
                                                 search_seconds=search_seconds)  # fmt: skip
    try:
        return run_drive(scenario, sensing=sensing, seed=seed, attentive=attentive, capture_rate=capture_rate,
                         control_rate=control_rate, renderer=renderer, pipeline=pipeline, progress=progress,
                         state=state)  # fmt: skip
    finally:
        if renderer is not None:
            renderer.close()
        if pipeline is not None and hasattr(pipeline.backend, "close"):
            pipeline.backend.close()


def drive_variants(
    scenario: DriveScenario,
    attentive: bool | None,
    drive_one: Callable[[DriveScenario, bool | None, Any], DriveResult],
    reporter: Callable[[str], AbstractContextManager[Any]] | None = None,
) -> list[tuple[str, DriveResult]]:
    """(tag, result) per variant of :func:`variants_of`, each driven by ``drive_one(scenario,
    attentive, progress)``; ``reporter(tag)`` gives each run's progress callback (a context)."""
    runs = []
    for tag, att in variants_of(scenario, attentive):
        if reporter is None:
            runs.append((tag, drive_one(scenario, att, None)))
            continue
        with reporter(tag) as progress:  # the bar opens once the world has opened
            runs.append((tag, drive_one(scenario, att, progress)))
    return runs
