"""Known beacons in the incremental run and the baselines; the GTSAM example's wrong basins.

    python benchmarks/bench_beacon_known_baselines.py [--seeds 608824 233218 537491 310215]
        [--verdict-seeds 386279 --verdict-runs 45]

Part 1 (issue 36, known beacons): the 3 x 3 m room of bench_beacon_defaults (beacons in the
corners, 5 cm ranges 3 % long plus one sigma) run by beacon_slam_incremental (stated noise), the
EKF and GTSAM's example port (their defaults), each without known beacons and with every beacon
known and fixed: mean APE after rigid alignment, and how far the fixed beacons moved.

Part 2 (the example's verdict): GTSAM's example port on plaza-sized simulated runs with one range
in ten poses (simulate_beacon_run(range_rate=0.1)), where its random beacon starts now and then
end in a wrong minimum: APE by status. The rule was written on Plaza1 (``rangeslam bench plaza
--dataset Plaza1 --methods "gtsam example" --trials 20 --lengths``); these seeds came after it.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.baselines import ekf_range_odometry, gtsam_range_example
from rangeslam.beacons import beacon_slam_incremental, simulate_beacon_run
from rangeslam.evaluation.metrics import ape, ape_statistics

CORNERS = np.array([[-0.9, -0.2], [1.9, -0.2], [1.9, 2.6], [-0.9, 2.6]])
ROOM = dict(
    n_steps=2000, step_length=0.005, radius=0.45, beacons=CORNERS, range_std=0.05,
    odometry_std=(2.5e-4, 0.002), range_scale=1.03, range_offset=0.05,
)  # fmt: skip
STATED = dict(range_sigma=0.05, odometry_sigma=(2.5e-4, 2.5e-4, 0.002))
ESTIMATORS = {
    "edm+isam2": lambda data, seed, **kw: beacon_slam_incremental(data, **STATED, **kw),
    "EKF": lambda data, seed, **kw: ekf_range_odometry(data, rng=seed, **kw),
    "GTSAM example": lambda data, seed, **kw: gtsam_range_example(
        data, rng=np.random.default_rng(seed), **kw
    ),
}


def errors(result, run) -> tuple[float, float]:
    """(mean APE, the largest beacon error) [m] after the poses' rigid alignment."""
    fit = ape(result.poses[:, :2], run.poses[:, :2], result.beacons, run.beacons)
    return float(ape_statistics(fit.errors).mean), float(np.nanmax(fit.beacon_errors))


def known_table(seeds) -> str:
    rows = []
    for name, run_it in ESTIMATORS.items():
        for seed in seeds:
            run = simulate_beacon_run(np.random.default_rng(seed), **ROOM)
            plain = run_it(run.data, seed)
            known = run_it(run.data, seed, beacons=run.beacons)
            moved = float(np.max(np.linalg.norm(known.beacons - run.beacons, axis=1)))
            (plain_ape, plain_worst), (known_ape, _) = errors(plain, run), errors(known, run)
            rows.append(
                [name, seed, f"{plain_ape:.4g}", f"{plain_worst:.2g}", plain.status.name,
                 f"{known_ape:.4g}", known.status.name, f"{moved:.2g}"]
            )  # fmt: skip
    header = [
        "method",
        "seed",
        "APE [m]",
        "worst beacon [m]",
        "status",
        "APE, 4 known fixed [m]",
        "status",
        "moved [m]",
    ]
    return markdown_table(header, rows)


def verdict_table(first: int, runs: int) -> str:
    by_status: dict[str, list[tuple[float, float]]] = {}
    for seed in range(first, first + runs):
        run = simulate_beacon_run(np.random.default_rng(seed), range_rate=0.1)
        res = gtsam_range_example(run.data, rng=np.random.default_rng(seed))
        by_status.setdefault(res.status.name, []).append(errors(res, run))
    rows = []
    for status, pairs in sorted(by_status.items()):
        a, b = np.array(pairs).T
        rows.append(
            [status, len(a), f"{a.min():.3g}-{a.max():.3g}", f"{b.min():.3g}-{b.max():.3g}"]
        )
    return markdown_table(["status", "runs", "APE [m]", "worst beacon [m]"], rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[608824, 233218, 537491, 310215])
    parser.add_argument("--verdict-seeds", type=int, default=386279)
    parser.add_argument("--verdict-runs", type=int, default=45)
    args = parser.parse_args()
    print(machine())
    print(known_table(args.seeds))
    print()
    print(verdict_table(args.verdict_seeds, args.verdict_runs))


if __name__ == "__main__":
    main()
