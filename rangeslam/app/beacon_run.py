"""``rangeslam run LOG.csv``: range-only SLAM of a beacon log (odometry and ranges to beacons).

The file's format: :mod:`rangeslam.datasets.beacon_log`. One library call does the work
(:func:`rangeslam.beacons.beacon_slam`, with the noise the file states and its known beacons);
this module reads the file, then prints and writes the report and a plot of the path and the
beacons (against the file's truth when it has one). Exit 0 converged, 1 not converged,
2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

__all__ = ["beacon_log_given", "beacon_run"]


def beacon_log_given(paths: list[Path]) -> bool:
    """True when ``rangeslam run`` was given one file and it is a beacon log."""
    from rangeslam.datasets.beacon_log import is_beacon_log

    return len(paths) == 1 and is_beacon_log(paths[0])


#: ``rangeslam run``'s options for RIRs (dest: flag), refused with a beacon log rather than
#: ignored: --excitation or --unknown-emission on a log did nothing and said nothing.
RIR_FLAGS = {
    "fs": "--fs", "mics": "--mics", "mics_from_npz": "--mics-from-npz",
    "step_bounds": "--step-bounds", "step_bounds_from_npz": "--step-bounds-from-npz",
    "keyframes": "--keyframes", "c": "--c", "measured": "--measured",
    "use_clipped": "--use-clipped", "fixed_c": "--fixed-c", "excitation": "--excitation",
    "unknown_emission": "--unknown-emission",
}  # fmt: skip


def _rir_flags(args: argparse.Namespace) -> list[str]:
    """The options for RIRs (:data:`RIR_FLAGS`) given, in the order of the table."""
    return [
        flag for dest, flag in RIR_FLAGS.items() if getattr(args, dest, None) not in (None, False)
    ]


def _settings(log) -> dict:
    """beacon_slam's keywords from what the log states (the rest derived from its data)."""
    settings: dict = {}
    if log.range_sigma is not None:
        settings["range_sigma"] = log.range_sigma
    if log.odometry_sigma is not None:
        settings["odometry_sigma"] = log.odometry_sigma
    if log.known is not None:
        settings["beacons"] = log.known
    return settings


def _against_truth(log, res) -> list[str]:
    """Report lines on the errors against the file's truth (none without truth)."""
    from rangeslam.evaluation.metrics import ape

    if log.truth is None:
        return []
    true_beacons = log.beacons if log.beacons is not None else np.full_like(res.beacons, np.nan)
    fit = ape(res.poses[:, :2], log.truth[:, :2], res.beacons, true_beacons)
    lines = [f"- APE (rigidly aligned) mean {np.nanmean(fit.errors):.4g} m, max "
             f"{np.nanmax(fit.errors):.4g} m"]  # fmt: skip
    if log.known is not None:
        raw = np.linalg.norm(res.poses[:, :2] - log.truth[:, :2], axis=1)
        lines.append(f"- position error in the known beacons' frame: mean {np.mean(raw):.4g} m")
    return lines


def _plot(out: Path, log, res) -> Path:
    """run_trajectory.png: the path and the beacons placed, rigidly aligned onto the file's
    truth when it has one (with the true beacons)."""
    from rangeslam.app.plotting import plot_walk_estimate
    from rangeslam.geometry.alignment import align

    path, marks = res.poses[:, :2], res.beacons[np.all(np.isfinite(res.beacons), axis=1)]
    truth = rot = shift = true_marks = None
    if log.truth is not None and np.all(np.isfinite(path)):
        fit = align(path, log.truth[:, :2])
        truth, rot, shift = log.truth[:, :2], fit.rotation, fit.translation
        if log.beacons is not None:
            true_marks = log.beacons[np.all(np.isfinite(log.beacons), axis=1)]
    verdict = "converged" if res.converged else "not converged"
    return plot_walk_estimate(
        out / "run_trajectory.png", receivers=path, sources=marks, true_trajectory=truth,
        rotation=rot, translation=shift, true_landmarks=true_marks,
        title=f"{log.path.name}: {res.method}, {verdict}", converged=bool(res.converged),
    )  # fmt: skip


def _write(out: Path, log, res, lines: list[str]) -> list[Path]:
    """run_summary.md / .json, run_trajectory.csv and run_landmarks.csv in ``out``."""
    from rangeslam.app.reports import versions, write_csv, write_summary
    from rangeslam.app.run_command import clear_run_files

    clear_run_files(out)
    traj = [
        {"time": t, "x": p[0], "y": p[1], "heading": p[2]}
        for t, p in zip(res.pose_time, res.poses, strict=True)
    ]
    marks = [
        {"beacon": int(b), "x": xy[0], "y": xy[1]}
        for b, xy in zip(log.data.beacon_ids, res.beacons, strict=True)
    ]
    written = [
        write_csv(out / "run_trajectory.csv", traj),
        write_csv(out / "run_landmarks.csv", marks),
        _plot(out, log, res),
    ]
    (out / "run_summary.md").write_text("\n".join(lines) + "\n")
    record = {
        "mode": "beacons",
        "file": str(log.path),
        "method": res.method,
        "status": res.status.name,
        "message": res.message,
        "range_scale": None if res.range_scale is None else float(np.nanmedian(res.range_scale)),
        "range_bias": None if res.range_bias is None else float(np.nanmedian(res.range_bias)),
        "seconds": res.seconds,
    }
    summary = write_summary(out / "run_summary.json", **record, versions=versions())
    return [summary, out / "run_summary.md", *written]


def beacon_run(args: argparse.Namespace) -> int:
    """Load the beacon log ``args.rirs[0]``, run beacon_slam, print and write the report."""
    from rangeslam.beacons import beacon_slam
    from rangeslam.datasets.beacon_log import load_beacon_log
    from rangeslam.errors import InvalidInputError, SolverError

    given = _rir_flags(args)
    if given:
        print(
            f"rangeslam: error: {', '.join(given)}: for RIRs; a beacon log ({args.rirs[0]}) "
            "takes none of them (its noise, known beacons and truth are in the file)",
            file=sys.stderr,
        )
        return 2
    try:
        log = load_beacon_log(args.rirs[0])
        res = beacon_slam(log.data, **_settings(log))
    except InvalidInputError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 2
    except SolverError as exc:
        print(f"rangeslam: not converged: {exc}", file=sys.stderr)
        return 1
    d = log.data
    lines = [
        f"# Beacon log {log.path.name}",
        "",
        f"- {len(d.odometry)} odometry steps, {len(d.ranges)} ranges to {d.n_beacons} beacons"
        + (
            f" ({int(np.sum(np.isfinite(log.known[:, 0])))} known)" if log.known is not None else ""
        ),
        f"- {res.method}: {res.status.name} in {res.seconds:.1f} s ({res.message})",
        *_against_truth(log, res),
    ]
    written = _write(args.out, log, res, lines)
    print("\n".join(lines))
    print("\nwritten: " + ", ".join(str(p) for p in written))
    if not res.converged:
        print(f"rangeslam: not converged: {res.message}", file=sys.stderr)
        return 1
    return 0
