"""Worlds and scenarios: the paper's numerical scenarios (Section III) and the driving world of
Section IV (Cases I and II, :mod:`trustnav.sim.driving`)."""

from trustnav.sim.driving.episode import DriveEnvironment, DriveResult, drive_metrics, run_drive
from trustnav.sim.driving.world import DRIVE_SCENARIOS, DriveScenario, load_drive_scenario
from trustnav.sim.paper import (
    SCENARIOS,
    Episode,
    PaperScenario,
    Pedestrian,
    ScenarioResult,
    episode_metrics,
    load_scenario,
    run_episode,
    run_scenario,
)

__all__ = [
    "DRIVE_SCENARIOS",
    "SCENARIOS",
    "DriveEnvironment",
    "DriveResult",
    "DriveScenario",
    "Episode",
    "PaperScenario",
    "Pedestrian",
    "ScenarioResult",
    "drive_metrics",
    "episode_metrics",
    "load_drive_scenario",
    "load_scenario",
    "run_drive",
    "run_episode",
    "run_scenario",
]
