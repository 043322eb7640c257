"""Figures and animation of a trust-aware drive (the paper's Figs. `path_carla1`, `trust_scene1`,
`dist_carla2`, `trust_frames`): top view, trust over time, distance over time, annotated camera
frames and an MP4 of the top view with the latest camera frame as picture-in-picture.

Reads drive results (duck-typed: the fields and methods of
:class:`trustnav.sim.driving.episode.DriveResult`: ``scenario``, ``times``, ``ego``, ``pedestrians``,
``trusts``, ``frames``, ``distances``, ``trust_series``, ``road_polygons``, ``top_view_image``) and
imports nothing of trustnav but :mod:`trustnav.viz`; never drives a simulation. Figures are
``matplotlib.figure.Figure`` objects on an Agg canvas: no pyplot, no global backend change; they
share the look of :mod:`trustnav.viz.style` (pedestrian j in ``person_colour(j)`` everywhere).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.viz import style

DriveResult = Any  # trustnav.sim.driving.episode.DriveResult, read duck-typed
FrameReport = Any  # trustnav.sim.driving.sensing.FrameReport

__all__ = [
    "annotated_frames",
    "camera_frame_index",
    "lateral_offset",
    "latest_annotated_frame",
    "plot_distance",
    "plot_top_view",
    "plot_trust",
    "plot_trust_comparison",
    "trust_rgb",
    "trusts_in_force",
    "write_animation",
    "write_comparison_outputs",
    "write_demo_outputs",
    "write_drive_outputs",
    "write_variant_outputs",
]

#: matplotlib colour of a trust value (green > 0.7, orange > 0.4, red otherwise)
trust_rgb = style.trust_colour

# map colours, as the video's top view (trustnav.sim.driving.topview)
_SURROUND, _SIDEWALK, _ROAD = "#dfe9d8", "#e9e4da", "#c8c8c8"


def _outlined() -> list[Any]:
    """Path effects of the white lane centre: outlined, so that it shows in the legend too."""
    from matplotlib import patheffects

    return [patheffects.withStroke(linewidth=2.4, foreground="0.55"), patheffects.Normal()]


# comparison runs: line style and colour, in the order given
_COMPARE = (("--", style.BASELINE_COLOUR), (":", "#444444"), ("-.", "#6b6b6b"))


def _many(results: Any) -> list[Any]:
    """One result or a sequence of them, as a list."""
    return list(results) if isinstance(results, Sequence) else [results]


def _yx(p: NDArray) -> tuple[NDArray, NDArray]:
    """Plot coordinates: the road runs left to right (map y on the horizontal axis, reversed)."""
    p = np.asarray(p)
    return p[..., 1], p[..., 0]


def trusts_in_force(result: DriveResult) -> NDArray[np.float64]:
    """(T+1, N) the trusts the controller used from sample i on (a sample is recorded before the
    frame captured at its time updates the trusts): those recorded at sample i + 1, the last
    sample keeping its own. At t = 0: the trusts of the first camera frame, as its boxes show."""
    tr = np.asarray(result.trusts, dtype=float)
    return np.concatenate([tr[1:], tr[-1:]]) if len(tr) > 1 else tr.copy()


def _variant(r: DriveResult) -> str:
    att = {p.attentive for p in r.scenario.pedestrians}
    return "attentive" if att == {True} else ("distracted" if att == {False} else "mixed")


def _name(r: DriveResult, j: int) -> str:
    p = r.scenario.pedestrians[j]
    return style.person_label(p.name, p.attentive)


def lateral_offset(result: DriveResult) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(map y, signed offset from the road's centre line) of the ego per sample; the offset is
    positive toward the road's left normal (map +x for a road driven toward -y, as Case I's)."""
    _, _, t = result.road_polygons()
    a = np.asarray(result.scenario.road.start, dtype=float)
    n = np.array([-t[1], t[0]])
    return result.ego[:, 1], (result.ego[:, :2] - a) @ n


def camera_frame_index(result: DriveResult) -> int | None:
    """The frame to show beside a top view: the latest of those that perceived the most pedestrians."""
    if not result.frames:
        return None
    best = max(f.detections for f in result.frames)
    return max(k for k, f in enumerate(result.frames) if f.detections == best)


