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
#: Trajectory error under which a SLAM trial counts as a success, metres (issue 4).
SUCCESS_M = 0.10
#: Steps of the EKF's delayed-initialisation window in ``compare``.
EKF_WINDOW = 5


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
    placement: str = "centred",
) -> list[Trial]:
    """The trials of a run, cell by cell. fig3: one cell per sigma (default FIG3_SIGMAS); fig5 and
    compare: one per (sigma, bounds, M) (defaults FIG5_SIGMAS, both, FIG5_STEPS), the bounds
    centred on the true steps (the paper's +-20%) or placed at random around them (see
    :func:`rangeslam.app.experiments.slam_experiment`)."""
    if bench not in BENCHES:
        raise InvalidInputError(f"bench must be one of {BENCHES}; got {bench!r}")
    if not (isinstance(trials, int) and trials >= 1):
        raise InvalidInputError(f"trials must be a positive integer; got {trials!r}")
    if placement not in ("centred", "random"):
        raise InvalidInputError(f"placement must be 'centred' or 'random'; got {placement!r}")
    if bench == "fig3":
        cells = [(("sigma", float(s)),) for s in (FIG3_SIGMAS if sigmas is None else sigmas)]
    else:
        cells = [
            (("sigma", float(s)), ("bounds", bool(b)), ("m", int(m)), ("placement", placement))
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
    e = calibration_experiment(params["sigma"], rng)
    outcome.seconds["calibrate"] = time.perf_counter() - t0
    outcome.row.update(
        mic_error_m=e.mic_error, crlb_m=e.mic_crlb, converged=bool(e.result.converged)
    )


def _slam_trial(
    params: dict, rng: np.random.Generator, outcome: TrialOutcome, *, ekf: bool, keep: bool
) -> None:
    """A Fig. 5 trial: every SLAM method's error, the CRLB, NEES and time, into ``outcome``
    (the EKFs when ``ekf``; the trajectories when ``keep``)."""
    from rangeslam.app.experiments import slam_experiment

    e = slam_experiment(
        params["m"], params["sigma"], params["bounds"], rng, bounds_placement=params["placement"]
    )
    outcome.seconds["edm_gtsam"] = e.seconds
    outcome.row.update(
        crlb_m=e.crlb,
        crlb_ranges_m=e.crlb_ranges,
        edm_error_m=e.edm_error,
        edm_gtsam_error_m=e.error,
        gtsam_error_m=e.baseline_error,
        landmark_error_m=e.source_error,
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
            self.names[t.cell] = ", ".join(f"{k}={v}" for k, v in t.params if k != "placement")
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


def _summary_header(bench: str) -> list[str]:
    """The Markdown header of a run's summary table."""
    if bench == "fig3":
        return [
            "sigma (mm)",
            "trials",
            "failed",
            "not identifiable",
            "RMS error (mm)",
            "RMS CRLB (mm)",
            "RMS error / RMS CRLB",
            "regime",
            "median error (mm)",
            "< 3x CRLB",
            "converged",
            "time median (s)",
        ]
    methods = bench_methods(bench)
    header = ["sigma (mm)", "bounds", "M", "trials", "failed", "not identifiable"]
    header += ["RMS CRLB (cm), with the step prior", "RMS CRLB (cm), ranges only"]
    header += [
        f"{METHOD_NAMES[m]}: RMS (cm), / CRLB, regime; median (cm), < 10 cm" for m in methods
    ]
    header += [
        "NEES / dof",
        "EDM start kept",
        "time median (s): "
        + ", ".join(METHOD_NAMES[m] for m in methods if m in ("edm_gtsam", "ekf")),
    ]
    return header


def _ratio_text(c: BoundComparison) -> str:
    """'0.93x attains' (or the regime alone when there is no ratio)."""
    return c.regime if not np.isfinite(c.ratio) else f"{c.ratio:.2f}x {c.regime}"


def _fig3_cell(cell_rows: list[dict], ok: list[dict], rec: dict, times: dict) -> list[str]:
    """One Fig. 3 cell: RMS error against the RMS of the per-trial CRLBs (mm), their ratio and
    regime, the median error, success and convergence rates, median time; fills ``rec`` with the
    same figures and returns the Markdown row."""
    first, n, failed = cell_rows[0], rec["trials"], rec["failed"]
    err, crlb = _column(ok, "mic_error_m"), _column(ok, "crlb_m")
    cmp = rms_against_bound(err, crlb)
    med_e = float(np.median(err)) if ok else np.nan
    success = (
        float(np.sum(err < 3 * crlb)) / n if first["sigma"] > 0 else float(np.sum(err < 1e-3)) / n
    )
    conv = float(np.sum(_column(ok, "converged"))) / n
    _, t = _stats([times[id(r)].get("calibrate", np.nan) for r in cell_rows])
    rec.update(
        rms_error_m=cmp.rms_error,
        rms_crlb_m=cmp.rms_bound,
        ratio=cmp.ratio,
        regime=cmp.regime,
        unidentifiable=cmp.unidentifiable,
        median_error_m=med_e,
        success=success,
        converged=conv,
        median_seconds=t,
    )
    # at zero noise there is no bound: the RMS error over every trial, for the exact recovery
    rms_all = float(np.sqrt(np.nanmean(err**2))) if ok else np.nan
    rms_e = cmp.rms_error if cmp.trials else rms_all
    return [
        f"{first['sigma'] * 1e3:g}",
        str(n),
        str(failed),
        str(cmp.unidentifiable),
        f"{rms_e * 1e3:.3g}",
        f"{cmp.rms_bound * 1e3:.3g}" if cmp.trials else "-",
        f"{cmp.ratio:.2f}" if np.isfinite(cmp.ratio) else "-",
        cmp.regime,
        f"{med_e * 1e3:.3g}",
        f"{success * 100:.0f}%",
        f"{conv * 100:.0f}%",
        f"{t:.2f}",
    ]


def _slam_cell(
    cell_rows: list[dict], ok: list[dict], rec: dict, times: dict, methods: list[str]
) -> list[str]:
    """One Fig. 5 / compare cell: the RMS of the per-trial CRLBs (with the step prior where the
    methods use one, and of the ranges alone), each method's RMS error against it, ratio and
    regime, median error and success rate, the mean NEES per dof, how often the EDM start was
    kept, median times; fills ``rec`` with the same figures and returns the Markdown row."""
    first, n = cell_rows[0], rec["trials"]
    crlb, crlb_ranges = _column(ok, "crlb_m"), _column(ok, "crlb_ranges_m")
    free = rms_against_bound(crlb_ranges, crlb_ranges)
    cells = [
        f"{first['sigma'] * 1e3:g}",
        "+-20%" if first["bounds"] else "none",
        str(first["m"]),
        str(n),
        str(rec["failed"]),
    ]
    comparisons = {}
    for m in methods:
        e = _column(ok, f"{m}_error_m")
        cmp = comparisons[m] = rms_against_bound(e, crlb)
        _, med = _stats(e)
        success = float(np.sum(e < SUCCESS_M)) / n
        rec[m] = {
            "rms_error_m": cmp.rms_error,
            "ratio": cmp.ratio,
            "regime": cmp.regime,
            "median_error_m": med,
            "success": success,
        }
        # with no finite bound (not identifiable), the RMS over every trial, without a ratio
        rms_all = (
            float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2))) if np.isfinite(e).any() else np.nan
        )
        rms = f"{(cmp.rms_error if cmp.trials else rms_all) * 100:.2f}"
        cells.append(f"{rms}, {_ratio_text(cmp)}; {med * 100:.2f}, {success * 100:.0f}%")
    ref = comparisons[methods[0]]
    cells[5:5] = [
        str(ref.unidentifiable),
        f"{ref.rms_bound * 100:.2f}" if ref.trials else "inf",
        f"{free.rms_bound * 100:.2f}" if free.trials else "inf",
    ]
    ratio, _, _ = mean_nees(_column(ok, "nees"), _column(ok, "nees_dof"))
    kept = float(np.mean(_column(ok, "edm_start_kept"))) if ok else float("nan")
    rec.update(
        rms_crlb_m=ref.rms_bound,
        rms_crlb_ranges_m=free.rms_bound,
        unidentifiable=ref.unidentifiable,
        unidentifiable_ranges=free.unidentifiable,
        nees_over_dof=ratio,
        edm_start_kept=kept,
    )
    t = {
        m: _stats([times[id(r)].get(m, np.nan) for r in cell_rows])[1]
        for m in ("edm_gtsam", "ekf")
        if m in methods
    }
    rec["median_seconds"] = t
    return [
        *cells,
        f"{ratio:.2f}",
        f"{kept * 100:.0f}%",
        ", ".join(f"{v:.2f}" for v in t.values()),
    ]


def summary_table(
    bench: str, rows: Sequence[dict], seconds: Sequence[dict]
) -> tuple[list[str], list[list[str]], list[dict]]:
    """(Markdown header, Markdown rows, JSON records) summarising each cell of a run. The
    yardstick is the RMS error over trials against the RMS of the per-trial CRLBs (with the step
    prior where the methods use one), with their ratio and regime (``rms_against_bound``); trials
    whose bound is inf are counted as not identifiable and left out of both. Errors in cm (mm in
    fig3); a failed trial counts as a failure of every method and is left out of the RMS."""
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
