"""Beacon SLAM with defaults from the data: a 3 x 3 m room and a 300 x 300 m field, and Plaza1.

    python benchmarks/bench_beacon_defaults.py [--seeds 524759 163842] [--no-plaza]

Each scene (simulate_beacon_run; the room: beacons in the corners of 3 x 3 m, 5 cm UWB ranges,
0.5 cm steps round a 0.45 m loop; the field: the same 100 times larger, 1 m ranges; ranges 3 %
long plus one sigma)
is run with only its stated noise (range_sigma, odometry_sigma): beacon_slam, the incremental
run, a plain GTSAM best-of-3 peer (the same graph from three random beacon starts, lowest cost
kept), beacon_slam with every beacon known (fixed) and with two known, the EKF and GTSAM's
example port (their defaults). Mean APE after rigid alignment; with known beacons also the mean
error without alignment (the beacons give the frame). Plaza1 (never Plaza2): beacon_slam,
the incremental run and the EKF with their defaults.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.baselines import ekf_range_odometry, gtsam_range_example
from rangeslam.beacons import beacon_slam, beacon_slam_incremental, simulate_beacon_run
from rangeslam.evaluation.metrics import ape, ape_statistics

# Beacons in the corners of a 3 x 3 m room round a path 2.0 x 2.5 m across (0.5 cm steps round a
# 0.45 m loop that drifts), and the same scene 100 times larger.
CORNERS = np.array([[-0.9, -0.2], [1.9, -0.2], [1.9, 2.6], [-0.9, 2.6]])
SCENES = {
    "room 3 x 3 m": dict(
        n_steps=2000, step_length=0.005, radius=0.45, beacons=CORNERS, range_std=0.05,
        odometry_std=(2.5e-4, 0.002),
        range_scale=1.03, range_offset=0.05,
    ),
    "field 300 x 300 m": dict(
        n_steps=2000, step_length=0.5, radius=45.0, beacons=100.0 * CORNERS, range_std=1.0,
        odometry_std=(0.025, 0.002),
        range_scale=1.03, range_offset=1.0,
    ),
}  # fmt: skip


def _ape(res, truth, beacons) -> float:
    return ape_statistics(ape(res.poses[:, :2], truth[:, :2], res.beacons, beacons).errors).mean


def _cell(res, truth, beacons, absolute: bool = False) -> str:
    text = f"{_ape(res, truth, beacons):.4g}"
    if absolute:
        raw = np.mean(np.linalg.norm(res.poses[:, :2] - truth[:, :2], axis=1))
        text += f" ({raw:.4g})"
    return text + ("" if res.converged else f" {res.status.name}")


def scene_row(name: str, seed: int) -> list[str]:
    """One scene, one seed: the APE of every method."""
    kw = SCENES[name]
    run = simulate_beacon_run(np.random.default_rng(seed), **kw)
    d, theta = kw["odometry_std"]
    stated = dict(range_sigma=kw["range_std"], odometry_sigma=(d, d, theta))
    start = run.poses[0]
    peers = [
        beacon_slam(run.data, start_pose=start, initialisation="random",
                    rng=np.random.default_rng([seed, k]), **stated)
        for k in range(3)
    ]  # fmt: skip
    two = np.array(run.beacons)
    two[2:] = np.nan
    truth, beacons = run.poses, run.beacons
    return [
        name,
        str(seed),
        _cell(beacon_slam(run.data, start_pose=start, **stated), truth, beacons),
        _cell(beacon_slam_incremental(run.data, start_pose=start, **stated), truth, beacons),
        _cell(min(peers, key=lambda r: r.cost), truth, beacons),
        _cell(beacon_slam(run.data, beacons=run.beacons, **stated), truth, beacons, True),
        _cell(beacon_slam(run.data, beacons=two, **stated), truth, beacons, True),
        _cell(ekf_range_odometry(run.data, start_pose=start, rng=seed), truth, beacons),
        _cell(gtsam_range_example(run.data, start_pose=start, rng=np.random.default_rng(seed)),
              truth, beacons),
    ]  # fmt: skip


def plaza_rows() -> list[list[str]]:
    from rangeslam.beacons import RangeOdometry
    from rangeslam.datasets import plaza

    p1 = plaza("Plaza1")
    data, truth = RangeOdometry.from_plaza(p1), p1.truth_at(p1.pose_time)
    rows = []
    for name, res in (
        ("beacon_slam", beacon_slam(data, start_pose=p1.truth[0])),
        ("beacon_slam_incremental", beacon_slam_incremental(data, start_pose=p1.truth[0])),
        ("ekf_range_odometry", ekf_range_odometry(p1, rng=0)),
    ):
        rows.append([name, _cell(res, truth, p1.beacons)])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[524759, 163842])
    ap.add_argument("--no-plaza", action="store_true")
    args = ap.parse_args()
    print(f"# Beacon defaults from the data ({machine()})\n")
    header = [
        "scene", "seed", "edm+gtsam", "edm+isam2", "GTSAM best-of-3", "4 known (unaligned)",
        "2 known (unaligned)", "EKF", "GTSAM example",
    ]  # fmt: skip
    rows = [scene_row(name, seed) for name in SCENES for seed in args.seeds]
    print("Mean APE [m] after rigid alignment; status when not converged.\n")
    print(markdown_table(header, rows))
    if not args.no_plaza:
        print("\nPlaza1, defaults, mean APE [m]:\n")
        print(markdown_table(["method", "APE"], plaza_rows()))


if __name__ == "__main__":
    main()
