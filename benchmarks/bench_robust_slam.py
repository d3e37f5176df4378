"""Robust slam with wrong picks: is a right answer said converged, a wrong one flagged?

    python benchmarks/bench_robust_slam.py [--walks 10] [--steps 8] [--seed 20261125]

Random non-planar walks (``walk_in_random_room``: M steps of 0.3 m in a random convex room, the
loudspeaker and its 6 nearest first-order images), 1 mm range noise, +-20% step bounds, and one
or two wrong picks (alternately) moved by 0.3-1 m; ``slam(noise_std=1e-3, robust="cauchy")``.
A row is right when the trajectory is within 1 cm after rigid alignment (with reflection). The
verdict is judged on the ranges the kernel kept (``SlamResult.inliers``).
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu import slam
from rangeslam.sim.scenes import add_range_noise, walk_in_random_room
from rangeslam.sim.trajectories import step_lengths

RIGHT = 0.01  # metres: a trajectory this close after alignment is a right answer


def walk_with_wrong_picks(m: int, n_wrong: int, rng: np.random.Generator):
    """(trajectory (M, 3), ranges (M, K) with 1 mm noise and ``n_wrong`` wrong picks, bounds)."""
    traj, landmarks = walk_in_random_room(m, rng=rng)
    ranges = add_range_noise(range_matrix(traj, landmarks), 1e-3, rng=rng)
    cells = rng.choice(ranges.size, size=n_wrong, replace=False)
    ranges.flat[cells] += rng.choice([-1, 1], size=n_wrong) * rng.uniform(0.3, 1.0, n_wrong)
    steps = step_lengths(traj)
    return traj, ranges, (0.8 * steps, 1.2 * steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=10)
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--seed", type=int, default=20261125)
    args = ap.parse_args()
    rows, tally = [], {"right, converged": 0, "right, flagged": 0, "wrong, converged": 0}
    for i, child in enumerate(np.random.SeedSequence(args.seed).spawn(args.walks)):
        rng = np.random.default_rng(child)
        n_wrong = 1 + i % 2
        traj, ranges, bounds = walk_with_wrong_picks(args.steps, n_wrong, rng)
        out, dt = timed(slam, ranges, step_bounds=bounds, noise_std=1e-3, robust="cauchy", rng=rng)
        err = align(out.receivers, traj, reflection=True).rmse
        right = err < RIGHT
        key = ("right" if right else "wrong") + (", converged" if out.converged else ", flagged")
        tally[key] = tally.get(key, 0) + 1
        rows.append([i, n_wrong, out.status.name, f"{err * 100:.2f}", out.n_outliers,
                     f"{dt:.1f}", out.message[:90]])  # fmt: skip
    print(
        f"## Robust slam, {args.walks} walks of M = {args.steps}, seed {args.seed} ({machine()})\n"
    )
    header = ["walk", "wrong picks", "status", "error [cm]", "left out", "time [s]", "message"]
    print(markdown_table(header, rows))
    print("\n" + ", ".join(f"{k}: {v}" for k, v in tally.items()))


if __name__ == "__main__":
    main()
