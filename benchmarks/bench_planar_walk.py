"""A planar walk fitted in 3-D against the same walk refitted in its plane (issue 42).

    python benchmarks/bench_planar_walk.py --walks 8 --seed 20261121

Fig. 5's walks (the lemniscate of eq. (12) at one height, a loudspeaker and its 6 first-order
images, sigma = 1 cm, +-20% step bounds placed at random around the true steps, noise given) as
``tests/test_fig5.py`` draws them, M = 10, 15, 20. For each walk: ``slam``'s answer (3-D), and
the nested model refitted from it: the receivers in the best-fitting plane of the answer's
trajectory (2 coordinates each), the landmarks free in 3-D, on the same objective (whitened
ranges, the "uniform" step prior's moment-matched Gaussian and its dead zone), by SciPy's
Levenberg-Marquardt. Printed per M: the mean trajectory RMS error of each (after the best rigid
motion with reflection; the planar one in the truth's plane), the mean NEES per degree of
freedom of each in its own information (3-D: ``slam``'s ``trajectory_cov``, M d - 6 dof; planar:
the Gauss-Newton information with the landmarks profiled out, 2 M - 3 dof), and how often the
likelihood-ratio test of the nested model keeps the plane (cost gap within chi-square(M - 3) at
``CHI2_LEVEL``; the 3-D cost minimised on the same objective from ``slam``'s answer).
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table
from scipy.optimize import least_squares
from scipy.stats import chi2

from rangeslam.app.experiments import FIG5_ROOM_SIZE, place_step_bounds
from rangeslam.evaluation.metrics import trajectory_nees
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.room import Room
from rangeslam.mdu import slam
from rangeslam.sim.scenes import add_range_noise, random_points_in_room
from rangeslam.sim.trajectories import lemniscate, step_lengths
from rangeslam.verdict.thresholds import CHI2_LEVEL


def scene(m: int, sigma: float, rng: np.random.Generator):
    """(trajectory (M, 3), ranges (M, 7), step bounds): Fig. 5's walk, as slam_experiment draws
    it."""
    room = Room.shoebox(FIG5_ROOM_SIZE)
    traj = lemniscate(m, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    source = random_points_in_room(room, 1, rng=rng)[0]
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    ranges = add_range_noise(range_matrix(traj, landmarks), sigma, rng=rng)
    return traj, ranges, place_step_bounds(step_lengths(traj), "random", rng)


def whitened(z, m, k, ranges, bounds, sigma, d):
    """Residuals of the graph's objective: ranges over sigma, each step's moment-matched uniform
    prior and its dead zone (scale sigma); receivers (M, d) in the walk's frame, d = 2 on the
    plane z = 0, landmarks (K, 3)."""
    lower, upper = bounds
    x = z[: d * m].reshape(m, d)
    x = np.c_[x, np.zeros(m)] if d == 2 else x
    s = z[d * m :].reshape(k, 3)
    r = (np.linalg.norm(x[:, None] - s[None], axis=2) - ranges).ravel() / sigma
    steps = np.linalg.norm(np.diff(x, axis=0), axis=1)
    spread = np.maximum((upper - lower) / np.sqrt(12.0), sigma)
    dead = (np.maximum(steps - upper, 0) - np.maximum(lower - steps, 0)) / sigma
    return np.r_[r, (steps - (lower + upper) / 2) / spread, dead]


def planar_refit(result, ranges, bounds, sigma, truth):
    """The nested model from ``slam``'s ``result``: (RMS error, NEES, dof, cost gap)."""
    m, k = ranges.shape
    pts = np.vstack([result.receivers, result.sources])
    centre = result.receivers.mean(axis=0)
    axes = np.linalg.svd(result.receivers - centre)[2]
    frame = (pts - centre) @ axes.T
    args = (m, k, ranges, bounds, sigma)
    flat = least_squares(whitened, np.r_[frame[:m, :2].ravel(), frame[m:].ravel()],
                         args=(*args, 2), method="lm", xtol=1e-12, ftol=1e-12)  # fmt: skip
    full = least_squares(whitened, frame.ravel(), args=(*args, 3), method="lm",
                         xtol=1e-12, ftol=1e-12)  # fmt: skip
    info = flat.jac.T @ flat.jac
    x = 2 * m
    f_x = (
        info[:x, :x]
        - info[:x, x:] @ np.linalg.pinv(info[x:, x:], rcond=1e-9, hermitian=True) @ info[x:, :x]
    )
    truth_axes = np.linalg.svd(truth - truth.mean(axis=0))[2]
    truth_2d = (truth - truth.mean(axis=0)) @ truth_axes[:2].T
    a = align(flat.x[:x].reshape(m, 2), truth_2d, reflection=True)
    e = ((a.aligned - truth_2d) @ a.rotation).ravel()
    return a.rmse, float(e @ f_x @ e), 2 * m - 3, 2 * (flat.cost - full.cost)


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
            nees, dof = trajectory_nees(a, out.trajectory_cov, traj)
            err, p_nees, p_dof, gap = planar_refit(out, ranges, bounds, sigma, traj)
            kept = gap <= chi2.ppf(CHI2_LEVEL, m - 3)
            cell.append((a.rmse, nees, dof, err, p_nees, p_dof, kept, out.converged))
        c = np.array(cell, dtype=float)
        rows.append([m, f"{c[:, 0].mean() * 100:.2f}", f"{c[:, 3].mean() * 100:.2f}",
                     f"{c[:, 1].sum() / c[:, 2].sum():.3f}", f"{c[:, 4].sum() / c[:, 5].sum():.3f}",
                     f"{int(c[:, 6].sum())}/{len(c)}", f"{int(c[:, 7].sum())}/{len(c)}"])  # fmt: skip
    print(f"seed {opts.seed}, {opts.walks} walks per M; {machine()}")
    header = ["M", "3-D error [cm]", "planar error [cm]", "3-D NEES/dof", "planar NEES/dof",
              "plane kept (LR)", "slam converged"]  # fmt: skip
    print(markdown_table(header, rows))


if __name__ == "__main__":
    main()
