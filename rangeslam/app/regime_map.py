"""Run the regime map (:mod:`rangeslam.app.regimes`) and summarise it, one table per figure of merit.

    from rangeslam.app.regime_map import regime_map, regime_tables
    rows = regime_map(trials=10, seed=0, jobs=2)
    for title, header, table in regime_tables(rows): ...

Figures of merit per cell and method: success (trajectory RMS error under 10 cm), the RMS error
over the trials against the RMS of the per-trial Cramer-Rao bounds (with the step prior; trials
whose bound is infinite are left out and counted as not identifiable), median and 90th percentile
of the error, median landmark error, median wall time, median GTSAM iterations, and the share of
trials a method's own verdict flagged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict

import numpy as np

from rangeslam.app.regimes import MAX_RANDOM_STARTS, REGIME_METHODS, RegimeCell, run_regime_trial
from rangeslam.errors import InvalidInputError

__all__ = [
    "MERITS",
    "METHOD_LABELS",
    "cell_of_row",
    "criterion_table",
    "regime_map",
    "regime_tables",
]

METHOD_LABELS = {
    "calibrate": "calibrate (EDM + LS)",
    "trace_min": "trace minimisation alone",
    "ls_1": "LS, 1 random start",
    "ls_k": "LS, best of k (equal time)",
    "edm": "EDM only",
    "edm_gtsam": "EDM + GTSAM",
    "gtsam_1": "GTSAM, 1 random start",
    "gtsam_k": "GTSAM, best of k (equal time)",
    "ekf": "EKF",
    "ekf_rts": "EKF + RTS",
}


def one_trial(task: tuple) -> dict:
    """``run(cell, trial, seed, max_starts=max_starts)`` of the task (run, cell, trial, seed,
    max_starts), for a pool; a trial that raises is a row whose status says why."""
    run, cell, trial, seed, max_starts = task
    try:
        return run(cell, trial, seed, max_starts=max_starts)
    except Exception as exc:  # a failing trial is recorded, and the map goes on
        why = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        return {
            "regime": cell.label, **asdict(cell), "trial": trial, "seed": seed,
            "status": f"failed: {why}",
        }  # fmt: skip


def regime_map(
    cells: Sequence,
    *,
    trials: int,
    seed: int,
    jobs: int = 1,
    max_starts: int = MAX_RANDOM_STARTS,
    on_row: Callable[[dict], None] | None = None,
    run: Callable[..., dict] = run_regime_trial,
) -> list[dict]:
    """Every method on ``trials`` scenes of each of ``cells``, over ``jobs`` processes: the rows
    of ``run`` (:func:`~rangeslam.app.regimes.run_regime_trial` for SLAM cells,
    :func:`~rangeslam.app.calibration_regimes.run_calibration_trial` for calibration ones; the
    random-start peers take at most ``max_starts`` starts) in the order of the cells and trials.
    ``on_row`` is called with each row as it finishes (progress, writing as it goes)."""
    if not (isinstance(trials, int) and trials >= 1):
        raise InvalidInputError(f"trials must be a positive integer; got {trials!r}")
    if not (isinstance(jobs, int) and jobs >= 1):
        raise InvalidInputError(f"jobs must be a positive integer; got {jobs!r}")
    tasks = [(run, cell, t, int(seed), int(max_starts)) for cell in cells for t in range(trials)]
    if jobs == 1:
        rows = []
        for task in tasks:
            rows.append(one_trial(task))
            if on_row is not None:
                on_row(rows[-1])
        return rows
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(one_trial, task) for task in tasks]
        for f in as_completed(futures):
            if on_row is not None:
                on_row(f.result())
        return [f.result() for f in futures]


def cell_of_row(row: dict) -> RegimeCell:
    """The :class:`RegimeCell` a row was drawn in."""
    return RegimeCell(
        row["walk"], int(row["m"]), bool(row["bounds"]), float(row["sigma"]), int(row["dim"]),
        float(row["missing"]), float(row["wrong"]),
    )  # fmt: skip


def finite(values) -> np.ndarray:
    """The finite values of ``values`` as floats (failed methods have NaN)."""
    v = np.asarray(values, dtype=float)
    return v[np.isfinite(v)]


def success_share(rows: list[dict], method: str) -> float:
    """Share of the trials in which ``method`` succeeded (error under the success threshold)."""
    return float(np.mean([r[f"{method}_success"] for r in rows]))


def success_text(rows: list[dict], method: str) -> str:
    """Share of trials with a trajectory error under 10 cm, percent."""
    return f"{100 * success_share(rows, method):.0f}%"


def yardstick(rows: list[dict], method: str):
    """``method``'s RMS error against the oracle and the bound over ``rows``
    (:func:`rangeslam.evaluation.metrics.rms_against_bound`); rows without an oracle (older
    CSVs) leave it out (NaN)."""
    from rangeslam.evaluation.metrics import rms_against_bound

    return rms_against_bound(
        [r[f"{method}_error_m"] for r in rows],
        [r["crlb_m"] for r in rows],
        [r.get("oracle_error_m", np.nan) for r in rows],
    )


def bound_text(rows: list[dict], method: str) -> str:
    """RMS error over the trials / the oracle's, and / the RMS bound where the oracle attains it
    (else "oracle only"); how many trials were unidentifiable."""
    c = yardstick(rows, method)
    if not c.trials:
        return f"- ({c.regime})"
    text = f"{c.search:.2f}x oracle, " + (f"{c.ratio:.2f}x bound" if c.attained else "oracle only")
    return text + (f" ({c.unidentifiable} n.i.)" if c.unidentifiable else "")


def column_quantile(rows: list[dict], key: str, q: float) -> float:
    """The ``q`` quantile of a column's finite values; NaN when there are none (or when the rows
    have no such column: calibration has no landmark error)."""
    v = finite([r.get(key, np.nan) for r in rows])
    return float(np.quantile(v, q)) if v.size else float("nan")


def quantile_text(rows: list[dict], key: str, q: float, scale: float, fmt: str) -> str:
    """:func:`column_quantile` times ``scale``, formatted; "-" when there is none."""
    value = column_quantile(rows, key, q)
    return "-" if np.isnan(value) else format(scale * value, fmt)


#: The methods that judge their own answer (a status); the others only fail or not.
JUDGED = ("edm_gtsam", "ekf", "ekf_rts", "calibrate")


def flagged_text(rows: list[dict], method: str) -> str:
    """Share of trials the method's verdict flagged or in which it failed, percent; for the
    methods without a verdict, "failed" and the share in which they failed."""
    share = f"{100 * np.mean([r[f'{method}_status'] != 'ok' for r in rows]):.0f}%"
    return share if method in JUDGED else f"failed {share}"


#: (title, text of one method in one cell) for each table of :func:`regime_tables`.
MERITS: dict[str, Callable[[list[dict], str], str]] = {
    "success (SLAM: error < 10 cm; calibration: < 5 cm)": success_text,
    "RMS error / the oracle's, and / RMS bound where the oracle attains it (n.i.: trials not "
    "identifiable)": bound_text,
    "median error [cm]": lambda rows, m: quantile_text(rows, f"{m}_error_m", 0.5, 100, ".2f"),
    "90th percentile of the error [cm]": lambda rows, m: quantile_text(
        rows, f"{m}_error_m", 0.9, 100, ".2f"
    ),
    "median landmark error [cm]": lambda rows, m: quantile_text(
        rows, f"{m}_landmark_error_m", 0.5, 100, ".1f"
    ),
    "median time [s]": lambda rows, m: quantile_text(rows, f"{m}_seconds", 0.5, 1, ".3f"),
    "median GTSAM iterations (random starts used)": lambda rows, m: (
        quantile_text(rows, f"{m}_iterations", 0.5, 1, ".0f")
        + (f" ({quantile_text(rows, f'{m}_starts', 0.5, 1, '.0f')})" if m == "gtsam_k" else "")
    ),
    "flagged by its own verdict, or failed": flagged_text,
}


def rows_by_cell(rows: Sequence[dict]) -> dict[str, list[dict]]:
    """The rows of finished trials (status "ok") grouped by their regime's label, in the order
    of first appearance."""
    cells: dict[str, list[dict]] = {}
    for r in rows:
        if r["status"] == "ok":
            cells.setdefault(r["regime"], []).append(r)
    return cells


def regime_tables(
    rows: Sequence[dict], methods: Sequence[str] = REGIME_METHODS, merits=None
) -> list[tuple[str, list[str], list[list[str]]]]:
    """One (title, header, table) per figure of merit (``merits``, default :data:`MERITS`, or
    the titles of it to keep): a row per regime (its label and trial count), a column per
    method."""
    keep = MERITS if merits is None else {t: MERITS[t] for t in merits}
    cells = rows_by_cell(rows)
    header = ["regime", "trials"] + [METHOD_LABELS[m] for m in methods]
    out = []
    for title, text in keep.items():
        table = [
            [label, str(len(cell_rows))] + [text(cell_rows, m) for m in methods]
            for label, cell_rows in cells.items()
        ]
        out.append((title, header, table))
    return out


#: Two 90th percentiles within this relative (and :data:`P90_TIE_M` absolute) margin are one:
#: methods that reach the same minimum differ by LM's tolerance, not by a better answer.
P90_TIE_RTOL = 0.01
P90_TIE_M = 1e-4


def criterion_row(label: str, rows: list[dict], lead: str, peers: Sequence[str], rival: str):
    """One cell of :func:`criterion_table`: the lead's success against the best peer's, its
    90th percentile of the error against ``rival``'s, and what fails."""
    success = {m: success_share(rows, m) for m in (lead, *peers)}
    best = max(peers, key=lambda m: success[m])
    p90 = {m: column_quantile(rows, f"{m}_error_m", 0.9) for m in (lead, rival)}
    p90 = {m: np.inf if np.isnan(v) else v for m, v in p90.items()}  # no answer: worst
    fails = []
    if success[lead] < success[best]:
        fails.append(f"success below {METHOD_LABELS[best]}'s")
    if p90[lead] > p90[rival] * (1 + P90_TIE_RTOL) + P90_TIE_M:
        fails.append(f"90th percentile above {METHOD_LABELS[rival]}'s")
    text = {m: "-" if not np.isfinite(v) else f"{100 * v:.2f}" for m, v in p90.items()}
    return [
        label, str(len(rows)), f"{100 * success[lead]:.0f}%",
        f"{100 * success[best]:.0f}% ({METHOD_LABELS[best]})", text[lead], text[rival],
        "yes" if not fails else "no: " + "; ".join(fails),
    ]  # fmt: skip


def criterion_table(
    rows: Sequence[dict],
    lead: str = "edm_gtsam",
    methods: Sequence[str] = REGIME_METHODS,
    rival: str = "gtsam_k",
) -> tuple[list[str], list[list[str]]]:
    """The test of each cell: does ``lead`` (EDM + GTSAM) succeed at least as often as
    every other method of ``methods``, with a 90th percentile of the error at most ``rival``'s
    (GTSAM best of k at equal time; ties within :data:`P90_TIE_RTOL` + :data:`P90_TIE_M`)?
    Returns (header, a row per cell of the finished trials)."""
    peers = [m for m in methods if m != lead]
    header = [
        "regime", "trials", f"{METHOD_LABELS[lead]} success", "best other success",
        f"{METHOD_LABELS[lead]} p90 [cm]", f"{METHOD_LABELS[rival]} p90 [cm]", "meets",
    ]  # fmt: skip
    table = [
        criterion_row(label, cell_rows, lead, peers, rival)
        for label, cell_rows in rows_by_cell(rows).items()
    ]
    return header, table
