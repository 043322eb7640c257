"""Wall time of a campaign of random single-integrator episodes with 1 and N Dask workers.

Runs the same campaign (default 400 episodes of ``random_si``, no independent check) into fresh
output directories, once per worker count and batch size, and prints the wall time of the Dask
part (cluster start to last record), the episodes per second, the scaling ratio against the
smallest worker count, how many cores the episodes obtained (their summed process CPU time over
the wall time) and the summed episode wall time over the run's wall time (near the worker count
when the workers are never idle), with the load average before each run (the machine may be
shared: CPU taken by other processes shows as episode wall > episode CPU).

    python benchmarks/bench_campaigns.py                         # 400 episodes, 1 and 2 workers
    python benchmarks/bench_campaigns.py --episodes 200 --batch 1 8 --workers 1 2 --repeat 2
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from trustnav.campaigns import RecordStore, run_campaign, spec_from_dict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--batch", nargs="+", default=["auto"], help="episodes per task: integers or auto")
    ap.add_argument("--repeat", type=int, default=1, help="alternate the worker counts this many times")
    ap.add_argument("--seed", type=int, default=0, help="first world seed")
    args = ap.parse_args()
    base: dict[str, float] = {}
    print(f"{args.episodes} random_si episodes; load average before each run (1 / 5 / 15 min)")
    for batch, _rep, n in ((b, r, n) for b in args.batch for r in range(args.repeat) for n in args.workers):
        doc = {
            "name": "bench",
            "batch": batch if batch == "auto" else int(batch),
            "sweeps": [{"name": "si", "family": "random_si", "seeds": {"start": args.seed, "count": args.episodes}}],
        }
        load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            rep = run_campaign(spec_from_dict(doc), tmp, workers=n, progress=False)
            wall = time.perf_counter() - t0
            recs = RecordStore(Path(tmp) / "records.jsonl").latest().values()
            cpu = sum(r["cpu_s"] for r in recs)
            busy = sum(r["wall_s"] for r in recs)
        if n == min(args.workers):
            base[batch] = wall
        print(
            f"batch {batch:>4}  workers {n:2d}: {wall:6.1f} s  {rep.ran / wall:5.1f} episodes/s  "
            f"speed-up {base[batch] / wall:4.2f}x  episode CPU {cpu:5.1f} s = {cpu / wall:4.2f} cores, "
            f"episode wall {busy / wall:4.2f} x run wall  failed {rep.failed}  (load {load})"
        )


if __name__ == "__main__":
    main()
