"""Worlds and scenarios: the paper's numerical scenarios (Section III)."""

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
    "SCENARIOS",
    "Episode",
    "PaperScenario",
    "Pedestrian",
    "ScenarioResult",
    "episode_metrics",
    "load_scenario",
    "run_episode",
    "run_scenario",
]
