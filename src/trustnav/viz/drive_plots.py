"""Figures and animation of a trust-aware drive (the paper's Figs. `path_carla1`, `trust_scene1`,
`dist_carla2`, `trust_frames`): top view, trust over time, distance over time, annotated camera
frames and an MP4 of the top view with the latest camera frame as picture-in-picture.

Reads drive results (duck-typed: the fields and methods of
:class:`trustnav.sim.driving.episode.DriveResult`: ``scenario``, ``times``, ``ego``, ``pedestrians``,
``trusts``, ``frames``, ``distances``, ``trust_series``, ``road_polygons``, ``top_view_image``) and
imports nothing of trustnav but :mod:`trustnav.viz`; never drives a simulation. Figures are
``matplotlib.figure.Figure`` objects on an Agg canvas: no pyplot, no global backend change.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

DriveResult = Any  # trustnav.sim.driving.episode.DriveResult, read duck-typed
FrameReport = Any  # trustnav.sim.driving.sensing.FrameReport

__all__ = [
    "annotated_frames",
    "latest_annotated_frame",
    "plot_distance",
    "plot_top_view",
    "plot_trust",
    "trust_rgb",
    "write_animation",
    "write_drive_outputs",
]

# matplotlib colours for trust, matching trustnav.viz.annotate (green > 0.7, orange > 0.4, red)
_TRUST_COLOURS = ((0.7, "#1a9e3a"), (0.4, "#f08c00"), (-1.0, "#d62020"))
_PED_STYLES = ("#1f77b4", "#9467bd", "#8c564b", "#e377c2")


def trust_rgb(trust: float) -> str:
    """Matplotlib colour of a trust value (green > 0.7, orange > 0.4, red otherwise)."""
    return next(c for lim, c in _TRUST_COLOURS if trust > lim)


def _figure(figsize: tuple[float, float]) -> tuple[Any, Any]:
    """A Figure with one Axes on its own Agg canvas (no pyplot state, no backend switch)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _many(results: Any) -> list[Any]:
    """One result or a sequence of them, as a list."""
    return list(results) if isinstance(results, Sequence) else [results]


def _yx(p: NDArray) -> tuple[NDArray, NDArray]:
    """Plot coordinates: the road runs left to right (map y on the horizontal axis, reversed)."""
    p = np.asarray(p)
    return p[..., 1], p[..., 0]


