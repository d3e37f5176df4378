"""GTSAM alone on Fig. 5 with GTSAM's default Levenberg-Marquardt damping bound and with ours.

    python benchmarks/bench_slam_lm.py [--sigma 0.001] [--trials 30] [--seed 5] [--steps 5 8 10 15 20]

Same scenes as bench_slam.py (+-20% bounds), one GTSAM-style start per trial refined twice: with
lambdaUpperBound = 1e12 (rangeslam's default) and 1e5 (GTSAM's). EDM + GTSAM is rangeslam.mdu.slam.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.experiments import gtsam_style_start, slam_experiment
from rangeslam.errors import SolverError
from rangeslam.geometry.alignment import align
from rangeslam.solvers.gtsam_graph import refine_graph


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigma", type=float, default=1e-3)
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--steps", type=int, nargs="+", default=[5, 8, 10, 15, 20])
    args = ap.parse_args()
    print(
        f"# GTSAM alone vs LM damping bound (sigma {args.sigma * 1e3:g} mm, {args.trials} trials, seed {args.seed}; {machine()})\n"
    )
    header = [
        "M",
        "EDM + GTSAM median (cm)",
        "GTSAM alone, bound 1e12: median (cm) / < 10 cm",
        "GTSAM alone, bound 1e5 (GTSAM's default): median (cm) / < 10 cm",
    ]
    rows = []
    for m in args.steps:
        rng = np.random.default_rng([args.seed, m])
        errors = []
        for _ in range(args.trials):
            e = slam_experiment(m, args.sigma, True, rng)
            x0, s0 = gtsam_style_start(e.ranges, e.step_bounds, rng)
            row = [e.error]
            for bound in (1e12, 1e5):
                try:
                    fit = refine_graph(
                        x0,
                        s0,
                        e.ranges,
                        noise_std=args.sigma,
                        step_bounds=e.step_bounds,
                        covariances=False,
                        max_iterations=5000,
                        lambda_upper_bound=bound,
                    )
                    row.append(align(fit.receivers, e.trajectory, reflection=True).rmse)
                except SolverError:
                    row.append(np.inf)
            errors.append(row)
        a = np.array(errors) * 100
        med, ok = np.median(a, axis=0), np.mean(a < 10, axis=0) * 100
        rows.append(
            [m, f"{med[0]:.2f}", f"{med[1]:.2f} / {ok[1]:.0f}%", f"{med[2]:.2f} / {ok[2]:.0f}%"]
        )
        print(
            markdown_table(header, rows[-1:])
            if len(rows) == 1
            else "| " + " | ".join(map(str, rows[-1])) + " |",
            flush=True,
        )


if __name__ == "__main__":
    main()
