"""What trust buys: one scenario driven trust-aware and trust-blind (issue 21, item 5).

:func:`compare_trust` drives the same scenario, with the same seed, camera, perception and trust
estimation, three ways: **trust-aware** (the controller gets each pedestrian's estimated trust, as
``trustnav drive``), and **trust-blind** at both ends of gamma(trust): every pedestrian handed
trust 0 (gamma = gamma_ini, the most cautious barrier rate) and trust 1 (gamma = gamma_ini + delta,
the least cautious). Only the trusts the controller gets differ (:class:`ConstantTrustEnvironment`).
A scenario with ``variants`` (Case II) is compared per variant. :func:`comparison_rows` is the table.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from trustnav.sim.driving.episode import DriveEnvironment, DriveResult, drive, make_sensor, prepare_scenario
from trustnav.sim.driving.sensing import make_render_sensing
from trustnav.sim.driving.variants import variants_of
from trustnav.sim.driving.world import DriveScenario
from trustnav.sim.engine import Observation
from trustnav.trust.traits import gamma as gamma_of

__all__ = ["TRUST_MODES", "ConstantTrustEnvironment", "TrustComparison", "TrustRun", "compare_trust", "comparison_rows"]

#: label -> the constant trust the controller gets (None: trust-aware, the estimated trusts)
TRUST_MODES: dict[str, float | None] = {"trust-aware": None, "constant trust 0": 0.0, "constant trust 1": 1.0}


class ConstantTrustEnvironment:
    """A drive world whose controller is handed ``trust`` for every pedestrian (trust-blind);
    perception, trust estimation and the records run as usual (the records keep the estimated
    trusts)."""

    def __init__(self, sim: DriveEnvironment, trust: float) -> None:
        if not 0.0 <= trust <= 1.0:
            raise ValueError(f"trust must be in [0, 1], got {trust!r}")
        self._sim = sim
        self.trust = float(trust)

    def observe(self) -> Observation:
        obs = self._sim.observe()
        return dataclasses.replace(obs, trusts=np.full(len(obs.trusts), self.trust))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sim, name)


@dataclass(frozen=True)
class TrustRun:
    """One drive of a comparison: the variant ("" when the scenario has none), the mode (a key of
    :data:`TRUST_MODES`), the trust the controller got (None: estimated) and its gamma."""

    variant: str
    mode: str
    trust: float | None
    gamma: float | None
    result: DriveResult

    def __post_init__(self) -> None:
        if self.mode not in TRUST_MODES:
            raise ValueError(f"mode must be one of {tuple(TRUST_MODES)}, got {self.mode!r}")


@dataclass(frozen=True)
class TrustComparison:
    """The runs of :func:`compare_trust`, variant by variant, each variant's modes in
    :data:`TRUST_MODES` order."""

    scenario: DriveScenario
    sensing: str
    seed: int
    runs: tuple[TrustRun, ...]

    def __post_init__(self) -> None:
        if not self.runs:
            raise ValueError("a comparison needs at least one run")

    @property
    def variants(self) -> list[str]:
        return list(dict.fromkeys(r.variant for r in self.runs))

    def by_variant(self) -> list[tuple[str, list[TrustRun]]]:
        return [(v, [r for r in self.runs if r.variant == v]) for v in self.variants]


def compare_trust(
    scenario: DriveScenario,
    sensing: str = "keypoints",
    seed: int = 0,
    attentive: bool | None = None,
    capture_rate: float | None = None,
    control_rate: float | None = None,
    state: str = "perceived",
    progress: Callable[[str, float, float], None] | None = None,
    modes: Sequence[str] = tuple(TRUST_MODES),
) -> TrustComparison:
    """Drive ``scenario`` trust-aware and at constant trust 0 and 1 (per variant: ``attentive``
    True/False one behaviour, None the scenario's variants or as given). Pure: no files written.
    ``progress(label, t, duration)`` after each control step. ``modes``: the keys of
    :data:`TRUST_MODES` to drive (default all, in that order)."""
    unknown = [m for m in modes if m not in TRUST_MODES]
    if unknown or not modes:
        raise ValueError(f"modes must be keys of TRUST_MODES {tuple(TRUST_MODES)}, got {tuple(modes)!r}")
    g = scenario.control.gamma
    runs = []
    for tag, att in variants_of(scenario, attentive):
        sc = prepare_scenario(scenario, att, control_rate)
        for mode in modes:
            trust = TRUST_MODES[mode]
            label = f"{tag + ' ' if tag else ''}{mode}"
            renderer = pipeline = None
            if sensing == "render":
                renderer, pipeline = make_render_sensing(sc, capture_rate)
            try:
                sim = DriveEnvironment(sc, seed=seed, sensor=make_sensor(sensing, renderer, pipeline),
                                      capture_rate=capture_rate, state=state)  # fmt: skip
                world = sim if trust is None else ConstantTrustEnvironment(sim, trust)
                step = None if progress is None else (lambda t, d, label=label: progress(label, t, d))
                result = drive(world, sensing, progress=step)  # type: ignore[arg-type]
            finally:
                if renderer is not None:
                    renderer.close()
                if pipeline is not None and hasattr(pipeline.backend, "close"):
                    pipeline.backend.close()
            gamma = None if trust is None else float(gamma_of(np.array([trust]), g)[0])
            runs.append(TrustRun(tag, mode, trust, gamma, result))
    return TrustComparison(scenario, sensing, seed, tuple(runs))


def comparison_rows(comp: TrustComparison) -> list[dict[str, Any]]:
    """The table: per run (variant, mode) the trust and gamma the controller got, per pedestrian
    the closest approach (true distance, m) and the trust estimated at the end, the time to the
    goal, the largest offset from the lane centre and the control steps inside R."""
    rows = []
    for run in comp.runs:
        m = run.result.metrics()
        rows.append(
            {
                "variant": run.variant,
                "mode": run.mode,
                "trust_given": "estimated" if run.trust is None else run.trust,
                "gamma": None if run.gamma is None else round(run.gamma, 4),
                "pedestrians": [
                    {
                        "name": p["name"],
                        "attentive": p["attentive"],
                        "min_distance": p["min_distance"],
                        "final_trust": p["final_trust"],
                    }
                    for p in m["pedestrians"]
                ],
                "time_to_goal": m["time_to_goal"],
                "max_lateral_offset": m["max_lateral_offset"],
                "margin_violations": m["margin_violations"],
                "relaxed_steps": m["relaxed_steps"],
            }
        )
    return rows
