"""Parameters of the trust estimator and of the trust-adaptive gamma, with the paper's presets."""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

__all__ = [
    "MOVING_AVERAGE_TRUST",
    "PAPER_GAMMA_CARLA",
    "PAPER_GAMMA_NUMERICAL",
    "PAPER_TRUST",
    "SECONDS_TRUST",
    "TRUST_LAWS",
    "GammaParams",
    "TrustParams",
]


def as_number(name: str, value: object) -> float:
    """``value`` as a float if it is a real number (Python or numpy, not bool), else ValueError."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if math.isnan(v):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return v


def _check_range(name: str, value: object, lo: float, hi: float, *, lo_open: bool = False) -> float:
    v = as_number(name, value)
    ok = (v > lo if lo_open else v >= lo) and v <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ValueError(f"{name} must lie in {left}{lo}, {hi}], got {value!r}")
    return v


@dataclass(frozen=True)
class TrustParams:
    """Trust-estimator constants (Section II of the paper).

    rho: weights of the total score `lin_comb` for (smartphone, eye contact, pose fluctuation);
    nu1, nu01: `smato_score`; nu2, nu02: `eye_score`; nu3, nu03: `pose_score`;
    fluctuation_sensitivity: F in `pose_conf`; alpha, beta, beta0: `agg_trust`.

    ``time_constants`` chooses the law. None (default): the paper's, one step per observation,
    however far apart observations are (trust then grows with the number of frames, not with
    time). Four positive numbers (T_1, T_2, T_3, T_tau) in seconds: the rate-invariant law, in
    which each trait and the trust relax toward the value their current input asks for with that
    time constant over the time elapsed since the track's previous observation,

        x(t) = x* + (x(t_prev) - x*) exp(-(t - t_prev) / T_x),
        x* = 1 - C_sm (s_1), C_eye (s_2), C_fluc (s_3), S (tau),

    the exact solution of dx/dt = (x* - x) / T_x with the input held over the interval, so the
    value after t seconds of the same behaviour does not depend on the frame rate; pose
    fluctuation then compares poses ``fluctuation_interval`` seconds apart (:class:`PoseFluctuation`).
    The "(0)" formulas (nu01, nu02, nu03, beta0) start a track in both laws; nu1, nu2, nu3, alpha and
    beta are the per-frame law's only. A distracted person's trust tends to their low score, however
    long they are watched.
    """

    rho: tuple[float, float, float] = (0.4, 0.5, 0.1)
    nu1: float = 0.6
    nu01: float = 1.0
    nu2: float = 0.10
    nu02: float = 1.0
    nu3: float = 0.8
    nu03: float = 0.5
    fluctuation_sensitivity: float = 0.25
    alpha: float = 1.0
    beta: float = 0.08
    beta0: float = 0.55
    time_constants: tuple[float, float, float, float] | None = None
    fluctuation_interval: float = 1.0

    def __post_init__(self) -> None:
        if self.time_constants is not None:
            tc = self.time_constants
            if isinstance(tc, (str, bytes)) or not hasattr(tc, "__len__") or len(tc) != 4:
                raise ValueError(f"time_constants must be 4 seconds (T_1, T_2, T_3, T_tau) or None, got {tc!r}")
            vals = tuple(as_number(f"time_constants[{i}]", v) for i, v in enumerate(tc))
            if not all(0.0 < v < math.inf for v in vals):
                raise ValueError(f"time_constants must be positive finite seconds, got {tc!r}")
            object.__setattr__(self, "time_constants", vals)
        fi = as_number("fluctuation_interval", self.fluctuation_interval)
        if not 0.0 < fi < math.inf:
            raise ValueError(f"fluctuation_interval must be positive seconds, got {self.fluctuation_interval!r}")
        object.__setattr__(self, "fluctuation_interval", fi)
        if isinstance(self.rho, (str, bytes)) or not hasattr(self.rho, "__len__") or len(self.rho) != 3:
            raise ValueError(f"rho must have 3 weights (smartphone, eye contact, pose) summing to 1, got {self.rho!r}")
        rho = tuple(_check_range(f"rho[{i}]", r, 0.0, 1.0) for i, r in enumerate(self.rho))
        if abs(sum(rho) - 1.0) > 1e-9:
            raise ValueError(f"rho must sum to 1 (lin_comb), got sum {sum(rho):.6g} for {rho}")
        object.__setattr__(self, "rho", rho)
        # The paper states nu_i, nu_0i in (0, 1]; 0 is accepted for nu1, nu2, nu3 because the
        # paper's own "raw estimate" comparison sets the recursive constants to zero.
        for name in ("nu1", "nu2", "nu3", "alpha", "beta"):
            object.__setattr__(self, name, _check_range(name, getattr(self, name), 0.0, 1.0))
        for name in ("nu01", "nu02", "nu03", "beta0"):
            object.__setattr__(self, name, _check_range(name, getattr(self, name), 0.0, 1.0, lo_open=True))
        f = self.fluctuation_sensitivity
        if isinstance(f, bool) or not isinstance(f, Real) or not f > 0 or math.isinf(f):
            raise ValueError(f"fluctuation_sensitivity (F in pose_conf) must be a positive number, got {f!r}")
        object.__setattr__(self, "fluctuation_sensitivity", float(f))


@dataclass(frozen=True)
class GammaParams:
    """Trust-adaptive CBF rate `weight`: gamma_j = gamma_ini + delta * trust_j ** lambda.

    The conditions after `weight` (gamma_ini + delta <= 1, lambda >= 1) are enforced so that
    gamma stays in [0, 1] for every trust in [0, 1].
    """

    gamma_ini: float = 0.03
    delta: float = 0.08
    lam: float = 1.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "gamma_ini", _check_range("gamma_ini", self.gamma_ini, 0.0, 1.0, lo_open=True))
        object.__setattr__(self, "delta", _check_range("delta", self.delta, 0.0, 1.0, lo_open=True))
        if self.gamma_ini + self.delta > 1.0 + 1e-12:
            raise ValueError(
                f"gamma_ini + delta must be <= 1 (condition after `weight`), got "
                f"{self.gamma_ini} + {self.delta} = {self.gamma_ini + self.delta}"
            )
        lam = self.lam
        if isinstance(lam, bool) or not isinstance(lam, Real) or not lam >= 1.0 or math.isinf(lam):
            raise ValueError(f"lam (lambda in `weight`) must be a finite number >= 1, got {lam!r}")
        object.__setattr__(self, "lam", float(lam))


#: Section IV (CARLA) values: rho = 0.4/0.5/0.1, nu1 = 0.6, nu01 = 1, nu2 = 0.10, nu02 = 1,
#: nu3 = 0.8, nu03 = 0.5, F = 0.25, alpha = 1, beta = 0.08, beta0 = 0.55 (monotone trust).
PAPER_TRUST = TrustParams()
#: `agg_trust` as a moving average (alpha + beta = 1, beta0 = 1), as described after `agg_trust`.
MOVING_AVERAGE_TRUST = TrustParams(alpha=0.92, beta=0.08, beta0=1.0)
#: The rate-invariant law (see :class:`TrustParams`), the default of video input and the drive:
#: smartphone use and eye contact follow their cue with 2 s, pose fluctuation with 4 s and the
#: trust its score with 3 s time constants; the paper's weights and "(0)" formulas.
SECONDS_TRUST = TrustParams(time_constants=(2.0, 2.0, 4.0, 3.0))
#: the trust laws by name (`trustnav estimate --trust`)
TRUST_LAWS: dict[str, TrustParams] = {"seconds": SECONDS_TRUST, "paper": PAPER_TRUST,
                                      "moving-average": MOVING_AVERAGE_TRUST}  # fmt: skip
#: Section III numerical simulations: gamma_ini = 0.03, delta = 0.08, lambda = 1.5.
PAPER_GAMMA_NUMERICAL = GammaParams(gamma_ini=0.03, delta=0.08, lam=1.5)
#: Section IV CARLA simulations: gamma_ini = 0.08, delta = 0.55, lambda = 2.
PAPER_GAMMA_CARLA = GammaParams(gamma_ini=0.08, delta=0.55, lam=2.0)
