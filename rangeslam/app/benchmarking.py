"""Benchmark runs: the paper's Fig. 3 and Fig. 5, and every SLAM method side by side.

A run is a list of :class:`Trial` s, one per (cell, trial index); a cell is one setting (a noise
level, a number of steps, bounds or none). Each trial draws its scene from its own Generator,
seeded from (seed, cell, trial) through numpy's ``SeedSequence``, so a run gives the same numbers
serially, over processes (``jobs``) or on a Dask cluster (``scheduler``). A trial that raises
becomes a row whose status says why, and the run goes on.

The rows hold what is deterministic (errors, bounds, flags); wall times are kept apart (they
differ between runs), so that the CSV of a seed is the same whatever the parallelism.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from rangeslam._validation import check_int
from rangeslam.app.defaults import FIG3_SIGMAS, FIG5_SIGMAS, FIG5_STEPS
from rangeslam.app.progress import Progress
from rangeslam.app.reports import markdown, versions, write_csv, write_summary, write_tum
from rangeslam.errors import InvalidInputError
from rangeslam.evaluation.metrics import (
    BoundComparison,
    mean_nees,
    rms_against_bound,
    trajectory_rmse,
)

__all__ = [
    "BENCHES",
    "FIG3_SIGMAS",
    "FIG5_SIGMAS",
    "FIG5_STEPS",
    "SLAM_METHODS",
    "Trial",
    "TrialOutcome",
    "markdown",
    "plan",
    "run_trial",
    "run_trials",
    "summary_table",
    "versions",
    "write_csv",
    "write_summary",
    "write_tum",
]

BENCHES = ("fig3", "fig5", "compare")
#: The --bounds choices: which step-bound settings a SLAM run covers.
BOUND_SETTINGS = {"both": (True, False), "with": (True,), "without": (False,)}
#: Columns of a SLAM trial: the EDM answer, EDM + GTSAM (rangeslam.mdu.slam), GTSAM from a
#: GTSAM-style start, and (``compare``) the filterpy EKF, filtered and RTS-smoothed.
SLAM_METHODS = ("edm", "edm_gtsam", "gtsam", "ekf", "ekf_rts")
METHOD_NAMES = {
    "edm": "EDM only",
    "edm_gtsam": "EDM + GTSAM",
    "gtsam": "GTSAM without EDM",
    "ekf": "EKF",
    "ekf_rts": "EKF + RTS",
}
#: Trajectory error under which a SLAM trial counts as a success, metres.
SUCCESS_M = 0.10
#: Steps of the EKF's delayed-initialisation window in ``compare``.
EKF_WINDOW = 5
#: Fresh noise draws per trial on which the oracle (the estimators' cost minimised from the
#: truth) is run: its Monte-Carlo RMS is what a cell's bound is checked against.
ORACLE_DRAWS = 16
MAX_ORACLE_DRAWS = 1000


@dataclass(frozen=True)
class Trial:
    """One trial of a run: ``bench`` in BENCHES, ``cell`` and ``index`` locate it, ``params`` is
    the setting ((name, value) pairs), ``seed`` the run's seed."""

    bench: str
    cell: int
    index: int
    params: tuple[tuple[str, object], ...]
    seed: int

    def rng(self) -> np.random.Generator:
        """The trial's Generator, keyed on the bench, the setting's values and the index (not on
        the cell's place in the plan): M = 5 draws the same scenes alone or in a full run."""
        p = dict(self.params)
        key = (
            BENCHES.index(self.bench),
            round(p["sigma"] * 1e9),  # nanometres
            int(p.get("bounds", 0)),
            int(p.get("m", 0)),
            self.index,
        )
        return np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=key))


@dataclass(frozen=True)
class TrialOutcome:
    """What a trial gives back: ``row`` (deterministic values for the CSV), ``seconds`` (wall
    time per method), ``trajectories`` (name -> (M, 3) positions, the truth as "truth"; only when
    asked for)."""

    row: dict
    seconds: dict = field(default_factory=dict)
    trajectories: dict | None = None


