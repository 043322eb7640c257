"""The demo's story (`trustnav demo`): paper Case I end to end, trust-aware beside trust-blind.

:func:`run_demo` drives Case I with the library's comparison (:func:`compare_trust`, render
sensing: rendered camera -> perception -> trust -> MPC) trust-aware and with every pedestrian handed
:data:`DEMO_EQUAL_TRUST` (:class:`~trustnav.sim.driving.compare.ConstantTrustEnvironment`: the same world,
camera and perception, only the trusts the controller gets differ), and trust-aware once more in
keypoint sensing (ideal landmarks). Pure: no files written (the figures:
:func:`trustnav.viz.drive_plots.write_demo_outputs`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from trustnav.sim.driving.compare import TRUST_MODES, compare_trust
from trustnav.sim.driving.episode import DriveResult, run_drive
from trustnav.sim.driving.world import load_drive_scenario

__all__ = ["DEMO_EQUAL_TRUST", "DemoRuns", "run_demo"]

#: the trust every pedestrian gets in the demo's trust-blind run: one value for all, as the control
#: run of the paper's Scenario II (`trustnav scenario paper-2`)
DEMO_EQUAL_TRUST = 1.0
_EQUAL_MODE = next(mode for mode, trust in TRUST_MODES.items() if trust == DEMO_EQUAL_TRUST)


@dataclass(frozen=True)
class DemoRuns:
    """The demo's three drives of Case I: trust-aware, equal trust (trust-blind), both in
    ``sensing``; and trust-aware in keypoint sensing."""

    trust_aware: DriveResult
    equal_trust: DriveResult
    keypoints: DriveResult
    sensing: str = "render"

    def runs(self) -> dict[str, dict[str, Any]]:
        """Each run's metrics: ``trust-aware``, ``equal_trust`` (with ``trust_given_to_controller``)
        and ``keypoints_sensing``."""
        equal = self.equal_trust.metrics()
        equal["trust_given_to_controller"] = DEMO_EQUAL_TRUST
        return {"trust-aware": self.trust_aware.metrics(), "equal_trust": equal,
                "keypoints_sensing": self.keypoints.metrics()}  # fmt: skip

    def metrics(self) -> dict[str, Any]:
        """metrics.json: the trust-aware run's metrics, the other two under ``equal_trust`` and
        ``keypoints_sensing``."""
        runs = self.runs()
        return dict(runs["trust-aware"], equal_trust=runs["equal_trust"], keypoints_sensing=runs["keypoints_sensing"])


def run_demo(
    seed: int = 0, sensing: str = "render", progress: Callable[[str, float, float], None] | None = None
) -> DemoRuns:
    """Drive the demo's story (Case I; ``seed``: the sensing noise). ``sensing``: of the trust-aware
    and equal-trust runs ("render", the demo's; "keypoints": fast). ``progress(label, t, duration)``
    after each control step of those two runs."""
    sc = load_drive_scenario("case-1")
    comp = compare_trust(sc, sensing=sensing, seed=seed, progress=progress, modes=("trust-aware", _EQUAL_MODE))
    aware, equal = (run.result for run in comp.runs)
    return DemoRuns(aware, equal, run_drive(sc, sensing="keypoints", seed=seed), sensing)
