"""Barrier `h_quad` and the trust-adaptive discrete CBF rows `cbf_imp` (plain numpy)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["TIMINGS", "Timing", "barrier", "cbf_rows", "predict_pedestrians"]

#: Where the pedestrian is taken in the h(k+1) term of `cbf_imp`:
#: "paper": at its predicted position x_p(t+k+1), as the paper writes `cbf_imp` (default);
#: "authors_code": at x_p(t+k) in both terms, as the authors' published code does.
Timing = Literal["paper", "authors_code"]
TIMINGS: tuple[str, ...] = ("paper", "authors_code")


def barrier(ego: ArrayLike, pedestrians: ArrayLike, radius: float) -> NDArray[np.float64]:
    """`h_quad`: phi = ||x_e - x_j||^2 - R^2, broadcast over leading axes."""
    d = np.asarray(ego, dtype=float)[..., None, :] - np.asarray(pedestrians, dtype=float)
    return np.einsum("...i,...i->...", d, d) - radius * radius


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
