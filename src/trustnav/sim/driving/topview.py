"""The driving world seen from above, drawn with OpenCV: one frame of a drive's top view.

Used by the Gymnasium environment's ``render()`` and (through :meth:`DriveResult.top_view_image`)
by the animation of :mod:`trustnav.viz.drive_plots`; reads a result's arrays only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["road_polygons", "top_view_image", "trust_bgr"]

# trust colours (BGR), matching trustnav.viz: green > 0.7, orange > 0.4, red otherwise
_TRUST_BGR = ((0.7, (58, 158, 26)), (0.4, (0, 140, 240)), (-1.0, (32, 32, 214)))


def trust_bgr(trust: float) -> tuple[int, int, int]:
    """OpenCV colour of a trust value (green > 0.7, orange > 0.4, red otherwise)."""
    return next(c for lim, c in _TRUST_BGR if trust > lim)


def road_polygons(road: Any) -> tuple[NDArray, NDArray, NDArray]:
    """Road and sidewalk outlines (xy) of a :class:`~trustnav.sim.driving.world.RoadSpec` and its unit direction."""
    a, b = np.asarray(road.start), np.asarray(road.end)
    t = (b - a) / np.linalg.norm(b - a)
    n = np.array([-t[1], t[0]])
    hw, sw = road.width / 2, road.sidewalk_width

    def band(l0: float, l1: float) -> NDArray:
        return np.array([a + l0 * n, b + l0 * n, b + l1 * n, a + l1 * n])

    return band(-hw, hw), np.stack([band(hw, hw + sw), band(-hw - sw, -hw)]), t


def top_view_image(
    result: Any, i: int, size: tuple[int, int] = (1280, 400), trail: NDArray | None = None
) -> NDArray[np.uint8]:
    """The top view (BGR) at sample ``i`` of a drive result (duck-typed: ``scenario``, ``times``,
    ``ego``, ``pedestrians``, ``trusts``, ``plans``, ``distances``), drawn with OpenCV: road, goal,
    R circles coloured by trust, the path so far (``trail``, default the ego path), the plan."""
    import cv2

    trail = result.ego[:, :2] if trail is None else trail

    w, h = size
    sc = result.scenario
    ys = np.array([sc.ego_start[1], sc.goal[1]])
    y_hi, y_lo = ys.max() + 4, ys.min() - 4
    xc = float(np.mean([sc.ego_start[0], sc.goal[0]]))
    scale = w / (y_hi - y_lo)

    def px(p: NDArray) -> NDArray[np.int32]:
        p = np.asarray(p, dtype=float).reshape(-1, 2)
        u = (y_hi - p[:, 1]) * scale
        v = h * 0.5 - (p[:, 0] - xc) * scale
        return np.round(np.column_stack([u, v])).astype(np.int32)

    img = np.full((h, w, 3), (96, 140, 96), dtype=np.uint8)
    road, walks, _ = road_polygons(result.scenario.road)
    for wlk in walks:
        cv2.fillPoly(img, [px(wlk)], (210, 220, 228))
    cv2.fillPoly(img, [px(road)], (90, 90, 90))
    ref = px(np.array([sc.ego_start, sc.goal]))
    for k in range(0, 60, 2):
        a = ref[0] + (ref[1] - ref[0]) * k / 60
        b = ref[0] + (ref[1] - ref[0]) * (k + 1) / 60
        cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (230, 230, 230), 1, cv2.LINE_AA)
    cv2.drawMarker(img, tuple(int(v) for v in px(np.array(sc.goal))[0]), (0, 215, 255), cv2.MARKER_STAR, 22, 2)
    radius = sc.control.safety_radius
    for j, p in enumerate(sc.pedestrians):
        q = result.pedestrians[i, j]
        tr = float(result.trusts[i, j])
        c = trust_bgr(tr)
        centre = tuple(int(v) for v in px(q)[0])
        cv2.circle(img, centre, int(radius * scale), c, 2, cv2.LINE_AA)
        cv2.circle(img, centre, 6, c, -1, cv2.LINE_AA)
        label = f"{p.name} {tr:.2f}"
        cv2.putText(img, label, (centre[0] - 40, centre[1] + (int(radius * scale) + 18) * (1 if q[0] < xc else -1)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, c, 1, cv2.LINE_AA)  # fmt: skip
    if i > 0:
        cv2.polylines(img, [px(trail[: i + 1])], False, (40, 40, 240), 2, cv2.LINE_AA)
    if i < len(result.plans):
        cv2.polylines(img, [px(result.plans[i][:, :2])], False, (255, 255, 0), 2, cv2.LINE_AA)
    x, y, yaw, v = result.ego[i]
    c, s = math.cos(yaw), math.sin(yaw)
    body = np.array([[x + c * dx - s * dy, y + s * dx + c * dy] for dx, dy in
                     ((-2.3, -0.9), (2.3, -0.9), (2.3, 0.9), (-2.3, 0.9))])  # fmt: skip
    overlay = img.copy()
    cv2.fillPoly(overlay, [px(body)], (30, 30, 220))
    img = cv2.addWeighted(overlay, 0.55, img, 0.45, 0.0)
    cv2.circle(img, tuple(int(v) for v in px(np.array([x, y]))[0]), 4, (255, 255, 255), -1, cv2.LINE_AA)
    d = result.distances[i]
    text = f"t = {result.times[i]:4.1f} s   v = {v:4.1f} m/s   " + "  ".join(
        f"d({p.name}) = {d[j]:4.1f} m" for j, p in enumerate(sc.pedestrians)
    )
    cv2.putText(img, text, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return img
