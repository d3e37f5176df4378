"""Does "converged" mean right? The verdict benchmark.

    python benchmarks/bench_verdicts.py --cases 500 --seed 1 --out /tmp/verdicts [--data DIR]

Simulated cases over every estimator and regime (rangeslam.evaluation.verdict_cases: each drawn
from its own integer seed, the reproduction recipe is ``make_case(estimator, regime, seed)``), and
the real-data cases (dEchorate under ``--data``, Plaza1 subsets; ``--no-real`` to skip). Each
case is classified by the truth it was built from: converged-right, converged-wrong,
flagged-right, flagged-wrong (false alarm), flagged-inconsistent-call (a right estimate flagged
INCONSISTENT when the noise_std passed was a third of the truth's). Writes ``verdicts.csv`` (one
row per case) to ``--out`` and prints a Markdown table per estimator x regime with a total row
and the false-alarm rates (``false_alarm_text``). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import csv
import signal
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from _common import machine, markdown_table

from rangeslam.datasets import data_root
from rangeslam.evaluation.verdict_cases import (
    OUTCOMES,
    CaseOutcome,
    draw_cases,
    real_cases,
    run_case,
)

#: The folder holding dechorate/: $RANGESLAM_DATA, else ../shared/data (rangeslam.datasets).
DEFAULT_DATA = data_root()
#: Share of the simulated cases per estimator (chosen for the run time: calibrate's robust
#: regimes take up to a minute a case, multilateration milliseconds).
WEIGHTS = {
    "multilaterate": 0.40,
    "calibrate": 0.11,
    "slam": 0.20,
    "reconstruct_room": 0.20,
    "calibrate_unknown_emission": 0.09,
}
COLUMNS = ("estimator", "regime", "seed", "identifiable", "status", "message", "error", "bound",
           "scale", "classification", "seconds")  # fmt: skip
HEADER = ["estimator", "regime", "cases", *OUTCOMES, "foreign exceptions", "timeouts"]


def _row(o: CaseOutcome) -> list:
    c = o.case
    return [c.estimator, c.regime, c.seed, c.identifiable, o.status, o.message.replace("\n", " "),
            f"{o.error:.6g}", f"{o.bound:.6g}", f"{c.scale:.4g}", o.classification,
            f"{o.seconds:.2f}"]  # fmt: skip


class CaseTimeout(BaseException):
    """A case ran past --timeout (a BaseException, so that run_case does not record it as the
    estimator's own exception)."""


def _alarm(signum, frame):
    raise CaseTimeout


def _run(case, timeout: int) -> CaseOutcome:
    """run_case under a SIGALRM of ``timeout`` seconds; past it the row's classification is
    "timeout" (neither converged nor flagged: a run too slow to be used)."""
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout)
    t0 = time.perf_counter()
    try:
        return run_case(case)
    except CaseTimeout:
        msg = f"no answer within {timeout} s"
        return CaseOutcome(case, "timeout", msg, float("nan"), case.bound, "timeout",
                           time.perf_counter() - t0)  # fmt: skip
    finally:
        signal.alarm(0)


def summary_rows(records: list[tuple[str, str, str]]) -> list[list]:
    """Per estimator x regime (``records``: (estimator, regime, classification) per case): cases,
    the classes of OUTCOMES, foreign exceptions, timeouts; then the total with the false-alarm
    rates (:func:`false_alarm_text`)."""
    groups: dict[tuple[str, str], Counter] = defaultdict(Counter)
    for est, regime, classification in records:
        groups[est, regime][classification] += 1
    rows, total = [], Counter()
    for (est, regime), n in groups.items():
        total.update(n)
        rows.append(
            [
                est,
                regime,
                sum(n.values()),
                *[n[k] for k in OUTCOMES],
                n["foreign-exception"],
                n["timeout"],
            ]
        )
    rows.append(["**total**", false_alarm_text(total), sum(total.values()),
                 *[total[k] for k in OUTCOMES], total["foreign-exception"],
                 total["timeout"]])  # fmt: skip
    return rows


def false_alarm_text(total: Counter) -> str:
    """The false-alarm rate two ways: the strict count (every flag on a right estimate, over the right
    estimates) and with a right flag of a contradicted call ("flagged-inconsistent-call": the
    noise_std passed was a third of the truth's, and the status says INCONSISTENT) not counted
    as a false alarm, over the cases where CONVERGED is the right verdict."""
    called = total["flagged-inconsistent-call"]
    wrong = total["flagged-wrong"]
    right = total["converged-right"] + wrong
    flags, cases = wrong + called, right + called
    issue = f"{flags}/{cases} = {100 * flags / max(cases, 1):.1f}%"
    restated = f"{wrong}/{right} = {100 * wrong / max(right, 1):.1f}%"
    return (
        f"false alarms {issue} (strict count); {restated} without INCONSISTENT on a "
        "contradicted call"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=500, help="simulated cases (real ones are added)")
    ap.add_argument("--seed", type=int, default=None, help="seed of the case draw (default: fresh)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--summarise", type=Path, help="only print the table of a verdicts.csv")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--no-real", action="store_true")
    ap.add_argument("--timeout", type=int, default=300, help="seconds per case (default 300)")
    ap.add_argument(
        "--only",
        nargs="+",
        metavar="ESTIMATOR",
        help="run only these estimators' cases (drawn as in the full run: the same seeds)",
    )
    args = ap.parse_args()
    if args.summarise is not None:
        with open(args.summarise, newline="") as f:
            rows = [(r["estimator"], r["regime"], r["classification"]) for r in csv.DictReader(f)]
        print(f"## Verdict benchmark: {len(rows)} cases from {args.summarise}\n")
        print(markdown_table(HEADER, summary_rows(rows)))
        return
    if args.out is None:
        ap.error("--out is required")
    args.out.mkdir(parents=True, exist_ok=True)
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    notes, cases = [], []
    if not args.no_real:  # first, so that an interrupted run still has them
        cases, notes = real_cases(args.data)
    cases += draw_cases(args.cases, seed, weights=WEIGHTS)
    if args.only:
        cases = [c for c in cases if c.estimator in args.only]
    for note in notes:
        print(note, file=sys.stderr)
    outcomes, t0 = [], time.perf_counter()
    with open(args.out / "verdicts.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(COLUMNS)
        for i, case in enumerate(cases):
            o = _run(case, args.timeout)
            outcomes.append(o)
            out.writerow(_row(o))
            f.flush()
            print(f"[{i + 1}/{len(cases)} {time.perf_counter() - t0:.0f}s] {case.estimator} | "
                  f"{case.regime} | {o.classification} ({o.seconds:.1f}s)", file=sys.stderr)  # fmt: skip
    print(f"## Verdict benchmark: {len(outcomes)} cases, seed {seed} ({machine()})\n")
    records = [(o.case.estimator, o.case.regime, o.classification) for o in outcomes]
    print(markdown_table(HEADER, summary_rows(records)))
    print(f"\n{time.perf_counter() - t0:.0f} s in all. " + " ".join(notes))


if __name__ == "__main__":
    main()
