"""Trust-aware caution: a speed bound from stopping distance, so the car can stop short of a
pedestrian who might step out before the camera would show it.

Trust in the paper sets how close the car may pass (gamma(trust), `weight`, in the rows of
`cbf_discrete`). It does not set how fast the car may approach someone who could step into its
path, and at the paper's camera (1 frame/s) a step-out is seen as motion only after about two
frames: too late at 8 m/s. This layer adds that: for each pedestrian ahead, the region they could
reach before the camera would show a step-out, growing as trust falls, and the largest speed at
which the car can still keep R from it, or stop short. It follows the longitudinal rule of
Responsibility-Sensitive Safety (Shalev-Shwartz et al. 2017, "On a formal model of safe and
scalable self-driving cars": a response time, then braking at a guaranteed deceleration) and
reachability-based planning (the other road user's reachable set over the time before they are
observed, e.g. Orzechowski et al. 2018 and Koschi and Althoff's SPOT; occlusion-aware planning
treats an unobserved step-out the same way).

For pedestrian j at ``s`` metres ahead along the car's heading and ``d`` metres beside its line,
with trust ``theta`` and radius ``r`` (R plus the estimate's uncertainty margin):

- **reach**: ``rho = walking_speed * ((1 - theta) ** trust_exponent * reaction + unseen)``, where
  ``reaction`` is the time before a step-out would show (camera period times the frames the
  tracker needs to see motion, plus the perception and control latencies) and ``unseen`` a time
  counted whatever the trust (what the camera's period hides of anyone: she may have started
  walking since the last frame; 0 by default);
- **conflict**: if ``d >= r + rho`` the car's line never comes within ``r`` of the region: no
  bound (a trusted pedestrian, or one far from the path). Else the line enters it
  ``g = sqrt((r + rho)^2 - d^2)`` before the pedestrian's abreast point;
- **bound**: the car, driving on for ``reaction`` and then braking at ``deceleration``, stops
  before that entry point: ``v reaction + v^2 / (2 deceleration) <= s - g``, so
  ``v <= b (sqrt(T^2 + 2 (s - g) / b) - T)`` with ``T = reaction``, ``b = deceleration``;
- **floor**: never below ``pass_speed`` (a car already beside someone who might step out keeps
  moving past at a careful speed rather than stopping beside them: once beside, stopping is no
  safer), nor applied to pedestrians abreast or behind the car's reference point (``s <= 0``).

The car's speed bound is the least over the pedestrians. The controller applies it twice
(:class:`~trustnav.control.MpcController`): as the cap of the reference speed its cost tracks,
and as a hard bound on the bicycle's speed rows ``v(k+1) <= cap`` (lowered by at most ``ease``
m/s^2 per step from the present speed, so a bound that appears below the speed brakes the car
smoothly; the model's widening to the reachable speeds keeps the QP feasible). It never touches
the CBF rows: the pedestrian's barrier, the road's and their relaxation are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from trustnav.control._validate import require_positive

__all__ = ["CautionConfig", "CautionDecision", "caution_bound", "reaction_time"]


def reaction_time(camera_rate: float, confirm_frames: float = 2.0, perception_latency: float = 0.0,
                  control_latency: float = 0.0, control_period: float = 0.0) -> float:  # fmt: skip
    """Time (s) before a step-out would reach the controller: ``confirm_frames`` camera periods
    (the tracker sees motion after about two frames), the perception latency, the command
    latency and one control period."""
    if not camera_rate > 0 or math.isinf(camera_rate):
        raise ValueError(f"camera_rate must be a positive finite number of frames/s, got {camera_rate!r}")
    return confirm_frames / camera_rate + perception_latency + control_latency + control_period


@dataclass(frozen=True)
class CautionConfig:
    """Options of the trust-aware caution (module docstring); times in s, speeds in m/s,
    decelerations in m/s^2.

    ``reaction`` (2.15 s: two frames at 1 frame/s, 0.1 s command latency, one 20 Hz step; the
    drive derives it from its camera, :func:`reaction_time`), ``walking_speed`` (1.4 m/s: a brisk
    step-out of an untrusted pedestrian), ``trust_exponent`` (2: the reach of trust 0.5 is a
    quarter of trust 0's), ``deceleration`` (4 m/s^2, below the vehicle's 6: the braking the bound
    counts on), ``pass_speed`` (4 m/s: the floor), ``ease`` (3 m/s^2: how fast a lower bound
    brings the speed rows down)."""

    reaction: float = 2.15
    walking_speed: float = 1.4
    trust_exponent: float = 2.0
    deceleration: float = 4.0
    pass_speed: float = 4.0
    ease: float = 3.0
    unseen: float = 0.0

    def __post_init__(self) -> None:
        names = ("reaction", "walking_speed", "trust_exponent", "deceleration", "pass_speed", "ease", "unseen")
        require_positive("caution", self, names, zero_ok=("reaction", "walking_speed", "pass_speed", "unseen"))


@dataclass(frozen=True)
class CautionDecision:
    """The step's speed bound (m/s), the pedestrian that sets it (index into the step's
    pedestrians), how far from that pedestrian the car's line must stay for no bound (``reach``:
    r + rho, m) and a note for the step's report."""

    speed: float
    pedestrian: int
    reach: float
    note: str


