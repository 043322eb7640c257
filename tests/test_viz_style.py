"""One look for every figure (trustnav.viz.style): the same colour for the same pedestrian in every
figure, the video's top view and the annotated frames; legends inside their axes; integer ticks
for integer parameters; the trust in force at t = 0 as the camera boxes show it; the copies of the
style kept by layers that may not import viz; estimates drawn with their 90 % ellipses."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.colors import to_hex

from trustnav.campaigns import plots as campaign_plots
from trustnav.sim.driving import topview
from trustnav.viz import drive_plots, paper_plots, style
from trustnav.viz.annotate import annotate

# -- a drive result, duck-typed as trustnav.viz reads it (fast: no simulation)


class _Drive:
    def __init__(self, steps: int = 40) -> None:
        road = SimpleNamespace(start=(33.5, 145.0), end=(33.5, 60.0), width=6.0, sidewalk_width=3.0)
        peds = (
            SimpleNamespace(name="attentive", attentive=True, position=(29.5, 101.0), velocity=(0.0, 0.0)),
            SimpleNamespace(name="distracted", attentive=False, position=(37.5, 101.0), velocity=(0.0, 0.0)),
        )
        self.scenario = SimpleNamespace(
            name="case-1", title="Case I (test)", ego_start=(33.5, 129.0), goal=(33.5, 75.0), road=road,
            pedestrians=peds, control=SimpleNamespace(safety_radius=2.5, rate=20.0), duration=25.0,
        )  # fmt: skip
        self.sensing, self.capture_rate = "keypoints", 1.0
        self.times = np.arange(steps + 1) * 0.25
        y = np.linspace(129.0, 75.0, steps + 1)
        x = 33.5 - 1.2 * np.exp(-(((y - 103.0) / 5.0) ** 2))
        self.ego = np.column_stack([x, y, np.full(steps + 1, -math.pi / 2), np.full(steps + 1, 8.0)])
        self.pedestrians = np.tile(np.array([[29.5, 101.0], [37.5, 101.0]]), (steps + 1, 1, 1))
        # sample 0 is recorded before the frame at t = 0; from sample 1 on the frame's trusts hold
        self.trusts = np.zeros((steps + 1, 2))
        self.trusts[1:] = [0.23, 0.08]
        self.trusts[5:] = [0.41, 0.12]
        self.plans = np.stack([self.ego[min(i, steps - 1) : min(i, steps - 1) + 1].repeat(8, axis=0)
                               for i in range(steps)])  # fmt: skip
        self.frames = [self._frame(0, 0.0, (0.23, 0.08)), self._frame(1, 1.0, (0.41, 0.12))]

    @staticmethod
    def _frame(k: int, t: float, trusts: tuple[float, float]) -> SimpleNamespace:
        kp = np.full((17, 2), np.nan)
        sensed, views = [], []
        for j, (x1, tr) in enumerate(zip((700, 300), trusts, strict=True)):
            person = SimpleNamespace(bbox=np.array([x1, 300.0, x1 + 60.0, 460.0]), keypoints=kp)
            sensed.append(SimpleNamespace(index=j, track_id=10 + j, person=person, eye_contact=0.5, phone=0.1,
                                          phone_label="N", trust=tr))  # fmt: skip
            views.append(SimpleNamespace(trust=tr, observed=True))
        return SimpleNamespace(index=k, time=t, sensed=sensed, views=views, detections=2, ground_truth=2,
                               image=np.full((720, 1280, 3), 90, np.uint8), camera=None)  # fmt: skip

    @property
    def distances(self) -> np.ndarray:
        return np.linalg.norm(self.ego[:, None, :2] - self.pedestrians, axis=2)

    def trust_series(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        return np.array([f.time for f in self.frames]), np.array([f.views[j].trust for f in self.frames])

    def road_polygons(self):  # type: ignore[no-untyped-def]
        return topview.road_polygons(self.scenario.road)

    def top_view_image(self, i: int, size: tuple[int, int] = (1280, 400)) -> np.ndarray:
        return topview.top_view_image(self, i, size)


@pytest.fixture
def figures(monkeypatch):
    """The figures the plot functions save, by file name (they are saved as usual too)."""
    kept: dict[str, object] = {}
    real = style.save

    def keep(fig, path):  # type: ignore[no-untyped-def]
        kept[str(path).rsplit("/", 1)[-1]] = fig
        return real(fig, path)

    monkeypatch.setattr(style, "save", keep)
    return kept


def _lines(fig, label_start: str) -> list:  # type: ignore[no-untyped-def]
    return [ln for ax in fig.axes for ln in ax.get_lines() if str(ln.get_label()).startswith(label_start)]


def _legends_inside(fig) -> int:  # type: ignore[no-untyped-def]
    """Every legend lies inside its axes and the canvas; returns how many were checked."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    canvas = fig.bbox
    n = 0
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        lb, ab = leg.get_window_extent(r), ax.get_window_extent(r)
        assert ab.x0 - 1 <= lb.x0 and lb.x1 <= ab.x1 + 1 and ab.y0 - 1 <= lb.y0 and lb.y1 <= ab.y1 + 1, (lb, ab)
        assert canvas.x0 <= lb.x0 and lb.x1 <= canvas.x1 and canvas.y0 <= lb.y0 and lb.y1 <= canvas.y1
        n += 1
    return n


