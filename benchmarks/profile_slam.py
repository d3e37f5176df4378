"""Where `slam`'s time goes, against GTSAM best-of-3 and best-of-7 on the same walks (issue 45).

    python benchmarks/profile_slam.py --walks 10 --seed 98101

Random non-planar walks as ``bench_edm_start.py`` draws them (M = 8 steps by default,
``--steps`` for others; 1 cm, +-20% step bounds, noise not given). Each part of ``slam`` is
timed by wrapping its function (wall-clock, ``time.perf_counter``): the convex-iteration
search with its GTSAM refinements (``search_edm_runs``), the judge (``judge_slam``) split into
its random starts (``random_minima``) and its leave-one-block-out refits
(``block_alternatives``), the verdict's checks (``slam_verdict``), the refit of a converged
answer in its plane (``planar_answer``) and the result (landmark mirrors, covariances:
``slam_result``). The peers: ``gtsam_best_of`` from ``bench_edm_start.py`` with 3 and with 7 random starts (7 is the
least number of starts after which Boender and Rinnooy Kan's rule ends a search whose starts all
reached one minimum). Ratios are of medians in one run. Also the issue's other terms: the median
trajectory error (RMS after the best rigid motion with reflection) and the success (< 10 cm) of
slam and of each peer, and slam's slowest walk against the best-of-3 median.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import time

import numpy as np
from _common import machine, markdown_table, wrap_parts
from bench_edm_start import gtsam_best_of, walk_scene

import rangeslam.mdu.slam  # noqa: F401  (the module, which the function of that name shadows)
from rangeslam.evaluation.metrics import trajectory_rmse
from rangeslam.mdu import slam_judge
from rangeslam.sim.trajectories import step_lengths

SLAM = sys.modules["rangeslam.mdu.slam"]
PARTS = {
    "search (SDP + GTSAM refinement)": (SLAM, "search_edm_runs"),
    "judge, in all": (SLAM, "judge_slam"),
    "judge: random starts": (slam_judge, "random_minima"),
    "judge: block refits": (slam_judge, "block_alternatives"),
    "verdict checks": (SLAM, "slam_verdict"),
    "the walk's plane (nested refit)": (SLAM, "planar_answer"),
    "result (mirrors, covariances)": (SLAM, "slam_result"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=10)
    ap.add_argument("--steps", type=int, default=8, help="steps M of each walk")
    ap.add_argument("--seed", type=int, required=True)
    args = ap.parse_args()
    spent: dict[str, float] = {}
    wrap_parts(PARTS, spent)
    rng = np.random.default_rng(args.seed)
    rows = []
    for i in range(args.walks):
        traj, _, ranges = walk_scene(args.steps, 0.01, rng)
        steps = step_lengths(traj)
        bounds = (0.8 * steps, 1.2 * steps)
        spent.clear()
        t0 = time.perf_counter()
        out = SLAM.slam(ranges, step_bounds=bounds, rng=i)
        total = time.perf_counter() - t0
        est3, peer3 = gtsam_best_of(3, ranges, bounds, 0.01, np.random.default_rng(i))
        est7, peer7 = gtsam_best_of(7, ranges, bounds, 0.01, np.random.default_rng(i))
        errors = [trajectory_rmse(e, traj) for e in (out.receivers, est3, est7)]
        starts = re.search(r"(\d+) starts reached", out.message)
        rows.append((total, peer3, peer7, dict(spent), int(starts.group(1)) if starts else 0,
                     errors))  # fmt: skip
        print(f"walk {i}: slam {total:.3f} s, best-of-3 {peer3:.3f} s, best-of-7 {peer7:.3f} s, "
              f"{out.status.name}; errors {', '.join(f'{e * 100:.2f}' for e in errors)} cm",
              flush=True)  # fmt: skip
    med = statistics.median
    total = med(r[0] for r in rows)
    table = [[name, f"{med(r[3].get(name, 0.0) for r in rows):.3f}",
              f"{med(r[3].get(name, 0.0) / r[0] for r in rows):.0%}"] for name in PARTS]  # fmt: skip
    print(f"\n{args.walks} walks of M = {args.steps}, seed {args.seed}, {machine()}\n")
    print(markdown_table(["part", "median s", "median share of slam"], table))
    print(
        f"\nslam median {total:.3f} s; starts the judge counted (median) {med(r[4] for r in rows)}"
    )
    for k, label in ((1, "best-of-3"), (2, "best-of-7")):
        peer = med(r[k] for r in rows)
        print(f"GTSAM {label} median {peer:.3f} s: slam / peer {total / peer:.1f}x")
    worst = max(r[0] for r in rows)
    print(f"slam's slowest walk {worst:.3f} s: {worst / med(r[1] for r in rows):.1f}x the "
          "best-of-3 median")  # fmt: skip
    for k, label in enumerate(("slam", "GTSAM best-of-3", "GTSAM best-of-7")):
        errs = [r[5][k] for r in rows]
        print(f"{label}: median error {med(errs) * 100:.2f} cm, success (< 10 cm) "
              f"{np.mean(np.array(errs) < 0.10):.0%}")  # fmt: skip


if __name__ == "__main__":
    main()
