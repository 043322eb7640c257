"""Issue 36: the drive's controller (bicycle, road edges, radii from covariances, latency) runs its
SQP iterations in the compiled loop, with the same result as the general path."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from trustnav.control import KinematicBicycle, LaneTrackingCost, MpcConfig, MpcController, SqpSolver
from trustnav.control.barrier import RoadEdgeBarrier, uncertainty_margins
from trustnav.control.reference import BoundedProportionalReference


def _drive_controller(compiled: bool) -> MpcController:
    cfg = MpcConfig(horizon=7, dt=0.1, safety_radius=2.5, latency=0.1, deterministic=True)
    cost = LaneTrackingCost(start=(0, 0), goal=(80, 0), reference=BoundedProportionalReference(0.5, 8.0))
    road = RoadEdgeBarrier((0, 0), (80, 0), 3.5, 3.5, margin=0.9, gamma=0.5, front=2.0)
    ctl = MpcController(KinematicBicycle(), cost, cfg, SqpSolver(), barriers=[road])
    if not compiled:
        ctl.solver._compiled_budget = lambda p, until: None  # the Python loop only
    return ctl


def test_compiled_road_loop_matches_the_general_path():
    """Both controllers see the same states (the compiled one's closed loop), with covariances and
    latency; their plans agree and no step of either ends at the iteration limit."""
    fast, slow = _drive_controller(compiled=True), _drive_controller(compiled=False)
    rng = np.random.default_rng(3)
    peds = np.array([[18.0, 2.4], [30.0, -2.6]])
    vels = np.array([[0.0, -0.3], [0.0, 0.2]])
    trusts = np.array([0.8, 0.2])
    x = np.array([0.0, 0.0, 0.0, 6.0])
    its = []
    for k in range(80):
        cov = np.zeros((2, 4, 4))
        for j in range(2):
            a = rng.normal(size=(4, 4)) * 0.05
            cov[j] = a @ a.T + np.diag([0.04, 0.04, 0.01, 0.01])
        a_sol = fast.step(x, peds, vels, trusts, time=0.1 * k, covariances=cov)
        b_sol = slow.step(x, peds, vels, trusts, time=0.1 * k, covariances=cov)
        assert a_sol.status is b_sol.status
        # the general loop sums in another order: the iterates may stop a few iterations apart
        np.testing.assert_allclose(a_sol.inputs, b_sol.inputs, atol=1e-5, rtol=0)  # 1.4e-6 seen
        its += [a_sol.iterations, b_sol.iterations]
        x = fast.model.step(x, a_sol.control, 0.1)
        peds = peds + 0.1 * vels
    assert max(its) < 50  # before issue 36 every other step of the last 30 ended at 50 iterations
    assert sum(its) > 2 * len(its)  # the road and the pedestrians bind


def test_compiled_road_rows_match_the_barrier_protocol():
    """The road's rows from the compiled kernel equal those of RoadEdgeBarrier.values through the
    protocol (values and Jacobians, at random plans and positions)."""
    ctl = _drive_controller(compiled=True)
    p = ctl.problem
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = np.array([rng.uniform(0, 40), rng.uniform(-2, 2), rng.uniform(-0.4, 0.4), rng.uniform(0, 8)])
        p.set_stage(x, rng.uniform(5, 40, (2, 2)), None, [0.5, 0.5])
        u = rng.uniform(p.ulo, p.uhi, (p.n_h, 2))
        p.build(u)
        g, jac = p._user_rows(p.xs, p.sens)
        rows = (np.arange(p.n_h)[:, None] * p.n_obs + p.n_p + np.arange(p.n_user)[None, :]).ravel()
        np.testing.assert_allclose(p.g[rows], g.ravel(), atol=1e-12)
        np.testing.assert_allclose(p.A[rows], jac.reshape(-1, p.n), atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 4), lead=st.floats(0.0, 2.0), on_top=st.booleans())
def test_compiled_margins_are_the_formula(seed, n, lead, on_top):
    """uncertainty_margins (compiled for (N, 4, 4) covariances) against its formula in numpy: z sqrt(n' S n)
    with S = P_pp + T (P_pv + P_vp) + T^2 P_vv, the largest eigenvalue at the ego's own position."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 4, 4))
    cov = a @ np.transpose(a, (0, 2, 1))
    ego, peds = rng.normal(size=2) * 5, rng.normal(size=(n, 2)) * 5
    if n and on_top:
        peds[0] = ego
    got = uncertainty_margins(ego, peds, cov, lead, 0.9)
    s = cov[:, :2, :2] + lead * (cov[:, :2, 2:] + cov[:, 2:, :2]) + lead * lead * cov[:, 2:, 2:]
    s = 0.5 * (s + np.transpose(s, (0, 2, 1)))
    d = ego[None] - peds
    dist = np.linalg.norm(d, axis=1)
    var = np.linalg.eigvalsh(s)[:, -1] if n else np.zeros(0)
    ok = dist > 1e-9
    u = d[ok] / dist[ok, None]
    var[ok] = np.einsum("ni,nij,nj->n", u, s[ok], u)
    np.testing.assert_allclose(got, NormalDist().inv_cdf(0.9) * np.sqrt(np.maximum(var, 0.0)), atol=1e-12, rtol=1e-12)
