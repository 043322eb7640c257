"""Which of the paper's Section III claims hold, and for which unstated parameters.

The paper does not state the reference gain Kp, its speed bound v_max, or the input bound. This
script sweeps them and prints Markdown tables (the numbers in docs/fidelity.md come from it):

    python benchmarks/fidelity_study.py              # ~1 min on 2 cores
    python benchmarks/fidelity_study.py --baselines  # Scenario III with the three solvers (~40 s)
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from trustnav.sim import load_scenario, run_episode
from trustnav.sim.paper import episode_metrics, with_overrides

R = 3.0


def scenario_1(gains, vmaxes) -> None:
    print("\n### Scenario I: min distance decreases with trust and stays >= R\n")
    print("| Kp | v_max | min distance for trust 0, 0.25, 0.5, 0.75, 1 | claim holds |")
    print("|---|---|---|---|")
    base = load_scenario("paper-1")
    for kp, vm in itertools.product(gains, vmaxes):
        sc = with_overrides(base, reference_gain=kp, reference_v_max=vm)
        d = [run_episode(sc, trusts=[t]).distances.min() for t in sc.trust_sweep]
        ok = all(a > b for a, b in itertools.pairwise(d)) and min(d) >= R - 1e-6
        print(f"| {kp} | {vm} | {', '.join(f'{v:.2f}' for v in d)} | {'yes' if ok else 'no'} |")


def scenario_2(gains, vmaxes) -> None:
    print("\n### Scenario II: distance to the trust-0.5 pedestrian, trust-aware vs equal-trust control\n")
    print("| Kp | v_max | trust-aware | control (both 1.0) | gain | both >= R |")
    print("|---|---|---|---|---|---|")
    base = load_scenario("paper-2")
    for kp, vm in itertools.product(gains, vmaxes):
        sc = with_overrides(base, reference_gain=kp, reference_v_max=vm)
        a = run_episode(sc).distances.min(axis=0)
        b = run_episode(sc, trusts=[1.0, 1.0]).distances.min(axis=0)
        ok = min(a.min(), b.min()) >= R - 1e-6
        print(f"| {kp} | {vm} | {a[1]:.2f} | {b[1]:.2f} | {a[1] - b[1]:+.2f} | {'yes' if ok else 'no'} |")


def scenario_3(gains, vmaxes) -> None:
    print("\n### Scenario III: margin per horizon and trust ordering, both CBF timings\n")
    print("| timing | Kp | v_max | N_h=1 min d | N_h=2 | N_h=3 | N_h=4 | N_h=4: low >= high (min) | "
          "N_h=4: low >= high, share of steps |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    base = load_scenario("paper-3")
    for timing, kp, vm in itertools.product(("paper", "authors_code"), gains, vmaxes):
        sc = with_overrides(base, reference_gain=kp, reference_v_max=vm)
        eps = [run_episode(sc, horizon=h, timing=timing) for h in (1, 2, 3, 4)]
        mins = [ep.distances.min() for ep in eps]
        d4 = eps[-1].distances
        order_min = d4[:, 1].min() >= d4[:, 0].min()
        share = float(np.mean(d4[:, 1] >= d4[:, 0] - 1e-9))
        cells = " | ".join(f"{m:.3f}{' (breach)' if m < R - 1e-6 else ''}" for m in mins)
        print(f"| {timing} | {kp} | {vm} | {cells} | {'yes' if order_min else 'no'} | {share:.2f} |")


def baselines() -> None:
    """Scenario III (shipped setting) with the default SQP and both SLSQP baselines."""
    print("\n### Scenario III with each solver (shipped setting, checked fallbacks)\n")
    print("| solver | timing | N_h | min distance (trust 1.0, 0.3) | margin violations | solver failures | "
          "fallback steps |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    sc = load_scenario("paper-3")
    for solver in ("sqp", "slsqp", "slsqp-authors"):
        for timing in ("paper", "authors_code"):
            for h in sc.horizons:
                m = episode_metrics(run_episode(sc, horizon=h, timing=timing, solver=solver), R)
                d = ", ".join(f"{v:.3f}" for v in m["min_distance"])
                print(f"| {solver} | {timing} | {h} | {d} | {m['margin_violations']} | {m['solver_failures']} | "
                      f"{m['fallback_steps']} |", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer settings")
    ap.add_argument("--baselines", action="store_true", help="only Scenario III with the three solvers")
    args = ap.parse_args()
    if args.baselines:
        baselines()
        return
    gains = [1.0, 1.5] if args.quick else [1.0, 1.5, 2.0]
    scenario_1(gains, [5.0, 10.0] if args.quick else [5.0, 10.0, 15.0])
    scenario_2(gains, [5.0, 7.0, 10.0] if args.quick else [5.0, 7.0, 10.0, 15.0])
    scenario_3([1.4, 1.5], [10.0, 17.5, 18.0] if args.quick else [10.0, 15.0, 17.2, 17.5, 18.0])


if __name__ == "__main__":
    main()
