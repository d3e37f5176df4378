"""Does calibrate stop at a worse minimum than least squares reaches from the truth?

    python benchmarks/bench_calibration_minima.py [--scenes 100] [--seed 19617] [--factors 1 3]

Fig. 3 scenes (``fig3_scene``: 6 microphones in a 1 m cube, a loudspeaker and its 5 nearest
first-order images) at 1 mm range noise, ``calibrate(noise_std=factor * 1 mm)``: the noise level
right, and declared too large (the chi-square test then accepts more). Scene i is
``fig3_scene(default_rng(seed + i))``, its noise ``default_rng(seed + i + 7919)``. A converged
answer is wrong when its receivers are more than 3 times their Cramer-Rao RMS bound off; the
oracle is least squares from the truth, and "cost / oracle" is the answer's sum of squared
residuals over the oracle's (1.000: the answer is the oracle's minimum, so the error is the
estimator's, not the search's).
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import align, calibrate, mdu_crlb
from rangeslam.app.experiments import fig3_scene
from rangeslam.geometry.edm import range_matrix
from rangeslam.solvers.least_squares import refine_unfolding

SIGMA = 1e-3  # m


def one_scene(seed: int, factor: float) -> dict:
    """One Fig. 3 scene calibrated with noise_std = factor * SIGMA: status, errors, cost ratio."""
    scene = fig3_scene(np.random.default_rng(seed))
    noise = SIGMA * np.random.default_rng(seed + 7919).standard_normal(scene.ranges.shape)
    ranges = scene.ranges + noise
    res, seconds = timed(calibrate, ranges, noise_std=factor * SIGMA, rng=seed)
    oracle = refine_unfolding(scene.mics, scene.sources, ranges, np.ones(ranges.shape, bool))
    cost = float(np.sum((range_matrix(res.receivers, res.sources) - ranges) ** 2))
    return {
        "seed": seed,
        "converged": res.converged,
        "error": align(res.receivers, scene.mics, reflection=True).rmse,
        "oracle_error": align(oracle.receivers, scene.mics, reflection=True).rmse,
        "bound": mdu_crlb(scene.mics, scene.sources, SIGMA).receiver_rmse,
        "cost_ratio": cost / float(np.sum(oracle.residuals**2)),
        "seconds": seconds,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=19617)
    ap.add_argument("--factors", type=float, nargs="+", default=[1.0, 3.0])
    args = ap.parse_args()
    print(f"## Calibration minima, {args.scenes} Fig. 3 scenes at 1 mm, seed {args.seed} "
          f"({machine()})\n")  # fmt: skip
    summary, wrong_rows = [], []
    for factor in args.factors:
        runs = [one_scene(args.seed + i, factor) for i in range(args.scenes)]
        converged = [r for r in runs if r["converged"]]
        wrong = [r for r in converged if r["error"] > 3 * r["bound"]]
        summary.append([f"{factor:g} x", f"{len(converged)}/{len(runs)}", len(wrong),
                        f"{np.median([r['seconds'] for r in runs]):.2f}"])  # fmt: skip
        wrong_rows += [[f"{factor:g} x", r["seed"], f"{100 * r['error']:.2f}",
                        f"{100 * r['oracle_error']:.2f}", f"{100 * r['bound']:.2f}",
                        f"{r['cost_ratio']:.3f}"] for r in wrong]  # fmt: skip
    header = ["noise_std / true", "converged", "converged beyond 3x bound", "median time [s]"]
    print(markdown_table(header, summary))
    if wrong_rows:
        header = ["noise_std / true", "scene seed", "error [cm]", "oracle error [cm]",
                  "bound [cm]", "cost / oracle"]  # fmt: skip
        print("\n" + markdown_table(header, wrong_rows))


if __name__ == "__main__":
    main()