# -- the copies of the style in layers that may not import viz


def test_copies_of_the_style_equal_the_style():
    assert topview.PERSON_COLOURS == style.PERSON_COLOURS
    assert topview.TRUST_BANDS == style.TRUST_BANDS
    assert campaign_plots.RC is style.RC and campaign_plots.DPI == style.DPI  # one style, not a copy
    assert [topview.trust_bgr(t) for t in (0.9, 0.5, 0.1)] == [style.trust_bgr(t) for t in (0.9, 0.5, 0.1)]


def test_person_colours_leave_out_the_trust_colours_and_labels_say_it_once():
    assert not {c for _, c in style.TRUST_BANDS} & set(style.PERSON_COLOURS)
    assert style.person_colour(0) != style.person_colour(1)
    assert style.person_colour(len(style.PERSON_COLOURS)) == style.person_colour(0)
    assert style.person_label("attentive", True) == "attentive"
    assert style.person_label("walker", False) == "walker (distracted)"


# -- one colour per person across figures, the video and the frames


def test_the_same_pedestrian_has_the_same_colour_in_every_figure_and_image(tmp_path, figures):
    r = _Drive()
    drive_plots.plot_trust(r, tmp_path / "trust.png")
    drive_plots.plot_distance(r, tmp_path / "distance.png")
    drive_plots.plot_top_view(r, tmp_path / "top_view.png")
    for j, name in enumerate(("attentive", "distracted")):
        want = style.person_colour(j)
        for fig in (figures["trust.png"], figures["distance.png"]):
            lines = _lines(fig, name)
            assert lines and {to_hex(ln.get_color()) for ln in lines} == {want}
        rings = [p for p in figures["top_view.png"].axes[0].patches if to_hex(p.get_edgecolor()) == want]
        assert len(rings) == 1
    # the video's top view: each pedestrian's R ring in its colour, left and right of its centre
    img = topview.top_view_image(r, 3)
    frame = topview.TopViewFrame.for_scenario(r.scenario, (1280, 400))
    for j in range(2):
        u, v = frame.point(r.pedestrians[3, j])
        ring = round(2.5 * frame.scale)
        assert tuple(img[v, u + ring]) == style.person_bgr(j) == topview.person_bgr(j)
    # the annotated camera frames: a chip in the pedestrian's colour beside its label
    frames = drive_plots.annotated_frames(r)
    for j in range(2):
        assert np.all(frames[0] == np.array(style.person_bgr(j)), axis=2).sum() > 50


def test_annotate_keeps_the_box_in_the_trust_colour_with_a_person_chip():
    rec = {"bbox": [40, 60, 100, 200], "trust": 0.9, "track_id": 3, "eye_contact": 0.5, "name": "ped",
           "colour": style.person_bgr(1)}  # fmt: skip
    img = annotate(np.zeros((240, 320, 3), np.uint8), [rec], [np.full((17, 2), np.nan)], ["N"])
    assert tuple(img[130, 40]) == style.trust_bgr(0.9)
    assert np.all(img == np.array(style.person_bgr(1)), axis=2).sum() > 20


# -- numbers consistent between panels; no artefact at t = 0


def test_trust_in_force_at_t0_is_the_first_frames_trust(tmp_path, figures):
    r = _Drive()
    tr = drive_plots.trusts_in_force(r)
    assert tr[0].tolist() == [0.23, 0.08] == [f.trust for f in r.frames[0].views]
    assert np.array_equal(tr, topview.trusts_in_force(r))
    drive_plots.plot_trust(r, tmp_path / "trust.png")
    (line,) = _lines(figures["trust.png"], "attentive")
    assert line.get_ydata()[0] == pytest.approx(0.23)  # no drop to 0 (a vertical line) at t = 0
    assert figures["trust.png"].axes[0].get_xlim()[0] == 0.0


# -- legends inside the axes, integer ticks for integer parameters


def test_legends_lie_inside_their_axes(tmp_path, figures):
    r = _Drive()
    drive_plots.plot_trust(r, tmp_path / "trust.png")
    drive_plots.plot_distance(r, tmp_path / "distance.png", comparisons=[("equal trust 1", _Drive())])
    drive_plots.plot_top_view(r, tmp_path / "top_view.png", comparisons=[("equal trust 1", _Drive())])
    drive_plots.plot_top_view([r, _Drive()], tmp_path / "two.png")
    assert sum(_legends_inside(f) for f in figures.values()) >= 6


