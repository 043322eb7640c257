"""Campaign figures: minimum distance vs trust, and violation / infeasibility rates vs horizon and
vs every swept numeric parameter (gamma_ini, delta, lambda of `weight`, trust, ...).

One PNG per sweep and question under ``figures/``; rates carry Wilson 95 % intervals. The figures
look like every trustnav figure (:mod:`trustnav.viz.style`: fonts, sizes, legends inside the axes,
integer ticks for integer parameters).
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from trustnav.campaigns.spec import CampaignSpec
from trustnav.campaigns.summary import TRUST_BANDS, wilson
from trustnav.viz.style import DPI, RC, new_figure

__all__ = ["write_figures"]


def _param_ticks(axis: Any, xs: Sequence[float], kind: str) -> None:
    """Ticks of a swept parameter: "bool" at 0 / 1 labelled no / yes, "int" at the values (or at
    integers when there are many), else matplotlib's."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, MaxNLocator

    if kind == "bool":
        axis.set_major_locator(FixedLocator([0.0, 1.0]))
        axis.set_major_formatter(FuncFormatter(lambda v, _p: {0.0: "no", 1.0: "yes"}.get(v, "")))
    elif kind == "int":
        if len(xs) <= 12:
            axis.set_major_locator(FixedLocator(sorted(xs)))
            axis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:.0f}"))
        else:
            axis.set_major_locator(MaxNLocator(integer=True))


def _kind(values: Sequence[Any]) -> str:
    """ "bool", "int" (integers, also as floats like 4.0) or "float" for a parameter's values."""
    if values and all(isinstance(v, bool) for v in values):
        return "bool"
    if values and all(isinstance(v, int | float) and float(v).is_integer() for v in values):
        return "int"
    return "float"


def _min_distance_vs_trust(name: str, recs: Sequence[Mapping[str, Any]], path: Path) -> bool:
    pairs = [
        (t, d)
        for r in recs
        for t, d in zip(r.get("ped_trust") or [], r.get("ped_min_distance") or [], strict=False)
        if t is not None and d is not None
    ]
    if not pairs:
        return False
    t, d = np.array(pairs).T
    radius = next((r["safety_radius"] for r in recs if r.get("safety_radius")), None)
    fig, ax = new_figure((6.4, 4.2))
    ax.scatter(
        t,
        d,
        s=6 if len(t) > 200 else 18,
        alpha=min(0.6, max(0.05, 300 / len(t))),
        color="tab:blue",
        lw=0,
        label="pedestrian",
    )
    edges = np.linspace(0, 1, 11)
    mids, med, lo, hi = [], [], [], []
    for a, b in itertools.pairwise(edges):
        sel = d[(t >= a) & ((t < b) | (b == 1.0) & (t <= b))]
        if sel.size >= 3:
            mids.append((a + b) / 2)
            med.append(np.median(sel))
            lo.append(np.percentile(sel, 10))
            hi.append(np.percentile(sel, 90))
    if mids:
        ax.fill_between(mids, lo, hi, color="tab:orange", alpha=0.25, label="10-90 %")
        ax.plot(mids, med, "o-", color="tab:orange", label="median")
    if radius:
        ax.axhline(radius, color="tab:red", ls="--", lw=1, label=f"R = {radius:g} m")
    top = np.percentile(d, 98) if d.size > 20 else d.max()
    ax.set_ylim(0, max(top * 1.1, (radius or 0) * 1.5))
    ax.set_xlim(-0.02, 1.02)
    ax.set_xlabel("trust of the pedestrian (0 to 1)")
    ax.set_ylabel("minimum distance to it (m)")
    ax.set_title(f"{name}: closest approach vs trust ({len(t)} pedestrians, {len(recs)} episodes)")
    ax.legend(loc="best", frameon=True)
    fig.savefig(path, dpi=DPI)
    return True


