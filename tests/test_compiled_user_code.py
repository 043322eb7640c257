"""Issue 36: user dynamics at compiled speed (CompiledDynamics): the same model as its Python twin."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.control import DynamicsModel, MpcConfig, PositionTrackingCost
from trustnav.control.problem import MpcProblem

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "custom_dynamics.py"


def _example():
    spec = importlib.util.spec_from_file_location("custom_dynamics_example", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # (dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


EX = _example()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), dt=st.floats(0.01, 0.3))
def test_compiled_model_is_its_python_twin(seed, dt):
    rng = np.random.default_rng(seed)
    fast, slow = EX.Unicycle(), EX.PythonUnicycle()
    x = rng.normal(size=3)
    u = rng.uniform([0.0, -1.5], [2.0, 1.5], (6, 2))
    np.testing.assert_allclose(fast.step(x, u[0], dt), slow.step(x, u[0], dt), atol=1e-12)
    for got, want in zip(fast.jacobians(x, u[0], dt), slow.jacobians(x, u[0], dt), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)
    xs_f, s_f = fast.sensitivities(x, u, dt)
    xs_s, s_s = DynamicsModel.sensitivities(slow, x, u, dt)
    np.testing.assert_allclose(xs_f, xs_s, atol=1e-12)
    np.testing.assert_allclose(s_f, s_s, atol=1e-12)
    np.testing.assert_allclose(fast.rollout(x, u, dt), xs_s, atol=1e-12)


def test_compiled_position_tracking_cost_is_its_formula():
    """PositionTrackingCost's compiled Gauss-Newton model against the residuals' formula in numpy."""
    rng = np.random.default_rng(4)
    cost = PositionTrackingCost(goal=(3.0, 20.0), position_weight=1.3, input_weight=0.02, rate_weight=0.2)
    p = MpcProblem(EX.Unicycle(), cost, MpcConfig(horizon=6, dt=0.1, safety_radius=1.0))
    p.set_stage([0.5, -0.2, 1.0], np.zeros((0, 2)), None, [], u_prev=[0.3, -0.1])
    u = rng.uniform([0.0, -1.5], [2.0, 1.5], (6, 2))
    xs, sens = p.model.sensitivities(p.x0, u, 0.1)
    h, g = np.empty((12, 12)), np.empty(12)
    value = cost.evaluate(p.stage, xs, sens, u, p.u_prev, h, g)
    r, w = cost._residuals(p.stage, xs, u, p.u_prev)
    jac = np.zeros((r.size, 12))
    jac[:12] = sens[1:, :2].reshape(12, 12)
    jac[12:24] = np.eye(12)
    jac[24:] = np.eye(12) - np.eye(12, k=-2)
    np.testing.assert_allclose(value, np.sum(w * r * r), rtol=1e-12)
    np.testing.assert_allclose(g, 2 * (jac * w[:, None]).T @ r, atol=1e-10)
    np.testing.assert_allclose(h, 2 * jac.T @ (jac * w[:, None]) + 1e-9 * np.eye(12), atol=1e-10)


def test_example_drives_the_compiled_model_faster_to_the_same_result():
    out = EX.main(["--seconds", "6", "--compare"])
    assert out["python_max_difference_m"] < 1e-6
    assert out["speedup"] > 3.0  # 15x on the full run (2 cores, load ~9): the bar itself is the script's figure
