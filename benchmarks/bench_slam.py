"""Fig. 5 of the paper: acoustic range-only SLAM on the lemniscate, with and without step bounds.

    python benchmarks/bench_slam.py [--trials 50] [--seed 0] [--steps 4 5 6 8 10 15 20]

The lemniscate of eq. (12) from a random phase, steps t_n = 0.3 n (about 30 cm), room 5 x 4 x 2.6 m,
a loudspeaker uniform in the room, landmarks = the loudspeaker and its 6 first-order images. Range
noise sigma; step bounds +-20% of the true steps, or none. Trajectory error: RMS over the steps
after the best rigid motion with reflection. Three estimators: the EDM answer (convex iteration
with eq. 11), EDM + GTSAM (rangeslam.slam), and GTSAM from a GTSAM-style start (random walk and
random landmarks, no EDM). CRLB: ranges alone (inf where they do not determine the trajectory).
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam.experiments import slam_experiment


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, nargs="+", default=[4, 5, 6, 8, 10, 15, 20])
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    header = [
        "sigma",
        "bounds",
        "M",
        "EDM mean / median (cm)",
        "EDM + GTSAM mean / median (cm)",
        "GTSAM alone mean / median (cm)",
        "CRLB median (cm)",
        "EDM + GTSAM < 10 cm",
        "landmarks, EDM + GTSAM (cm)",
        "converged",
        "time median (s)",
    ]
    print(f"# Fig. 5: range-only SLAM ({args.trials} trials per row; {machine()})\n")
    print(markdown_table(header, []), flush=True)  # rows follow as they are measured
    for sigma in (1e-3, 1e-2):
        for bounds in (True, False):
            for m in args.steps:
                runs, times = [], []
                for _ in range(args.trials):
                    run, dt = timed(slam_experiment, m, sigma, bounds, rng)
                    runs.append(run)
                    times.append(dt)
                e = np.array([r.error for r in runs]) * 100
                ee = np.array([r.edm_error for r in runs]) * 100
                eb = np.array([r.baseline_error for r in runs]) * 100
                es = np.array([r.source_error for r in runs]) * 100
                crlb = np.array([r.crlb for r in runs]) * 100
                row = [
                    f"{sigma * 1e3:g} mm",
                    "+-20%" if bounds else "none",
                    m,
                    f"{ee.mean():.2f} / {np.median(ee):.2f}",
                    f"{e.mean():.2f} / {np.median(e):.2f}",
                    f"{eb.mean():.1f} / {np.median(eb):.1f}",
                    f"{np.median(crlb):.2f}",
                    f"{np.mean(e < 10) * 100:.0f}%",
                    f"{es.mean():.2f} / {np.median(es):.2f}",
                    f"{np.mean([r.converged for r in runs]) * 100:.0f}%",
                    f"{np.median(times):.2f}",
                ]
                print("| " + " | ".join(str(c) for c in row) + " |", flush=True)


if __name__ == "__main__":
    main()