def _rates_vs(
    name: str, label: str, groups: Mapping[float, Sequence[Mapping[str, Any]]], path: Path, kind: str = "float"
) -> bool:
    """Violation and infeasibility rates, and the closest approach, per value of a parameter
    (``kind``: "int", "bool" or "float", for the ticks)."""
    xs = sorted(groups)
    if len(xs) < 2:
        return False
    fig, (ax, ax2) = new_figure((11.5, 3.8), ncols=2)
    for key, color, text in (
        ("breach", "tab:red", "margin violation"),
        ("relaxed", "tab:purple", "infeasible (relaxed step)"),
    ):
        rates, err_lo, err_hi = [], [], []
        for x in xs:
            ok = [r for r in groups[x] if r.get("status") == "ok"]
            k = sum(bool(r["breach"]) if key == "breach" else (r["relaxed_steps"] or 0) > 0 for r in ok)
            p = k / len(ok) if ok else np.nan
            ci = wilson(k, len(ok)) or (np.nan, np.nan)
            rates.append(p)
            err_lo.append(max(0.0, p - ci[0]))
            err_hi.append(max(0.0, ci[1] - p))
        dodge = (xs[-1] - xs[0]) * (0.008 if key == "breach" else -0.008)  # both series visible where equal
        ax.errorbar(np.add(xs, dodge), rates, yerr=[err_lo, err_hi], fmt="o-", color=color, capsize=3, label=text)
    ax.set_xlabel(label)
    ax.set_ylabel("share of episodes (95 % CI)")
    ax.set_ylim(bottom=0)
    ax.legend(loc="best", frameon=True)
    med, p05 = [], []
    for x in xs:
        md = [r["min_distance"] for r in groups[x] if r.get("status") == "ok" and r.get("min_distance") is not None]
        med.append(np.median(md) if md else np.nan)
        p05.append(np.percentile(md, 5) if md else np.nan)
    ax2.plot(xs, med, "o-", color="tab:blue", label="episode min, median")
    ax2.plot(xs, p05, "s--", color="tab:blue", alpha=0.6, label="episode min, 5th percentile")
    for (band_name, lo, hi), color in zip((TRUST_BANDS[0], TRUST_BANDS[2]), ("tab:green", "tab:orange"), strict=True):
        band = []
        for x in xs:
            ds = [
                d
                for r in groups[x]
                if r.get("status") == "ok"
                for t, d in zip(r.get("ped_trust") or [], r.get("ped_min_distance") or [], strict=False)
                if t is not None and d is not None and lo <= t < hi
            ]
            band.append(np.median(ds) if ds else np.nan)
        if not np.all(np.isnan(band)):
            ax2.plot(xs, band, "^:", color=color, label=f"per pedestrian, {band_name} trust, median")
    radius = next((r["safety_radius"] for g in groups.values() for r in g if r.get("safety_radius")), None)
    if radius:
        ax2.axhline(radius, color="tab:red", ls="--", lw=1, label=f"R = {radius:g} m")
    ax2.set_xlabel(label)
    ax2.set_ylabel("minimum distance (m)")
    ax2.legend(loc="best", frameon=True, fontsize=7)
    for a in (ax, ax2):
        _param_ticks(a.xaxis, xs, kind)
    n = sum(len(g) for g in groups.values())
    fig.suptitle(f"{name}: rates and closest approach vs {label} ({n} episodes)")
    fig.savefig(path, dpi=DPI)
    return True


def write_figures(spec: CampaignSpec, records: Sequence[Mapping[str, Any]], out: str | Path) -> list[Path]:
    """Write the figures of every sweep under ``out/figures``; return their paths."""
    from matplotlib import rc_context

    with rc_context(RC):
        return _write_figures(spec, records, out)


def _write_figures(spec: CampaignSpec, records: Sequence[Mapping[str, Any]], out: str | Path) -> list[Path]:
    fig_dir = Path(out) / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    keys = {t.key for t in spec.tasks()}
    written: list[Path] = []
    for s in spec.sweeps:
        recs = [r for r in records if r["sweep"] == s.name and r["key"] in keys]
        if not recs:
            continue
        ok = [r for r in recs if r.get("status") == "ok"]
        path = fig_dir / f"{s.name}_min_distance_vs_trust.png"
        if _min_distance_vs_trust(s.name, ok, path):
            written.append(path)
        swept = {n for n, _ in s.grid} | {n for n, _, _ in s.random}
        by_h: dict[float, list[Mapping[str, Any]]] = defaultdict(list)
        for r in recs:
            h = r.get("horizon") if r.get("horizon") is not None else r["params"].get("horizon")
            if h is not None:
                by_h[float(h)].append(r)
        path = fig_dir / f"{s.name}_rates_vs_horizon.png"
        if _rates_vs(s.name, "horizon N_h (steps)", by_h, path, "int"):
            written.append(path)
        for pname in sorted(swept - {"horizon"}):
            groups: dict[float, list[Mapping[str, Any]]] = defaultdict(list)
            values = []
            for r in recs:
                v = r["params"].get(pname)
                if isinstance(v, int | float):  # bools (attentive) as 0 / 1
                    groups[float(v)].append(r)
                    values.append(v)
            path = fig_dir / f"{s.name}_rates_vs_{pname}.png"
            if _rates_vs(s.name, pname, groups, path, _kind(values)):
                written.append(path)
    return written
