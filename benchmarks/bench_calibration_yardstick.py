"""Calibration against its two yardsticks: the oracle and the Cramer-Rao bound.

    python benchmarks/bench_calibration_yardstick.py [--trials 20] [--seed 0] [--jobs 2]
        [--wrong-picks]

The calibration cells of the regime map (Fig. 3's 6 microphones x the loudspeaker and its 5
nearest first-order images, and 12 x 12 in random rooms; 1 mm and 1 cm; with ``--wrong-picks``
also 5% wrong picks at 1 cm, where each trial takes about a minute),
``--trials`` scenes each, the methods of the regime map on the same ranges: ``calibrate``, trace
minimisation alone, least squares from one random start, and best of k random starts at
``calibrate``'s wall time. The oracle is least squares on the ranges from the truth (Huber with
wrong picks). Per cell: the RMS of the per-scene receiver-gauge CRLBs, the oracle's RMS error and
their ratio; the bound is quoted only where the oracle is within 10% of it. Per method: RMS error
over the oracle's (the search), and over the bound where it is attained.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from _common import machine, markdown_table

from rangeslam.app.calibration_regimes import (
    CALIBRATION_METHODS,
    calibration_cells,
    run_calibration_trial,
)
from rangeslam.app.regime_map import yardstick

NAMES = {
    "calibrate": "calibrate",
    "trace_min": "trace min.",
    "ls_1": "LS, 1 start",
    "ls_k": "LS, best of k",
}


def _trial(task: tuple) -> dict:
    cell, trial, seed = task
    return run_calibration_trial(cell, trial, seed)


def cell_row(label: str, rows: list[dict]) -> list[str]:
    """The Markdown row of one cell: bound, oracle, ratio, attained; per method RMS and ratios."""
    ref = yardstick(rows, "calibrate")
    attained = "attained" if ref.attained else "not attained: oracle only"
    bound = f"{ref.rms_bound * 1e3:.3g}" if ref.attained else f"({ref.rms_bound * 1e3:.3g})"
    out = [label, str(len(rows)), bound, f"{ref.rms_oracle * 1e3:.3g}"]
    out += [f"{ref.efficiency:.2f}", attained]
    for method in CALIBRATION_METHODS:
        c = yardstick(rows, method)
        ratio = f"{c.ratio:.2f}" if c.attained else "-"
        out.append(f"{c.rms_error * 1e3:.3g}, {c.search:.2f}, {ratio}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--wrong-picks", action="store_true", help="also the cells with wrong picks")
    args = ap.parse_args()
    cells = [c for c in calibration_cells() if args.wrong_picks or not c.wrong]
    tasks = [(cell, t, args.seed) for cell in cells for t in range(args.trials)]
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for row in pool.map(_trial, tasks):
            rows.append(row)
            print(f"{len(rows)}/{len(tasks)} trials, {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr)  # fmt: skip
    header = ["cell", "trials", "RMS CRLB (mm)", "oracle RMS (mm)", "oracle / CRLB", "bound"]
    header += [f"{NAMES[m]}: RMS (mm), / oracle, / CRLB" for m in CALIBRATION_METHODS]
    table = []
    for cell in cells:
        mine = [r for r in rows if r["regime"] == cell.label and r["status"] == "ok"]
        table.append(cell_row(cell.label, mine))
    print(f"# Calibration: the oracle and the bound (seed {args.seed}; {machine()})\n")
    print(markdown_table(header, table))
    print(f"\n{len(tasks)} trials in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