@style.styled()
def plot_top_view(
    results: DriveResult | Sequence[DriveResult],
    path: str | Path,
    title: str | None = None,
    comparisons: Sequence[tuple[str, DriveResult]] = (),
    camera_frames: Sequence[NDArray[np.uint8]] | None = None,
    offset_only: Sequence[tuple[str, DriveResult]] = (),
) -> Path:
    """Top view to scale (road, lane centre, ego path(s), pedestrians in their own colours with
    their R rings at the closest approach), under it the lateral offset from the lane centre
    (magnified, so that a bend of decimetres shows) and, for one result with camera frames, the
    annotated camera frame that saw the most pedestrians.

    ``results``: one drive, or several (Case II: attentive vs distracted, one path each).
    ``comparisons``: (label, result) drives of the same scenario drawn as dashed / dotted paths,
    e.g. ``("equal trust 1.0", equal)``: the same world with every pedestrian trusted alike.
    ``camera_frames``: the annotated frames (BGR) of the first result (default: drawn here).
    ``offset_only``: (label, result) drives drawn in the offset panel only (e.g. the same drive
    in keypoint sensing, to show how much of the bend perception costs)."""
    rs = _many(results)
    r0 = rs[0]
    sc = r0.scenario
    cams = None
    if len(rs) == 1 and r0.frames:
        cams = list(camera_frames) if camera_frames is not None else annotated_frames(r0)
    fig, _ = style.new_figure((10.5, 6.6 if cams else 6.0), nrows=0)
    gs = fig.add_gridspec(2, 2, height_ratios=(1.35, 1.0), width_ratios=(1.45, 1.0))
    ax = fig.add_subplot(gs[0, :])
    ax_off = fig.add_subplot(gs[1, 0] if cams else gs[1, :])
    radius = sc.control.safety_radius

    # -- the map, to scale
    ax.set_facecolor(_SURROUND)
    ax.grid(False)
    road, walks, _ = r0.road_polygons()
    ax.fill(*_yx(road), color=_ROAD, zorder=0)
    for w in walks:
        ax.fill(*_yx(w), color=_SIDEWALK, zorder=0)
    ax.plot(*_yx(np.array([sc.ego_start, sc.goal])), color="white", ls=(0, (6, 4)), lw=1.2, zorder=1,
            label="lane centre", path_effects=_outlined())  # fmt: skip
    runs = [(k, r, "-", style.EGO_COLOUR if k == 0 else "#0057b8") for k, r in enumerate(rs)]
    runs += [(len(rs) + k, r, *_COMPARE[k % len(_COMPARE)]) for k, (_, r) in enumerate(comparisons)]
    tags = [_variant(r) + " run" if len(rs) > 1 else "trust-aware" for r in rs] + [lab for lab, _ in comparisons]
    n_map = len(runs)
    runs += [(n_map + k, r, *_COMPARE[(len(comparisons) + k) % len(_COMPARE)]) for k, (_, r) in enumerate(offset_only)]
    tags += [lab for lab, _ in offset_only]
    for (k, r, ls, colour), tag in zip(runs[:n_map], tags[:n_map], strict=True):
        lw = 2.0 if k == 0 else 1.6
        ax.plot(*_yx(r.ego[:, :2]), ls=ls, color=colour, lw=lw, zorder=3, label=f"{tag} path")
    ax.plot(*_yx(np.array(sc.ego_start)), "s", color=style.EGO_COLOUR, ms=6, zorder=5, label="start")
    ax.plot(*_yx(np.array(sc.goal)), marker="*", ms=14, color="gold", mec="k", zorder=5, ls="", label="goal")
    for k, r in enumerate(rs):
        for j in range(len(r.scenario.pedestrians)):
            _pedestrian_on_map(ax, r, j, k, radius, comparisons if len(rs) == 1 else (),
                               f"{_variant(r)} run" if len(rs) > 1 else "")  # fmt: skip
    regions = rs[0].estimate_regions() if hasattr(rs[0], "estimate_regions") else []
    for j, mean, ring in regions:  # what the camera placed, frame by frame, with its 90 % region
        colour = style.person_colour(j)
        ax.plot(*_yx(ring), ls="--", lw=0.9, color=colour, zorder=6)
        ax.plot(*_yx(mean), "x", ms=5, mew=1.3, color=colour, zorder=6)
    if regions:
        ax.plot([], [], "x--", color="0.3", lw=0.9, label="camera estimates, 90 % regions")
    ax.set_aspect("equal", adjustable="box")
    ys = np.concatenate([r.ego[:, 1] for r in rs])
    x_left, x_right = max(ys.max(), sc.ego_start[1]) + 3, min(ys.min(), sc.goal[1]) - 3
    ax.set_xlim(x_left, x_right)
    xs = np.array([sc.ego_start[0], sc.goal[0], *[p.position[0] for p in sc.pedestrians]])
    ax.set_ylim(xs.min() - 7.0, xs.max() + 6.0)
    ax.set_xlabel("map y (m), driving direction →")
    ax.set_ylabel("map x (m)")
    sensing = f"{r0.sensing} sensing" + (f", camera {r0.capture_rate:g} frame/s" if r0.frames else "")
    sensing += _latency_note(r0)
    ax.set_title(f"top view to scale ({sensing}); rings: R = {radius:g} m at the closest approach")
    style.separate_coincident(ax)
    style.legend(ax, loc="lower left", ncol=3, fontsize=7.5)

    # -- lateral offset, magnified
    peak = 0.0
    for (k, r, ls, colour), tag in zip(runs, tags, strict=True):
        y, off = lateral_offset(r)
        i = int(np.argmax(np.abs(off)))
        peak = max(peak, abs(off[i]))
        ax_off.plot(y, off, ls=ls, color=colour, lw=2.0 if k == 0 else 1.6,
                    label=f"{tag}: bend {abs(off[i]):.2f} m")  # fmt: skip
    lim = max(1.0, 1.35 * peak)
    a = np.asarray(sc.road.start, dtype=float)
    _, _, t = r0.road_polygons()
    n = np.array([-t[1], t[0]])
    for j, p in enumerate(sc.pedestrians):
        side = float((np.asarray(p.position) - a) @ n)
        c = style.person_colour(j)
        ax_off.axvline(p.position[1], color=c, ls=":", lw=1.2)
        ax_off.text(p.position[1], 0.93 * lim * np.sign(side or 1.0), f" {p.name} side",
                    color=c, ha="left", va="top" if side > 0 else "bottom")  # fmt: skip
    ax_off.axhline(0.0, color="0.5", lw=0.8, label="lane centre")
    ax_off.set_ylim(-lim, lim)
    ax_off.set_xlim(x_left, x_right)
    ax_off.set_xlabel("map y (m), driving direction →")
    ax_off.set_ylabel("offset from lane centre (m)")
    ax_off.set_title("the path's offset from the lane centre (vertical scale magnified)")
    style.separate_coincident(ax_off)
    style.legend(ax_off)

    # -- the camera frame
    if cams:
        k = camera_frame_index(r0)
        assert k is not None
        ax_cam = fig.add_subplot(gs[1, 1])
        f = r0.frames[k]
        from trustnav.viz.annotate import label_rects

        recs, _, labels = _frame_records(f)
        shown = [r["bbox"] for r in recs] + [list(b) for b in label_rects(cams[k].shape, recs, labels)]
        ax_cam.imshow(np.ascontiguousarray(_crop_to_people(cams[k], shown)[..., ::-1]))
        ax_cam.set_axis_off()
        ax_cam.set_title(f"camera at t = {f.time:.0f} s: label = perception's track and trust\n(box colour: "
                         "trust), chip = pedestrian, skeleton = eye contact", fontsize=8)  # fmt: skip
    fig.suptitle(title or sc.title)
    return style.save(fig, path)