def plot_top_view(results: DriveResult | Sequence[DriveResult], path: str | Path, title: str | None = None) -> Path:
    """Top view: road, reference line, ego path(s), pedestrians with their R circles coloured by
    final trust (several results: one path each, e.g. Case II attentive vs distracted)."""
    from matplotlib.patches import Circle

    rs = _many(results)
    r0 = rs[0]
    sc = r0.scenario
    fig, ax = _figure((10, 4.2))
    road, walks, _ = r0.road_polygons()
    ax.fill(*_yx(road), color="#c8c8c8", zorder=0)
    for w in walks:
        ax.fill(*_yx(w), color="#e9e4da", zorder=0)
    ref = np.array([sc.ego_start, sc.goal])
    ax.plot(*_yx(ref), "k--", lw=1, label="reference (lane)")
    ax.plot(*_yx(np.array(sc.goal)), marker="*", ms=14, color="gold", mec="k", zorder=5, label="goal")
    styles = ("-", "-.", ":")
    for k, r in enumerate(rs):
        tag = _variant(r) if len(rs) > 1 else "ego path"
        ax.plot(*_yx(r.ego[:, :2]), styles[k % 3], color="#222222" if k == 0 else "#0057b8", lw=2, label=tag)
        for j, p in enumerate(r.scenario.pedestrians):
            tr = float(r.trusts[-1, j])
            c = trust_rgb(tr)
            p0, p1 = r.pedestrians[0, j], r.pedestrians[-1, j]
            if np.linalg.norm(p1 - p0) > 0.05:
                ax.plot(*_yx(r.pedestrians[:, j]), color=c, lw=1.5)
            i_min = int(np.argmin(r.distances[:, j]))
            q = r.pedestrians[i_min, j]
            circ = Circle(_yx(q)[::1], sc.control.safety_radius, fill=False, ls="--", color=c, lw=1.3)
            ax.add_patch(circ)
            ax.plot(*_yx(q), "o", color=c, ms=8, mec="k", zorder=6)
            if k == 0 or len(rs) > 1:
                who = p.name if len(rs) == 1 else f"{p.name} ({_variant(r)})"
                label = f"{who}: trust {tr:.2f}, min d {r.distances[:, j].min():.2f} m"
                off = -3.9 if q[0] < np.mean([sc.ego_start[0], sc.goal[0]]) else 3.9
                off += 1.4 * k * np.sign(off)
                ax.annotate(label, _yx(q), xytext=(q[1], q[0] + off), fontsize=8, ha="center", va="center",
                            color=c, arrowprops={"arrowstyle": "-", "color": c, "lw": 0.6})  # fmt: skip
    ax.set_aspect("equal")
    ys = np.concatenate([r.ego[:, 1] for r in rs])
    ax.set_xlim(max(ys.max(), sc.ego_start[1]) + 3, min(ys.min(), sc.goal[1]) - 3)
    xs = np.array([sc.ego_start[0], sc.goal[0], *[p.position[0] for p in sc.pedestrians]])
    ax.set_ylim(xs.min() - 6.5, xs.max() + 6.5)
    ax.set_xlabel("map y (m)   (driving direction ->)")
    ax.set_ylabel("map x (m)")
    ax.set_title(
        title or f"{sc.title}  [{r0.sensing} sensing, circles R = {sc.control.safety_radius:g} m]", fontsize=10
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=8, ncol=5, frameon=False)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=130)
    return out


def _variant(r: DriveResult) -> str:
    att = {p.attentive for p in r.scenario.pedestrians}
    return "attentive" if att == {True} else ("distracted" if att == {False} else "mixed")


def plot_trust(result: DriveResult, path: str | Path) -> Path:
    """Trust of each pedestrian over time as the controller used it, with a marker at every frame
    that observed (and so updated) the pedestrian (Fig. `trust_scene1`)."""
    fig, ax = _figure((6.4, 3.6))
    for j, p in enumerate(result.scenario.pedestrians):
        c = _PED_STYLES[j % len(_PED_STYLES)]
        kind = "attentive" if p.attentive else "distracted"
        label = p.name if p.name == kind else f"{p.name} ({kind})"
        ax.step(result.times, result.trusts[:, j], where="post", color=c, lw=1.6, label=label)
        t, tr = result.trust_series(j)
        ax.plot(t, tr, "o", color=c, ms=5)
    for f in result.frames:
        ax.axvline(f.time, color="0.85", lw=0.6, zorder=0)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("time (s)   (grey lines: camera frames; dots: frames that observed the pedestrian)")
    ax.set_ylabel("aggregated trust")
    ax.set_title(f"{result.scenario.name}: trust from the camera ({result.sensing}, {result.capture_rate:g} frame/s)",
                 fontsize=10)  # fmt: skip
    return _finish(fig, ax, path)


def _finish(fig: Any, ax: Any, path: str | Path) -> Path:
    """Legend, grid and layout of a time plot; saved to ``path`` and closed."""
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=130)
    return out