def caution_bound(
    config: CautionConfig,
    position: NDArray[np.float64],
    heading: NDArray[np.float64],
    pedestrians: NDArray[np.float64],
    trusts: NDArray[np.float64],
    radii: NDArray[np.float64],
) -> CautionDecision | None:
    """The speed bound of the pedestrians ahead, or None where none binds below ``inf``.

    position (2,) of the car's reference point, heading (2,) a unit vector along its path;
    pedestrians (N, 2), trusts (N,) in [0, 1], radii (N,) (R plus any uncertainty margin)."""
    n = len(pedestrians)
    if n == 0:
        return None
    if len(trusts) != n or len(radii) != n:
        raise ValueError(
            f"caution_bound: {n} pedestrians need {n} trusts and radii, got {len(trusts)} and {len(radii)}"
        )
    v, j, reach_j, s_j = _least_bound(
        float(position[0]), float(position[1]), float(heading[0]), float(heading[1]),
        np.ascontiguousarray(pedestrians, dtype=float), np.ascontiguousarray(trusts, dtype=float),
        np.ascontiguousarray(radii, dtype=float), *bound_constants(config),
    )  # fmt: skip
    if j < 0:
        return None
    return CautionDecision(v, j, reach_j, caution_note(v, float(trusts[j]), s_j))


def bound_constants(config: CautionConfig) -> tuple[float, float, float, float, float, float]:
    """What the compiled bound takes from ``config``: the reaction time, the deceleration, the
    reach of trust 0 in that time, the trust exponent, the reach of ``unseen`` and the floor (a
    controller gathers them once)."""
    c = config
    return (float(c.reaction), float(c.deceleration), float(c.walking_speed * c.reaction), float(c.trust_exponent),
            float(c.walking_speed * c.unseen), float(c.pass_speed))  # fmt: skip


def caution_note(speed: float, trust: float, ahead: float) -> str:
    """The step's report of a bound ``speed`` set by a pedestrian of ``trust`` ``ahead`` metres ahead."""
    return f"caution: speed bound {speed:.1f} m/s for a pedestrian (trust {trust:.2f}) {ahead:.1f} m ahead"


@njit(cache=True)
def _least_bound(px, py, hx, hy, peds, trusts, radii, t, b, reach_speed, exponent, unseen, floor):  # fmt: skip
    """:func:`caution_bound`'s arithmetic in one compiled pass (a step's few pedestrians: numpy's
    per-call cost, or the interpreter's, would dominate): the least bound over the pedestrians
    ahead and whose it is, (bound, index, r + rho, metres ahead); index -1 where none binds."""
    best_v, best_j, best_reach, best_s = math.inf, -1, 0.0, 0.0
    for j in range(peds.shape[0]):
        rx, ry = peds[j, 0] - px, peds[j, 1] - py
        s = rx * hx + ry * hy  # ahead along the path
        if s <= 0.0:
            continue
        d = abs(rx * hy - ry * hx)  # beside the path's line
        reach = radii[j] + reach_speed * (1.0 - min(max(trusts[j], 0.0), 1.0)) ** exponent + unseen
        if d >= reach:
            continue
        room = s - math.sqrt(reach * reach - d * d)
        v = max(b * (math.sqrt(t * t + 2.0 * max(room, 0.0) / b) - t), floor)
        if best_j < 0 or v < best_v:
            best_v, best_j, best_reach, best_s = v, j, reach, s
    return best_v, best_j, best_reach, best_s