def plan(
    bench: str,
    trials: int,
    seed: int,
    *,
    sigmas: Sequence[float] | None = None,
    steps: Sequence[int] | None = None,
    bounds: Sequence[bool] = (True, False),
    placement: str = "random",
    oracle_draws: int = ORACLE_DRAWS,
) -> list[Trial]:
    """The trials of a run, cell by cell. fig3: one cell per sigma (default FIG3_SIGMAS); fig5 and
    compare: one per (sigma, bounds, M) (defaults FIG5_SIGMAS, both, FIG5_STEPS), the bounds
    placed at random around the true steps (the default: real odometry bounds are not centred on
    the truth) or centred on them (the paper's +-20%; see
    :func:`rangeslam.app.experiments.slam_experiment`). Every trial also runs the oracle on
    ``oracle_draws`` fresh noise draws of its scene (the check of the bound)."""
    if bench not in BENCHES:
        raise InvalidInputError(f"bench must be one of {BENCHES}; got {bench!r}")
    if not (isinstance(trials, int) and trials >= 1):
        raise InvalidInputError(f"trials must be a positive integer; got {trials!r}")
    if placement not in ("centred", "random"):
        raise InvalidInputError(f"placement must be 'centred' or 'random'; got {placement!r}")
    draws = ("oracle_draws", check_int(oracle_draws, "oracle_draws", 0, MAX_ORACLE_DRAWS))
    if bench == "fig3":
        cells = [(("sigma", float(s)), draws) for s in (FIG3_SIGMAS if sigmas is None else sigmas)]
    else:
        cells = [
            (
                ("sigma", float(s)),
                ("bounds", bool(b)),
                ("m", int(m)),
                ("placement", placement),
                draws,
            )
            for s in (FIG5_SIGMAS if sigmas is None else sigmas)
            for b in bounds
            for m in (FIG5_STEPS if steps is None else steps)
        ]
    for cell in cells:
        p = dict(cell)
        if p["sigma"] < 0 or not np.isfinite(p["sigma"]):
            raise InvalidInputError(f"sigmas must be finite and >= 0; got {p['sigma']}")
        if "m" in p and p["m"] < 3:
            raise InvalidInputError(f"steps must be >= 3; got {p['m']}")
    return [
        Trial(bench, c, i, cell, int(seed)) for c, cell in enumerate(cells) for i in range(trials)
    ]


def _fig3_trial(params: dict, rng: np.random.Generator, outcome: TrialOutcome) -> None:
    """A Fig. 3 trial: calibration error against its CRLB, convergence, time, into ``outcome``."""
    from rangeslam.app.experiments import calibration_experiment

    t0 = time.perf_counter()
    e = calibration_experiment(params["sigma"], rng, oracle_draws=params.get("oracle_draws", 0))
    outcome.seconds["calibrate"] = time.perf_counter() - t0
    outcome.row.update(
        mic_error_m=e.mic_error,
        crlb_m=e.mic_crlb,
        oracle_error_m=e.oracle_error,
        oracle_rms_m=e.oracle_rms,
        converged=bool(e.result.converged),
    )


def _slam_trial(
    params: dict, rng: np.random.Generator, outcome: TrialOutcome, *, ekf: bool, keep: bool
) -> None:
    """A Fig. 5 trial: every SLAM method's error, the CRLB, NEES and time, into ``outcome``
    (the EKFs when ``ekf``; the trajectories when ``keep``)."""
    from rangeslam.app.experiments import slam_experiment

    e = slam_experiment(
        params["m"],
        params["sigma"],
        params["bounds"],
        rng,
        bounds_placement=params["placement"],
        oracle_draws=params.get("oracle_draws", 0),
    )
    outcome.seconds["edm_gtsam"] = e.seconds
    outcome.row.update(
        crlb_m=e.crlb,
        crlb_ranges_m=e.crlb_ranges,
        edm_error_m=e.edm_error,
        edm_gtsam_error_m=e.error,
        gtsam_error_m=e.baseline_error,
        landmark_error_m=e.source_error,
        oracle_error_m=e.oracle_error,
        oracle_landmark_error_m=e.oracle_source_error,
        oracle_rms_m=e.oracle_rms,
        nees=e.nees,
        nees_dof=e.nees_dof,
        converged=bool(e.converged),
        edm_start_kept=e.result.start == "edm",
    )
    estimates = {
        "edm": e.result.edm_receivers,
        "edm_gtsam": e.result.receivers,
        "gtsam": e.baseline_receivers,
    }
    if ekf:
        estimates.update(_ekf_trial(e, params, rng, outcome))
    if keep:
        outcome.trajectories.update(truth=e.trajectory, **estimates)


