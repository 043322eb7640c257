"""Figures tested by what they show, not by file size: after drawing, every text lies inside the
figure and every annotation and legend inside its axes; no two drawn curves coincide unseen (a
curve drawn over another is drawn distinguishably and its legend says so); every drawn line is
named (a legend entry, a legend entry of its colour and style, or a text label of its colour).
For the drive's figures (top view, trust, distance, the trust comparison) on real keypoint drives
of the paper's cases, and the campaign figures."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from trustnav.viz import drive_plots, style

TOL = 1.0  # px: a text may touch the edge it must not cross


# ------------------------------------------------------------------ what a figure shows


def _inside(inner: Any, outer: Any) -> bool:
    return (
        inner.x0 >= outer.x0 - TOL
        and inner.y0 >= outer.y0 - TOL
        and inner.x1 <= outer.x1 + TOL
        and inner.y1 <= outer.y1 + TOL
    )


def texts_cut_off(fig: Figure) -> list[str]:
    """Texts (titles, axis and tick labels, legends, annotations) not wholly where they are read."""
    r = fig.canvas.get_renderer()
    bad = []
    for t in fig.texts:
        if t.get_visible() and t.get_text() and not _inside(t.get_window_extent(r), fig.bbox):
            bad.append(f"figure text {t.get_text()!r}")
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        if not _inside(ax.get_tightbbox(r), fig.bbox):  # ticks, axis labels, title, legend
            bad.append(f"axes {ax.get_title()!r} reaches past the figure")
        for t in ax.texts:
            if t.get_visible() and t.get_text() and not _inside(t.get_window_extent(r), ax.bbox):
                bad.append(f"label {t.get_text()!r} crosses the axes {ax.get_title()!r}")
        leg = ax.get_legend()
        if leg is not None and leg.get_bbox_to_anchor().bounds == ax.bbox.bounds:  # a legend inside the axes
            if not _inside(leg.get_window_extent(r), ax.bbox):
                bad.append(f"legend of {ax.get_title()!r} crosses its axes")
    return bad


def _curves(ax: Any) -> list[Any]:
    return [ln for ln in ax.get_lines() if ln.get_visible() and len(np.atleast_1d(ln.get_xdata())) > 0]


def _points(ln: Any) -> np.ndarray:
    return np.column_stack([np.atleast_1d(ln.get_xdata()), np.atleast_1d(ln.get_ydata())]).astype(float)


def _dashes(ln: Any) -> Any:
    return getattr(ln, "_dash_pattern", ln.get_linestyle())


def hidden_curves(fig: Figure) -> list[str]:
    """Pairs of curves on the same points (within 0.2 % of the axes' span) where the later one is
    not drawn distinguishably (another colour, or dashes offset against the earlier's) or its
    legend entry does not say that it lies on the other."""
    bad = []
    for ax in fig.axes:
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        span = np.array([abs(x1 - x0), abs(y1 - y0)])
        lines = [ln for ln in _curves(ax) if len(_points(ln)) > 1 and ln.get_transform() == ax.transData]
        for i, b in enumerate(lines):
            for a in lines[:i]:
                pa, pb = _points(a), _points(b)
                if pa.shape != pb.shape or not np.all(np.abs(pa - pb) <= 2e-3 * span):
                    continue
                seen = to_rgba(a.get_color()) != to_rgba(b.get_color()) or _dashes(a) != _dashes(b)
                if not seen or "same curve as" not in b.get_label():
                    bad.append(f"{b.get_label()!r} lies on {a.get_label()!r} in {ax.get_title()!r}")
    return bad


def _flat(handles: Any) -> list[Any]:
    out = []
    for h in handles:
        out += _flat(h) if isinstance(h, tuple) else [h]  # containers (errorbars) are tuples
    return out


def unnamed_lines(fig: Figure) -> list[str]:
    """Drawn lines that nothing names: not in the legend (itself, or as part of an entry such as
    an error bar's caps), no legend entry of the same colour and line style (markers: the same
    colour), no text label of their colour in the axes."""
    bad = []
    for ax in fig.axes:
        shown = ax.get_legend() is not None
        entries = [h for h in _flat(ax.get_legend_handles_labels()[0]) if isinstance(h, Line2D)] if shown else []
        in_legend = {id(h) for h in entries}
        styles = {(to_rgba(h.get_color()), h.get_linestyle()) for h in entries}
        colours = {c for c, _ in styles}
        text_colours = {to_rgba(t.get_color()) for t in ax.texts if t.get_visible() and t.get_text()}
        for ln in _curves(ax):
            colour, ls = to_rgba(ln.get_color()), ln.get_linestyle()
            named = (
                id(ln) in in_legend
                or (colour, ls) in styles
                or (ls in ("None", "") and colour in colours)
                or colour in text_colours
            )
            if not named:
                bad.append(f"line {ln.get_label()!r} ({ln.get_color()}, {ls}) in {ax.get_title()!r}")
    return bad


def minima_under_legend(fig: Figure) -> list[str]:
    """Curves whose lowest point (a closest approach) the legend hides."""
    r = fig.canvas.get_renderer()
    bad = []
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        box = leg.get_window_extent(r)
        for ln in _curves(ax):
            p = _points(ln)
            if len(p) > 1 and ln.get_transform() == ax.transData:
                x, y = ax.transData.transform(p[int(np.argmin(p[:, 1]))])
                if box.x0 <= x <= box.x1 and box.y0 <= y <= box.y1:
                    bad.append(f"the minimum of {ln.get_label()!r} lies under the legend")
    return bad


def check(fig: Figure) -> list[str]:
    return texts_cut_off(fig) + hidden_curves(fig) + unnamed_lines(fig)


@pytest.fixture
def drawn(monkeypatch):
    """The figures saved during a test, each drawn as saved (constrained layout applied)."""
    figs: list[Figure] = []
    save = Figure.savefig

    def savefig(self: Figure, *args: Any, **kw: Any) -> Any:
        out = save(self, *args, **kw)
        self.canvas.draw()
        figs.append(self)
        return out

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figs


# ------------------------------------------------------------------ the checks can fail


def test_the_checks_catch_a_cut_label_a_hidden_curve_and_an_unnamed_line():
    fig, ax = style.new_figure((4.0, 3.0))
    t = np.linspace(0, 1, 20)
    ax.plot(t, t, color="C0", label="a")
    ax.plot(t, t, color="C0", label="b")  # on top of a, same look, no note
    ax.plot(t, 1 - t, color="C2")  # no label, no text of its colour
    ax.text(0.95, 0.5, "a label running out of the axes")
    ax.legend(loc="upper left")
    fig.canvas.draw()
    problems = check(fig)
    assert any("crosses the axes" in p for p in problems)
    assert any("'b' lies on 'a'" in p for p in problems)
    assert any("C2" in p for p in problems)


def test_separate_coincident_makes_both_curves_seen_and_says_so():
    fig, ax = style.new_figure((4.0, 3.0))
    t = np.linspace(0, 1, 20)
    ax.plot(t, t, color="C0", ls="--", label="attentive, equal trust 1: min 4.00 m")
    ax.plot(t, t + 1e-4, color="C4", ls="--", label="distracted, equal trust 1: min 4.00 m")
    assert hidden_curves(fig)  # same dashes: the later one hides the earlier
    style.separate_coincident(ax)
    ax.legend()
    fig.canvas.draw()
    assert hidden_curves(fig) == []
    assert ax.get_lines()[1].get_label().endswith("(same curve as attentive)")


# ------------------------------------------------------------------ the drive's figures


@pytest.fixture(scope="module")
def case1():
    from trustnav.sim.driving import load_drive_scenario
    from trustnav.sim.driving.compare import compare_trust

    comp = compare_trust(load_drive_scenario("case-1"), sensing="keypoints", seed=3)
    return {r.mode: r.result for r in comp.runs}


@pytest.fixture(scope="module")
def case2():
    from trustnav.sim.driving import load_drive_scenario
    from trustnav.sim.driving.compare import compare_trust

    return compare_trust(load_drive_scenario("case-2"), sensing="keypoints", seed=4)


@pytest.mark.slow
def test_case1_figures_show_everything_they_draw(case1, drawn, tmp_path):
    """The demo's figures: the trust-aware drive with the equal-trust run beside it. At equal trust
    the two pedestrians, either side of the lane at the same distance, give the same distance
    curve: it must be drawn so that both show, and said."""
    aware, equal = case1["trust-aware"], case1["constant trust 1"]
    d = equal.distances
    assert np.allclose(d[:, 0], d[:, 1], atol=0.02)  # the case the fault was about
    drive_plots.plot_top_view(aware, tmp_path / "top.png", comparisons=[("equal trust 1", equal)],
                              offset_only=[("trust 0", case1["constant trust 0"])])  # fmt: skip
    drive_plots.plot_distance(aware, tmp_path / "distance.png", comparisons=[("equal trust 1", equal)])
    drive_plots.plot_trust(aware, tmp_path / "trust.png")
    assert len(drawn) == 3
    for fig in drawn:
        assert check(fig) == [], fig.axes[0].get_title()
    assert minima_under_legend(drawn[1]) == []  # the closest approaches stay in sight
    notes = [t.get_text() for t in drawn[1].axes[0].get_legend().get_texts() if "same curve as" in t.get_text()]
    assert notes == ["distracted, equal trust 1: min 4.00 m (same curve as attentive)"]


@pytest.mark.slow
def test_case2_and_comparison_figures_show_everything_they_draw(case2, drawn, tmp_path):
    results = [r.result for r in case2.runs if r.mode == "trust-aware"]
    drive_plots.plot_top_view(results, tmp_path / "top.png")
    drive_plots.plot_distance(results, tmp_path / "distance.png")
    groups = [(v, [(r.mode, r.result) for r in runs]) for v, runs in case2.by_variant()]
    drive_plots.plot_trust_comparison(groups, tmp_path / "compare.png")
    assert len(drawn) == 3
    assert minima_under_legend(drawn[1]) == []
    for fig in drawn:
        assert check(fig) == [], fig.axes[0].get_title()


@pytest.mark.slow
def test_camera_inset_shows_every_label_whole(case1):
    """The top view's camera inset is a crop of the annotated frame: each label perception's
    track id and trust, whole inside the crop, the chip in the pedestrian's colour."""
    from trustnav.viz.annotate import label_rects

    aware = case1["trust-aware"]
    k = drive_plots.camera_frame_index(aware)
    f = aware.frames[k]
    recs, _, labels = drive_plots._frame_records(f)
    assert recs and all(r["name"] == f"track {r['track_id']}" for r in recs)  # perception's id, not a scenario name
    assert all(r["colour"] == style.person_bgr(s.index) for r, s in zip(recs, f.sensed, strict=True))
    img = drive_plots.annotated_frames(aware)[k]
    rects = label_rects(img.shape, recs, labels)
    x0, y0, w, h = drive_plots._crop_window(img.shape, [r["bbox"] for r in recs] + [list(b) for b in rects])
    for lx1, ly1, lx2, ly2 in rects:
        assert x0 <= lx1 and lx2 <= x0 + w and y0 <= ly1 and ly2 <= y0 + h


# ------------------------------------------------------------------ the campaign figures


def _records(n: int = 120, seed: int = 5) -> list[dict]:
    rng = np.random.default_rng(seed)
    recs = []
    for i in range(n):
        h = int(rng.choice([5, 7, 9]))
        trust = rng.uniform(0, 1, 3)
        d = 2.5 + 3.0 * (1 - trust) + rng.normal(0, 0.3, 3)
        recs.append({"sweep": "si", "key": f"k{i}", "status": "ok", "horizon": h, "params": {"horizon": h,
                     "gamma": float(rng.choice([0.2, 0.5]))}, "ped_trust": list(trust),
                     "ped_min_distance": list(d), "min_distance": float(d.min()), "safety_radius": 2.5,
                     "breach": bool(d.min() < 2.5), "relaxed_steps": int(rng.integers(0, 2))})  # fmt: skip
    return recs


def test_campaign_figures_show_everything_they_draw(drawn, tmp_path):
    from collections import defaultdict

    from trustnav.campaigns import plots

    recs = _records()
    assert plots._min_distance_vs_trust("si", recs, tmp_path / "a.png")
    by_h: dict[float, list[dict]] = defaultdict(list)
    for r in recs:
        by_h[float(r["horizon"])].append(r)
    assert plots._rates_vs("si", "horizon N_h (steps)", by_h, tmp_path / "b.png", "int")
    assert len(drawn) == 2
    for fig in drawn:
        assert check(fig) == [], fig.axes[0].get_title()
