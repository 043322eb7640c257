"""Per-step time of the default SQP+DAQP controller vs CasADi (SQP + qpOASES, IPOPT) and two SLSQP baselines.

* **CasADi** (optional, ``pip install -e .[bench]``): the same problem written independently in
  CasADi from the paper's equations (:class:`CasadiMpc`), solved by ``sqpmethod`` with qpOASES and
  by IPOPT at every state the default controller's closed loop visits, warm-started at the same
  plan, timed interleaved with it (each call's wall time, Python call included); the largest
  input difference between the plans is reported (CasADi SQP and IPOPT run with tolerance
  1e-9; sqpmethod with ``convexify_strategy="eigen-clip"``). Without casadi these columns say "n/a";
* **compiled floor**: per step, the controller's SQP iterations times (one fused QP build + one
  DAQP update and solve) at the returned plan, measured warm right after the step; beside it the
  whole controller step in the same closed loop run alone (warm, as the floor), and its ratio to
  the floor;
* **SLSQP, authors' style** (:class:`AuthorsSlsqpSolver`): as the paper's code writes the MPC:
  one closure per pedestrian and horizon step, scipy's default ftol and maxiter, the previous
  solution as warm start (not shifted);
* **SLSQP, tuned** (:class:`SlsqpSolver`): one vectorised constraint function, ftol 1e-10,
  maxiter 500, the controller's shifted plan as warm start.

All run the same closed-loop episode (same start, same pedestrians, random placement with a
fixed seed, or the paper's Scenario II). The default runs the whole episode; the baselines run
their first steps (they are slow); the trajectory difference is measured over the steps both ran.
Prints a Markdown table and the speed-ups; ``--json FILE`` writes the rows.

    python benchmarks/bench_mpc.py --quick      # < 1 min
    python benchmarks/bench_mpc.py              # full grid
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time

import daqp
import numpy as np

from trustnav.control import (
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    MpcController,
    SingleIntegrator,
    SlsqpSolver,
    SolveStatus,
    SqpSolver,
    VelocityTrackingCost,
)
from trustnav.control.reference import BoundedProportionalReference
from trustnav.control.solvers import AuthorsSlsqpSolver
from trustnav.sim import load_scenario
from trustnav.trust import PAPER_GAMMA_CARLA

try:  # optional: the `bench` extra
    import casadi as ca
except ImportError:  # pragma: no cover - depends on the environment
    ca = None


def _setup(model_name: str, n_p: int, n_h: int, seed: int | str):
    rng = np.random.default_rng(seed if isinstance(seed, int) else 0)
    if model_name == "single_integrator":
        if seed == "paper-2":
            sc = load_scenario("paper-2")
            peds = np.array([p.position for p in sc.pedestrians])
            trusts = np.array([p.trust for p in sc.pedestrians])
            x0, cfg, cost = np.array(sc.ego_start), sc.config(n_h), sc.cost()
        else:
            x0 = np.array([20.0, 5.0])
            peds = np.empty((0, 2))
            while len(peds) < n_p:  # keep clear of start, goal and each other's margins
                # near the first part of the path, so that CBF rows bind from the first steps
                c = rng.uniform([10, 11], [30, 11 + 2 * n_p])
                if np.all(np.linalg.norm(peds - c, axis=1) > 3.5) and abs(c[0] - 20) > 3.5:
                    peds = np.vstack([peds, c])
            trusts = rng.uniform(0, 1, n_p)
            cfg = MpcConfig(horizon=n_h, dt=0.05, safety_radius=3.0)
            cost = VelocityTrackingCost(goal=(20, 45), reference=BoundedProportionalReference(1.5, 10.0))
        return SingleIntegrator(), x0, peds, trusts, cfg, cost
    # bicycle on a straight road (0,0) -> (100,0), pedestrians beside and on the lane
    x0 = np.array([0.0, 0.0, 0.0, 8.0])
    peds = np.column_stack([rng.uniform(6, 40, n_p), rng.choice([-1, 1], n_p) * rng.uniform(2.8, 8, n_p)])
    trusts = rng.uniform(0, 1, n_p)
    cfg = MpcConfig(horizon=n_h, dt=0.1, safety_radius=2.5, gamma=PAPER_GAMMA_CARLA)
    cost = LaneTrackingCost(start=(0, 0), goal=(100, 0), reference=BoundedProportionalReference(0.5, 8.0))
    return KinematicBicycle(), x0, peds, trusts, cfg, cost


# ---- CasADi: the same problems, written from the paper's equations (optional `bench` extra) ----


def _ref_velocities(pos, goal, gain, v_max, n_h, dt):
    """Bounded proportional reference u_bar(k) = Kp (goal - x_bar(k)), norm <= v_max, along its own rollout."""
    out, p = np.empty((n_h, 2)), np.array(pos, dtype=float)
    for k in range(n_h):
        v = gain * (np.asarray(goal, dtype=float) - p)
        nrm = float(np.hypot(*v))
        out[k] = v * (v_max / nrm) if nrm > v_max else v
        p = p + out[k] * dt
    return out


def _lane_reference(pos, start, goal, gain, v_max, n_h, dt):
    """Lane waypoints: the position projected onto start -> goal, marched at the bounded speed."""
    a, b = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    length = float(np.hypot(*(b - a)))
    t_hat = (b - a) / length
    s = float(np.clip((np.asarray(pos, dtype=float) - a) @ t_hat, 0.0, length))
    pts, speeds = np.empty((n_h + 1, 2)), np.empty(n_h + 1)
    for k in range(n_h + 1):
        speeds[k] = min(v_max, gain * (length - s))
        pts[k] = a + s * t_hat
        s = min(length, s + speeds[k] * dt)
    return pts, math.atan2(t_hat[1], t_hat[0]), speeds


@contextlib.contextmanager
def _stdout_silenced():
    """Silence fd 1 (qpOASES prints its licence banner from C++ when it first runs)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def _casadi_bicycle(ca, model, cost, x0, u, ref, n_h: int, dt: float):  # type: ignore[no-untyped-def]
    """The bicycle's predicted states (Euler substeps, as the model integrates) and its lane-tracking
    cost in CasADi, from ``ref`` = points (2 x (n_h + 1)), speeds (n_h + 1), lane yaw, u_prev (2)."""
    pts = ca.reshape(ref[: 2 * (n_h + 1)], 2, n_h + 1)
    vref = ref[2 * (n_h + 1) : 3 * (n_h + 1)]
    yaw_ref = ref[3 * (n_h + 1)]
    u_prev = ref[3 * (n_h + 1) + 1 :]
    n_sub = max(1, math.ceil(dt / model.integration_step - 1e-9)) if model.integration_step else 1
    h = dt / n_sub
    w = cost.weights
    xs, x, obj = [x0], x0, 0
    nrm = ca.vertcat(-ca.sin(yaw_ref), ca.cos(yaw_ref))
    for k in range(n_h):
        st, ac = u[2 * k], u[2 * k + 1]
        for _ in range(n_sub):
            x = ca.vertcat(x[0] + x[3] * ca.cos(x[2]) * h, x[1] + x[3] * ca.sin(x[2]) * h,
                           x[2] + x[3] * ca.tan(st) / model.wheelbase * h, x[3] + ac * h)  # fmt: skip
        xs.append(x)
        d_head = x[2] - yaw_ref
        prev = u_prev if k == 0 else u[2 * k - 2 : 2 * k]
        obj += (w.cte * ca.dot(nrm, x[:2] - pts[:, k + 1]) ** 2
                + w.heading * ca.atan2(ca.sin(d_head), ca.cos(d_head)) ** 2
                + w.speed * (x[3] - vref[k + 1]) ** 2 + w.steer * st**2 + w.accel * ac**2
                + w.steer_rate * (st - prev[0]) ** 2 + w.accel_rate * (ac - prev[1]) ** 2)  # fmt: skip
    return xs, obj