def _ekf_trial(e, params: dict, rng: np.random.Generator, outcome: TrialOutcome) -> dict:
    """The filterpy EKF, filtered and RTS-smoothed, on a Fig. 5 trial's ranges: their errors
    (and why they failed) into ``outcome``; returns their trajectories (M, 3) by name."""
    from rangeslam.baselines.ekf_slam import ekf_slam

    estimates = {}
    for name, smooth in (("ekf", False), ("ekf_rts", True)):
        t0 = time.perf_counter()
        try:
            # A genuine filter: the first steps (at most 5) are its delayed-initialisation
            # window, the rest are filtered. (Its own default waits until a linearisation
            # test passes, which on the planar Fig. 5 walk is never: a batch fit of all M.)
            out = ekf_slam(
                e.ranges,
                step_bounds=e.step_bounds,
                noise_std=params["sigma"],
                smooth=smooth,
                init_steps=min(EKF_WINDOW, params["m"]),
                rng=rng,
            )
        except Exception as exc:  # the EKF failing is its result, not the trial's
            outcome.row[f"{name}_error_m"] = float("nan")
            outcome.row[f"{name}_status"] = _one_line(exc)
            continue
        outcome.seconds[name] = time.perf_counter() - t0
        outcome.row[f"{name}_error_m"] = trajectory_rmse(out.receivers, e.trajectory)
        outcome.row[f"{name}_converged"] = bool(out.converged)
        outcome.row["ekf_filtered_steps"] = params["m"] - min(EKF_WINDOW, params["m"])
        estimates[name] = out.receivers
    return estimates


def _one_line(exc: BaseException) -> str:
    """The exception as one line of at most 300 characters: its type and first line."""
    return f"{type(exc).__name__}: {exc}".splitlines()[0][:300]


def run_trial(trial: Trial, keep_trajectories: bool = False) -> TrialOutcome:
    """Run one trial; never raises: a failure is the row's ``status``."""
    params = dict(trial.params)
    row = {"bench": trial.bench, "cell": trial.cell, "trial": trial.index, **params}
    outcome = TrialOutcome(row=row, trajectories={} if keep_trajectories else None)
    row["status"] = "ok"
    try:
        if trial.bench == "fig3":
            _fig3_trial(params, trial.rng(), outcome)
        else:
            _slam_trial(
                params, trial.rng(), outcome, ekf=trial.bench == "compare", keep=keep_trajectories
            )
    except Exception as exc:  # a failing trial is recorded, and the run goes on
        row["status"] = f"failed: {_one_line(exc)}"
    return outcome


def run_trials(
    trials: Sequence[Trial],
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    keep_trajectories: bool = False,
    progress: Progress | bool = False,
    on_outcome: Callable[[TrialOutcome], None] | None = None,
) -> list[TrialOutcome]:
    """Run ``trials`` in order (``jobs`` = 1), over ``jobs`` processes, or on the Dask cluster at
    ``scheduler`` (needs the ``dask`` extra). Outcomes come back in the order of ``trials``.

    ``progress``: a :class:`~rangeslam.app.progress.Progress` to update per finished trial (a cell
    is named when its last trial finishes), True for a default one on standard error, False for
    none. ``on_outcome`` is called with each outcome as it finishes (to write it at once)."""
    if not (isinstance(jobs, int) and jobs >= 1):
        raise InvalidInputError(f"jobs must be a positive integer; got {jobs!r}")
    if scheduler is not None and jobs != 1:
        raise InvalidInputError("give either jobs (local processes) or scheduler (Dask), not both")
    if not isinstance(progress, Progress):
        label = trials[0].bench if trials else "bench"
        progress = Progress(len(trials), label, enabled=bool(progress))
    tracker = _CellTracker(trials, progress, on_outcome)
    with progress:
        if scheduler is not None:
            return _run_dask(trials, scheduler, keep_trajectories, tracker)
        if jobs == 1:
            return [tracker.finished(run_trial(t, keep_trajectories)) for t in trials]
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(run_trial, t, keep_trajectories) for t in trials]
            for f in as_completed(futures):
                tracker.finished(f.result())
            return [f.result() for f in futures]


