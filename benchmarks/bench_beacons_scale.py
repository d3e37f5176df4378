"""Range-only SLAM at scale: time per pose and peak memory from a thousand to 100,000 poses.

    python benchmarks/bench_beacons_scale.py [--poses 1000 10000 100000] [--seed 0]

A simulated robot looping around a plaza (``simulate_beacon_run``) with 20 radio beacons on a
circle of 22 m around it, ranges 1.05 times the distance plus 0.3 m plus N(0, 0.3^2) m, to one
beacon at random from 40 % of the poses; the batch (``beacon_slam``) and the incremental run
(``beacon_slam_incremental``) each in its own process, so that the peak resident memory is that
run's. APE after rigid alignment. Plaza1's own cost against length comes from
``rangeslam bench plaza --lengths 500 1000 2000 4000 0``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

from _common import machine, markdown_table

CHILD = r"""
import json, resource, sys, time
import numpy as np
from rangeslam.beacons import beacon_slam, beacon_slam_incremental, simulate_beacon_run
from rangeslam.evaluation.metrics import ape, ape_statistics

n, method, seed = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
angle = np.linspace(0, 2 * np.pi, 20, endpoint=False)
beacons = np.column_stack([22 * np.cos(angle), 22 * np.sin(angle) + 15.0])
sim = simulate_beacon_run(np.random.default_rng([seed, n]), n_steps=n, beacons=beacons,
                          range_scale=1.05, range_offset=0.3)
fn = beacon_slam if method == "batch" else beacon_slam_incremental
t0 = time.perf_counter()
res = fn(sim.data, start_pose=sim.poses[0], range_sigma=0.3)
seconds = time.perf_counter() - t0
stats = ape_statistics(ape(res.poses[:, :2], sim.poses[:, :2], res.beacons, sim.beacons).errors)
print(json.dumps({"seconds": seconds, "mean": stats.mean, "max": stats.max,
                  "converged": bool(res.converged), "scale": float(np.nanmedian(res.range_scale)),
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "duration": float(sim.data.pose_time[-1] - sim.data.pose_time[0])}))
"""


def run_child(n: int, method: str, seed: int) -> dict:
    """One run in a fresh interpreter; its JSON line."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(n), method, str(seed)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, nargs="+", default=[1000, 10000, 100000])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"# Range-only SLAM at scale (20 beacons, seed {args.seed}; {machine()})\n")
    rows = []
    for n in args.poses:
        for method in ("batch", "incremental"):
            r = run_child(n, method, args.seed)
            rows.append(
                [
                    n,
                    method,
                    f"{r['seconds']:.1f}",
                    f"{1e3 * r['seconds'] / n:.2f}",
                    f"{r['duration'] / r['seconds']:.0f}",
                    f"{r['rss_mb']:.0f}",
                    f"{r['mean']:.3f}",
                    f"{r['scale']:.4f}",
                    "yes" if r["converged"] else "no",
                ]
            )
            print(" | ".join(str(c) for c in rows[-1]), file=sys.stderr, flush=True)
    header = [
        "poses",
        "method",
        "time [s]",
        "per pose [ms]",
        "x real time",
        "peak memory [MB]",
        "APE mean [m]",
        "range scale (true 1.05)",
        "converged",
    ]
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