class CasadiMpc:
    """`proposed` in CasADi, single shooting in the inputs U, from the paper's equations: `h_quad`,
    `cbf_imp` with constant-velocity pedestrians (`ped_predict`), gamma_j by `weight`; the single
    integrator with ||u - u_bar||^2, or the Euler-sub-stepped kinematic bicycle with the Section IV
    lane-tracking cost and speed rows. Solved by ``sqpmethod`` + qpOASES and by IPOPT."""

    def __init__(self, model_name: str, model, cfg: MpcConfig, cost, n_p: int, sqp_options: dict | None = None) -> None:
        self.model_name, self.model, self.cfg, self.cost, self.n_p = model_name, model, cfg, cost, n_p
        n_h, dt = cfg.horizon, cfg.dt
        nx = 2 if model_name == "single_integrator" else 4
        u = ca.SX.sym("u", 2 * n_h)
        x0 = ca.SX.sym("x0", nx)
        peds = ca.SX.sym("peds", 2 * n_p)
        vels = ca.SX.sym("vels", 2 * n_p)
        decay = ca.SX.sym("decay", n_p)  # 1 - gamma_j
        if model_name == "single_integrator":
            ref = ca.SX.sym("ubar", 2 * n_h)
            params = [x0, peds, vels, decay, ref]
            xs = [x0]
            for k in range(n_h):
                xs.append(xs[-1] + dt * u[2 * k : 2 * k + 2])
            obj = ca.sumsqr(u - ref)
            extra_g = []
        else:
            ref = ca.SX.sym("ref", 3 * (n_h + 1) + 3)  # points, speeds, lane yaw, u_prev(2)
            params = [x0, peds, vels, decay, ref]
            xs, obj = _casadi_bicycle(ca, model, cost, x0, u, ref, n_h, dt)
            extra_g = [xs[k + 1][3] for k in range(n_h)]  # speed rows, widened to what v(0) can reach
            t = np.arange(1, n_h + 1) * dt
            lo_u, hi_u = model.input_bounds()
            self._speed = (lambda v0: (np.minimum(model.speed_min, v0 + t * hi_u[1]),
                                       np.maximum(model.speed_max, v0 + t * lo_u[1])))  # fmt: skip
        r2 = cfg.safety_radius**2
        cbf = []
        for k in range(n_h):  # `cbf_imp`: h(x(k+1), q(k+1)) - (1 - gamma_j) h(x(k), q(k)) >= 0
            for j in range(n_p):
                q_k = peds[2 * j : 2 * j + 2] + k * dt * vels[2 * j : 2 * j + 2]
                q_n = q_k + dt * vels[2 * j : 2 * j + 2]
                h_n = ca.sumsqr(xs[k + 1][:2] - q_n) - r2
                h_k = ca.sumsqr(xs[k][:2] - q_k) - r2
                cbf.append(h_n - decay[j] * h_k)
        g = ca.vertcat(*cbf, *extra_g)
        self.n_cbf, self.ng = len(cbf), g.shape[0]
        lo, hi = model.input_bounds()
        self.lbx, self.ubx = np.tile(lo, n_h), np.tile(hi, n_h)
        nlp = {"x": u, "p": ca.vertcat(*params), "f": obj, "g": g}
        quiet = {"print_time": False, "error_on_fail": False}
        self.sqp = ca.nlpsol("sqp", "sqpmethod", nlp, {
            **quiet, "qpsol": "qpoases", "print_header": False, "print_iteration": False, "print_status": False,
            "qpsol_options": {"printLevel": "none", "error_on_fail": False}, "max_iter": 50,
            "tol_pr": 1e-9, "tol_du": 1e-9, "convexify_strategy": "eigen-clip", **(sqp_options or {}),
        })  # fmt: skip
        self.ipopt = ca.nlpsol("ipopt", "ipopt", nlp, {
            **quiet, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-9, "ipopt.max_iter": 200,
        })  # fmt: skip

    def arguments(self, x, peds, vels, trusts, u_prev, u0) -> dict:
        """Solver arguments at ego state x (world coordinates), warm-started at plan u0."""
        cfg, n_h = self.cfg, self.cfg.horizon
        gm = cfg.gamma
        decay = 1.0 - (gm.gamma_ini + gm.delta * np.power(trusts, gm.lam))  # `weight`
        if self.model_name == "single_integrator":
            rf = self.cost.reference
            ref = _ref_velocities(x[:2], self.cost.goal, rf.gain, rf.v_max, n_h, cfg.dt).ravel()
            lbg, ubg = np.zeros(self.ng), np.full(self.ng, np.inf)
        else:
            rf = self.cost.reference
            pts, yaw, sp = _lane_reference(x[:2], self.cost.start, self.cost.goal, rf.gain, rf.v_max, n_h, cfg.dt)
            ref = np.concatenate([pts.ravel(), sp, [yaw], u_prev])  # points column by column in CasADi
            lo, hi = self._speed(float(x[3]))
            lbg = np.concatenate([np.zeros(self.n_cbf), lo])
            ubg = np.concatenate([np.full(self.n_cbf, np.inf), hi])
        p = np.concatenate([x, peds.ravel(), vels.ravel(), decay, ref])
        return {"x0": np.asarray(u0, dtype=float).ravel(), "p": p, "lbx": self.lbx, "ubx": self.ubx,
                "lbg": lbg, "ubg": ubg}  # fmt: skip

    def first_guess(self, x) -> np.ndarray:
        """The first plan without a previous one: the clipped reference (single integrator), or rest."""
        n_h = self.cfg.horizon
        if self.model_name != "single_integrator":
            return np.zeros((n_h, 2))
        rf = self.cost.reference
        ubar = _ref_velocities(x[:2], self.cost.goal, rf.gain, rf.v_max, n_h, self.cfg.dt)
        return np.clip(ubar, self.lbx[:2], self.ubx[:2])

    def solve(self, which: str, args: dict) -> tuple[np.ndarray, bool, float]:
        """(inputs (N_h, 2), success, wall seconds of the call)."""
        solver = self.sqp if which == "sqp" else self.ipopt
        t0 = time.perf_counter()
        out = solver(**args)
        dt = time.perf_counter() - t0
        stats = solver.stats()
        # a step below sqpmethod's min_step_size ends at a stationary point: converged, too
        ok = bool(stats["success"]) or stats["return_status"] == "Search_Direction_Becomes_Too_Small"
        return np.asarray(out["x"]).reshape(-1, 2), ok, dt