def plot_distance(results: DriveResult | Sequence[DriveResult], path: str | Path) -> Path:
    """Ego-pedestrian distance over time with the margin R (Fig. `dist_carla2`)."""
    rs = _many(results)
    fig, ax = _figure((6.4, 3.6))
    for k, r in enumerate(rs):
        for j, p in enumerate(r.scenario.pedestrians):
            tag = p.name if len(rs) == 1 else f"{p.name} ({_variant(r)})"
            c = (
                _PED_STYLES[(j + k) % len(_PED_STYLES)]
                if len(rs) == 1
                else ("#1a9e3a" if _variant(r) == "attentive" else "#d62020")
            )
            d = r.distances[:, j]
            ax.plot(r.times, d, color=c, lw=1.6, label=f"{tag}: min {d.min():.2f} m")
    radius = rs[0].scenario.control.safety_radius
    ax.axhline(radius, color="r", ls="--", lw=1.2, label=f"R = {radius:g} m")
    ax.set_ylim(0, min(15.0, max(r.distances.max() for r in rs) + 1))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance to pedestrian (m)")
    ax.set_title(f"{rs[0].scenario.name}: distance to the pedestrians", fontsize=10)
    return _finish(fig, ax, path)


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


def annotated_frames(result: DriveResult) -> list[NDArray[np.uint8]]:
    """Each captured frame annotated with trustnav.viz.annotate (BGR): box coloured by trust with
    'track trust phone', skeleton coloured by eye contact; plus the time."""
    import cv2

    from trustnav.viz.annotate import annotate

    out = []
    for f in result.frames:
        recs, kps, labels = [], [], []
        for s in f.sensed:
            v = f.views[s.index]
            recs.append({"bbox": [float(x) for x in s.person.bbox], "trust": float(v.trust or 0.0),
                         "eye_contact": s.eye_contact, "track_id": s.track_id})  # fmt: skip
            kps.append(s.person.keypoints)
            labels.append(s.phone_label)
        img = annotate(_backdrop(result, f), recs, kps, labels)
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


def _bgr(hex_colour: str) -> tuple[int, int, int]:
    h = hex_colour.lstrip("#")
    r, g, b = (int(h[i : i + 2], 16) for i in (0, 2, 4))
    return (b, g, r)


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
    idx_of_frame = np.searchsorted(result.times, [f.time for f in result.frames], side="left")
    sc = result.scenario
    images = []
    for i in range(len(result.times)):
        img = np.zeros((canvas[1], canvas[0], 3), dtype=np.uint8)
        img[: size[1]] = result.top_view_image(i, size)
        shown = [k for k, fi in enumerate(idx_of_frame) if fi <= i]
        if shown and frames:
            cam = cv2.resize(frames[shown[-1]], (cam_w, cam_h), interpolation=cv2.INTER_AREA)
            img[size[1] :, :cam_w] = cam
        x0, y = cam_w + 24, size[1] + 40
        lines = [
            (f"{sc.title}", (255, 255, 255)),
            (f"{result.sensing} sensing, camera {result.capture_rate:g} frame/s, control {sc.control.rate:g} Hz", None),
            ("left: latest camera frame (box colour = trust, skeleton colour = eye contact, phone N/U/Y)", None),
            ("cyan: MPC plan; red: path; circles: R around each pedestrian", None),
        ]
        for j, p in enumerate(sc.pedestrians):
            tr = float(result.trusts[i, j])
            kind = "attentive" if p.attentive else "distracted"
            lines.append((f"{p.name} ({kind}): trust {tr:.2f}, distance {result.distances[i, j]:.1f} m",
                          _bgr(trust_rgb(tr))))  # fmt: skip
        for text, colour in lines:
            cv2.putText(img, text, (x0, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour or (200, 200, 200), 1, cv2.LINE_AA)
            y += 28
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
    pil = [Image.fromarray(cv2.cvtColor(im, cv2.COLOR_BGR2RGB)).resize((640, 280)) for im in images[::2]]
    pil[0].save(gif, save_all=True, append_images=pil[1:], duration=int(2000 / fps), loop=0)
    return gif


def write_drive_outputs(result: DriveResult, out: str | Path, video: bool = True) -> dict[str, Path]:
    """Write a drive's figures, annotated frames and animation into ``out``; returns their paths
    (metrics.json is the caller's)."""
    import cv2

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "top_view": plot_top_view(result, out / "top_view.png"),
        "trust": plot_trust(result, out / "trust.png"),
        "distance": plot_distance(result, out / "distance.png"),
    }
    frames = annotated_frames(result)
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