class _CellTracker:
    """Counts finished trials per cell: updates the progress (naming a cell when its last trial
    is in) and hands each outcome to ``on_outcome``."""

    def __init__(self, trials: Sequence[Trial], progress: Progress, on_outcome) -> None:
        self.left: dict[int, int] = {}
        self.names: dict[int, str] = {}
        for t in trials:
            self.left[t.cell] = self.left.get(t.cell, 0) + 1
            self.names[t.cell] = ", ".join(
                f"{k}={v}" for k, v in t.params if k not in ("placement", "oracle_draws")
            )
        self.progress = progress
        self.on_outcome = on_outcome

    def finished(self, outcome: TrialOutcome) -> TrialOutcome:
        """Record one finished trial; returns it."""
        cell = outcome.row["cell"]
        self.left[cell] -= 1
        if self.on_outcome is not None:
            self.on_outcome(outcome)
        self.progress.update(stage=self.names[cell] if self.left[cell] == 0 else None)
        return outcome


def _run_dask(trials, scheduler: str, keep: bool, tracker: _CellTracker) -> list[TrialOutcome]:
    """Run ``trials`` on the Dask cluster at ``scheduler``, in order; bad addresses refused."""
    try:
        from dask.distributed import Client, as_completed
    except ImportError as exc:
        raise InvalidInputError("--scheduler needs Dask: pip install 'rangeslam[dask]'") from exc
    try:
        client = Client(scheduler, timeout="5s")
    except OSError as exc:
        raise InvalidInputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
    with client:
        futures = client.map(run_trial, list(trials), keep_trajectories=keep, pure=False)
        for future in as_completed(futures):
            tracker.finished(future.result())
        return client.gather(futures)


def _stats(values) -> tuple[float, float]:
    """(mean, median) of the finite values (failed trials have none), NaNs when there are none."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    return float(np.mean(v)), float(np.median(v))


def _cells(rows: Sequence[dict]) -> dict[int, list[dict]]:
    """The rows grouped by cell, in order of first appearance."""
    cells: dict[int, list[dict]] = {}
    for row in rows:
        cells.setdefault(row["cell"], []).append(row)
    return cells


def _column(rows: Sequence[dict], name: str) -> np.ndarray:
    """The values of column ``name`` over ``rows`` as float64 (NaN where a row has none)."""
    return np.array([r.get(name, np.nan) for r in rows], dtype=float)


def bench_methods(bench: str) -> list[str]:
    """The SLAM methods of a fig5 or compare run (the EKFs only in compare)."""
    return [m for m in SLAM_METHODS if bench == "compare" or not m.startswith("ekf")]


#: What a table says in place of a bound the oracle does not attain.
NOT_ATTAINED = "not attained: oracle only"


def _summary_header(bench: str) -> list[str]:
    """The Markdown header of a run's summary table."""
    yardstick = [
        "RMS CRLB",
        "oracle RMS (Monte Carlo)",
        "oracle / CRLB",
        "bound",
    ]
    if bench == "fig3":
        return [
            "sigma (mm)",
            "trials",
            "failed",
            "not identifiable",
            *(f"{h} (mm)" if "RMS" in h else h for h in yardstick),
            "RMS error (mm)",
            "error / oracle",
            "error / CRLB",
            "median error (mm)",
            "converged",
            "time median (s)",
        ]
    methods = bench_methods(bench)
    header = ["sigma (mm)", "bounds", "M", "trials", "failed", "not identifiable"]
    header += [f"{h} (cm)" if "RMS" in h else h for h in yardstick]
    header += [
        f"{METHOD_NAMES[m]}: RMS (cm), / oracle, / CRLB; median (cm), < 10 cm" for m in methods
    ]
    header += [
        "landmarks RMS (cm): EDM + GTSAM, oracle",
        "NEES / dof",
        "EDM start kept",
        "time median (s): "
        + ", ".join(METHOD_NAMES[m] for m in methods if m in ("edm_gtsam", "ekf")),
    ]
    return header


