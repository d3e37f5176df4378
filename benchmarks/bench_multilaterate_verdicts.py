"""multilaterate's verdict on many cases of a few regimes, and its time per call.

    python benchmarks/bench_multilaterate_verdicts.py counts --seed 76029489 --cases 300
    python benchmarks/bench_multilaterate_verdicts.py time --seed 75358373 --repeats 10

``counts``: ``--cases`` cases of each of the verdict benchmark's multilaterate regimes "d+1
anchors", "nearly coplanar" and "noise_std not given" (rangeslam.evaluation.verdict_cases, each
drawn from its own seed taken from ``--seed``), classified as the verdict benchmark does.
``time``: the median seconds per call of each multilaterate case of ``bench_verdicts.py --cases
300 --seed SEED`` (the same draws), over ``--repeats`` calls each, per regime and over all.
Run it with PYTHONPATH set to the checkout to measure.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections import Counter

import numpy as np
from bench_verdicts import WEIGHTS

from rangeslam.errors import RangeSlamError
from rangeslam.evaluation.verdict_cases import draw_cases, make_case, run_case

REGIMES = ("d+1 anchors", "nearly coplanar", "noise_std not given")


def counts(seed: int, n: int) -> None:
    """Classification counts of ``n`` cases per regime of REGIMES."""
    rng = np.random.default_rng(seed)
    for regime in REGIMES:
        seeds = [int(rng.integers(2**31)) for _ in range(n)]
        found = Counter(
            run_case(make_case("multilaterate", regime, s)).classification for s in seeds
        )
        print(regime, dict(sorted(found.items())))


def timing(seed: int, repeats: int) -> None:
    """Median milliseconds per call, per regime and over all multilaterate cases."""
    cases = [c for c in draw_cases(300, seed, weights=WEIGHTS) if c.estimator == "multilaterate"]
    per: dict[str, list[float]] = {}
    for case in cases:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            # a refused case (too few anchors: a package error) is timed as well
            with contextlib.suppress(RangeSlamError):
                case.run()
            times.append(time.perf_counter() - t0)
        per.setdefault(case.regime, []).append(float(np.median(times)))
    for regime, values in per.items():
        print(f"{regime:22s} median {1e3 * np.median(values):8.3f} ms")
    every = np.concatenate(list(per.values()))
    print(
        f"{'all':22s} median {1e3 * np.median(every):8.3f} ms  mean {1e3 * np.mean(every):8.3f} ms"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("counts", "time"))
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--cases", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args()
    if args.what == "counts":
        counts(args.seed, args.cases)
    else:
        timing(args.seed, args.repeats)


if __name__ == "__main__":
    main()