class CasadiDrive:
    """The drive's problem in CasADi, from the paper's equations as :class:`CasadiMpc`'s bicycle, with
    what the drive's controller adds: each pedestrian's own R^2 (R plus its uncertainty margin), the
    road's edges (`cbf_discrete` of :class:`~trustnav.control.barrier.RoadEdgeBarrier`'s functions:
    the position's offset from the road's line, and the car's front point ``front`` ahead along its
    heading), in the ego-centred frame of the controller's step (after its latency compensation).
    Solved by ``sqpmethod`` + qpOASES, as the other rows."""

    def __init__(self, model, cfg: MpcConfig, cost, road, n_p: int) -> None:
        n_h, dt = cfg.horizon, cfg.dt
        u = ca.SX.sym("u", 2 * n_h)
        x0 = ca.SX.sym("x0", 4)
        peds = ca.SX.sym("peds", 2 * n_p)
        vels = ca.SX.sym("vels", 2 * n_p)
        decay = ca.SX.sym("decay", n_p)
        r2 = ca.SX.sym("r2", n_p)
        ref = ca.SX.sym("ref", 3 * (n_h + 1) + 3)
        rd = ca.SX.sym("road", 8)  # start (ego-centred), normal, room left / right, front, 1 - gamma
        xs, obj = _casadi_bicycle(ca, model, cost, x0, u, ref, n_h, dt)

        def edges(s):  # the road's functions at state s
            d = ca.dot(s[:2] - rd[0:2], rd[2:4])
            out = [rd[4] - d, d + rd[5]]
            if road.front > 0:
                df = d + rd[6] * (ca.cos(s[2]) * rd[2] + ca.sin(s[2]) * rd[3])
                out += [rd[4] - df, df + rd[5]]
            return out

        rows = []
        for k in range(n_h):
            for j in range(n_p):
                q_k = peds[2 * j : 2 * j + 2] + k * dt * vels[2 * j : 2 * j + 2]
                q_n = q_k + dt * vels[2 * j : 2 * j + 2] if cfg.timing == "paper" else q_k
                rows.append(ca.sumsqr(xs[k + 1][:2] - q_n) - r2[j] - decay[j] * (ca.sumsqr(xs[k][:2] - q_k) - r2[j]))
            for e1, e0 in zip(edges(xs[k + 1]), edges(xs[k]), strict=True):
                rows.append(e1 - rd[7] * e0)
        speed = [xs[k + 1][3] for k in range(n_h)]
        self.n_obs = n_p + road.size()
        self.n_cbf = len(rows)
        self.decided = self.n_obs * model.decided_steps(dt)
        g = ca.vertcat(*rows, *speed)
        self.ng = g.shape[0]
        lo, hi = model.input_bounds()
        self.lbx, self.ubx = np.tile(lo, n_h), np.tile(hi, n_h)
        t = np.arange(1, n_h + 1) * dt
        self._speed = (lambda v0: (np.minimum(model.speed_min, v0 + t * hi[1]),
                                   np.maximum(model.speed_max, v0 + t * lo[1])))  # fmt: skip
        params = ca.vertcat(x0, peds, vels, decay, r2, ref, rd)
        self.sqp = ca.nlpsol("sqp", "sqpmethod", {"x": u, "p": params, "f": obj, "g": g}, {
            "print_time": False, "error_on_fail": False, "qpsol": "qpoases", "print_header": False,
            "print_iteration": False, "print_status": False, "max_iter": 50, "tol_pr": 1e-9, "tol_du": 1e-9,
            "convexify_strategy": "eigen-clip", "qpsol_options": {"printLevel": "none", "error_on_fail": False},
        })  # fmt: skip
        self.road = road

    def arguments(self, p, u0) -> dict:
        """Arguments for the problem the controller's last step solved (``p``: its MpcProblem)."""
        st, road = p.stage, self.road
        ref = np.concatenate([st.points.ravel(), st.speed, [st.yaw[0]], p.u_prev])
        rd = np.array([*(road.start - p.origin), *road.normal, *road.room, road.front, 1.0 - road.gamma])
        par = np.concatenate([p.x0, p.peds.ravel(), p.vels.ravel(), p.one_minus_gamma, p.r2, ref, rd])
        lo, hi = self._speed(float(p.x0[3]))
        lbg = np.concatenate([np.zeros(self.n_cbf), lo])
        lbg[: self.decided] = -np.inf  # rows the state decides (none with sub-steps)
        ubg = np.concatenate([np.full(self.n_cbf, np.inf), hi])
        return {"x0": np.asarray(u0, dtype=float).ravel(), "p": par, "lbx": self.lbx, "ubx": self.ubx,
                "lbg": lbg, "ubg": ubg}  # fmt: skip

    def solve(self, args: dict) -> tuple[np.ndarray, bool, float]:
        t0 = time.perf_counter()
        out = self.sqp(**args)
        dt = time.perf_counter() - t0
        stats = self.sqp.stats()
        ok = bool(stats["success"]) or stats["return_status"] == "Search_Direction_Becomes_Too_Small"
        return np.asarray(out["x"]).reshape(-1, 2), ok, dt


