"""Unsynchronised microphones and unknown emission times: the xtdoa real data and a simulation.

    python benchmarks/bench_xtdoa.py real [--data xtdoa] [--subsets 200] [--sizes 6 8 11]
    python benchmarks/bench_xtdoa.py sim [--draws 100] [--noisy 40]
    python benchmarks/bench_xtdoa.py robust [--runs 3] [--seed 0]

real: the authors' protocol (El Badawy, Larsson, Pollefeys, Dokmanic, "Localizing unsynchronized
sensors with unknown sources", arXiv 2102.03565; their data, MIT licence): random subsets of K of
the 23 clean events, each event its own offset and each microphone its own clock offset; the
mean microphone error after a similarity alignment (their figure) and a rigid one; time per solve.
Also, per subset, whether the answer is the least-squares fit started from the truth (microphones
at their measured positions, sources fitted to all 23 clean events with the microphones held):
the global search is then as good as the model allows.

robust: all 65 events without the authors' mask W (calibrate_unknown_emission with
receiver_offsets=True, robust=True), ``--runs`` seeds: the inlier decision against W (arrivals and
whole events), the microphones' errors, seconds.

sim: M = K = 12 in a 10 x 10 x 3 m room, offsets uniform in +-3 m: exact recovery (1e-6 m) at zero
noise in ``--draws`` configurations; at 1 mm, the receivers' RMS error (rigid alignment) against
the RMS of the per-draw Cramer-Rao bounds with both offset kinds unknown.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.xtdoa_bench import (
    fit_from_reference,
    reference_sources,
    robust_row,
    robust_table,
    subset_rows,
    summary_rows,
    summary_table,
)
from rangeslam.datasets import xtdoa
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.clock_offsets import clock_offsets_crlb
from rangeslam.mdu.emission import calibrate_unknown_emission

ROOM = np.array([10.0, 10.0, 3.0])


def real(args) -> None:
    data = xtdoa(args.data)
    sources = reference_sources(data)
    rows = subset_rows(data, args.sizes, args.subsets, seed=args.seed)
    same = {}
    for r in rows:
        cols = np.array([int(c) for c in r["columns"].split()])
        gap = abs(r["similarity_error_m"] - fit_from_reference(data, cols, sources))
        same.setdefault(r["K"], []).append(gap < 1e-3)
    header, table = summary_table(summary_rows(rows))
    header.append("= fit from truth")
    for line in table:
        line.append(f"{100 * np.mean(same[int(line[0])]):.0f}%")
    print(markdown_table(header, table))


def robust(args) -> None:
    data = xtdoa(args.data)
    rows = []
    for seed in range(args.seed, args.seed + args.runs):
        rows.append(robust_row(data, seed))
        print(rows[-1], flush=True)
    print(markdown_table(*robust_table(rows)))


def simulate(args) -> None:
    rng = np.random.default_rng(args.seed)
    exact, times = 0, []
    for _ in range(args.draws):
        x, s, t = _scene(rng)
        t0 = time.perf_counter()
        out = calibrate_unknown_emission(
            t, np.arange(12), receiver_offsets=True, noise_std=0.0, rng=rng
        )
        times.append(time.perf_counter() - t0)
        exact += bool(align(out.receivers, x, reflection=True).errors.max() < 1e-6)
    err2, bound2, conv = [], [], 0
    for _ in range(args.noisy):
        x, s, t = _scene(rng)
        noisy = t + 1e-3 * rng.standard_normal(t.shape)
        out = calibrate_unknown_emission(
            noisy, np.arange(12), receiver_offsets=True, noise_std=1e-3, rng=rng
        )
        conv += out.converged
        err2.append(np.mean(align(out.receivers, x, reflection=True).errors ** 2))
        bound2.append(clock_offsets_crlb(x, s, 1e-3) ** 2)
    rms, bound = np.sqrt(np.mean(err2)), np.sqrt(np.mean(bound2))
    print(
        markdown_table(
            ["case", "figure"],
            [
                ["zero noise: exact to 1e-6 m", f"{exact}/{args.draws}"],
                [
                    "zero noise: median (max) s per solve",
                    f"{np.median(times):.2f} ({max(times):.2f})",
                ],
                ["1 mm: converged", f"{conv}/{args.noisy}"],
                ["1 mm: receivers RMS error [mm]", f"{1e3 * rms:.2f}"],
                ["1 mm: RMS of the CRLB [mm]", f"{1e3 * bound:.2f}"],
                ["1 mm: ratio", f"{rms / bound:.3f}"],
            ],
        )
    )


def _scene(rng):
    x = rng.uniform(0, 1, (12, 3)) * ROOM
    s = rng.uniform(0, 1, (12, 3)) * ROOM
    a, b = rng.uniform(-3, 3, 12), rng.uniform(-3, 3, 12)
    return x, s, range_matrix(x, s) + a[:, None] + b[None, :]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=("real", "sim", "robust"))
    ap.add_argument(
        "--data",
        default="xtdoa",
        help="a path, or a name under $RANGESLAM_DATA (else ../shared/data)",
    )
    ap.add_argument("--subsets", type=int, default=200)
    ap.add_argument("--sizes", type=int, nargs="+", default=list(range(6, 22)))
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--noisy", type=int, default=40)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(machine())
    t0 = time.perf_counter()
    {"real": real, "sim": simulate, "robust": robust}[args.part](args)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
