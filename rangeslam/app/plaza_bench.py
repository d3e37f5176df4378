"""``rangeslam bench plaza``: range-only SLAM on the CMU Plaza data, every method side by side.

Data: J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with
ground truth", Journal of Field Robotics 26(9), 2009 (shipped with GTSAM).

Errors are those of evo's APE: the estimated positions are rigidly aligned onto the ground truth
at the pose times (no scale), then the per-pose distances give mean, median, max and RMSE; the
beacons are moved by the same alignment and compared with the surveyed ones. Every method starts
from the true start pose (the gauge, as GTSAM's example hard-codes it); the alignment removes it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from rangeslam.app.defaults import DEFAULT_METHODS, PLAZA_METHODS
from rangeslam.app.progress import Progress
from rangeslam.beacons import (
    BeaconSlamResult,
    RangeOdometry,
    beacon_slam,
    beacon_slam_incremental,
)
from rangeslam.errors import RangeSlamError
from rangeslam.evaluation.metrics import PositionErrors, ape, ape_statistics

__all__ = [
    "DEFAULT_METHODS",
    "PLAZA_METHODS",
    "evaluate",
    "length_rows",
    "method_rows",
    "method_runs",
    "run_method",
]

RANDOM_METHODS = ("gtsam random beacons", "isam2 random beacons", "gtsam example")


def run_method(method: str, dataset, rng: np.random.Generator, n_poses: int | None = None):
    """Run one method on a Plaza data set (optionally its first ``n_poses`` poses)."""
    from rangeslam.baselines import ekf_range_odometry, gtsam_range_example, odometry_only

    data = RangeOdometry.from_plaza(dataset)
    if n_poses is not None and n_poses < len(data.pose_time):
        data = data.first(n_poses)
        if method not in ("edm+gtsam", "edm+isam2"):
            raise RangeSlamError(f"lengths are run for the EDM pipelines only, not {method!r}")
    start = dataset.truth[0]
    if method == "edm+gtsam":
        return beacon_slam(data, start_pose=start)
    if method == "edm+isam2":
        return beacon_slam_incremental(data, start_pose=start)
    if method == "gtsam random beacons":
        return beacon_slam(data, start_pose=start, initialisation="random", rng=rng)
    if method == "isam2 random beacons":
        return beacon_slam_incremental(data, start_pose=start, initialisation="random", rng=rng)
    t0 = time.perf_counter()
    if method == "gtsam example":
        res = gtsam_range_example(dataset, rng=rng)
    elif method == "odometry":
        res = odometry_only(dataset)
    elif method == "ekf":
        res = ekf_range_odometry(dataset, rng=rng)
    else:
        raise RangeSlamError(f"unknown method {method!r}; known: {PLAZA_METHODS}")
    if not np.isfinite(res.seconds):
        from dataclasses import replace

        res = replace(res, seconds=time.perf_counter() - t0)
    return res


#: APE of one result (:class:`rangeslam.evaluation.metrics.PositionErrors`).
Evaluation = PositionErrors


def evaluate(result: BeaconSlamResult, dataset) -> PositionErrors:
    """Rigidly align the result's positions onto the ground truth at its pose times (as evo's APE)
    and carry the beacons along. Poses that are NaN (a method that stopped) are left out of the
    alignment and count as missing in the errors (NaN)."""
    truth = dataset.truth_at(result.pose_time)
    return ape(result.poses[:, :2], truth, result.beacons, dataset.beacons)


def _median(values) -> float:
    """Median of the finite values (NaN when there are none, or no values)."""
    if values is None:
        return float("nan")
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(np.median(finite)) if finite.size else float("nan")


def _row(method: str, trial: int, result: BeaconSlamResult | None, dataset, error: str = ""):
    """One CSV row of a run: its APE, beacon errors, range calibration, timings and verdict
    (only the method, trial and failure when there is no result)."""
    row = {"method": method, "trial": trial, "status": "ok" if not error else f"failed: {error}"}
    if result is None:
        return row
    ev = evaluate(result, dataset)
    stats = ape_statistics(ev.errors)
    duration = float(result.pose_time[-1] - result.pose_time[0])
    row.update(
        poses=len(result.pose_time),
        mean=stats.mean,
        median=stats.median,
        max=stats.max,
        rmse=stats.rmse,
        missing_poses=stats.missing,
        beacons_placed=int(np.sum(np.isfinite(ev.beacon_errors))),
        beacon_max=float(np.nanmax(ev.beacon_errors))
        if np.any(np.isfinite(ev.beacon_errors))
        else np.nan,
        **{
            f"beacon_{int(i)}": float(v)
            for i, v in zip(dataset.beacon_ids, ev.beacon_errors, strict=True)
        },
        range_scale=_median(result.range_scale),
        range_bias=_median(result.range_bias),
        seconds=float(result.seconds),
        per_pose_ms=1e3 * float(result.seconds) / len(result.pose_time),
        real_time_factor=duration / float(result.seconds),
        converged=bool(result.converged),
        message=result.message,
    )
    return row


def method_runs(methods, trials: int) -> list[tuple[str, int]]:
    """The (method, trial) pairs of a bench: ``trials`` of each method with random starts, one of
    the others."""
    return [(m, t) for m in methods for t in range(trials if m in RANDOM_METHODS else 1)]


def method_rows(
    dataset,
    *,
    trials: int,
    seed: int,
    methods=DEFAULT_METHODS,
    keep=None,
    progress: Progress | None = None,
    on_row: Callable[[list[dict]], None] | None = None,
):
    """One row per method (and per trial for the methods with random starts). ``keep``, a dict,
    receives the result of each method's median trial (by mean APE, the lower of the middle two
    for an even count; the trial the table's median stands for), for plots and TUM files, updated
    as trials finish; ``progress`` is updated after each run; ``on_row`` receives the rows so far
    after each run (to write them)."""
    rows, seen = [], {}
    for method, trial in method_runs(methods, trials):
        rng = np.random.default_rng([seed, PLAZA_METHODS.index(method), trial])
        try:
            res = run_method(method, dataset, rng)
        except RangeSlamError as exc:
            rows.append(_row(method, trial, None, dataset, str(exc).splitlines()[0]))
        else:
            rows.append(_row(method, trial, res, dataset))
            if keep is not None:
                seen.setdefault(method, []).append((rows[-1]["mean"], trial, res))
                ranked = sorted(seen[method], key=lambda x: (np.nan_to_num(x[0], nan=np.inf), x[1]))
                keep[method] = ranked[(len(ranked) - 1) // 2][2]
        _finished(rows, f"{method} #{trial + 1}", progress, on_row)
    return rows


def _finished(rows: list[dict], stage: str, progress: Progress | None, on_row) -> None:
    """Tell the progress and the writer that a run finished."""
    if on_row is not None:
        on_row(rows)
    if progress is not None:
        progress.update(stage=stage)


def length_rows(
    dataset,
    lengths,
    *,
    methods=("edm+gtsam", "edm+isam2"),
    seed: int = 0,
    progress: Progress | None = None,
    on_row: Callable[[list[dict]], None] | None = None,
):
    """Cost against trajectory length: each EDM pipeline on the first n poses, n in ``lengths``
    (None or 0: all of them). ``progress`` and ``on_row`` as in :func:`method_rows`."""
    rows = []
    for n in lengths:
        n_poses = len(dataset.pose_time) if not n else min(int(n), len(dataset.pose_time))
        for method in methods:
            rng = np.random.default_rng([seed, n_poses])
            try:
                res = run_method(method, dataset, rng, n_poses=n_poses)
            except RangeSlamError as exc:
                row = _row(method, 0, None, dataset, str(exc).splitlines()[0])
                row["poses"] = n_poses
                rows.append(row)
            else:
                rows.append(_row(method, 0, res, dataset))
            _finished(rows, f"{method}, {n_poses} poses", progress, on_row)
    return rows


def dataset_beacons(rows) -> list[str]:
    """The beacon columns (beacon_<id>) of a row."""
    return [k for k in rows[0] if k.startswith("beacon_") and k not in ("beacon_max",)]


def _fmt(x, digits: int = 2) -> str:
    """``x`` with ``digits`` decimals; "-" for None or a non-finite value."""
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def _median_and_worst(rows: list[dict], key: str, digits: int = 2) -> str:
    """Column ``key`` of ``rows``: the one value, or the median and the worst (largest)."""
    values = np.array([r[key] for r in rows], dtype=float)
    if len(values) == 1:
        return _fmt(values[0], digits)
    return f"{_fmt(np.median(values), digits)} (worst {_fmt(np.max(values), digits)})"


def methods_table(rows) -> tuple[list[str], list[list[str]]]:
    """Markdown table of the method rows: for methods with random starts, the median over the
    trials and the worst trial. "worst beacon" is over the beacons placed ("beacons placed",
    fewest over the trials)."""
    header = [
        "method",
        "trials (converged)",
        "mean [m]",
        "median [m]",
        "max [m]",
        "worst beacon [m]",
        "beacons placed",
        "range scale",
        "time [s]",
    ]
    table = []
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        ok = [r for r in mine if r["status"] == "ok"]
        conv = sum(bool(r.get("converged")) for r in ok)
        if not ok:
            table.append([method, f"{len(mine)} (0)", mine[0]["status"], "", "", "", "", "", ""])
            continue
        table.append(
            [
                method,
                f"{len(mine)} ({conv})",
                _median_and_worst(ok, "mean"),
                _median_and_worst(ok, "median"),
                _median_and_worst(ok, "max"),
                _median_and_worst(ok, "beacon_max"),
                f"{min(r['beacons_placed'] for r in ok)}/{len(dataset_beacons(ok))}",
                _fmt(float(np.median([r["range_scale"] for r in ok])), 4),
                _fmt(float(np.median([r["seconds"] for r in ok])), 1),
            ]
        )
    return header, table


def lengths_table(rows) -> tuple[list[str], list[list[str]]]:
    """Markdown table of the length rows: cost (time, per pose, x real time), error, verdict."""
    header = [
        "poses",
        "method",
        "time [s]",
        "per pose [ms]",
        "x real time",
        "mean [m]",
        "converged",
        "status",
    ]
    table = []
    for r in rows:
        table.append(
            [
                str(r.get("poses", "")),
                r["method"],
                _fmt(r.get("seconds", np.nan), 1),
                _fmt(r.get("per_pose_ms", np.nan), 2),
                _fmt(r.get("real_time_factor", np.nan), 0),
                _fmt(r.get("mean", np.nan)),
                "-" if "converged" not in r else ("yes" if r["converged"] else "no"),
                r["status"] if r["status"] != "ok" or r.get("converged", True) else r["message"],
            ]
        )
    return header, table