def _record_drive(seed: int):
    """The drive scenario (Case I) and the controller's inputs at every step of its keypoint drive."""
    from trustnav.sim.driving import load_drive_scenario, run_drive

    sc = load_drive_scenario("case-1")
    calls = []
    step = MpcController.step

    def recorded(self, *args, **kw):
        pos = tuple(np.array(a, dtype=float) if a is not None else None for a in args)
        named = tuple((k, None if v is None else np.array(v, dtype=float)) for k, v in sorted(kw.items()))
        calls.append(pos + named)
        return step(self, *args, **kw)

    MpcController.step = recorded
    try:
        run_drive(sc, "keypoints", seed=seed)
    finally:
        MpcController.step = step
    return sc, calls


def run_drive_case(seed: int = 0, casadi: bool = True) -> dict:
    """The `bicycle_drive` row: the controller ``trustnav drive case-1 --sensing keypoints`` uses
    (bicycle, road edges, radii from the tracks' covariances, latency compensation, yielding),
    replayed at every state of that drive (seed ``seed``), CasADi SQP solving the same problem
    (its road rows and radii included) from the controller's warm start right after it."""
    sc, calls = _record_drive(seed)
    model, cfg, cost = sc.vehicle.model(), sc.control.config(), sc.control.cost(sc.ego_start, sc.goal)
    barriers = sc.control.barriers(sc.road, sc.vehicle)

    def controller():
        return MpcController(model, cost, cfg, SqpSolver(), barriers=barriers)

    for args in calls[:3]:  # warm-up: numba, DAQP (a controller of its own)
        warm = controller()
        _replay(warm, args)
    ctl = controller()
    cas = {} if casadi and ca is not None else None
    rec = {k: [] for k in ("t", "it", "sqp", "d_sqp", "np")}
    fails, cas_fail, prev = 0, 0, None
    for args in calls:
        t0 = time.perf_counter()
        sol = _replay(ctl, args)
        rec["t"].append(time.perf_counter() - t0)
        rec["it"].append(sol.iterations)
        rec["np"].append(ctl.problem.n_p)
        fails += sol.fallback or sol.status is SolveStatus.FAILED
        if cas is not None:
            p = ctl.problem
            if p.n_p not in cas:
                with _stdout_silenced():
                    cas[p.n_p] = CasadiDrive(model, cfg, cost, barriers[0], p.n_p)
            u0 = np.clip(np.vstack([prev[1:], prev[-1:]]), p.ulo, p.uhi) if prev is not None else np.zeros((p.n_h, 2))
            u_c, ok, t_c = cas[p.n_p].solve(cas[p.n_p].arguments(p, u0))
            rec["sqp"].append(t_c)
            cas_fail += not ok
            if ok and sol.status is SolveStatus.OPTIMAL and not sol.fallback:
                rec["d_sqp"].append(float(np.max(np.abs(u_c - sol.inputs))))
        prev = sol.inputs
    its = np.array(rec["it"])
    row = {
        "model": "bicycle_drive", "case": f"case-1 keypoints seed {seed}", "n_p": int(max(rec["np"])),
        "n_h": cfg.horizon, "default_median_ms": _ms(rec["t"]), "default_p95_ms": _ms(rec["t"], 95),
        "default_max_ms": float(max(rec["t"]) * 1e3), "default_steps": len(calls),
        "iterations_median": float(np.median(its)), "iterations_p95": float(np.percentile(its, 95)),
        "iterations_max": int(its.max()), "at_iteration_limit_share": float(np.mean(its >= SqpSolver().max_iter)),
        "failures": int(fails), "load_1min": os.getloadavg()[0],
        "casadi_sqp_median_ms": _ms(rec["sqp"]) if cas is not None else None,
        "casadi_sqp_p95_ms": _ms(rec["sqp"], 95) if cas is not None else None,
        "casadi_sqp_failures": cas_fail if cas is not None else None,
        "casadi_sqp_max_input_diff": float(max(rec["d_sqp"])) if rec["d_sqp"] else None,
        "casadi_sqp_input_diff_p95": float(np.percentile(rec["d_sqp"], 95)) if rec["d_sqp"] else None,
    }  # fmt: skip
    return row


