"""Figures of the paper's numerical scenarios (Figs. `scene1`, `scene2_1`, `pred_hor`), in the
look of :mod:`trustnav.viz.style` (pedestrian j in ``person_colour(j)``, metres and seconds on
the axes)."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.patches import Circle

from trustnav.viz import style

__all__ = ["plot_distances", "plot_paths", "plot_scenario"]


def _pedestrian(ax: Any, sc: Any, j: int, label: bool = True) -> None:
    """Pedestrian j at its start: dot and R circle in its own colour, with its trust."""
    p = sc.pedestrians[j]
    c = style.person_colour(j)
    ax.add_patch(Circle(p.position, sc.safety_radius, color=c, alpha=0.10, lw=0))
    ax.add_patch(Circle(p.position, sc.safety_radius, color=c, fill=False, ls="--", lw=1.0))
    ax.plot(*p.position, "o", color=c, mec="k", ms=6, zorder=5)
    if label:
        x, y = p.position
        ax.text(x, y + sc.safety_radius + 0.8, f"ped {j + 1}, trust {p.trust:g}", ha="center", va="bottom", color=c)


def _title(text: str, width: int = 62) -> str:
    return "\n".join(textwrap.wrap(text, width))


@style.styled()
def plot_paths(result: Any, path: str | Path) -> Path:
    """Ego paths in the 50 m x 50 m world (Scenario I: one per trust; II: trust-aware vs equal trust)."""
    sc = result.scenario
    fig, ax = style.new_figure((5.6, 5.8))
    if sc.trust_sweep:
        cmap = colormaps["viridis"]
        for t, ep in zip(sc.trust_sweep, result.episodes, strict=True):
            d = ep.distances[:, 0].min()
            ax.plot(ep.ego[:, 0], ep.ego[:, 1], color=cmap(0.9 * t), label=f"trust {t:g}: min d {d:.2f} m")
        p = sc.pedestrians[0]
        c = style.person_colour(0)
        ax.add_patch(Circle(p.position, sc.safety_radius, color=c, fill=False, ls="--", lw=1.0))
        ax.plot(*p.position, "o", color=c, mec="k", ms=6, zorder=5, label=f"pedestrian, R = {sc.safety_radius:g} m")
    else:
        for j in range(len(sc.pedestrians)):
            _pedestrian(ax, sc, j)
        ep = result.episodes[0]
        d = ", ".join(f"{v:.1f}" for v in ep.distances.min(axis=0))
        ax.plot(ep.ego[:, 0], ep.ego[:, 1], color=style.EGO_COLOUR, lw=1.8, label=f"trust-aware (min d {d} m)")
        if result.control is not None:
            c = result.control
            dc = ", ".join(f"{v:.1f}" for v in c.distances.min(axis=0))
            ax.plot(c.ego[:, 0], c.ego[:, 1], color=style.BASELINE_COLOUR, lw=1.4, ls="--",
                    label=f"equal trust 1.0 (min d {dc} m)")  # fmt: skip
        ax.plot([sc.ego_start[0], sc.goal[0]], [sc.ego_start[1], sc.goal[1]], color="k", lw=0.7, ls=":",
                alpha=0.7, zorder=1, label="straight line")  # fmt: skip
    ax.plot(*sc.ego_start, "s", color=style.EGO_COLOUR, ms=6, label="start")
    ax.plot(*sc.goal, "*", color="gold", mec="k", ms=13, label="goal")
    ax.set_xlim(0, sc.world_size[0])
    ax.set_ylim(0, sc.world_size[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(_title(sc.title))
    style.legend(ax)
    return style.save(fig, path)


@style.styled()
def plot_distances(result: Any, path: str | Path) -> Path:
    """Scenario III: distance to each pedestrian over time per horizon, R as a red line; one row
    per CBF timing."""
    sc = result.scenario
    rows = result.variant_episodes or {sc.timing: result.episodes}
    n_r, n_c = len(rows), len(sc.horizons)
    fig, axes = style.new_figure((2.9 * n_c + 0.6, 2.5 * n_r + 0.5), n_r, n_c, squeeze=False, sharey=True)
    for r, (timing, eps) in enumerate(rows.items()):
        for c, ep in enumerate(eps):
            ax = axes[r, c]
            d = ep.distances
            t = np.arange(len(d)) * sc.dt
            for j, p in enumerate(sc.pedestrians):
                ax.plot(t, d[:, j], color=style.person_colour(j), label=f"ped {j + 1}, trust {p.trust:g}")
            ax.axhline(
                sc.safety_radius, color=style.MARGIN_COLOUR, lw=1.0, ls="--", label=f"R = {sc.safety_radius:g} m"
            )
            breach = d.min() < sc.safety_radius - 1e-6
            ax.set_title(f"N_h = {ep.horizon}, {timing.replace('_', ' ')} timing" + ("  BREACH" if breach else ""),
                         fontsize=9, color=style.MARGIN_COLOUR if breach else "k")  # fmt: skip
            ax.set_ylim(0, 25)
            if r == n_r - 1:
                ax.set_xlabel("time (s)")
            if c == 0:
                ax.set_ylabel("distance (m)")
    style.legend(axes[0, 0], loc="upper right")
    fig.suptitle(sc.title)
    return style.save(fig, path)


def plot_scenario(result: Any, out_dir: str | Path) -> Path:
    """The figure the paper shows for this scenario, as ``out_dir/<scenario>.png``."""
    out = Path(out_dir) / f"{result.scenario.name}.png"
    if len(result.scenario.horizons) > 1:
        return plot_distances(result, out)
    return plot_paths(result, out)
