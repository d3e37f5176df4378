"""``rangeslam run FILE.pyfg``: a range-aided SLAM problem (CORA's PyFG files) solved with GTSAM
from the odometry, each robot's first pose placed from the data (never from the reference),
judged, and scored against the file's reference values (the only use of them).

One library call does the work (:func:`rangeslam.rangeaided.gtsam_solve.solve_gtsam`); this
module reads the file and writes, in ``--out``:

- ``run_trajectory.tum`` (robot A), ``run_trajectory_B.tum``, ... one TUM file per robot
  (``timestamp x y z qx qy qz qw``, evo's format), and ``run_reference*.tum`` the file's
  reference values the same way, so ``evo_ape tum run_reference.tum run_trajectory.tum -a``
  scores one robot;
- ``run_landmarks.csv``: each landmark's estimate and reference;
- ``run_summary.md`` / ``.json``: the verdict with every check (name, statistic, level,
  passed), how each robot was placed, the time, and the APE against the reference: all robots
  and landmarks moved by one rigid motion (evo's ``-a``, no scale) fitted to all poses, with
  odometry alone (from the same first poses) beside it;
- ``run_trajectory.png``: the aligned paths over the reference.

Exit 0 converged, 1 not converged, 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

__all__ = ["pyfg_given", "pyfg_run", "score", "tum_name"]


def pyfg_given(paths: list[Path]) -> bool:
    """True when ``rangeslam run`` was given one ``.pyfg`` file."""
    return len(paths) == 1 and paths[0].suffix.lower() == ".pyfg"


def tum_name(stem: str, robot: int) -> str:
    """``run_trajectory.tum`` for the first robot, ``run_trajectory_B.tum`` ... after (the
    robot's letter, or its number when the letters do not follow A, B, C)."""
    return f"{stem}.tum" if robot == 0 else f"{stem}_{chr(ord('A') + robot)}.tum"


def score(problem, result) -> dict:
    """APE of ``result`` against ``problem``'s reference: one rigid motion (no scale) fitted to
    all poses' positions carries every robot and landmark (evo's ``-a`` on the joint
    trajectory). Returns mean, median, max, rmse [m] and the landmark errors [m]."""
    from rangeslam.evaluation.metrics import ape, ape_statistics
    from rangeslam.rangeaided.poses import positions

    if problem.truth_poses is None:
        return {}
    marks = result.landmarks if problem.n_landmarks else np.zeros((0, problem.dim))
    truth = (
        problem.truth_landmarks
        if problem.truth_landmarks is not None
        else np.full_like(marks, np.nan)
    )
    fit = ape(positions(result.poses), positions(problem.truth_poses), marks, truth)
    stats = ape_statistics(fit.errors)
    return {
        "ape_mean_m": stats.mean, "ape_median_m": stats.median, "ape_max_m": stats.max,
        "ape_rmse_m": stats.rmse, "landmark_errors_m": [float(e) for e in fit.beacon_errors],
        "aligned": fit.aligned, "aligned_landmarks": fit.aligned_beacons,
    }  # fmt: skip


def _quaternions(poses: np.ndarray) -> np.ndarray:
    """(n, 4) TUM orientations: 2-D headings as rotations about z; 3-D quaternions as they are."""
    if poses.shape[1] == 7:
        return poses[:, 3:]
    half = 0.5 * poses[:, 2]
    return np.column_stack([np.zeros((len(poses), 2)), np.sin(half), np.cos(half)])


def _write_tums(out: Path, problem, poses: np.ndarray, stem: str) -> list[Path]:
    from rangeslam.app.reports import write_tum
    from rangeslam.rangeaided.poses import positions

    written = []
    for r in range(len(problem.robots)):
        rows = problem.robot_rows(r)
        path = out / tum_name(stem, r)
        write_tum(path, positions(poses[rows]), times=problem.pose_time[rows],
                  quaternions=_quaternions(poses[rows]))  # fmt: skip
        written.append(path)
    return written


def _plot(out: Path, problem, result, scores: dict, title: str) -> Path:
    """run_trajectory.png: each robot's aligned path over the reference, landmarks (top view)."""
    import matplotlib.pyplot as plt

    from rangeslam.app.plot_style import save_figure
    from rangeslam.rangeaided.poses import positions

    fig, ax = plt.subplots(figsize=(7, 6))
    est = scores.get("aligned", positions(result.poses))
    ref = None if problem.truth_poses is None else positions(problem.truth_poses)
    for r, name in enumerate(problem.robots):
        rows = problem.robot_rows(r)
        line = ax.plot(est[rows, 0], est[rows, 1], lw=1.2, label=f"robot {name} (estimate)")[0]
        if ref is not None:
            ax.plot(ref[rows, 0], ref[rows, 1], "--", lw=0.8, color=line.get_color(), alpha=0.6,
                    label=f"robot {name} (reference)")  # fmt: skip
    marks = scores.get("aligned_landmarks", result.landmarks)
    if problem.n_landmarks:
        ax.plot(marks[:, 0], marks[:, 1], "k^", label="landmarks (estimate)")
        if problem.truth_landmarks is not None:
            ax.plot(problem.truth_landmarks[:, 0], problem.truth_landmarks[:, 1], "kx",
                    label="landmarks (reference)")  # fmt: skip
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    return save_figure(fig, out / "run_trajectory.png")


def _check_words(check) -> str:
    """One check in words: "name passed (statistic against level)"."""
    verdict = "passed" if check.passed else "FAILED"
    return f"{check.name} {verdict} ({check.statistic:.4g} against {check.level:.4g})"


def _lines(path: Path, problem, result, scores: dict, odometry: dict) -> list[str]:
    r = problem.ranges
    lines = [
        f"# PyFG file {path.name}",
        "",
        f"- {problem.dim}-D, {len(problem.robots)} robots ({', '.join(problem.robots)}), "
        f"{problem.n_poses} poses, {problem.n_landmarks} landmarks, {len(problem.odometry.time)} "
        f"odometry edges, {len(r.ranges)} ranges ({int(np.sum(~r.to_landmark))} between poses), "
        f"{len(problem.landmark_observations.time)} landmark observations",
        f"- {result.method}: **{result.status.name}** in {result.seconds:.2f} s (judge "
        f"{result.judge_seconds:.2f} s), {result.iterations} iterations ({result.message})",
        f"- first poses: {result.placement}",
        "- checks: " + "; ".join(_check_words(c) for c in result.checks),
    ]
    if scores:
        lines.append(
            f"- APE (all robots, one rigid alignment, no scale): mean {scores['ape_mean_m']:.4g} "
            f"m, median {scores['ape_median_m']:.4g} m, max {scores['ape_max_m']:.4g} m, RMSE "
            f"{scores['ape_rmse_m']:.4g} m; odometry alone: mean {odometry['ape_mean_m']:.4g} m, "
            f"RMSE {odometry['ape_rmse_m']:.4g} m"
        )
    return lines


def _write(out: Path, path: Path, problem, result, lines: list[str], extra: dict) -> list[Path]:
    from rangeslam.app.reports import versions, write_csv, write_summary
    from rangeslam.app.run_command import clear_run_files

    out.mkdir(parents=True, exist_ok=True)
    clear_run_files(out)
    written = _write_tums(out, problem, result.poses, "run_trajectory")
    if problem.truth_poses is not None:
        written += _write_tums(out, problem, problem.truth_poses, "run_reference")
    axes = "xyz"[: problem.dim]
    rows = []
    for j, name in enumerate(problem.landmark_names):
        row = {"landmark": name, **{a: float(result.landmarks[j, k]) for k, a in enumerate(axes)}}
        if problem.truth_landmarks is not None:
            row.update({f"reference_{a}": float(problem.truth_landmarks[j, k])
                        for k, a in enumerate(axes)})  # fmt: skip
        rows.append(row)
    written.append(write_csv(out / "run_landmarks.csv", rows or [{"landmark": ""}]))
    title = f"{path.name}: {result.method}, {result.status.name}"
    written.append(_plot(out, problem, result, extra.pop("plot_scores"), title))
    (out / "run_summary.md").write_text("\n".join(lines) + "\n")
    record = {"mode": "pyfg", "file": str(path), "method": result.method,
              "status": result.status.name, "converged": result.converged,
              "message": result.message, "seconds": result.seconds,
              "iterations": result.iterations, "judge_seconds": result.judge_seconds,
              "placement": result.placement,
              "checks": [{"name": c.name, "statistic": float(c.statistic), "level": float(c.level),
                          "passed": bool(c.passed), "reason": c.reason} for c in result.checks],
              **extra}  # fmt: skip
    summary = write_summary(out / "run_summary.json", **record, versions=versions())
    return [summary, out / "run_summary.md", *written]


def pyfg_run(args: argparse.Namespace) -> int:
    """Load the PyFG file ``args.rirs[0]``, solve it, print and write the report."""
    from rangeslam.app.beacon_run import RIR_FLAGS
    from rangeslam.datasets.pyfg import load_pyfg
    from rangeslam.errors import InvalidInputError
    from rangeslam.rangeaided.gtsam_solve import dead_reckoning_result, solve_gtsam

    given = [
        flag for dest, flag in RIR_FLAGS.items() if getattr(args, dest, None) not in (None, False)
    ]
    if given:
        print(f"rangeslam: error: {', '.join(given)}: for RIRs; a PyFG file ({args.rirs[0]}) "
              "takes none of them (its noise and reference are in the file)", file=sys.stderr)  # fmt: skip
        return 2
    path = args.rirs[0]
    try:
        problem = load_pyfg(path)
        result = solve_gtsam(problem)
    except InvalidInputError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 2
    scores = score(problem, result)
    odometry = score(problem, dead_reckoning_result(problem, first_poses=result.first_poses))
    lines = _lines(path, problem, result, scores, odometry)
    extra = {k: v for k, v in scores.items() if not k.startswith("aligned")}
    extra["odometry_ape_mean_m"] = odometry.get("ape_mean_m")
    extra["odometry_ape_rmse_m"] = odometry.get("ape_rmse_m")
    extra["plot_scores"] = scores
    written = _write(args.out, path, problem, result, lines, extra)
    print("\n".join(lines))
    print("\nwritten: " + ", ".join(str(p) for p in written))
    if not result.converged:
        print(f"rangeslam: not converged: {result.message}", file=sys.stderr)
        return 1
    return 0
