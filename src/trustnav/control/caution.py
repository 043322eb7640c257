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

**Unseen pedestrians** (``occlusion``; the caller gives each pedestrian's state and covariance at
the last frame that observed her, and when: :func:`unseen_regions`). A tracker coasting a person
the camera no longer sees (below the image in front of the car, beside it) grows her covariance
by its walking model's random acceleration, so R plus her margin grows faster than she walks away
and the car waits, or is trapped, for as long as the track lives. Trust makes the same bet here
as above: over the ``tau`` s since she was last seen she keeps to her last estimated velocity
(its uncertainty propagated, no process noise) and may leave that path by at most
``rho = walking_speed * (1 - theta) ** trust_exponent * (tau + lead)``; the region used is that
one where its margin (the estimate's plus ``rho``) is below the tracker's, the tracker's
otherwise. A trusted crosser's region leaves the lane at her walking pace; an untrusted one's
grows at up to walking speed, as the tracker's or faster.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from trustnav.control._validate import require_positive
from trustnav.control.barrier import _margins4

__all__ = ["CautionConfig", "CautionDecision", "caution_bound", "reaction_time", "unseen_regions"]


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
    brings the speed rows down), ``occlusion`` (True: an unseen pedestrian's region from her last
    sighting, :func:`unseen_regions`; False: the tracker's alone)."""

    reaction: float = 2.15
    walking_speed: float = 1.4
    trust_exponent: float = 2.0
    deceleration: float = 4.0
    pass_speed: float = 4.0
    ease: float = 3.0
    unseen: float = 0.0
    occlusion: bool = True

    def __post_init__(self) -> None:
        names = ("reaction", "walking_speed", "trust_exponent", "deceleration", "pass_speed", "ease", "unseen")
        require_positive("caution", self, names, zero_ok=("reaction", "walking_speed", "pass_speed", "unseen"))
        if not isinstance(self.occlusion, bool):
            raise ValueError(f"caution occlusion must be true or false, got {self.occlusion!r}")


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


def unseen_regions(
    config: CautionConfig,
    tau: NDArray[np.float64],
    seen_states: NDArray[np.float64],
    seen_covariances: NDArray[np.float64],
    trusts: NDArray[np.float64],
    lead: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Each pedestrian's region on the bet that she keeps to her last seen velocity (module
    docstring, "Unseen pedestrians"): her state (N, 4) ``tau`` (N,) s after her last sighting
    (``seen_states`` (N, 4), ``seen_covariances`` (N, 4, 4) of (x, y, v_x, v_y) then), propagated
    at constant velocity without process noise, and the reach ``rho`` (N,) (m) she may have
    strayed from it by ``tau + lead`` s, given her trust (N,). Returns (states, covariances, rho)."""
    tau = np.ascontiguousarray(tau, dtype=float)
    x = np.ascontiguousarray(seen_states, dtype=float)
    p = np.ascontiguousarray(seen_covariances, dtype=float)
    states, cov, rho = np.empty(x.shape), np.empty(p.shape), np.empty(tau.shape)
    _unseen(tau, x, p, np.ascontiguousarray(trusts, dtype=float), float(lead), float(config.walking_speed),
            float(config.trust_exponent), states, cov, rho)  # fmt: skip
    return states, cov, rho


@njit(cache=True)
def _unseen(tau, x, p, trusts, lead, walking, exponent, states, cov, rho):
    """:func:`unseen_regions` in one compiled pass (a step has a few pedestrians)."""
    for j in range(x.shape[0]):
        t = max(tau[j], 0.0)
        for a in range(4):
            states[j, a] = x[j, a] + (t * x[j, a + 2] if a < 2 else 0.0)
        # F P F' with F = [[I, t I], [0, I]]
        for a in range(4):
            for b in range(4):
                v = p[j, a, b]
                if a < 2:
                    v += t * p[j, a + 2, b]
                if b < 2:
                    v += t * p[j, a, b + 2]
                if a < 2 and b < 2:
                    v += t * t * p[j, a + 2, b + 2]
                cov[j, a, b] = v
        theta = min(max(trusts[j], 0.0), 1.0)
        rho[j] = walking * (1.0 - theta) ** exponent * (t + lead)


@njit(cache=True)
def _unseen_step(consts, times, x, p, trusts, peds, vels, margins, cov, out_peds, out_vels, out_margins, out_cov):
    """The controller's step of :func:`unseen_regions`, ``consts`` = (ego x, ego y, now, lead,
    latency, walking_speed, trust_exponent, z): for each pedestrian last seen ``now - times[j]`` >
    0 s ago, the bet's place at ``now + latency`` (as the latency compensation puts her), velocity,
    covariance and margin (:func:`~trustnav.control.barrier.uncertainty_margins` over ``lead``
    plus ``rho``) replace ``peds``, ``vels``, ``cov`` and ``margins`` in their copies ``out_*``
    where that margin is below ``margins[j]``. Returns how many were replaced (-1: an input is
    not finite)."""
    n = x.shape[0]
    now, lead, latency, walking, exponent, z = consts[2], consts[3], consts[4], consts[5], consts[6], consts[7]
    tau = np.empty(n)
    for j in range(n):
        tau[j] = now - times[j]
        if not np.isfinite(tau[j]):
            return -1
        for a in range(4):
            if not np.isfinite(x[j, a]):
                return -1
            for b in range(4):
                if not np.isfinite(p[j, a, b]):
                    return -1
    states, covs, rho = np.empty((n, 4)), np.empty((n, 4, 4)), np.empty(n)
    _unseen(tau, x, p, trusts, lead, walking, exponent, states, covs, rho)
    pos = np.empty((n, 2))
    for j in range(n):
        pos[j, 0] = states[j, 0] + states[j, 2] * latency
        pos[j, 1] = states[j, 1] + states[j, 3] * latency
    m = np.empty(n)
    _margins4(consts[:2], pos, covs, lead, z, m)
    used = 0
    for j in range(n):
        bet = m[j] + rho[j]
        if tau[j] > 0.0 and bet < margins[j]:
            used += 1
            out_peds[j, 0], out_peds[j, 1] = pos[j, 0], pos[j, 1]
            out_vels[j, 0], out_vels[j, 1] = states[j, 2], states[j, 3]
            out_margins[j] = bet
            for a in range(4):
                for b in range(4):
                    out_cov[j, a, b] = covs[j, a, b]
        else:
            out_peds[j, 0], out_peds[j, 1] = peds[j, 0], peds[j, 1]
            out_vels[j, 0], out_vels[j, 1] = vels[j, 0], vels[j, 1]
            out_margins[j] = margins[j]
            for a in range(4):
                for b in range(4):
                    out_cov[j, a, b] = cov[j, a, b]
    return used


@njit(cache=True)
def _caution_step(k, px, py, now, hx, hy, times, x, p, trusts, peds, vels, margins, cov, out):
    """A bicycle controller's caution for the step in one compiled pass (a step's few pedestrians:
    one call instead of several, each of whose dispatch costs more than its arithmetic): the unseen
    bet of :func:`_unseen_step` (``k`` its constants; the car at (px, py) and the time ``now`` are
    written here); each pedestrian's radius, R (``k[8]``) plus her margin; and the least speed
    bound of :func:`_least_bound` along the unit heading (hx, hy) (``k[9:15]``:
    :func:`bound_constants`). ``out`` (22 N,) holds the step's positions (N, 2), velocities (N, 2),
    margins (N,), covariances (N, 4, 4) and radii (N,) in that order. Returns (pedestrians
    replaced, -1 where an input is not finite or of another shape; then :func:`_least_bound`'s
    bound, index, r + rho and metres ahead)."""
    n = peds.shape[0]
    if times.shape[0] != n or x.shape[0] != n or x.shape[1] != 4 or trusts.shape[0] != n or vels.shape[0] != n:
        return -1, math.inf, -1, 0.0, 0.0
    for q in (p, cov):
        if q.shape[0] != n or q.shape[1] != 4 or q.shape[2] != 4:
            return -1, math.inf, -1, 0.0, 0.0
    if margins.shape[0] != n or out.shape[0] != 22 * n:
        return -1, math.inf, -1, 0.0, 0.0
    out_peds, out_vels = out[: 2 * n].reshape((n, 2)), out[2 * n : 4 * n].reshape((n, 2))
    out_margins, out_cov, radii = out[4 * n : 5 * n], out[5 * n : 21 * n].reshape((n, 4, 4)), out[21 * n :]
    k[0], k[1], k[2] = px, py, now
    used = _unseen_step(k, times, x, p, trusts, peds, vels, margins, cov, out_peds, out_vels, out_margins, out_cov)
    if used < 0:
        return used, math.inf, -1, 0.0, 0.0
    for j in range(n):
        radii[j] = k[8] + out_margins[j]
    v, j, reach, s = _least_bound(px, py, hx, hy, out_peds, trusts, radii, k[9], k[10], k[11], k[12], k[13], k[14])
    return used, v, j, reach, s
