"""Figures of the paper's numerical scenarios (Figs. `scene1`, `scene2_1`, `pred_hor`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle

__all__ = ["plot_distances", "plot_paths", "plot_scenario"]


def _ped_markers(ax: Any, sc: Any) -> None:
    for j, p in enumerate(sc.pedestrians):
        ax.add_patch(Circle(p.position, sc.safety_radius, color="tab:red", alpha=0.12, lw=0))
        ax.add_patch(Circle(p.position, sc.safety_radius, color="tab:red", fill=False, ls="--", lw=0.8))
        ax.plot(*p.position, "ko", ms=5)
        ax.annotate(
            f"ped {j + 1}, trust {p.trust:g}", p.position, xytext=(4, 6), textcoords="offset points", fontsize=8
        )


def plot_paths(result: Any, path: str | Path) -> Path:
    """Ego paths in the 50 x 50 world (Scenario I: one per trust; II: trust-aware vs control)."""
    sc = result.scenario
    fig = Figure(figsize=(5.5, 5.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    if sc.trust_sweep:
        cmap = colormaps["viridis"]
        for t, ep in zip(sc.trust_sweep, result.episodes, strict=True):
            ax.plot(ep.ego[:, 0], ep.ego[:, 1], color=cmap(t), lw=1.6, label=f"trust {t:g}")
        p = sc.pedestrians[0]
        ax.add_patch(Circle(p.position, sc.safety_radius, color="tab:red", fill=False, ls="--", lw=0.8))
        ax.plot(*p.position, "ko", ms=5)
    else:
        _ped_markers(ax, sc)
        ep = result.episodes[0]
        ax.plot(ep.ego[:, 0], ep.ego[:, 1], color="tab:blue", lw=1.8, label="trust-aware path")
        if result.control is not None:
            c = result.control.ego
            ax.plot(c[:, 0], c[:, 1], color="tab:gray", lw=1.2, ls="-.", label="control: all trusts 1.0")
        ax.plot([sc.ego_start[0], sc.goal[0]], [sc.ego_start[1], sc.goal[1]], color="k", lw=0.8, ls=":",
                label="direct line")  # fmt: skip
    ax.plot(*sc.ego_start, "bs", ms=6)
    ax.plot(*sc.goal, "g*", ms=12, label="goal")
    ax.set_xlim(0, sc.world_size[0])
    ax.set_ylim(0, sc.world_size[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(sc.title, fontsize=7)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=130)
    return out


def plot_distances(result: Any, path: str | Path) -> Path:
    """Scenario III: distance to each pedestrian over time per horizon, R as a red line; one row
    per CBF timing."""
    sc = result.scenario
    rows = result.variant_episodes or {sc.timing: result.episodes}
    n_r, n_c = len(rows), len(sc.horizons)
    fig = Figure(figsize=(3.2 * n_c, 2.6 * n_r))
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_r, n_c, squeeze=False, sharey=True)
    lo = int(np.argmin([p.trust for p in sc.pedestrians]))
    hi = int(np.argmax([p.trust for p in sc.pedestrians]))
    for r, (timing, eps) in enumerate(rows.items()):
        for c, ep in enumerate(eps):
            ax = axes[r, c]
            d = ep.distances
            ax.plot(d[:, hi], color="tab:green", lw=1.4, label=f"high trust ({sc.pedestrians[hi].trust:g})")
            ax.plot(d[:, lo], color="tab:blue", lw=1.4, label=f"low trust ({sc.pedestrians[lo].trust:g})")
            ax.axhline(sc.safety_radius, color="tab:red", lw=1.0, label="R")
            breach = d.min() < sc.safety_radius - 1e-6
            ax.set_title(f"N_h = {ep.horizon}, {timing}" + ("  BREACH" if breach else ""), fontsize=8,
                         color="tab:red" if breach else "k")  # fmt: skip
            ax.set_ylim(0, 25)
            ax.grid(alpha=0.3)
            if r == n_r - 1:
                ax.set_xlabel("time step")
            if c == 0:
                ax.set_ylabel("distance")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(sc.title, fontsize=9)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=120)
    return out


def plot_scenario(result: Any, out_dir: str | Path) -> Path:
    """The figure the paper shows for this scenario, as ``out_dir/<scenario>.png``."""
    out = Path(out_dir) / f"{result.scenario.name}.png"
    if len(result.scenario.horizons) > 1:
        return plot_distances(result, out)
    return plot_paths(result, out)