def _yardstick_cells(c: BoundComparison, scale: float) -> list[str]:
    """The cell's bound, the oracle's Monte-Carlo RMS, their ratio and whether the bound is
    attained (in units of 1 / ``scale`` metres); the bound is '-' where it is not."""
    if not c.trials:
        return ["inf" if c.unidentifiable else "-", "-", "-", c.regime]
    bound = f"{c.rms_bound * scale:.3g}" if c.attained else f"({c.rms_bound * scale:.3g})"
    return [
        bound,
        f"{c.rms_oracle * scale:.3g}",
        f"{c.efficiency:.2f}",
        "attained" if c.attained else NOT_ATTAINED,
    ]


def _against(c: BoundComparison) -> list[str]:
    """'error / oracle' and 'error / CRLB' of one method; the latter '-' where not attained."""
    search = f"{c.search:.2f}" if np.isfinite(c.search) else "-"
    return [search, f"{c.ratio:.2f}" if c.attained else "-"]


def _comparison_record(c: BoundComparison) -> dict:
    """The JSON record of a comparison: every figure, the bound only where attained."""
    return {
        "rms_error_m": c.rms_error,
        "rms_oracle_m": c.rms_oracle,
        "rms_crlb_m": c.rms_bound,
        "lower_bound_m": c.lower_bound,
        "error_over_oracle": c.search,
        "oracle_over_crlb": c.efficiency,
        "error_over_crlb": c.ratio,
        "regime": c.regime,
        "unidentifiable": c.unidentifiable,
    }


def _fig3_cell(cell_rows: list[dict], ok: list[dict], rec: dict, times: dict) -> list[str]:
    """One Fig. 3 cell: the yardstick (bound, oracle, whether attained), the RMS error against
    the oracle and (where attained) the bound, the median error, the convergence rate, the
    median time (mm); fills ``rec`` with the same figures and returns the Markdown row."""
    first, n, failed = cell_rows[0], rec["trials"], rec["failed"]
    err = _column(ok, "mic_error_m")
    cmp = rms_against_bound(
        err, _column(ok, "crlb_m"), _column(ok, "oracle_error_m"), _oracle_rms(ok)
    )
    med_e = float(np.median(err)) if ok else np.nan
    conv = float(np.sum(_column(ok, "converged"))) / n
    _, t = _stats([times[id(r)].get("calibrate", np.nan) for r in cell_rows])
    rec.update(_comparison_record(cmp), median_error_m=med_e, converged=conv, median_seconds=t)
    # at zero noise there is no bound: the RMS error over every trial, for the exact recovery
    rms_all = float(np.sqrt(np.nanmean(err**2))) if ok else np.nan
    rms_e = cmp.rms_error if cmp.trials else rms_all
    return [
        f"{first['sigma'] * 1e3:g}",
        str(n),
        str(failed),
        str(cmp.unidentifiable),
        *_yardstick_cells(cmp, 1e3),
        f"{rms_e * 1e3:.3g}",
        *_against(cmp),
        f"{med_e * 1e3:.3g}",
        f"{conv * 100:.0f}%",
        f"{t:.2f}",
    ]


def _oracle_rms(rows: list[dict]) -> np.ndarray:
    """Per trial, the oracle's Monte-Carlo RMS error where it was run, else its error on the
    trial's own data (metres)."""
    mc, same = _column(rows, "oracle_rms_m"), _column(rows, "oracle_error_m")
    return np.where(np.isfinite(mc), mc, same)


def _method_cell(e: np.ndarray, cmp: BoundComparison, n: int) -> str:
    """One method's Fig. 5 cell: RMS (cm), / oracle, / CRLB; median (cm), success rate."""
    finite = e[np.isfinite(e)]
    rms_all = float(np.sqrt(np.mean(finite**2))) if finite.size else np.nan
    rms = cmp.rms_error if cmp.trials else rms_all
    _, med = _stats(e)
    search, ratio = _against(cmp)
    success = float(np.sum(e < SUCCESS_M)) / n
    return f"{rms * 100:.2f}, {search}, {ratio}; {med * 100:.2f}, {success * 100:.0f}%"