def _crop_window(shape: tuple[int, ...], boxes: Sequence[Any]) -> tuple[int, int, int, int]:
    """(x0, y0, width, height) px of the part of a frame of ``shape`` round ``boxes`` ([x1, y1, x2,
    y2] px: the people and their labels, every one whole inside), at the frame's aspect ratio and
    at least 45 % of its width, so that the labels stay readable when the frame is drawn small."""
    h, w = shape[:2]
    if not boxes:
        return 0, 0, w, h
    b = np.array([np.asarray(x, dtype=float)[:4] for x in boxes])
    pad = 0.02 * w  # a margin round the people and their labels
    x1, y1, x2, y2 = b[:, 0].min() - pad, b[:, 1].min() - 0.05 * h, b[:, 2].max() + pad, b[:, 3].max() + 0.05 * h
    cw = min(float(w), max(0.45 * w, x2 - x1, (y2 - y1) * w / h))
    ch = cw * h / w
    cx = min(max((x1 + x2) / 2, cw / 2), w - cw / 2)
    cy = min(max((y1 + y2) / 2, ch / 2), h - ch / 2)
    u0, v0 = max(0, int(np.floor(cx - cw / 2))), max(0, int(np.floor(cy - ch / 2)))
    return u0, v0, min(w - u0, int(np.ceil(cw)) + 1), min(h - v0, int(np.ceil(ch)) + 1)


def _crop_to_people(img: NDArray[np.uint8], boxes: Sequence[Any]) -> NDArray[np.uint8]:
    """The part of a camera frame round its people and their labels (:func:`_crop_window`)."""
    u0, v0, cw, ch = _crop_window(img.shape, boxes)
    return img[v0 : v0 + ch, u0 : u0 + cw]


