"""The driving world seen from above, drawn with OpenCV: one frame of a drive's top view.

Used by the Gymnasium environment's ``render()`` and (through :meth:`DriveResult.top_view_image`)
by the animation of :mod:`trustnav.viz.drive_plots`; reads a result's arrays only.

The image is drawn in layers on one :class:`TopViewFrame` (the map -> pixel transform):
:func:`draw_background` (surroundings, sidewalks, road, lane centre, goal), :func:`draw_pedestrians`
(R ring and label in the pedestrian's own colour, a dot in its trust colour),
:func:`draw_estimates` (estimated positions with their 90 % ellipses, dashed, in the pedestrian's
colour; not drawn by :func:`top_view_image` unless it is given ``estimates``), :func:`draw_ego`
(path so far, MPC plan, car) and :func:`draw_caption`. A new layer is one more function called
from :func:`top_view_image`.

Colours are those of :mod:`trustnav.viz.style` (pedestrian j in ``PERSON_COLOURS[j]``, trust
green > 0.7, orange > 0.4, red otherwise). The simulation may not import ``trustnav.viz``
(docs/architecture.md), so the values are repeated here; ``tests/test_viz_style.py`` checks that
they are equal.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "PERSON_COLOURS",
    "TRUST_BANDS",
    "TopViewFrame",
    "draw_background",
    "draw_caption",
    "draw_ego",
    "draw_estimates",
    "draw_pedestrians",
    "ellipse_points",
    "person_bgr",
    "road_polygons",
    "top_view_image",
    "trust_bgr",
    "trusts_in_force",
]

# == trustnav.viz.style.PERSON_COLOURS / TRUST_BANDS (checked by tests/test_viz_style.py)
PERSON_COLOURS: tuple[str, ...] = ("#1f77b4", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22")
TRUST_BANDS: tuple[tuple[float, str], ...] = ((0.7, "#1a9e3a"), (0.4, "#f08c00"), (float("-inf"), "#d62020"))

# the map's colours (BGR), as the matplotlib top view of trustnav.viz.drive_plots
_SURROUND, _SIDEWALK, _ROAD, _LANE = (216, 233, 223), (218, 228, 233), (200, 200, 200), (255, 255, 255)
_PATH, _PLAN, _CAR, _GOAL = (34, 34, 34), (255, 255, 0), (70, 70, 70), (0, 200, 255)

Estimate = tuple[int, ArrayLike, ArrayLike]  # (pedestrian index, mean xy (2,), covariance (2, 2))


def _bgr(colour: str) -> tuple[int, int, int]:
    h = colour.lstrip("#")
    r, g, b = (int(h[i : i + 2], 16) for i in (0, 2, 4))
    return (b, g, r)


def trust_bgr(trust: float) -> tuple[int, int, int]:
    """OpenCV colour of a trust value (green > 0.7, orange > 0.4, red otherwise)."""
    return _bgr(next(c for lim, c in TRUST_BANDS if trust > lim))


def person_bgr(index: int) -> tuple[int, int, int]:
    """OpenCV colour of pedestrian ``index`` (scenario order), as in every figure."""
    return _bgr(PERSON_COLOURS[int(index) % len(PERSON_COLOURS)])


def road_polygons(road: Any) -> tuple[NDArray, NDArray, NDArray]:
    """Road and sidewalk outlines (xy) of a :class:`~trustnav.sim.driving.world.RoadSpec` and its unit direction."""
    a, b = np.asarray(road.start), np.asarray(road.end)
    t = (b - a) / np.linalg.norm(b - a)
    n = np.array([-t[1], t[0]])
    hw, sw = road.width / 2, road.sidewalk_width

    def band(l0: float, l1: float) -> NDArray:
        return np.array([a + l0 * n, b + l0 * n, b + l1 * n, a + l1 * n])

    return band(-hw, hw), np.stack([band(hw, hw + sw), band(-hw - sw, -hw)]), t


def trusts_in_force(result: Any) -> NDArray[np.float64]:
    """(T+1, N) the trusts the controller used from sample i on: a result records sample i before
    the frame captured at its time updates the trusts, so the trusts in force from t_i are those
    recorded at sample i + 1 (the last sample keeps its own). At t = 0 this is the trust of the
    first camera frame, the number its boxes show."""
    tr = np.asarray(result.trusts, dtype=float)
    return np.concatenate([tr[1:], tr[-1:]]) if len(tr) > 1 else tr.copy()


@dataclass(frozen=True)
class TopViewFrame:
    """Map (x, y) in metres -> image pixels: the road runs left to right (map y decreasing to the
    right), map x upward, ``scale`` pixels per metre, the lane centre ``xc`` at mid-height."""

    size: tuple[int, int]
    y_hi: float
    xc: float
    scale: float

    @classmethod
    def for_scenario(cls, scenario: Any, size: tuple[int, int] = (1280, 400)) -> TopViewFrame:
        ys = np.array([scenario.ego_start[1], scenario.goal[1]])
        y_hi, y_lo = ys.max() + 4, ys.min() - 4
        xc = float(np.mean([scenario.ego_start[0], scenario.goal[0]]))
        return cls((int(size[0]), int(size[1])), float(y_hi), xc, size[0] / float(y_hi - y_lo))

    def px(self, p: ArrayLike) -> NDArray[np.int32]:
        """(n, 2) pixel coordinates (u, v) of map points (n, 2) or one point (2,)."""
        p = np.asarray(p, dtype=float).reshape(-1, 2)
        u = (self.y_hi - p[:, 1]) * self.scale
        v = self.size[1] * 0.5 - (p[:, 0] - self.xc) * self.scale
        return np.round(np.column_stack([u, v])).astype(np.int32)

    def point(self, p: ArrayLike) -> tuple[int, int]:
        u, v = self.px(p)[0]
        return int(u), int(v)


def draw_background(img: NDArray[np.uint8], frame: TopViewFrame, scenario: Any) -> None:
    """Surroundings, sidewalks, road, dashed lane centre (start -> goal) and the goal star."""
    import cv2

    img[:] = _SURROUND
    road, walks, _ = road_polygons(scenario.road)
    for wlk in walks:
        cv2.fillPoly(img, [frame.px(wlk)], _SIDEWALK)
    cv2.fillPoly(img, [frame.px(road)], _ROAD)
    _dashed(img, frame.px(np.array([scenario.ego_start, scenario.goal])).astype(float), _LANE, 1, 30)
    cv2.drawMarker(img, frame.point(scenario.goal), _GOAL, cv2.MARKER_STAR, 22, 2)


def _dashed(img: NDArray[np.uint8], pts: NDArray, colour: tuple[int, int, int], thick: int, n: int = 0) -> None:
    """A dashed polyline through ``pts`` (pixels); ``n`` dashes per segment (0: every other segment)."""
    import cv2

    if n:
        a, b = pts[0], pts[-1]
        pts = np.array([a + (b - a) * k / (2 * n) for k in range(2 * n + 1)])
    for k in range(0, len(pts) - 1, 2):
        p, q = pts[k], pts[k + 1]
        cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), colour, thick, cv2.LINE_AA)


def _label(img: NDArray[np.uint8], text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """Text on a light backing so it reads on any background."""
    import cv2

    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    x, y = org
    x = min(max(x, 2), img.shape[1] - w - 4)
    y = min(max(y, h + 4), img.shape[0] - base - 2)
    cv2.rectangle(img, (x - 3, y - h - 3), (x + w + 3, y + base + 1), (250, 250, 250), -1)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)


def draw_pedestrians(img: NDArray[np.uint8], frame: TopViewFrame, result: Any, i: int, trusts: NDArray) -> None:
    """Each pedestrian at sample ``i``: R ring and label (name, trust in force, distance) in its own
    colour, a dot in its trust colour (the colour of its box in the camera frame)."""
    import cv2

    sc = result.scenario
    r_px = round(sc.control.safety_radius * frame.scale)
    for j, p in enumerate(sc.pedestrians):
        q = result.pedestrians[i, j]
        tr = float(trusts[j])
        c = person_bgr(j)
        centre = frame.point(q)
        cv2.circle(img, centre, r_px, c, 2, cv2.LINE_AA)
        cv2.circle(img, centre, 7, c, -1, cv2.LINE_AA)
        cv2.circle(img, centre, 5, trust_bgr(tr), -1, cv2.LINE_AA)
        text = f"{p.name}  trust {tr:.2f}  d {float(result.distances[i, j]):.1f} m"
        above = q[0] >= frame.xc
        _label(img, text, (centre[0] - 80, centre[1] + (-(r_px + 10) if above else r_px + 22)), c)


def ellipse_points(mean: ArrayLike, cov: ArrayLike, prob: float = 0.9, n: int = 72) -> NDArray[np.float64]:
    """(n, 2) points of the ellipse that holds ``prob`` of a 2-D Gaussian (``mean`` (2,),
    ``cov`` (2, 2) symmetric positive semi-definite): radius sqrt(chi2_2(prob)) = sqrt(-2 ln(1 - prob))
    standard deviations along each principal axis."""
    m = np.asarray(mean, dtype=float)
    c = np.asarray(cov, dtype=float)
    if m.shape != (2,) or not np.isfinite(m).all():
        raise ValueError(f"estimate mean must be 2 finite numbers (x, y), got {mean!r}")
    if c.shape != (2, 2) or not np.isfinite(c).all() or not np.allclose(c, c.T, atol=1e-9 * max(1.0, abs(c).max())):
        raise ValueError(f"estimate covariance must be a finite symmetric 2 x 2 matrix, got {cov!r}")
    if not 0.0 < prob < 1.0:
        raise ValueError(f"prob must lie in (0, 1), got {prob!r}")
    w, v = np.linalg.eigh(c)
    if w.min() < -1e-9 * max(1.0, w.max()):
        raise ValueError(f"estimate covariance must be positive semi-definite, eigenvalues {w.tolist()}")
    k = math.sqrt(-2.0 * math.log(1.0 - prob))
    a = np.linspace(0.0, 2.0 * math.pi, n)
    unit = np.stack([np.cos(a), np.sin(a)])
    return m + (v @ (np.sqrt(np.clip(w, 0.0, None))[:, None] * k * unit)).T


def draw_estimates(
    target: Any,
    estimates: Iterable[Estimate],
    frame: TopViewFrame | Callable[[NDArray], NDArray] | None = None,
    prob: float = 0.9,
) -> int:
    """Estimated pedestrian positions with their ``prob`` (90 %) ellipses, dashed, in each
    pedestrian's colour; ``estimates``: (pedestrian index, mean xy (2,), covariance (2, 2)) each.

    ``target`` is a BGR image (then ``frame`` is its :class:`TopViewFrame`) or a matplotlib Axes
    (then ``frame``, if given, maps map points (n, 2) to the axes' coordinates, e.g. ``lambda p:
    p[:, ::-1]`` for a top view with map y on the horizontal axis). Returns how many were drawn."""
    drawn = 0
    image = isinstance(target, np.ndarray)
    if image and not isinstance(frame, TopViewFrame):
        raise ValueError("draw_estimates on an image needs its TopViewFrame (frame=...)")
    for est in estimates:
        try:
            index, mean, cov = est
        except (TypeError, ValueError):
            raise ValueError(f"an estimate is (index, mean (2,), covariance (2, 2)), got {est!r}") from None
        ring = ellipse_points(mean, cov, prob)
        centre = np.asarray(mean, dtype=float)[None]
        if image:
            import cv2

            assert isinstance(frame, TopViewFrame)
            c = person_bgr(index)
            _dashed(target, frame.px(ring).astype(float), c, 2)
            cv2.drawMarker(target, frame.point(centre), c, cv2.MARKER_TILTED_CROSS, 10, 2, cv2.LINE_AA)
        else:
            to_axes = frame if callable(frame) else (lambda p: p)
            colour = PERSON_COLOURS[int(index) % len(PERSON_COLOURS)]
            xy, mu = to_axes(ring), to_axes(centre)
            target.plot(xy[:, 0], xy[:, 1], ls="--", lw=1.2, color=colour, zorder=6)
            target.plot(mu[:, 0], mu[:, 1], "x", ms=7, mew=1.6, color=colour, zorder=6)
        drawn += 1
    return drawn


def draw_ego(img: NDArray[np.uint8], frame: TopViewFrame, result: Any, i: int, trail: NDArray) -> NDArray[np.uint8]:
    """The path so far (``trail``), the MPC plan of step ``i`` and the car (4.6 m x 1.8 m, half
    transparent); returns the image (the car is blended into a new one)."""
    import cv2

    if i > 0:
        cv2.polylines(img, [frame.px(trail[: i + 1])], False, _PATH, 2, cv2.LINE_AA)
    if i < len(result.plans):
        plan = frame.px(result.plans[i][:, :2])
        cv2.polylines(img, [plan], False, (60, 60, 60), 4, cv2.LINE_AA)
        cv2.polylines(img, [plan], False, _PLAN, 2, cv2.LINE_AA)
    x, y, yaw, _v = result.ego[i]
    c, s = math.cos(yaw), math.sin(yaw)
    body = np.array([[x + c * dx - s * dy, y + s * dx + c * dy] for dx, dy in
                     ((-2.3, -0.9), (2.3, -0.9), (2.3, 0.9), (-2.3, 0.9))])  # fmt: skip
    overlay = img.copy()
    cv2.fillPoly(overlay, [frame.px(body)], _CAR)
    img = cv2.addWeighted(overlay, 0.6, img, 0.4, 0.0)
    cv2.circle(img, frame.point([x, y]), 4, (255, 255, 255), -1, cv2.LINE_AA)
    return img


def draw_caption(img: NDArray[np.uint8], result: Any, i: int) -> None:
    """Time, speed and the distance to each pedestrian, top left."""
    import cv2

    d = result.distances[i]
    text = f"t = {result.times[i]:4.1f} s   v = {result.ego[i, 3]:4.1f} m/s   " + "  ".join(
        f"d({p.name}) = {d[j]:4.1f} m" for j, p in enumerate(result.scenario.pedestrians)
    )
    cv2.putText(img, text, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (30, 30, 30), 1, cv2.LINE_AA)


def top_view_image(
    result: Any,
    i: int,
    size: tuple[int, int] = (1280, 400),
    trail: NDArray | None = None,
    estimates: Iterable[Estimate] | None = None,
) -> NDArray[np.uint8]:
    """The top view (BGR) at sample ``i`` of a drive result (duck-typed: ``scenario``, ``times``,
    ``ego``, ``pedestrians``, ``trusts``, ``plans``, ``distances``): road, goal, pedestrians with
    their R rings and the trusts in force at t_i (:func:`trusts_in_force`), ``estimates``
    (:func:`draw_estimates`) if given, the path so far (``trail``, default the ego path), the plan,
    the car and a caption."""
    w, h = size
    frame = TopViewFrame.for_scenario(result.scenario, size)
    img = np.empty((h, w, 3), dtype=np.uint8)
    draw_background(img, frame, result.scenario)
    draw_pedestrians(img, frame, result, i, trusts_in_force(result)[i])
    if estimates is not None:
        draw_estimates(img, estimates, frame)
    img = draw_ego(img, frame, result, i, result.ego[:, :2] if trail is None else trail)
    draw_caption(img, result, i)
    return img