def _slam_cell(
    cell_rows: list[dict], ok: list[dict], rec: dict, times: dict, methods: list[str]
) -> list[str]:
    """One Fig. 5 / compare cell: the yardstick (the RMS of the per-trial CRLBs with the step
    prior the methods use, the oracle's Monte-Carlo RMS, whether it attains the bound), each
    method's RMS error against the oracle and, where attained, the bound, median error and
    success rate, the landmark errors, the mean NEES per dof, how often the EDM start was kept,
    median times; fills ``rec`` with the same figures and returns the Markdown row."""
    first, n = cell_rows[0], rec["trials"]
    crlb, oracle, oracle_mc = _column(ok, "crlb_m"), _column(ok, "oracle_error_m"), _oracle_rms(ok)
    yardstick = rms_against_bound(oracle, crlb, oracle, oracle_mc)
    cells = [
        f"{first['sigma'] * 1e3:g}",
        "+-20%" if first["bounds"] else "none",
        str(first["m"]),
        str(n),
        str(rec["failed"]),
        str(yardstick.unidentifiable),
        *_yardstick_cells(yardstick, 100),
    ]
    rec.update(_comparison_record(yardstick))
    for m in methods:
        e = _column(ok, f"{m}_error_m")
        cmp = rms_against_bound(e, crlb, oracle, oracle_mc)
        if m.startswith("ekf") and not np.any(_column(ok, "ekf_filtered_steps") > 0):
            cells.append("batch fit (no step filtered)")
        else:
            cells.append(_method_cell(e, cmp, n))
        _, med = _stats(e)
        rec[m] = {**_comparison_record(cmp), "median_error_m": med}
        rec[m]["success"] = float(np.sum(e < SUCCESS_M)) / n
    lm, lm_oracle = _column(ok, "landmark_error_m"), _column(ok, "oracle_landmark_error_m")
    rec.update(landmark_rms_m=_finite_rms(lm), oracle_landmark_rms_m=_finite_rms(lm_oracle))
    ratio, _, _ = mean_nees(_column(ok, "nees"), _column(ok, "nees_dof"))
    kept = float(np.mean(_column(ok, "edm_start_kept"))) if ok else float("nan")
    rec.update(nees_over_dof=ratio, edm_start_kept=kept)
    t = {
        m: _stats([times[id(r)].get(m, np.nan) for r in cell_rows])[1]
        for m in ("edm_gtsam", "ekf")
        if m in methods
    }
    rec["median_seconds"] = t
    return [
        *cells,
        f"{rec['landmark_rms_m'] * 100:.2f}, {rec['oracle_landmark_rms_m'] * 100:.2f}",
        f"{ratio:.2f}",
        f"{kept * 100:.0f}%",
        ", ".join(f"{v:.2f}" for v in t.values()),
    ]


def _finite_rms(values: np.ndarray) -> float:
    """RMS of the finite values (NaN when none)."""
    v = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def summary_table(
    bench: str, rows: Sequence[dict], seconds: Sequence[dict]
) -> tuple[list[str], list[list[str]], list[dict]]:
    """(Markdown header, Markdown rows, JSON records) summarising each cell of a run. Two
    yardsticks (``rms_against_bound``): the oracle (the estimators' cost minimised from the
    truth; error / oracle measures the search) and the RMS of the per-trial CRLBs (with the step
    prior where the methods use one), quoted as a lower bound only in the cells where the
    oracle's Monte-Carlo RMS is within 10% of it ("attained"); elsewhere the table says "not
    attained: oracle only" and gives the bound in parentheses. Trials whose bound is inf are
    counted as not identifiable and left out. Errors in cm (mm in fig3); a failed trial counts as
    a failure of every method and is left out of the RMS."""
    times = {id(r): s for r, s in zip(rows, seconds, strict=True)}
    table, records = [], []
    for cell_rows in _cells(rows).values():
        first = cell_rows[0]
        ok = [r for r in cell_rows if r["status"] == "ok"]
        rec = {k: first[k] for k in ("sigma", "bounds", "m") if k in first}
        rec.update(trials=len(cell_rows), failed=len(cell_rows) - len(ok))
        if bench == "fig3":
            table.append(_fig3_cell(cell_rows, ok, rec, times))
        else:
            table.append(_slam_cell(cell_rows, ok, rec, times, bench_methods(bench)))
        records.append(rec)
    return _summary_header(bench), table, records
