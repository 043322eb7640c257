"""Barrier `h_quad` and the trust-adaptive discrete CBF rows `cbf_imp` (plain numpy)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.trust.params import as_number

__all__ = ["TIMINGS", "Timing", "barrier", "cbf_rows", "continuous_time_radius", "predict_pedestrians"]

#: Where the pedestrian is taken in the h(k+1) term of `cbf_imp`:
#: "paper": at its predicted position x_p(t+k+1), as the paper writes `cbf_imp` (default);
#: "authors_code": at x_p(t+k) in both terms, as the authors' published code does.
Timing = Literal["paper", "authors_code"]
TIMINGS: tuple[str, ...] = ("paper", "authors_code")


def barrier(ego: ArrayLike, pedestrians: ArrayLike, radius: float) -> NDArray[np.float64]:
    """`h_quad`: phi = ||x_e - x_j||^2 - R^2, broadcast over leading axes."""
    d = np.asarray(ego, dtype=float)[..., None, :] - np.asarray(pedestrians, dtype=float)
    return np.einsum("...i,...i->...", d, d) - radius * radius


def continuous_time_radius(radius: float, max_relative_speed: float, dt: float) -> float:
    """Margin R' that keeps R between control steps: `cbf_discrete` holds h >= 0 at the steps
    only, and a chord of length c (the relative displacement in one step) whose ends are R' =
    sqrt(R^2 + c^2 / 4) from a pedestrian stays R away from it all along (relative motion linear
    within the step, as for the single integrator and constant-velocity pedestrians; the bicycle's
    arc is within its chord's sagitta of it). c = max_relative_speed * dt: the ego's largest speed
    plus the pedestrians'."""
    for name, value in (("radius", radius), ("max_relative_speed", max_relative_speed), ("dt", dt)):
        as_number(name, value)
    if not 0 < radius < np.inf or not 0 <= max_relative_speed < np.inf or not 0 < dt < np.inf:
        raise ValueError(
            f"need radius > 0, max_relative_speed >= 0 and dt > 0 (finite), got {radius!r}, "
            f"{max_relative_speed!r}, {dt!r}"
        )
    c = float(max_relative_speed) * float(dt)
    return float(np.sqrt(radius * radius + 0.25 * c * c))


def predict_pedestrians(pedestrians: ArrayLike, velocities: ArrayLike, steps: int, dt: float) -> NDArray[np.float64]:
    """Constant-velocity prediction `ped_predict`: positions (steps+1, N_p, 2)."""
    p = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
    v = np.asarray(velocities, dtype=float).reshape(-1, 2)
    k = np.arange(steps + 1, dtype=float)[:, None, None]
    return p[None] + k * dt * v[None]


def cbf_rows(
    ego_positions: ArrayLike,
    pedestrians: ArrayLike,
    velocities: ArrayLike,
    one_minus_gamma: ArrayLike,
    radius: float,
    dt: float,
    timing: Timing = "paper",
) -> NDArray[np.float64]:
    """Values of the N_h x N_p rows of `cbf_imp`, >= 0 when satisfied.

    row[k, j] = phi(x_e(k+1), x_j(k+1 or k)) - (1 - gamma_j) phi(x_e(k), x_j(k)).
    """
    pos = np.asarray(ego_positions, dtype=float)
    n = pos.shape[0] - 1
    q = predict_pedestrians(pedestrians, velocities, n, dt)
    q_next = q[1:] if timing == "paper" else q[:-1]
    h_now = np.einsum("kji,kji->kj", pos[:-1, None] - q[:-1], pos[:-1, None] - q[:-1]) - radius**2
    h_next = np.einsum("kji,kji->kj", pos[1:, None] - q_next, pos[1:, None] - q_next) - radius**2
    return h_next - np.asarray(one_minus_gamma, dtype=float)[None, :] * h_now
