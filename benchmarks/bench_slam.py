"""Fig. 5 of the paper: acoustic range-only SLAM on the lemniscate, with and without step bounds.

    python benchmarks/bench_slam.py [--trials 50] [--seed 0] [--steps 4 5 6 8 10 15 20]
        [--sigmas 0.001 0.01] [--bounds both|with|without] [--step-prior uniform|dead_zone]
        [--placement centred|random] [--extra-starts 0]

The lemniscate of eq. (12) from a random phase, steps t_n = 0.3 n (about 30 cm), room 5 x 4 x 2.6 m,
a loudspeaker uniform in the room, landmarks = the loudspeaker and its 6 first-order images. Range
noise sigma; step bounds +-20% of the true steps, or none. Trajectory error: RMS over the steps
after the best rigid motion with reflection. Three estimators: the EDM answer (convex iteration
with eq. 11), EDM + GTSAM (rangeslam.mdu.slam), and GTSAM from a GTSAM-style start (random walk and
random landmarks, no EDM), with the same step prior. Yardstick: the RMS error over the trials
against the RMS of the per-trial CRLBs with the step prior the methods use (rms_against_bound:
their ratio and regime; trials whose bound is inf are not identifiable, counted and left out),
and the RMS CRLB of the ranges alone beside it. NEES: of the whole trajectory against EDM + GTSAM's covariance, mean
over the trials divided by its dof (1 for a consistent estimator), with the 95% chi-square band.
Time: the rangeslam.mdu.slam call alone.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.benchmarking import BOUND_SETTINGS
from rangeslam.app.experiments import slam_experiment
from rangeslam.evaluation.metrics import mean_nees, rms_against_bound


def against_bound(errors_m, bounds_m) -> str:
    """'RMS (cm), ratio x regime; median (cm)' of one method over the trials of a row."""
    c = rms_against_bound(errors_m, bounds_m)
    med = np.median(errors_m) * 100
    if not c.trials:
        return f"- ({c.regime}); {med:.2f}"
    return f"{c.rms_error * 100:.2f}, {c.ratio:.2f}x {c.regime}; {med:.2f}"


def rms_bound(bounds_m) -> str:
    """RMS of the finite per-trial bounds (cm), and how many were inf."""
    c = rms_against_bound(bounds_m, bounds_m)
    text = f"{c.rms_bound * 100:.2f}" if c.trials else "inf"
    return text + (f" ({c.unidentifiable} inf)" if c.trials and c.unidentifiable else "")


def nees_summary(runs) -> str:
    """Mean NEES / dof over the trials with covariances, and the 95% chi-square band of that mean
    for a consistent estimator."""
    mean, lo, hi = mean_nees([r.nees for r in runs], [r.nees_dof for r in runs])
    return "-" if np.isnan(mean) else f"{mean:.2f} [{lo:.2f}, {hi:.2f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, nargs="+", default=[4, 5, 6, 8, 10, 15, 20])
    ap.add_argument("--sigmas", type=float, nargs="+", default=[1e-3, 1e-2], help="metres")
    ap.add_argument("--bounds", choices=list(BOUND_SETTINGS), default="both")
    ap.add_argument("--step-prior", choices=["uniform", "dead_zone"], default="uniform")
    ap.add_argument("--placement", choices=["centred", "random"], default="centred")
    ap.add_argument("--extra-starts", type=int, default=0, help="slam's extra_starts")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    header = [
        "sigma",
        "bounds",
        "M",
        "RMS CRLB with step prior (cm)",
        "RMS CRLB ranges only (cm)",
        "EDM: RMS (cm), / CRLB, regime; median",
        "EDM + GTSAM: RMS (cm), / CRLB, regime; median",
        "GTSAM alone: RMS (cm), / CRLB, regime; median",
        "< 10 cm: EDM + GTSAM / GTSAM alone",
        "landmarks, EDM + GTSAM (cm)",
        "NEES / dof [95% band]",
        "converged",
        "time median (s)",
    ]
    print(
        f"# Fig. 5: range-only SLAM ({args.trials} trials per row, seed {args.seed}, step prior "
        f"{args.step_prior}, bounds {args.placement}, extra starts {args.extra_starts}; "
        f"{machine()})\n"
    )
    print(markdown_table(header, []), flush=True)  # rows follow as they are measured
    with_bounds = BOUND_SETTINGS[args.bounds]
    for sigma in args.sigmas:
        for bounds in with_bounds:
            for m in args.steps:
                runs = [
                    slam_experiment(
                        m,
                        sigma,
                        bounds,
                        rng,
                        bounds_placement=args.placement,
                        step_prior=args.step_prior,
                        extra_starts=args.extra_starts,
                    )
                    for _ in range(args.trials)
                ]
                e = np.array([r.error for r in runs])
                eb = np.array([r.baseline_error for r in runs])
                es = np.array([r.source_error for r in runs]) * 100
                crlb = np.array([r.crlb for r in runs])
                row = [
                    f"{sigma * 1e3:g} mm",
                    "+-20%" if bounds else "none",
                    m,
                    rms_bound(crlb),
                    rms_bound(np.array([r.crlb_ranges for r in runs])),
                    against_bound(np.array([r.edm_error for r in runs]), crlb),
                    against_bound(e, crlb),
                    against_bound(eb, crlb),
                    f"{np.mean(e < 0.1) * 100:.0f}% / {np.mean(eb < 0.1) * 100:.0f}%",
                    f"{es.mean():.2f} / {np.median(es):.2f}",
                    nees_summary(runs),
                    f"{np.mean([r.converged for r in runs]) * 100:.0f}%",
                    f"{np.median([r.seconds for r in runs]):.2f}",
                ]
                print("| " + " | ".join(str(c) for c in row) + " |", flush=True)


if __name__ == "__main__":
    main()
