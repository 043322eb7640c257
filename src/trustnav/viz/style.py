"""One look for every trustnav figure, video and annotated frame.

* **Fonts and sizes**: :data:`RC` (matplotlib rc values, applied only while a figure is drawn:
  :func:`styled`, never globally) and :data:`DPI`.
* **One colour per person**: pedestrian ``j`` (scenario order) is drawn in
  :func:`person_colour` ``(j)`` in every figure, in the video's top view and on the annotated camera
  frames (a chip beside the label). The palette leaves out green, orange and red, which mean trust.
* **Trust colours**: green > 0.7, orange > 0.4, red otherwise (:func:`trust_colour`,
  :func:`trust_bgr`): the boxes of the annotated frames.
* **Layout**: :func:`new_figure` (a Figure on its own Agg canvas with constrained layout: nothing
  is cut off), :func:`legend` (inside the axes), :func:`integer_ticks` (integer parameters get
  integer ticks), :func:`save`.

``trustnav.campaigns.plots`` draws with this module; ``trustnav.sim.driving.topview`` (the video's
top view, drawn with OpenCV) may not import ``trustnav.viz`` (docs/architecture.md): it keeps a
copy of the colours it needs, and ``tests/test_viz_style.py`` checks that the copy equals these.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "BASELINE_COLOUR",
    "DPI",
    "EGO_COLOUR",
    "MARGIN_COLOUR",
    "PERSON_COLOURS",
    "RC",
    "TRUST_BANDS",
    "hex_bgr",
    "integer_ticks",
    "legend",
    "new_figure",
    "person_bgr",
    "person_colour",
    "person_label",
    "save",
    "styled",
    "trust_bgr",
    "trust_colour",
]

DPI = 130

#: matplotlib rc values of every trustnav figure (applied with :func:`styled`)
RC: dict[str, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "legend.fontsize": 8.0,
    "legend.framealpha": 0.9,
    "legend.edgecolor": "0.8",
    "figure.titlesize": 10.0,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.6,
    "figure.dpi": DPI,
    "savefig.dpi": DPI,
}

#: person j -> PERSON_COLOURS[j % len]: matplotlib's tab10 without its green, orange and red
PERSON_COLOURS: tuple[str, ...] = ("#1f77b4", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22")
EGO_COLOUR = "#222222"  # the trust-aware ego path
BASELINE_COLOUR = "#8a8a8a"  # a comparison run (equal trust)
MARGIN_COLOUR = "#d62020"  # the safety radius R

#: (lower bound, colour): trust above the bound gets the colour (first match)
TRUST_BANDS: tuple[tuple[float, str], ...] = ((0.7, "#1a9e3a"), (0.4, "#f08c00"), (float("-inf"), "#d62020"))


def hex_bgr(colour: str) -> tuple[int, int, int]:
    """'#rrggbb' as an OpenCV (b, g, r) tuple."""
    h = colour.lstrip("#")
    r, g, b = (int(h[i : i + 2], 16) for i in (0, 2, 4))
    return (b, g, r)


def person_colour(index: int) -> str:
    """Matplotlib colour ('#rrggbb') of pedestrian ``index`` (scenario order), the same everywhere."""
    return PERSON_COLOURS[int(index) % len(PERSON_COLOURS)]


def person_bgr(index: int) -> tuple[int, int, int]:
    """OpenCV (b, g, r) colour of pedestrian ``index``: :func:`person_colour` for images."""
    return hex_bgr(person_colour(index))


def trust_colour(trust: float) -> str:
    """Matplotlib colour of a trust value: green > 0.7, orange > 0.4, red otherwise."""
    return next(c for lim, c in TRUST_BANDS if trust > lim)


def trust_bgr(trust: float) -> tuple[int, int, int]:
    """OpenCV (b, g, r) colour of a trust value (:func:`trust_colour`)."""
    return hex_bgr(trust_colour(trust))


def person_label(name: str, attentive: bool | None = None) -> str:
    """A pedestrian's label: its name, with its behaviour in brackets unless the name says it
    already ("attentive", not "attentive (attentive)")."""
    if attentive is None:
        return name
    kind = "attentive" if attentive else "distracted"
    return name if kind in name else f"{name} ({kind})"


@contextlib.contextmanager
def styled() -> Iterator[None]:
    """Draw with :data:`RC` (matplotlib's rc values restored afterwards); also a decorator."""
    from matplotlib import rc_context

    with rc_context(RC):
        yield


def new_figure(
    figsize: tuple[float, float] = (6.4, 3.6), nrows: int = 1, ncols: int = 1, **subplots: Any
) -> tuple[Any, Any]:
    """A Figure on its own Agg canvas (no pyplot, no backend switch) with constrained layout, and
    its Axes (one, or an array as ``Figure.subplots`` gives). Call it inside :func:`styled`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    if nrows == 0:  # the caller lays the figure out itself (gridspec)
        return fig, None
    return fig, fig.subplots(nrows, ncols, **subplots)


def legend(ax: Any, loc: str = "best", **kw: Any) -> Any:
    """A legend inside the axes (framed, so it stays readable over data)."""
    return ax.legend(loc=loc, frameon=True, **kw)


def separate_coincident(ax: Any, rtol: float = 2e-3) -> list[tuple[str, str]]:
    """Make lines drawn over an earlier one visible: a line with the same points as an earlier line
    (within ``rtol`` of the axes' span) is drawn with dashes that alternate with the earlier one's
    (both at the earlier's width) and its legend label says so (``(same curve as attentive)``).
    Call before the legend; returns the (earlier, later) labels of the pairs found."""
    lines = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 1 and ln.get_transform() == ax.transData]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    span = np.array([abs(x1 - x0) or 1.0, abs(y1 - y0) or 1.0])
    pairs: list[tuple[str, str]] = []
    for i, b in enumerate(lines):
        pb = np.column_stack([b.get_xdata(), b.get_ydata()]).astype(float)
        for a in lines[:i]:
            pa = np.column_stack([a.get_xdata(), a.get_ydata()]).astype(float)
            if pa.shape != pb.shape or not np.all(np.abs(pa - pb) <= rtol * span):
                continue
            dash = 4.0
            a.set_linestyle((0.0, (dash, dash)))
            b.set_linestyle((dash, (dash, dash)))
            b.set_linewidth(a.get_linewidth())
            first = a.get_label().split(":")[0].split(",")[0]
            b.set_label(f"{b.get_label()} (same curve as {first})")
            pairs.append((a.get_label(), b.get_label()))
            break
    return pairs


def integer_ticks(axis: Any, values: Sequence[float] | None = None) -> None:
    """Integer ticks on ``axis`` (``ax.xaxis``): at ``values`` when there are at most 12 of them,
    else wherever matplotlib puts them, but only at integers."""
    from matplotlib.ticker import FixedLocator, MaxNLocator

    if values is not None and 0 < len(set(values)) <= 12:
        axis.set_major_locator(FixedLocator(sorted({float(v) for v in values})))
        axis.set_major_formatter(_int_formatter())
    else:
        axis.set_major_locator(MaxNLocator(integer=True))


def _int_formatter() -> Any:
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda v, _pos: f"{v:.0f}")


def save(fig: Any, path: str | Path) -> Path:
    """Save ``fig`` as PNG at :data:`DPI`; returns the path."""
    out = Path(path)
    fig.savefig(out, dpi=DPI)
    return out