def drive_solve_times(seeds: int, casadi: bool) -> dict:
    """``trustnav drive case-1 --sensing keypoints`` for seeds 0..seeds-1: the controller's solve
    time per step (``MpcSolution.solve_time``, the whole step) pooled over the drives, beside the
    bicycle 10 x 7 row measured in the same run."""
    from trustnav.sim.driving import load_drive_scenario, run_drive

    sc = load_drive_scenario("case-1")
    times = np.concatenate([run_drive(sc, "keypoints", seed=s).solve_times for s in range(seeds)])
    row = run_case("bicycle", 10, 7, 1, 100, 0, casadi=casadi)
    out = {"drive_seeds": seeds, "drive_steps": int(times.size), "drive_median_ms": _ms(times),
           "drive_p95_ms": _ms(times, 95), "bench_median_ms": row["default_median_ms"],
           "bench_p95_ms": row["default_p95_ms"], "bench_alone_median_ms": row["alone_median_ms"],
           "bench_alone_p95_ms": row["alone_p95_ms"], "load_1min": os.getloadavg()[0]}  # fmt: skip
    out["median_ratio"] = out["drive_median_ms"] / out["bench_median_ms"]
    out["p95_ratio"] = out["drive_p95_ms"] / out["bench_p95_ms"]
    return out


def _replay(ctl: MpcController, args: tuple):
    pos = [a for a in args if not isinstance(a, tuple)]
    kw = dict(a for a in args if isinstance(a, tuple))
    if kw.get("time") is not None:
        kw["time"] = float(kw["time"])
    return ctl.step(*pos, **kw)


def _floor(ctl: MpcController, plan: np.ndarray, iterations: int, qp: dict) -> float:
    """Compiled floor of one step: ``iterations`` x (fused QP build + DAQP update + solve) at
    ``plan`` (best of 3), with a DAQP workspace of the benchmark's own."""
    p = ctl.problem
    best = math.inf
    for _ in range(3):
        p.flatten()  # the cost's Hessian (the exact-Hessian SQP's later QPs cost a little more)
        t0 = time.perf_counter()
        p.build(plan)
        model = qp.get("model")
        if model is None:
            model = daqp.Model()
            model.setup(p.H, p.f, p.A, p.bu, p.bl)
            model.settings = {"primal_tol": 1e-9}
            qp["model"] = model
        elif p.nonlinear:
            model.update(H=p.H, f=p.f, A=p.A, bupper=p.bu, blower=p.bl)
        else:
            model.update(f=p.f, A=p.A, bupper=p.bu, blower=p.bl)
        model.solve()
        best = min(best, time.perf_counter() - t0)
    return max(iterations, 1) * best


