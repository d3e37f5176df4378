"""A planar walk fitted in 3-D against the same walk in its plane, as slam reports it (issue 42).

    python benchmarks/bench_planar_walk.py --walks 8 --seed 20261121

Fig. 5's walks (the lemniscate of eq. (12) at one height, a loudspeaker and its 6 first-order
images, sigma = 1 cm, +-20% step bounds placed at random around the true steps, noise given) as
``tests/test_fig5.py`` draws them, M = 10, 15, 20. For each walk: ``slam``'s answer, which is
the walk refitted in its plane when the likelihood-ratio test of that nested model keeps it
(:mod:`rangeslam.mdu.planar_walk`), and the 3-D model: GTSAM on the same graph without the plane
from that answer (a 3-D minimum next to it), with its covariances. Printed per M: the mean
trajectory RMS error of each (after the best rigid motion with reflection), the mean NEES per
degree of freedom of each in its own covariance (slam's: ``trajectory_dof``, 2 M - 3 in the
plane; 3-D: M d - 6), how often slam kept the plane, and how often it converged.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.experiments import fig5_scene, place_step_bounds
from rangeslam.evaluation.metrics import trajectory_nees
from rangeslam.geometry.alignment import align
from rangeslam.mdu import slam
from rangeslam.sim.trajectories import step_lengths
from rangeslam.solvers.gtsam_graph import refine_graph


def scene(m: int, sigma: float, rng: np.random.Generator):
    """(trajectory (M, 3), ranges (M, 7), step bounds): Fig. 5's walk, as slam_experiment draws
    it (:func:`rangeslam.app.experiments.fig5_scene`, bounds placed at random)."""
    traj, _, ranges = fig5_scene(m, sigma, rng)
    return traj, ranges, place_step_bounds(step_lengths(traj), "random", rng)


def in_3d(out, ranges, bounds, sigma):
    """(M, 3) trajectory and (M d, M d) covariance of the 3-D graph minimised from ``slam``'s
    answer ``out`` (GTSAM, the same ranges, bounds and sigma; the covariance in the receiver
    gauge)."""
    fit = refine_graph(out.receivers, out.sources, ranges, noise_std=sigma, step_bounds=bounds,
                       max_iterations=5000)  # fmt: skip
    m = len(out.receivers)
    return fit.receivers, fit.joint_cov[: 3 * m, : 3 * m]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=8, help="walks per M")
    ap.add_argument("--seed", type=int, default=20261121)
    ap.add_argument("--steps", type=int, nargs="+", default=[10, 15, 20])
    opts = ap.parse_args()
    rng, sigma, rows = np.random.default_rng(opts.seed), 0.01, []
    for m in opts.steps:
        cell = []
        for _ in range(opts.walks):
            traj, ranges, bounds = scene(m, sigma, rng)
            out = slam(ranges, step_bounds=bounds, noise_std=sigma, rng=rng)
            a = align(out.receivers, traj, reflection=True)
            nees, dof = trajectory_nees(a, out.trajectory_cov, traj, out.trajectory_dof)
            rec3, cov3 = in_3d(out, ranges, bounds, sigma)
            a3 = align(rec3, traj, reflection=True)
            nees3, dof3 = trajectory_nees(a3, cov3, traj)
            cell.append((a3.rmse, nees3, dof3, a.rmse, nees, dof, out.planar_walk, out.converged))
        c = np.array(cell, dtype=float)
        rows.append([m, f"{c[:, 0].mean() * 100:.2f}", f"{c[:, 3].mean() * 100:.2f}",
                     f"{c[:, 1].sum() / c[:, 2].sum():.3f}", f"{c[:, 4].sum() / c[:, 5].sum():.3f}",
                     f"{int(c[:, 6].sum())}/{len(c)}", f"{int(c[:, 7].sum())}/{len(c)}"])  # fmt: skip
    print(f"seed {opts.seed}, {opts.walks} walks per M; {machine()}")
    header = ["M", "3-D error [cm]", "slam error [cm]", "3-D NEES/dof", "slam NEES/dof",
              "slam kept the plane", "slam converged"]  # fmt: skip
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
