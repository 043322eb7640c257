"""trustnav's controller and CasADi SQP side by side on random single-integrator worlds (issue 36).

An independent check of the default controller against CasADi ``sqpmethod`` + qpOASES on random
worlds of ``--pedestrians`` (10) static pedestrians and an ``--horizon`` (20) step horizon, built as
``bench_mpc.py``'s (a start at (20, 5), a goal at (20, 45), pedestrians in the first part of the
path, trusts uniform in [0, 1]), one world per seed. The CasADi problem is written here again from
the paper's equations (single shooting in U: x(k+1) = x(k) + dt u(k), cost sum ||u - u_bar||^2 with
the bounded proportional reference, `h_quad`, `cbf_imp` with gamma_j by `weight`), not taken from
``bench_mpc.py``. At every state trustnav's closed loop visits, CasADi solves the same problem from
the same warm start (the controller's shifted plan); the two calls alternate in a shuffled order.

Prints per-step medians and p95s, their ratios (taken in the same run), trustnav's iteration
statistics and the share of its steps that ended at the SQP's iteration limit, and the machine's
1-minute load average.

    python benchmarks/side_by_side.py --first-seed 1000          # 20 worlds x 500 steps, ~30 s
    python benchmarks/side_by_side.py --first-seed 1000 --walking 1 --on-path --json out/sbs.json

Seeds 100-119 were used while tuning the solver (the curvature's floor and start); report others.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

from trustnav.control import MpcConfig, MpcController, SingleIntegrator, SolveStatus, SqpSolver, VelocityTrackingCost
from trustnav.control.reference import BoundedProportionalReference

try:  # optional: the `bench` extra
    import casadi as ca
except ImportError:  # pragma: no cover - depends on the environment
    ca = None

GOAL = (20.0, 45.0)
START = (20.0, 5.0)


def world(
    seed: int, n_p: int, walking: float = 0.0, on_path: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pedestrians (n_p, 2), their velocities (n_p, 2) and trusts (n_p,) of one random world: near
    the first part of the path, 3.5 m apart and 3.5 m off the straight line from start to goal;
    standing, or (``walking`` > 0) walking in random directions at up to ``walking`` m/s.
    ``on_path``: pedestrians may stand on the straight line too."""
    rng = np.random.default_rng(seed)
    peds = np.empty((0, 2))
    while len(peds) < n_p:
        c = rng.uniform([10.0, 11.0], [30.0, 11.0 + 2.0 * n_p])
        if np.all(np.linalg.norm(peds - c, axis=1) > 3.5) and (on_path or abs(c[0] - START[0]) > 3.5):
            peds = np.vstack([peds, c])
    trusts = rng.uniform(0.0, 1.0, n_p)
    vels = np.zeros((n_p, 2))
    if walking > 0:
        heading = rng.uniform(-math.pi, math.pi, n_p)
        vels = rng.uniform(0.0, walking, n_p)[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    return peds, vels, trusts


class CasadiSingleIntegrator:
    """`proposed` for the single integrator, written in CasADi (``sqpmethod`` + qpOASES, exact
    Hessian convexified by eigen-clip, tolerances 1e-9, at most ``max_iter`` iterations)."""

    def __init__(self, cfg: MpcConfig, n_p: int, bounds: tuple[np.ndarray, np.ndarray], max_iter: int) -> None:
        n_h, dt = cfg.horizon, cfg.dt
        u = ca.SX.sym("u", n_h, 2)
        x0 = ca.SX.sym("x0", 1, 2)
        q = ca.SX.sym("q", n_p, 2)
        v = ca.SX.sym("v", n_p, 2)
        omg = ca.SX.sym("omg", n_p)  # 1 - gamma_j
        ubar = ca.SX.sym("ubar", n_h, 2)
        r2 = cfg.safety_radius**2
        pos = [x0]
        for k in range(n_h):
            pos.append(pos[-1] + dt * u[k, :])
        rows = []
        for k in range(n_h):
            for j in range(n_p):  # `ped_predict`: constant velocity, q(k) = q_j + k dt v_j
                q_now = q[j, :] + k * dt * v[j, :]
                h_next = ca.sumsqr(pos[k + 1] - (q_now + dt * v[j, :])) - r2
                h_now = ca.sumsqr(pos[k] - q_now) - r2
                rows.append(h_next - omg[j] * h_now)
        params = ca.vertcat(ca.vec(x0), ca.vec(q), ca.vec(v), omg, ca.vec(ubar))
        nlp = {"x": ca.vec(u), "p": params, "f": ca.sumsqr(u - ubar), "g": ca.vertcat(*rows)}
        self.solver = ca.nlpsol("sqp", "sqpmethod", nlp, {
            "print_time": False, "error_on_fail": False, "qpsol": "qpoases", "print_header": False,
            "print_iteration": False, "print_status": False, "max_iter": max_iter, "tol_pr": 1e-9, "tol_du": 1e-9,
            "convexify_strategy": "eigen-clip", "qpsol_options": {"printLevel": "none", "error_on_fail": False},
        })  # fmt: skip
        lo, hi = bounds
        self.lbx = np.repeat(lo, n_h)  # column-major: all u_x, then all u_y
        self.ubx = np.repeat(hi, n_h)
        self.ng = n_h * n_p
        self.cfg = cfg

    def arguments(self, x, peds, vels, trusts, gain, v_max, u0) -> dict:
        cfg, n_h = self.cfg, self.cfg.horizon
        g = cfg.gamma
        omg = 1.0 - (g.gamma_ini + g.delta * np.power(trusts, g.lam))  # `weight`
        ubar, p = np.empty((n_h, 2)), np.array(x, dtype=float)
        for k in range(n_h):  # bounded proportional reference along its own rollout
            v = gain * (np.asarray(GOAL) - p)
            nrm = math.hypot(v[0], v[1])
            ubar[k] = v * (v_max / nrm) if nrm > v_max else v
            p = p + ubar[k] * cfg.dt
        par = np.concatenate([x, peds.T.ravel(), vels.T.ravel(), omg, ubar.T.ravel()])
        return {"x0": np.asarray(u0).T.ravel(), "p": par, "lbx": self.lbx, "ubx": self.ubx,
                "lbg": np.zeros(self.ng), "ubg": np.full(self.ng, np.inf)}  # fmt: skip

    def solve(self, args: dict) -> tuple[np.ndarray, bool, int, float]:
        """(plan (N_h, 2), success, iterations, wall seconds of the call)."""
        t0 = time.perf_counter()
        out = self.solver(**args)
        wall = time.perf_counter() - t0
        st = self.solver.stats()
        ok = bool(st["success"]) or st["return_status"] == "Search_Direction_Becomes_Too_Small"
        n_h = self.cfg.horizon
        return np.asarray(out["x"]).reshape(2, n_h).T, ok, int(st.get("iter_count", -1)), wall


def run(args) -> dict:
    cfg = MpcConfig(horizon=args.horizon, dt=0.05, safety_radius=3.0, **({"deadlock": None} if args.plain else {}))
    ref = BoundedProportionalReference(1.5, 10.0)
    cost = VelocityTrackingCost(goal=GOAL, reference=ref)
    model = SingleIntegrator()
    bounds = model.input_bounds()
    rec = {k: [] for k in ("ours", "cas", "its", "cas_its", "diff")}
    limit_steps = deadline_steps = not_optimal = cas_fail = 0
    max_iter = SqpSolver().max_iter
    order = np.random.default_rng(0)
    cas = None
    for w in range(args.worlds):
        seed = args.first_seed + w
        peds, vels, trusts = world(seed, args.pedestrians, args.walking, args.on_path)
        if cas is None and ca is not None and not args.no_casadi:
            cas = CasadiSingleIntegrator(cfg, len(peds), bounds, max_iter)
        ctl = MpcController(model, cost, cfg, SqpSolver())
        ctl.step(np.array(START), peds, vels, trusts)  # warm-up step (DAQP set up), not timed
        ctl.reset()
        x, plan = np.array(START), None
        for _ in range(args.steps):
            u0 = None if plan is None else np.clip(np.vstack([plan[1:], plan[-1:]]), *bounds)
            solved = None
            for who in order.permutation(["ours", "cas"] if cas is not None and u0 is not None else ["ours"]):
                if who == "cas":
                    solved = cas.solve(cas.arguments(x, peds, vels, trusts, ref.gain, ref.v_max, u0))
                    continue
                t0 = time.perf_counter()
                sol = ctl.step(x, peds, vels, trusts)
                rec["ours"].append(time.perf_counter() - t0)
            rec["its"].append(sol.iterations)
            limit_steps += sol.iterations >= max_iter
            deadline_steps += sol.deadline_hit
            not_optimal += sol.status is not SolveStatus.OPTIMAL
            if solved is not None:
                u_c, ok, it_c, t_c = solved
                rec["cas"].append(t_c)
                rec["cas_its"].append(it_c)
                cas_fail += not ok
                if ok and sol.status is SolveStatus.OPTIMAL:
                    rec["diff"].append(float(np.max(np.abs(u_c - sol.inputs))))
            plan = sol.inputs
            x = model.step(x, sol.control, cfg.dt)
            peds = peds + cfg.dt * vels
    ours, its = np.array(rec["ours"]) * 1e3, np.array(rec["its"])
    out = {
        "worlds": args.worlds, "walking": args.walking, "on_path": args.on_path, "plain": args.plain,
        "first_seed": args.first_seed, "n_p": args.pedestrians, "n_h": args.horizon, "steps": len(ours),
        "load_1min": os.getloadavg()[0],
        "default_median_ms": float(np.median(ours)), "default_p95_ms": float(np.percentile(ours, 95)),
        "iterations_median": float(np.median(its)), "iterations_p95": float(np.percentile(its, 95)),
        "iterations_max": int(its.max()), "at_iteration_limit": int(limit_steps),
        "at_iteration_limit_share": limit_steps / len(its), "deadline_hit": int(deadline_steps),
        "not_optimal": int(not_optimal),
    }  # fmt: skip
    if rec["cas"]:
        c = np.array(rec["cas"]) * 1e3
        out.update({
            "casadi_version": ca.__version__, "casadi_sqp_median_ms": float(np.median(c)),
            "casadi_sqp_p95_ms": float(np.percentile(c, 95)),
            "casadi_iterations_median": float(np.median(rec["cas_its"])),
            "casadi_iterations_max": int(max(rec["cas_its"])), "casadi_failures": int(cas_fail),
            "speedup_median": float(np.median(c) / np.median(ours)),
            "speedup_p95": float(np.percentile(c, 95) / np.percentile(ours, 95)),
            "max_input_diff": float(max(rec["diff"])) if rec["diff"] else None,
            "input_diff_p95": float(np.percentile(rec["diff"], 95)) if rec["diff"] else None,
        })  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", type=int, default=20, help="random worlds, one per seed")
    ap.add_argument("--first-seed", type=int, default=1000, help="seed of the first world")
    ap.add_argument("--steps", type=int, default=500, help="closed-loop steps per world (25 s: past the crowd)")
    ap.add_argument("--pedestrians", type=int, default=10)
    ap.add_argument("--horizon", type=int, default=20)
    ap.add_argument("--walking", type=float, default=0.0, help="pedestrians walk at up to this speed (m/s)")
    ap.add_argument("--on-path", action="store_true", help="pedestrians may stand on the straight path too")
    ap.add_argument("--plain", action="store_true", help="the paper's plain controller (no route layer: wedges stay)")
    ap.add_argument("--no-casadi", action="store_true", help="trustnav alone")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    if ca is None and not args.no_casadi:
        print("NOTE: casadi is not installed (pip install -e .[bench]): trustnav alone.", file=sys.stderr)
    r = run(args)
    print(f"{r['worlds']} worlds (seeds {r['first_seed']}-{r['first_seed'] + r['worlds'] - 1}), "
          f"{r['n_p']} x {r['n_h']}, {r['steps']} steps; load (1 min) {r['load_1min']:.2f}")  # fmt: skip
    print(f"trustnav: median {r['default_median_ms']:.3f} ms, p95 {r['default_p95_ms']:.3f} ms; SQP iterations "
          f"median {r['iterations_median']:.0f}, p95 {r['iterations_p95']:.0f}, max {r['iterations_max']}; "
          f"at the iteration limit {r['at_iteration_limit']} ({100 * r['at_iteration_limit_share']:.2f} %); "
          f"deadline hit {r['deadline_hit']}; not OPTIMAL {r['not_optimal']}")  # fmt: skip
    if "casadi_sqp_median_ms" in r:
        print(f"CasADi {r['casadi_version']} SQP: median {r['casadi_sqp_median_ms']:.3f} ms, p95 "
              f"{r['casadi_sqp_p95_ms']:.3f} ms; iterations median {r['casadi_iterations_median']:.0f}, max "
              f"{r['casadi_iterations_max']}; failures {r['casadi_failures']}")  # fmt: skip
        diff = "n/a" if r["max_input_diff"] is None else f"{r['max_input_diff']:.1e} (p95 {r['input_diff_p95']:.1e})"
        print(f"speed-up over CasADi SQP: median {r['speedup_median']:.2f}x, p95 {r['speedup_p95']:.2f}x "
              f"(bars: >= 3x, >= 2x); largest input difference where both converged: {diff}")  # fmt: skip
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(r, fh, indent=2)


if __name__ == "__main__":
    main()
