"""Zero-knowledge calibration on real echoes: the 30 dEchorate microphones from echoes alone.

    python benchmarks/bench_dechorate_calibration.py [--data dechorate]

Ranges from the 30 microphones to the 14 virtual sources of loudspeakers 0 and 1 (direct path and
six first-order echoes each); positions unknown to the solver. Microphone error: distance to the
dataset's calibrated position after the best rigid motion (with reflection) of all 30. The picks
include whole arrays that heard a wrong echo (up to 59 cm off), hence the robust mode; the plain
mode is shown for contrast. Cite: Di Carlo et al., "dEchorate: a calibrated room impulse response
dataset for echo-aware signal processing", EURASIP JASMP 2021.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import align, calibrate
from rangeslam.datasets import load_dechorate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        default="dechorate",
        help="a path, or a name under $RANGESLAM_DATA (else ../shared/data)",
    )
    args = ap.parse_args()
    data = load_dechorate(args.data)
    ranges = np.hstack([data.ranges(0), data.ranges(1)])
    configs = [
        ("plain", None, 4, 3),
        ("robust", None, 4, 3),
        ("robust", 0.005, 4, 3),
        ("robust", 0.01, 4, 3),
        ("robust", 0.02, 4, 3),
        ("robust", 0.01, 4, 10),
        ("robust", 0.01, 8, 3),
    ]
    rows = []
    for mode, noise, attempts, iterations in configs:
        out, dt = timed(
            calibrate,
            ranges,
            noise_std=noise,
            robust=mode == "robust",
            max_attempts=attempts,
            max_iterations=iterations,
            random_starts=0,
            rng=np.random.default_rng(0),
        )
        err = align(out.receivers, data.mics, reflection=True).errors * 100
        rows.append(
            [
                mode,
                "unknown" if noise is None else f"{noise * 100:g} cm",
                f"{attempts} x {iterations}",
                f"{np.median(err):.2f}",
                f"{err.max():.2f}",
                f"{out.n_outliers}/{ranges.size}",
                out.converged,
                f"{dt:.1f}",
            ]
        )
    print(f"## dEchorate zero-knowledge calibration, 30 microphones x 14 sources ({machine()})\n")
    print(
        markdown_table(
            [
                "mode",
                "noise_std",
                "attempts x SDP iterations",
                "median mic error [cm]",
                "worst mic [cm]",
                "ranges dropped",
                "converged",
                "time [s]",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    main()