def _pedestrian_on_map(
    ax: Any, r: DriveResult, j: int, k: int, radius: float, others: Sequence[tuple[str, DriveResult]], run: str
) -> None:
    """Pedestrian j of run k: its path if it walks, a dot and R ring at its closest approach, and a
    label with its trust and minimum distance (and those of the comparison runs)."""
    from matplotlib.patches import Circle

    c = style.person_colour(j)
    if np.linalg.norm(r.pedestrians[-1, j] - r.pedestrians[0, j]) > 0.05:
        ax.plot(*_yx(r.pedestrians[:, j]), color=c, lw=1.5, zorder=2)
    i_min = int(np.argmin(r.distances[:, j]))
    q = r.pedestrians[i_min, j]
    ax.add_patch(Circle(_yx(q), radius, fill=False, ls="--", color=c, lw=1.4, zorder=4))
    ax.plot(*_yx(q), "o", color=c, ms=8, mec="k", zorder=6)
    lines = [f"{r.scenario.pedestrians[j].name}, {run}" if run else _name(r, j),
             f"final trust {float(r.trusts[-1, j]):.2f}, min d {r.distances[:, j].min():.2f} m"]  # fmt: skip
    for label, o in others:
        lines.append(f"{label}: min d {o.distances[:, j].min():.2f} m")
    right = k % 2 == 0
    x = q[1] - (radius + 0.8) if right else q[1] + (radius + 0.8)
    ax.text(x, q[0], "\n".join(lines), color=c, fontsize=8, ha="left" if right else "right", va="center", zorder=7,
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": c, "lw": 0.6, "alpha": 0.85})  # fmt: skip


@style.styled()
def plot_trust(result: DriveResult, path: str | Path) -> Path:
    """Trust of each pedestrian over time as the controller used it (from the first camera frame
    on), with a dot at every frame that observed (and so updated) the pedestrian and a tick at the
    top for every camera frame (Fig. `trust_scene1`)."""
    fig, ax = style.new_figure((6.4, 3.6))
    t = np.asarray(result.times)
    tr = trusts_in_force(result)
    for j in range(len(result.scenario.pedestrians)):
        c = style.person_colour(j)
        ax.step(t, tr[:, j], where="post", color=c, label=_name(result, j))
        ft, ftr = result.trust_series(j)
        ax.plot(ft, ftr, "o", color=c, ms=5)
    if result.frames:
        ft = [f.time for f in result.frames]
        ax.plot(ft, [1.0] * len(ft), "v", color="0.45", ms=5, transform=ax.get_xaxis_transform(), clip_on=False,
                label="camera frame (dot: pedestrian observed)")  # fmt: skip
    ax.set_xlim(0.0, max(float(t[-1]), 1e-3))
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("trust (0 to 1)")
    ax.set_title(f"{result.scenario.name}: trust from the camera ({result.sensing} sensing, "
                 f"{result.capture_rate:g} frame/s{_latency_note(result)})", pad=9)  # fmt: skip
    style.legend(ax, loc="upper right")
    return style.save(fig, path)


@style.styled()
def plot_distance(
    results: DriveResult | Sequence[DriveResult],
    path: str | Path,
    comparisons: Sequence[tuple[str, DriveResult]] = (),
) -> Path:
    """Ego-pedestrian distance over time with the margin R (Fig. `dist_carla2`): each pedestrian
    in its own colour, one line style per run (several results: Case II's two runs; comparisons:
    e.g. the equal-trust run, dashed)."""
    rs = _many(results)
    fig, ax = style.new_figure((6.4, 4.0))
    styles = ("-", "--", ":", "-.")
    runs = [(r, "" if len(rs) == 1 else f"{_variant(r)} run") for r in rs] + [(r, lab) for lab, r in comparisons]
    for k, (r, tag) in enumerate(runs):
        for j in range(len(r.scenario.pedestrians)):
            d = r.distances[:, j]
            who = f"{r.scenario.pedestrians[j].name}, {tag}" if k < len(rs) and tag else _name(r, j)
            who += f", {tag}" if k >= len(rs) else ""
            ax.plot(r.times, d, color=style.person_colour(j), ls=styles[k % len(styles)],
                    lw=1.8 if k == 0 else 1.4, label=f"{who}: min {d.min():.2f} m")  # fmt: skip
    radius = rs[0].scenario.control.safety_radius
    ax.axhline(radius, color=style.MARGIN_COLOUR, ls="--", lw=1.2, label=f"R = {radius:g} m")
    ax.set_ylim(0, min(15.0, max(r.distances.max() for r, _ in runs) + 1))
    ax.set_xlim(0.0, max(float(r.times[-1]) for r, _ in runs))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance to pedestrian (m)")
    ax.set_title(f"{rs[0].scenario.name}: distance to the pedestrians")
    style.separate_coincident(ax)
    # upper right, over the receding arms: lower left, the labels of several runs covered the closest approaches
    style.legend(ax, loc="upper right", fontsize=7)
    return style.save(fig, path)


#: line style and colour of the runs of a trust comparison, in order (trust-aware first)
_MODES = (("-", style.EGO_COLOUR), ("--", "#0057b8"), (":", "#b8005c"))


@style.styled()
def plot_trust_comparison(
    groups: Sequence[tuple[str, Sequence[tuple[str, DriveResult]]]], path: str | Path, title: str | None = None
) -> Path:
    """What trust buys, in one figure: per group (a scenario's variant: Case II's attentive and
    distracted walker; one group otherwise) a row of the paths on the map, to scale across the
    road, with each pedestrian and R around it at its closest approach in the trust-aware run, and
    the distance to each pedestrian over time, one line style per run (label, result): e.g.
    trust-aware, constant trust 0, constant trust 1."""
    from matplotlib.patches import Circle

    n = len(groups)
    fig, axes = style.new_figure((13.0, 3.4 * n + 0.4), nrows=n, ncols=2, squeeze=False,
                                 gridspec_kw={"width_ratios": (1.4, 1.0)})  # fmt: skip
    r0 = groups[0][1][0][1]
    sc = r0.scenario
    radius = sc.control.safety_radius
    for (gname, runs), (ax, ax_d) in zip(groups, axes, strict=True):
        first = runs[0][1]
        ax.set_facecolor(_SURROUND)
        ax.grid(False)
        road, walks, _ = first.road_polygons()
        ax.fill(*_yx(road), color=_ROAD, zorder=0)
        for w in walks:
            ax.fill(*_yx(w), color=_SIDEWALK, zorder=0)
        ax.plot(*_yx(np.array([sc.ego_start, sc.goal])), color="white", ls=(0, (6, 4)), lw=1.0, zorder=1,
                label="lane centre", path_effects=_outlined())  # fmt: skip
        for k, (label, r) in enumerate(runs):
            ls, colour = _MODES[k % len(_MODES)]
            ax.plot(*_yx(r.ego[:, :2]), ls=ls, color=colour, lw=2.0 if k == 0 else 1.6, zorder=3, label=label)
        for j, ped in enumerate(first.scenario.pedestrians):
            c = style.person_colour(j)
            if np.linalg.norm(first.pedestrians[-1, j] - first.pedestrians[0, j]) > 0.05:
                ax.plot(*_yx(first.pedestrians[:, j]), color=c, lw=1.3, zorder=2, label=f"{ped.name}'s walk")
            q = first.pedestrians[int(np.argmin(first.distances[:, j])), j]
            ax.add_patch(Circle(_yx(q), radius, fill=False, ls="--", color=c, lw=1.2, zorder=4))
            ax.plot(*_yx(q), "o", color=c, ms=7, mec="k", zorder=6,
                    label=style.person_label(ped.name, ped.attentive))  # fmt: skip
        ax.plot(*_yx(np.array(sc.goal)), marker="*", ms=12, color="gold", mec="k", zorder=5, ls="", label="goal")
        ys = np.concatenate([r.ego[:, 1] for _, r in runs])
        ax.set_xlim(max(ys.max(), sc.ego_start[1]) + 2, min(ys.min(), sc.goal[1]) - 2)
        xs = np.array([sc.ego_start[0], sc.goal[0], *[p.position[0] for p in sc.pedestrians]])
        ax.set_ylim(xs.min() - 5.0, xs.max() + 5.0)
        ax.set_xlabel("map y (m), driving direction →")
        ax.set_ylabel("map x (m), magnified")
        ax.set_title(f"{gname + ': ' if gname else ''}paths (across the road magnified; rings: R = {radius:g} m "
                     "at the trust-aware closest approach)", fontsize=9)  # fmt: skip
        style.separate_coincident(ax)
        style.legend(ax, loc="lower left", ncol=2, fontsize=7)
        for k, (label, r) in enumerate(runs):
            ls, _ = _MODES[k % len(_MODES)]
            for j in range(len(r.scenario.pedestrians)):
                d = r.distances[:, j]
                ax_d.plot(r.times, d, ls=ls, color=style.person_colour(j), lw=1.8 if k == 0 else 1.4,
                          label=f"{r.scenario.pedestrians[j].name}, {label}: min {d.min():.2f} m")  # fmt: skip
        ax_d.axhline(radius, color=style.MARGIN_COLOUR, ls="--", lw=1.1, label=f"R = {radius:g} m")
        top = max(float(r.distances.max()) for _, r in runs)
        ax_d.set_ylim(0.0, min(15.0, top + 1.0))
        ax_d.set_xlim(0.0, max(float(r.times[-1]) for _, r in runs))
        ax_d.set_xlabel("time (s)")
        ax_d.set_ylabel("distance to pedestrian (m)")
        ax_d.set_title(f"{gname + ': ' if gname else ''}distance to each pedestrian")
        style.separate_coincident(ax_d)
        ax_d.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=True, fontsize=6.5)
    fig.suptitle(title or f"{sc.title}: trust-aware vs trust-blind ({r0.sensing} sensing, seed {r0.seed})")
    return style.save(fig, path)


