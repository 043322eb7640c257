"""Safety campaigns: thousands of closed-loop episodes and parameter sweeps on dask.distributed.

``spec`` (YAML / TOML campaign specs, validated) -> ``runner`` (Dask tasks, JSON Lines records,
resume) -> ``episodes`` (one runner per family: paper scenarios, random worlds, driving world)
-> ``summary`` / ``plots`` (per-point safety statistics, figures). ``trustnav sweep`` is
``command.run_sweep_command``. See docs/campaigns.md.
"""

from trustnav.campaigns.episodes import OUTCOME_FIELDS, run_episode_task
from trustnav.campaigns.records import RecordStore
from trustnav.campaigns.runner import RunReport, run_campaign
from trustnav.campaigns.spec import FAMILIES, CampaignSpec, SpecError, load_spec, spec_from_dict
from trustnav.campaigns.summary import summarise, write_summary

__all__ = [
    "FAMILIES",
    "OUTCOME_FIELDS",
    "CampaignSpec",
    "RecordStore",
    "RunReport",
    "SpecError",
    "load_spec",
    "run_campaign",
    "run_episode_task",
    "spec_from_dict",
    "summarise",
    "write_summary",
]
