"""``rangeslam bench pyfg FILES``: range-aided SLAM methods on PyFG files (CORA's benchmark
problems), one table row per file and method: status, where the first poses came from, time,
APE against the file's reference.

Methods (:data:`PYFG_METHODS`, a registry: a peer is one entry):

- ``odometry``: dead reckoning from each robot's reference first pose, ranges unused (a
  baseline: the reference places the robots, so it is read here, for the table only);
- ``gtsam``: :func:`rangeslam.rangeaided.gtsam_solve.solve_gtsam` as ``rangeslam run`` runs it:
  started from the EDM windows where the file is a beacon log ("EDM windows" in the table), else
  from the odometry with the first poses from the data (robot A's at the origin, the others
  placed from the ranges and observations they share); GTSAM's Levenberg-Marquardt on the
  file's graph, the judge of alternative answers; the reference is not read;
- ``gtsam-reference-start``: the same graph and judge, started from the odometry with each
  robot's reference first pose (CORA's odometry-start protocol: the truth places the robots
  relative to each other; for comparison only);
- ``edm+gtsam``: :func:`rangeslam.beacons.beacon_slam` (EDM windows, stitching, GTSAM with the
  range calibration unknown), ``edm+isam2`` (:func:`rangeslam.beacons.beacon_slam_incremental`,
  the same start, iSAM2), ``ekf`` (:func:`rangeslam.baselines.ekf_range_odometry`, filterpy) and
  ``gtsam-example`` (:func:`rangeslam.baselines.gtsam_range_example`, GTSAM's
  RangeISAMExample), where the problem is a one-robot 2-D beacon log
  (:meth:`RangeOdometry.from_problem <rangeslam.beacons.RangeOdometry.from_problem>`: unicycle
  odometry, ranges to landmarks only); they derive their noise from the data, not from the
  file, and read no reference pose. Elsewhere: not run, and the row says why (their model
  does not hold several robots, 3-D, sideways odometry or ranges between robots).

APE: one rigid motion (no scale) fitted to all poses carries every robot and landmark (evo's
``-a`` on the joint trajectory). Times are wall times on this machine; CORA's published times
(:data:`CORA_SECONDS`) are the authors' machine's, shown beside them for scale only.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

__all__ = ["CORA_SECONDS", "PYFG_METHODS", "pyfg_rows", "run_pyfg_bench"]

#: CORA's solve times [s] as published (Papalia et al., T-RO 2024), on the authors' machine.
CORA_SECONDS = {"plaza1": 10.56, "plaza2": 2.71, "single_drone": 2.26, "tiers": 11.30}


def _reference_first(problem) -> np.ndarray:
    """(R, w) each robot's reference first pose (the bench's baselines only)."""
    from rangeslam.errors import InvalidInputError

    if problem.truth_poses is None:
        raise InvalidInputError("the file has no reference poses to start from")
    return problem.truth_poses[[problem.robot_rows(r)[0] for r in range(len(problem.robots))]]


def _odometry(problem):
    from rangeslam.rangeaided.gtsam_solve import dead_reckoning_result

    res = dead_reckoning_result(problem, first_poses=_reference_first(problem))
    return res.poses, res.landmarks, "-", res.seconds, "reference", None, ""


def _gtsam(problem):
    from rangeslam.rangeaided.gtsam_solve import solve_gtsam

    res = solve_gtsam(problem)
    first = "EDM windows" if res.start == "edm" else "data"
    return (res.poses, res.landmarks, res.status.name, res.seconds, first, res.judge_seconds,
            res.message)  # fmt: skip


def _gtsam_reference_start(problem):
    from rangeslam.rangeaided.gtsam_solve import solve_gtsam
    from rangeslam.rangeaided.start import landmark_start, odometry_start

    t0 = time.perf_counter()
    poses, _ = odometry_start(problem, _reference_first(problem))
    marks = landmark_start(problem, poses)
    prep = time.perf_counter() - t0
    res = solve_gtsam(problem, start=(poses, marks))
    seconds = prep + res.seconds  # the start, the graph, LM: as gtsam's row
    return (res.poses, res.landmarks, res.status.name, seconds, "reference", res.judge_seconds,
            res.message)  # fmt: skip


def _beacon_log_method(run):
    """A method of the beacon-log family as a PYFG_METHODS entry: ``run(data)`` on the problem as
    a :class:`rangeslam.beacons.RangeOdometry` (InvalidInputError, naming why, where it is
    not one: the row then says "not run" and the reason). Each starts at the origin facing +x
    (robot A's first pose, the gauge of the other rows) and derives its noise from the data,
    not from the file."""

    def method(problem):
        from rangeslam.beacons import RangeOdometry

        data = RangeOdometry.from_problem(problem)
        t0 = time.perf_counter()
        res = run(data)
        seconds = time.perf_counter() - t0
        placed = np.where(np.isfinite(res.beacons), res.beacons, np.nan)
        return res.poses, placed, res.status.name, seconds, "data", None, res.message

    return method


def _edm_gtsam(data):
    from rangeslam.beacons import beacon_slam

    return beacon_slam(data)


def _edm_isam2(data):
    from rangeslam.beacons import beacon_slam_incremental

    return beacon_slam_incremental(data)


def _ekf(data):
    from rangeslam.baselines import ekf_range_odometry

    return ekf_range_odometry(data, rng=np.random.default_rng(0))


def _gtsam_example(data):
    from rangeslam.baselines import gtsam_range_example

    return gtsam_range_example(data, rng=np.random.default_rng(0))


#: name -> function(problem) -> (poses, landmarks, status, seconds, first poses from ("data",
#: "reference"), judge seconds or None, message).
PYFG_METHODS = {
    "odometry": _odometry,
    "gtsam": _gtsam,
    "gtsam-reference-start": _gtsam_reference_start,
    "edm+gtsam": _beacon_log_method(_edm_gtsam),
    "edm+isam2": _beacon_log_method(_edm_isam2),
    "ekf": _beacon_log_method(_ekf),
    "gtsam-example": _beacon_log_method(_gtsam_example),
}


def _ape(problem, poses, marks) -> tuple[float, float]:
    from rangeslam.evaluation.metrics import ape, ape_statistics
    from rangeslam.rangeaided.poses import positions

    truth = problem.truth_landmarks
    if truth is None or not len(truth):
        truth = np.zeros((0, problem.dim))
        marks = np.zeros((0, problem.dim))
    stats = ape_statistics(ape(positions(poses), positions(problem.truth_poses),
                               np.nan_to_num(marks), truth).errors)  # fmt: skip
    return stats.mean, stats.rmse


def pyfg_rows(path: Path, methods: list[str]) -> list[dict]:
    """One row per method on the PyFG file ``path``: file, method, status, where the first
    poses came from, seconds (solve; judge apart), APE mean and RMSE [m], CORA's published
    seconds, and the message (or why the method did not run)."""
    from rangeslam.datasets.pyfg import load_pyfg
    from rangeslam.errors import InvalidInputError

    problem = load_pyfg(path)
    name = Path(path).stem
    rows = []
    for method in methods:
        row = {"file": name, "method": method, "cora_seconds": CORA_SECONDS.get(name)}
        try:
            poses, marks, status, seconds, first, judging, message = PYFG_METHODS[method](problem)
        except InvalidInputError as exc:
            rows.append({**row, "status": "not run", "message": str(exc)})
            continue
        mean, rmse = _ape(problem, poses, marks)
        rows.append({**row, "status": status, "first_poses": first, "seconds": seconds,
                     "judge_seconds": judging, "ape_mean_m": mean, "ape_rmse_m": rmse,
                     "message": message})  # fmt: skip
    return rows


def _table(rows: list[dict]) -> str:
    from rangeslam.app.reports import markdown

    def cell(row, key, spec):
        value = row.get(key)
        return "-" if value is None else format(value, spec)

    body = [[r["file"], r["method"], r.get("first_poses", "-"), r["status"],
             cell(r, "seconds", ".2f"), cell(r, "judge_seconds", ".1f"),
             cell(r, "ape_mean_m", ".3f"), cell(r, "ape_rmse_m", ".3f"),
             cell(r, "cora_seconds", ".2f")] for r in rows]  # fmt: skip
    header = ["file", "method", "first poses", "status", "time [s]", "judge [s]",
              "APE mean [m]", "APE RMSE [m]", "CORA's time [s] (their machine)"]  # fmt: skip
    return markdown(header, body)


def run_pyfg_bench(args: argparse.Namespace) -> int:
    """Every method of ``args.methods`` on every file of ``args.files``; writes pyfg_bench.md,
    .csv and .json in ``args.out`` and prints the table. Exit 0, or 2 on a bad file."""
    import sys

    from rangeslam.app.reports import versions, write_csv, write_summary
    from rangeslam.datasets.pyfg import PYFG_CITATION
    from rangeslam.errors import InvalidInputError

    rows: list[dict] = []
    try:
        for path in args.files:
            rows += pyfg_rows(path, args.methods)
    except InvalidInputError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = "## Range-aided SLAM on PyFG files\n\n" + _table(rows)
    (out / "pyfg_bench.md").write_text(text + "\n")
    written = [out / "pyfg_bench.md", write_csv(out / "pyfg_bench.csv", rows)]
    written.append(write_summary(out / "pyfg_bench.json", bench="pyfg", citation=PYFG_CITATION,
                                 rows=rows, versions=versions()))  # fmt: skip
    print(text)
    print("\nwritten: " + ", ".join(str(p) for p in written))
    return 0