def _episode(model, x0, peds, trusts, cfg, cost, solver, steps):
    ctl = MpcController(model, cost, cfg, solver)
    vels = np.zeros_like(peds)
    x = x0.copy()
    path, times, failures, unconverged = [x], [], 0, 0
    for _ in range(steps):
        t0 = time.perf_counter()
        sol = ctl.step(x, peds, vels, trusts)
        times.append(time.perf_counter() - t0)
        failures += sol.fallback or sol.status is SolveStatus.FAILED
        unconverged += sol.status is SolveStatus.MAX_ITER
        x = model.step(x, sol.control, cfg.dt)
        path.append(x)
    return np.array(path), np.array(times), failures, unconverged


def _compared_episode(model, x0, peds, trusts, cfg, cost, steps, cas: CasadiMpc | None):
    """The default controller's closed loop; at every state it visits, CasADi's SQP and IPOPT solve
    the same problem from the same warm start (interleaved), and the compiled floor is measured."""
    ctl = MpcController(model, cost, cfg, SqpSolver())
    vels = np.zeros_like(peds)
    x, plan, u_prev = x0.copy(), None, np.zeros(model.nu)
    rec = {k: [] for k in ("t", "floor", "it", "sqp", "ipopt", "d_sqp", "d_ipopt")}
    path, failures, unconverged, cas_fail = [x], 0, 0, {"sqp": 0, "ipopt": 0}
    lo, hi = model.input_bounds()
    order_rng = np.random.default_rng(0)
    for _ in range(steps):
        # CasADi's warm start is the controller's: its shifted previous plan, or its first guess
        if plan is not None:
            u0 = np.clip(np.vstack([plan[1:], plan[-1:]]), lo, hi)
        elif cas is not None:
            u0 = cas.first_guess(x)
        # the three run in a shuffled order at every step (fixed seed): none always runs on caches
        # another has just filled; the floor is measured after the controller
        solved, args = {}, None if cas is None else cas.arguments(x, peds, vels, trusts, u_prev, u0)
        for who in order_rng.permutation(["default", "sqp", "ipopt"] if cas is not None else ["default"]):
            if who != "default":
                solved[str(who)] = cas.solve(str(who), args)
                continue
            t0 = time.perf_counter()
            sol = ctl.step(x, peds, vels, trusts)
            rec["t"].append(time.perf_counter() - t0)
        rec["it"].append(sol.iterations)
        rec["floor"].append(_floor(ctl, sol.inputs, sol.iterations, rec.setdefault("qp", {})))
        for which, (u_c, ok, t_c) in solved.items():
            rec[which].append(t_c)
            cas_fail[which] += not ok
            if ok and sol.status is SolveStatus.OPTIMAL:
                rec["d_" + which].append(float(np.max(np.abs(u_c - sol.inputs))))
        failures += sol.fallback or sol.status is SolveStatus.FAILED
        unconverged += sol.status is SolveStatus.MAX_ITER
        plan, u_prev = sol.inputs, sol.control
        x = model.step(x, sol.control, cfg.dt)
        path.append(x)
    return np.array(path), rec, failures, unconverged, cas_fail


def _ms(values, q: float | None = None) -> float:
    if not len(values):
        return math.nan
    return float((np.median(values) if q is None else np.percentile(values, q)) * 1e3)


def run_case(model_name, n_p, n_h, seed, steps, baseline_steps, per_row=False, casadi=True):
    model, x0, peds, trusts, cfg, cost = _setup(model_name, n_p, n_h, seed)
    # warm-up (numba compilation, DAQP allocation) outside the timed episode
    _episode(model, x0, peds, trusts, cfg, cost, SqpSolver(), 2)
    cas = None
    if casadi and ca is not None:
        with _stdout_silenced():  # built and run once outside the timed episode
            cas = CasadiMpc(model_name, model, cfg, cost, len(peds))
            for which in ("sqp", "ipopt"):
                cas.solve(which, cas.arguments(x0, peds, np.zeros_like(peds), trusts, np.zeros(2), cas.first_guess(x0)))
    p_def, rec, f_def, u_def, cas_fail = _compared_episode(model, x0, peds, trusts, cfg, cost, steps, cas)
    t_def = np.array(rec["t"])
    med_d = _ms(t_def)
    # the same closed loop run alone (warm caches, as the floor is measured): the step's own overhead
    _, t_alone, _, _ = _episode(model, x0, peds, trusts, cfg, cost, SqpSolver(), steps)
    row = {
        "model": model_name,
        "case": str(seed),
        "n_p": len(peds),
        "n_h": n_h,
        "default_median_ms": med_d,
        "default_p95_ms": _ms(t_def, 95),
        "default_max_ms": float(t_def.max() * 1e3),
        "floor_median_ms": _ms(rec["floor"]),
        "alone_median_ms": _ms(t_alone),
        "alone_p95_ms": _ms(t_alone, 95),
        "alone_over_floor": _ms(t_alone) / _ms(rec["floor"]),
        "iterations_median": float(np.median(rec["it"])),
        "iterations_p95": float(np.percentile(rec["it"], 95)),
        "iterations_max": int(np.max(rec["it"])),
        # steps that ended at the SQP's iteration limit (SqpSolver.max_iter), as a share of the steps
        "at_iteration_limit_share": float(np.mean(np.array(rec["it"]) >= SqpSolver().max_iter)),
        "load_1min": os.getloadavg()[0],
        "failures": int(f_def),
        "unconverged_checked_feasible": int(u_def),
        "default_steps": len(t_def),
        "casadi_version": None if cas is None else ca.__version__,
    }
    for which in ("sqp", "ipopt"):
        tag = "casadi_sqp" if which == "sqp" else "ipopt"
        row[f"{tag}_median_ms"] = _ms(rec[which]) if cas is not None else None
        row[f"{tag}_p95_ms"] = _ms(rec[which], 95) if cas is not None else None
        row[f"{tag}_failures"] = cas_fail[which] if cas is not None else None
        diffs = rec["d_" + which]
        row[f"{tag}_max_input_diff"] = float(max(diffs)) if diffs else None
    for tag, solver in (("authors", AuthorsSlsqpSolver()), ("tuned", SlsqpSolver(per_row=per_row))):
        if baseline_steps <= 0:
            continue
        p_b, t_b, f_b, _ = _episode(model, x0, peds, trusts, cfg, cost, solver, baseline_steps)
        k = min(len(p_def), len(p_b))
        med_b = float(np.median(t_b) * 1e3)
        row.update({
            f"{tag}_median_ms": med_b,
            f"{tag}_p95_ms": float(np.percentile(t_b, 95) * 1e3),
            f"{tag}_speedup": med_b / med_d,
            f"{tag}_max_trajectory_diff": float(np.max(np.abs(p_def[:k, :2] - p_b[:k, :2]))),
            f"{tag}_failures": int(f_b),
            f"{tag}_steps": len(t_b),
        })  # fmt: skip
    return row


