"""Plaza speed in pairs: our batch and incremental runs against GTSAM's example, run in turn.

    python benchmarks/bench_plaza_speed.py [--dataset Plaza1] [--runs 5] [--seed 0]

Each round runs "edm+gtsam", "edm+isam2" and "gtsam example" (a port of GTSAM's
RangeISAMExample_plaza2, random beacons from the round's generator) one after the other in this
process, so that a machine whose speed drifts moves all three alike; the ratios are taken round by
round and their median reported, with each method's median time, its x real time and its APE.
Times are in-process (the data loaded once; imports excluded).
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.plaza_bench import evaluate, run_method
from rangeslam.datasets import plaza
from rangeslam.evaluation.metrics import ape_statistics

METHODS = ("edm+gtsam", "edm+isam2", "gtsam example")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="Plaza1", choices=("Plaza1", "Plaza2"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    dataset = plaza(args.dataset)
    duration = float(dataset.pose_time[-1] - dataset.pose_time[0])
    seconds = {m: [] for m in METHODS}
    errors = {m: [] for m in METHODS}
    for k in range(args.runs):
        for method in METHODS:
            res = run_method(method, dataset, np.random.default_rng([args.seed, k]))
            seconds[method].append(float(res.seconds))
            errors[method].append(ape_statistics(evaluate(res, dataset).errors).mean)
    base = np.array(seconds["gtsam example"])
    rows = []
    for method in METHODS:
        t = np.array(seconds[method])
        rows.append(
            [
                method,
                f"{np.median(t):.2f} ({t.min():.2f}-{t.max():.2f})",
                f"{duration / np.median(t):.0f}",
                f"{np.median(t / base):.2f}",
                f"{np.median(errors[method]):.3f} (worst {np.max(errors[method]):.3f})",
            ]
        )
    print(f"# {args.dataset}: {args.runs} rounds, seed {args.seed}; {machine()}\n")
    header = [
        "method",
        "time [s], median (min-max)",
        "x real time",
        "time / GTSAM's example, median of rounds",
        "APE mean [m], median",
    ]
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