def test_paper_figures_have_units_and_legends_inside(tmp_path, figures):
    from trustnav.sim.paper import run_scenario

    result = run_scenario("paper-2")
    paper_plots.plot_scenario(result, tmp_path)
    fig = figures["paper-2.png"]
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    assert _legends_inside(fig) == 1
    for j in range(2):  # each pedestrian's ring in its own colour
        assert any(to_hex(p.get_edgecolor()) == style.person_colour(j) for p in ax.patches)


def _campaign_records(param: str, values: list) -> list[dict]:
    recs = []
    for i, v in enumerate(values * 3):
        recs.append({"status": "ok", "breach": i % 4 == 0, "relaxed_steps": i % 3, "min_distance": 3.0 + 0.1 * i,
                     "ped_trust": [0.1, 0.9], "ped_min_distance": [4.0, 3.2], "safety_radius": 2.5,
                     "params": {param: v}})  # fmt: skip
    return recs


@pytest.mark.parametrize(
    ("param", "values", "kind", "ticks"),
    [("horizon", [4, 7], "int", [4.0, 7.0]), ("attentive", [True, False], "bool", [0.0, 1.0])],
)
def test_campaign_rates_have_integer_ticks_and_legends_inside(tmp_path, monkeypatch, param, values, kind, ticks):
    from collections import defaultdict

    from matplotlib.figure import Figure

    kept = []
    real = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (kept.append(self), real(self, *a, **k))[1])
    groups: dict[float, list] = defaultdict(list)
    for r in _campaign_records(param, values):
        groups[float(r["params"][param])].append(r)
    assert campaign_plots._kind(values) == kind
    from matplotlib import rc_context

    with rc_context(campaign_plots.RC):
        assert campaign_plots._rates_vs("t", param, groups, tmp_path / "r.png", kind)
    (fig,) = kept
    fig.canvas.draw()
    for ax in fig.axes:
        assert list(ax.get_xticks()) == ticks  # no tick at N_h = 4.5
    if kind == "bool":
        assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["no", "yes"]
    assert _legends_inside(fig) == 2


def test_integer_ticks_helper():
    fig, ax = style.new_figure()
    ax.plot([1, 2, 3, 4], [0, 1, 0, 1])
    style.integer_ticks(ax.xaxis, [1, 2, 3, 4])
    assert list(ax.get_xticks()) == [1.0, 2.0, 3.0, 4.0]
    style.integer_ticks(ax.yaxis)
    fig.canvas.draw()
    assert all(float(t).is_integer() for t in ax.get_yticks())


# -- estimates with 90 % ellipses (the next layer of the top view)


def test_ellipse_holds_90_percent_and_bad_covariances_are_named():
    pts = topview.ellipse_points([1.0, 2.0], np.diag([4.0, 1.0]), prob=0.9)
    k = math.sqrt(-2 * math.log(0.1))  # 2.146 standard deviations
    d = pts - [1.0, 2.0]
    assert np.allclose((d[:, 0] / 2.0) ** 2 + d[:, 1] ** 2, k**2)
    with pytest.raises(ValueError, match="covariance"):
        topview.ellipse_points([0, 0], [[1, 2], [0, 1]])
    with pytest.raises(ValueError, match="positive semi-definite"):
        topview.ellipse_points([0, 0], [[1, 0], [0, -1]])
    with pytest.raises(ValueError, match="mean"):
        topview.ellipse_points([0, 0, 0], np.eye(2))


def test_draw_estimates_on_the_video_image_and_on_axes():
    r = _Drive()
    size = (1280, 400)
    frame = topview.TopViewFrame.for_scenario(r.scenario, size)
    est = [(0, (29.5, 104.0), np.diag([0.5, 1.5])), (1, np.array([37.5, 104.0]), 0.2 * np.eye(2))]
    plain = topview.top_view_image(r, 0, size)
    img = topview.top_view_image(r, 0, size, estimates=est)
    for j, (_, mean, _cov) in enumerate(est):
        u, v = frame.point(mean)
        patch = img[v - 40 : v + 40, u - 40 : u + 40]
        assert (
            np.all(patch == np.array(style.person_bgr(j)), axis=2).sum()
            > np.all(plain[v - 40 : v + 40, u - 40 : u + 40] == np.array(style.person_bgr(j)), axis=2).sum()
        )
    with pytest.raises(ValueError, match="TopViewFrame"):
        topview.draw_estimates(plain.copy(), est)
    _fig, ax = style.new_figure()
    assert topview.draw_estimates(ax, est, lambda p: p[:, ::-1]) == 2
    dashed = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
    assert [to_hex(ln.get_color()) for ln in dashed] == [style.person_colour(0), style.person_colour(1)]
    assert dashed[0].get_xdata().mean() == pytest.approx(104.0, abs=0.1)  # map y on the horizontal axis