def _fmt(v, spec: str = ".3f") -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="subset, few baseline steps (< 1 min)")
    ap.add_argument("--json", help="write the rows to this file")
    ap.add_argument("--steps", type=int, default=100, help="closed-loop steps of the default controller")
    ap.add_argument("--per-row-baseline", action="store_true",
                    help="tuned baseline with one closure per CBF row (slower)")  # fmt: skip
    ap.add_argument("--no-slsqp", action="store_true", help="skip the SLSQP baselines")
    ap.add_argument("--no-casadi", action="store_true", help="skip CasADi even when it is installed")
    ap.add_argument("--drive-seeds", type=int, default=0,
                    help="also: Case I keypoint drives of these many seeds against the bicycle 10 x 7 row")  # fmt: skip
    args = ap.parse_args()
    if args.quick:
        cases = [("single_integrator", 2, 7, "paper-2", 20), ("single_integrator", 2, 7, 1, 20),
                 ("single_integrator", 10, 20, 1, 3), ("bicycle", 10, 7, 1, 3),
                 ("bicycle_drive", 2, 7, 0, 0)]  # fmt: skip
    else:
        cases = [("single_integrator", 2, 7, "paper-2", 100), ("bicycle_drive", 2, 7, 0, 0)]
        for model in ("single_integrator", "bicycle"):
            for n_p in (2, 10, 50):
                for n_h in (7, 20):
                    big = n_p * n_h >= 200 or (model == "bicycle" and n_p * n_h >= 70)
                    cases.append((model, n_p, n_h, 1, 3 if big else (10 if n_p * n_h >= 70 else 40)))
    use_casadi = not args.no_casadi and ca is not None
    if not use_casadi:
        why = "--no-casadi given" if args.no_casadi else "casadi is not installed (pip install -e .[bench])"
        print(f"NOTE: CasADi columns skipped: {why}; they read n/a.\n")
    else:
        print(f"CasADi {ca.__version__}: sqpmethod + qpOASES and IPOPT on the same states, interleaved.\n")
    rows = []
    print("| model | case | N_p x N_h | default median / p95 / max (ms) | compiled floor median (ms) "
          "| default run alone median / p95 (ms), x floor | SQP its "
          "median / p95 / max, at limit | CasADi SQP median / p95 (ms) | IPOPT median / p95 (ms) "
          "| default / CasADi SQP: median, p95 | "
          "max input diff (SQP / IPOPT) | failures (default / CasADi SQP / IPOPT) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for model, n_p, n_h, seed, bsteps in cases:
        if model == "bicycle_drive":  # the drive's controller at the states of a Case I drive
            r = run_drive_case(int(seed), use_casadi)
            rows.append(r)
            sqp = r["casadi_sqp_median_ms"]
            ratio = (
                "n/a"
                if not sqp
                else f"{r['default_median_ms'] / sqp:.2f}, {r['default_p95_ms'] / r['casadi_sqp_p95_ms']:.2f}"
            )
            print(f"| {model} | {r['case']} | {r['n_p']} x {n_h} "
                  f"| {r['default_median_ms']:.3f} / {r['default_p95_ms']:.3f} / {r['default_max_ms']:.3f} | n/a | n/a "
                  f"| {r['iterations_median']:.0f} / {r['iterations_p95']:.0f} / {r['iterations_max']}, "
                  f"{100 * r['at_iteration_limit_share']:.1f} % | {_fmt(sqp)} / {_fmt(r['casadi_sqp_p95_ms'])} | n/a "
                  f"| {ratio} | {_fmt(r['casadi_sqp_max_input_diff'], '.1e')} / n/a "
                  f"| {r['failures']} / {_fmt(r['casadi_sqp_failures'], 'd')} / n/a |", flush=True)  # fmt: skip
            continue
        r = run_case(model, n_p, n_h, seed, args.steps, 0 if args.no_slsqp else bsteps, args.per_row_baseline,
                     use_casadi)  # fmt: skip
        rows.append(r)
        case = r["case"] if r["case"] == "paper-2" else f"seed {r['case']}"
        sqp, ipo = r["casadi_sqp_median_ms"], r["ipopt_median_ms"]
        ratio = "n/a"
        if sqp:
            ratio = f"{r['default_median_ms'] / sqp:.2f}, {r['default_p95_ms'] / r['casadi_sqp_p95_ms']:.2f}"
        print(f"| {model} | {case} | {r['n_p']} x {n_h} "
              f"| {r['default_median_ms']:.3f} / {r['default_p95_ms']:.3f} / {r['default_max_ms']:.3f} "
              f"| {r['floor_median_ms']:.3f} | {r['alone_median_ms']:.3f} / {r['alone_p95_ms']:.3f}, "
              f"{r['alone_over_floor']:.1f}x | {r['iterations_median']:.0f} / {r['iterations_p95']:.0f} / "
              f"{r['iterations_max']}, {100 * r['at_iteration_limit_share']:.1f} % "
              f"| {_fmt(sqp)} / {_fmt(r['casadi_sqp_p95_ms'])} | {_fmt(ipo, '.2f')} / {_fmt(r['ipopt_p95_ms'], '.2f')} "
              f"| {ratio} | {_fmt(r['casadi_sqp_max_input_diff'], '.1e')} / {_fmt(r['ipopt_max_input_diff'], '.1e')} "
              f"| {r['failures']} / {_fmt(r['casadi_sqp_failures'], 'd')} / {_fmt(r['ipopt_failures'], 'd')} |",
              flush=True)  # fmt: skip
    print(f"\nload average (1 min) at the end: {os.getloadavg()[0]:.2f}")
    if use_casadi:
        print("\nRatios below 1 favour trustnav (targets: median <= 0.33, p95 <= 0.5). CasADi times are the wall time "
              "of one solver call from Python; the default's are whole controller steps. Input differences are "
              "taken where both solvers converged (the default OPTIMAL), over the whole planned horizon.")  # fmt: skip
    if not args.no_slsqp:
        _slsqp_table([r for r in rows if r["model"] != "bicycle_drive"])
    if args.drive_seeds > 0:
        d = drive_solve_times(args.drive_seeds, use_casadi)
        print(f"\ntrustnav drive case-1 --sensing keypoints, seeds 0-{d['drive_seeds'] - 1} "
              f"({d['drive_steps']} steps): "
              f"solve median {d['drive_median_ms']:.3f} ms, p95 {d['drive_p95_ms']:.3f} ms; the bicycle 10 x 7 row "
              f"in the same run {d['bench_median_ms']:.3f} / {d['bench_p95_ms']:.3f} ms (alone "
              f"{d['bench_alone_median_ms']:.3f} / {d['bench_alone_p95_ms']:.3f}): {d['median_ratio']:.2f}x median "
              f"(bar <= 2), {d['p95_ratio']:.2f}x p95 (bar <= 4); load {d['load_1min']:.2f}")  # fmt: skip
        rows.append({"model": "drive_case1_keypoints", **d})
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


def _slsqp_table(rows: list[dict]) -> None:
    print("\n| model | case | N_p x N_h | SLSQP authors' style median / p95 (ms) | SLSQP tuned median / p95 (ms) | "
          "default median / p95 (ms) | speed-up vs authors' | vs tuned | max traj. diff (authors' / tuned) | "
          "failures (default / authors' / tuned) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        case = r["case"] if r["case"] == "paper-2" else f"seed {r['case']}"
        auth = f"{r['authors_median_ms']:.2f} / {r['authors_p95_ms']:.2f}"
        tuned = f"{r['tuned_median_ms']:.2f} / {r['tuned_p95_ms']:.2f}"
        dflt = f"{r['default_median_ms']:.3f} / {r['default_p95_ms']:.3f}"
        diff = f"{r['authors_max_trajectory_diff']:.1e} / {r['tuned_max_trajectory_diff']:.1e}"
        fails = f"{r['failures']} / {r['authors_failures']} / {r['tuned_failures']}"
        print(f"| {r['model']} | {case} | {r['n_p']} x {r['n_h']} | {auth} | {tuned} | {dflt} "
              f"| {r['authors_speedup']:.0f}x | {r['tuned_speedup']:.0f}x | {diff} | {fails} |")  # fmt: skip
    a = [r["authors_speedup"] for r in rows]
    t = [r["tuned_speedup"] for r in rows]
    ratio = [r["authors_median_ms"] / r["tuned_median_ms"] for r in rows]
    print(f"\nDefault SQP + DAQP against the authors' style: {min(a):.0f}x-{max(a):.0f}x faster per solve "
          f"(median); against SLSQP, tuned: {min(t):.0f}x-{max(t):.0f}x. The authors' style takes "
          f"{min(ratio):.1f}x-{max(ratio):.1f}x the time of the tuned SLSQP. Failures count steps where the "
          "controller applied a fallback or the solver failed; trajectory differences are meaningful only "
          "where the baseline converged.")  # fmt: skip


if __name__ == "__main__":
    main()