# ------------------------------------------------------------------ camera frames and animation


def _backdrop(result: DriveResult, frame: FrameReport) -> NDArray[np.uint8]:
    """RGB image of a frame: the rendered one, or (keypoint sensing) sky, ground and road edges."""
    import cv2

    if frame.image is not None:
        return frame.image
    cam = frame.camera
    assert cam is not None
    w, h = cam.spec.width, cam.spec.height
    img = np.empty((h, w, 3), dtype=np.uint8)
    uv, depth = cam.project(cam.position[None] + 1e4 * cam.forward[None])
    horizon = int(np.clip(uv[0, 1], 0, h)) if depth[0] > 0 else h // 2
    img[:horizon] = (200, 218, 236)
    img[horizon:] = (120, 120, 118)
    road = result.scenario.road
    a, b = np.asarray(road.start), np.asarray(road.end)
    t = (b - a) / np.linalg.norm(b - a)
    n = np.array([-t[1], t[0]])
    s = np.linspace(-100.0, np.linalg.norm(b - a) + 100.0, 400)
    for lat in (-road.width / 2, road.width / 2):
        pts = a + s[:, None] * t + lat * n
        uv, depth = cam.project(np.column_stack([pts, np.zeros(len(pts))]))
        ok = depth > 0.5
        if ok.sum() > 1:
            cv2.polylines(img, [np.round(uv[ok]).astype(np.int32)], False, (250, 250, 250), 3, cv2.LINE_AA)
    cv2.putText(img, "keypoint sensing (no rendering): projected joints", (20, h - 24), cv2.FONT_HERSHEY_SIMPLEX,
                0.8, (255, 255, 255), 2, cv2.LINE_AA)  # fmt: skip
    return img


def _frame_records(f: FrameReport) -> tuple[list[dict], list[NDArray[np.float64]], list[str]]:
    """A frame's people as :func:`trustnav.viz.annotate.annotate` takes them: labelled with what
    perception made of them (its track, ``track k``, and the track's trust), the chip in the colour of
    the pedestrian each is (the colour that links it to the other figures)."""
    recs, kps, labels = [], [], []
    for s in f.sensed:
        j = s.index  # the world pedestrian it is (None: a detection of nobody)
        trust = getattr(s, "trust", None)  # the trust of the track it joined, where known
        if trust is None and j is not None:
            trust = f.views[j].trust
        rec = {"bbox": [float(x) for x in s.person.bbox], "trust": float(trust or 0.0),
               "eye_contact": s.eye_contact, "track_id": s.track_id, "name": f"track {s.track_id}"}  # fmt: skip
        if j is not None:
            rec["colour"] = style.person_bgr(j)
        recs.append(rec)
        kps.append(s.person.keypoints)
        labels.append(s.phone_label)
    return recs, kps, labels


def annotated_frames(result: DriveResult) -> list[NDArray[np.uint8]]:
    """Each captured frame annotated with trustnav.viz.annotate (BGR): box coloured by trust with
    perception's 'track k trust phone' and a chip in the pedestrian's colour, skeleton coloured by
    eye contact; plus the time."""
    import cv2

    from trustnav.viz.annotate import annotate

    out = []
    for f in result.frames:
        img = annotate(_backdrop(result, f), *_frame_records(f))
        text = f"frame {f.index}  t = {f.time:.1f} s  detected {f.detections}/{f.ground_truth}"
        cv2.putText(img, text, (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(img, text, (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2, cv2.LINE_AA)
        out.append(img)
    return out


def latest_annotated_frame(result: DriveResult) -> NDArray[np.uint8] | None:
    """The latest captured frame, annotated, as RGB (``DriveEnv(render_fn=...)``); None before the first."""
    import cv2

    if not result.frames:
        return None
    last = _LastFrame(result)
    return cv2.cvtColor(annotated_frames(last)[0], cv2.COLOR_BGR2RGB)


class _LastFrame:
    """A result seen through its last frame only."""

    def __init__(self, result: DriveResult) -> None:
        self._r = result
        self.frames = result.frames[-1:]

    def __getattr__(self, name: str) -> Any:
        return getattr(self._r, name)


def write_animation(
    result: DriveResult, path: str | Path, frames: Sequence[NDArray[np.uint8]] | None = None, fps: float = 20.0
) -> Path:
    """MP4 (OpenCV 'mp4v') of the top view, one video frame per control step, with the latest
    annotated camera frame as picture-in-picture; a GIF (Pillow) where no MP4 encoder exists.
    Returns the path written."""
    import cv2

    frames = annotated_frames(result) if frames is None else list(frames)
    size = (1280, 400)
    cam_w, cam_h = 640, 360
    canvas = (size[0], size[1] + cam_h)
    idx_of_frame = np.searchsorted(result.times, [f.known_at for f in result.frames], side="left")
    sc = result.scenario
    trusts = trusts_in_force(result)
    images = []
    for i in range(len(result.times)):
        img = np.full((canvas[1], canvas[0], 3), 24, dtype=np.uint8)
        img[: size[1]] = result.top_view_image(i, size)
        shown = [k for k, fi in enumerate(idx_of_frame) if fi <= i]
        if shown and frames:
            cam = cv2.resize(frames[shown[-1]], (cam_w, cam_h), interpolation=cv2.INTER_AREA)
            img[size[1] :, :cam_w] = cam
        x0, y = cam_w + 24, size[1] + 40
        lines = [
            (f"{sc.title}", (255, 255, 255)),
            (
                f"{result.sensing} sensing, camera {result.capture_rate:g} frame/s{_latency_note(result)}, "
                f"control {sc.control.rate:g} Hz",
                None,
            ),
            ("left: latest camera frame (box colour = trust, chip = pedestrian,", None),
            ("      skeleton colour = eye contact, phone N/U/Y)", None),
            ("top: cyan = MPC plan, black = path; ring = R around each pedestrian", None),
            ("      in its colour, dot = its trust (green > 0.7, orange > 0.4, red)", None),
        ]
        for j in range(len(sc.pedestrians)):
            lines.append((f"{_name(result, j)}: trust {trusts[i, j]:.2f}, distance {result.distances[i, j]:.1f} m",
                          _light(style.person_colour(j))))  # fmt: skip
        for text, colour in lines:
            cv2.putText(img, text, (x0, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour or (200, 200, 200), 1, cv2.LINE_AA)
            y += 26
        images.append(img)
    size = canvas
    out = Path(path)
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    if writer.isOpened():
        for img in images:
            writer.write(img)
        writer.release()
        if out.exists() and out.stat().st_size > 0:
            return out
    from PIL import Image

    gif = out.with_suffix(".gif")
    pil = [Image.fromarray(cv2.cvtColor(im, cv2.COLOR_BGR2RGB)).resize((640, 380)) for im in images[::2]]
    pil[0].save(gif, save_all=True, append_images=pil[1:], duration=int(2000 / fps), loop=0)
    return gif


def _light(colour: str) -> tuple[int, int, int]:
    """A person's colour lightened for text on the video's dark panel (BGR)."""
    b, g, r = style.hex_bgr(colour)
    return tuple(int(v + (255 - v) * 0.35) for v in (b, g, r))  # type: ignore[return-value]


def write_drive_outputs(
    result: DriveResult,
    out: str | Path,
    video: bool = True,
    comparisons: Sequence[tuple[str, DriveResult]] = (),
    offset_only: Sequence[tuple[str, DriveResult]] = (),
) -> dict[str, Path]:
    """Write a drive's figures, annotated frames and animation into ``out``; returns their paths
    (metrics.json is the caller's). ``comparisons``: (label, result) runs of the same scenario
    drawn beside it in the top view and the distance plot (e.g. the equal-trust run);
    ``offset_only``: runs drawn in the top view's offset panel only (:func:`plot_top_view`)."""
    import cv2

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    frames = annotated_frames(result)
    paths = {
        "top_view": plot_top_view(
            result, out / "top_view.png", comparisons=comparisons, camera_frames=frames, offset_only=offset_only
        ),
        "trust": plot_trust(result, out / "trust.png"),
        "distance": plot_distance(result, out / "distance.png", comparisons=comparisons),
    }
    fdir = out / "frames"
    fdir.mkdir(exist_ok=True)
    for old in fdir.glob("frame_*.png"):
        old.unlink()
    for f, img in zip(result.frames, frames, strict=True):
        cv2.imwrite(str(fdir / f"frame_{f.index:03d}.png"), img)
    paths["frames"] = fdir
    if video:
        paths["video"] = write_animation(result, out / "drive.mp4", frames, fps=result.scenario.control.rate)
    return paths


def write_variant_outputs(
    runs: Sequence[tuple[str, DriveResult]], out: str | Path, video: bool = True, title: str = ""
) -> list[tuple[str, dict[str, Any], Path]]:
    """Write a drive's outputs: per run (tag, result) its figures, frames, animation and
    metrics.json (several runs: each in ``out/<tag>/``, and the runs compared in ``out``'s top view,
    distance plot and metrics.json; ``title``: the top view's). Returns (tag, metrics, folder) per
    run (an empty tag: the scenario's name)."""
    out = Path(out)
    done = []
    for tag, result in runs:
        where = out / tag if len(runs) > 1 else out
        metrics = result.metrics()
        where.mkdir(parents=True, exist_ok=True)
        write_drive_outputs(result, where, video=video)
        (where / "metrics.json").write_text(json.dumps(metrics, indent=2))
        done.append((tag or result.scenario.name, metrics, where))
    if len(runs) > 1:
        results = [r for _, r in runs]
        plot_distance(results, out / "distance.png")
        plot_top_view(results, out / "top_view.png", title=title)
        (out / "metrics.json").write_text(json.dumps({tag: m for tag, m, _ in done}, indent=2))
    return done


def write_comparison_outputs(comp: Any, rows: Sequence[dict[str, Any]], out: str | Path, state: str) -> None:
    """Write a trust comparison (``comp``: a :class:`trustnav.sim.driving.compare.TrustComparison`,
    ``rows``: its ``comparison_rows``; ``state``: where the controller's pedestrians came from) into
    ``out``: compare.png (:func:`plot_trust_comparison`), metrics.json and table.csv (a row per run
    and pedestrian)."""
    import csv

    out = Path(out)
    plot_trust_comparison([(v, [(r.mode, r.result) for r in runs]) for v, runs in comp.by_variant()],
                          out / "compare.png")  # fmt: skip
    metrics = {"scenario": comp.scenario.name, "sensing": comp.sensing, "seed": comp.seed, "state": state,
               "table": list(rows), "runs": [dict(variant=r.variant, mode=r.mode, **r.result.metrics())
                                             for r in comp.runs]}  # fmt: skip
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    with open(out / "table.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["variant", "mode", "trust_given", "gamma", "pedestrian", "attentive", "min_distance",
                    "final_trust", "time_to_goal", "max_lateral_offset", "margin_violations"])  # fmt: skip
        for r in rows:
            for p in r["pedestrians"]:
                w.writerow([r["variant"], r["mode"], r["trust_given"], r["gamma"], p["name"], p["attentive"],
                            p["min_distance"], p["final_trust"], r["time_to_goal"], r["max_lateral_offset"],
                            r["margin_violations"]])  # fmt: skip


def write_demo_outputs(demo: Any, out: str | Path, video: bool = True) -> dict[str, Path]:
    """Write the demo's outputs once (``demo``: a :class:`trustnav.sim.driving.demo.DemoRuns`): the
    trust-aware drive's figures, frames and animation with the equal-trust run drawn beside it in
    the top view and the distance plot, keypoint sensing in the offset panel, and metrics.json."""
    equal = f"equal trust {demo.runs()['equal_trust']['trust_given_to_controller']:g}"
    paths = write_drive_outputs(demo.trust_aware, out, video=video, comparisons=[(equal, demo.equal_trust)],
                                offset_only=[("trust-aware, keypoint sensing", demo.keypoints)])  # fmt: skip
    paths["metrics"] = Path(out) / "metrics.json"
    paths["metrics"].write_text(json.dumps(demo.metrics(), indent=2))
    return paths


def _latency_note(result: Any) -> str:
    """The title's note for a drive whose frames reached the estimates late (else empty): its
    ``sensing.perception_latency``."""
    sensing = getattr(getattr(result, "scenario", None), "sensing", None)
    latency = float(getattr(sensing, "perception_latency", 0.0) or 0.0)
    return f", perception latency {latency:g} s" if latency > 0 else ""
