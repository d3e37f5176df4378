"""``rangeslam run LOG.csv``: range-only SLAM of a beacon log (odometry and ranges to beacons).

The file's format: :mod:`rangeslam.datasets.beacon_log`. One library call does the work
(:func:`rangeslam.beacons.beacon_slam`, with the noise the file states and its known beacons);
this module reads the file, then prints and writes the report and a plot of the path and the
beacons (against the file's truth when it has one). The report counts the outliers (ranges more
than 3 range sigmas off the fit, per beacon, with their lines in the file) and gives the range
calibration (one scale and bias when shared). Exit 0 converged, 1 not converged, 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

__all__ = ["beacon_log_given", "beacon_run"]


def beacon_log_given(paths: list[Path]) -> bool:
    """True when ``rangeslam run`` was given one .csv or .txt file: a beacon log (RIRs are never
    text), so a file not in the format is refused naming the line that broke it."""
    return len(paths) == 1 and paths[0].suffix.lower() in (".csv", ".txt") and paths[0].is_file()


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


#: The kernel on the range factors of a beacon log's run (beacon_slam's default, named here so
#: the report can say it): ranges 40 sigmas long, 5% of them, are found and the path stays within
#: the noise (README, "Beacon logs"; Cauchy and Tukey did about as well).
RUN_KERNEL = "huber"


def _settings(log) -> dict:
    """beacon_slam's keywords from what the log states (the rest derived from its data), and
    the robust kernel :data:`RUN_KERNEL`."""
    settings: dict = {"robust": RUN_KERNEL}
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


def _outlier_lines(log, res, record: dict) -> list[str]:
    """Report lines on the ranges the fit does not explain (beyond 3 range sigmas of it:
    ``res.range_inlier``; ranges to beacons never placed are unused, not outliers): how many,
    per beacon, their lines in the file; the counts and every line in ``record``."""
    from rangeslam.beacons.defaults import range_noise

    d = log.data
    placed = np.all(np.isfinite(res.beacons), axis=1)[d.range_beacon]
    out = placed & ~np.asarray(res.range_inlier, dtype=bool)
    sigma, said = log.range_sigma, "stated"
    if sigma is None:
        sigma, said = range_noise(d), "from the data"
    where = log.range_lines[out] if log.range_lines is not None else np.array([], dtype=int)
    record.update(
        n_ranges=len(d.ranges),
        n_outliers=int(out.sum()),
        outlier_threshold_m=3.0 * sigma,
        outlier_lines=[int(n) for n in where],
    )
    per_beacon = [
        f"{int(b)}: {int(out[d.range_beacon == k].sum())} of {int(np.sum(d.range_beacon == k))}"
        for k, b in enumerate(d.beacon_ids)
    ]
    text = [
        f"- outliers: {int(out.sum())} of {len(d.ranges)} ranges ({100 * out.mean():.1f}%) are "
        f"more than 3 range sigmas ({3 * sigma:.3g} m, sigma {said}) off the fit, which the "
        f"robust kernel ({RUN_KERNEL}) down-weighted; per beacon: {', '.join(per_beacon)}"
    ]
    if out.any():
        more = " ..." if out.sum() > 10 else ""
        text.append(
            f"- outlying ranges on lines {', '.join(str(int(n)) for n in where[:10])}{more} "
            "(all in run_summary.json, outlier_lines)"
        )
    for k, b in enumerate(d.beacon_ids):
        mine = d.range_beacon == k
        if np.any(placed[mine]) and 2 * np.sum(out[mine]) >= np.sum(mine):
            text.append(
                f"- warning: beacon {int(b)} kept at most half of its ranges: it is placed "
                "against the other half of its data"
            )
    return text


def _as_json(value):
    """A calibration for the JSON: None, a float (shared), or a list (per beacon)."""
    if value is None:
        return None
    return float(value) if np.ndim(value) == 0 else np.asarray(value, dtype=float).tolist()


def _calibration_lines(res, record: dict) -> list[str]:
    """The range calibration found (measured = scale x distance + bias) in the report and in
    ``record``: floats when one is shared by the beacons (beacon_slam's default)."""
    scale, bias = res.range_scale, res.range_bias
    record.update(range_scale=_as_json(scale), range_bias=_as_json(bias))
    if np.ndim(scale) or np.ndim(bias):
        return []
    scale = 1.0 if scale is None else scale
    bias = 0.0 if bias is None else bias
    return [f"- range calibration (shared): measured = {scale:.5g} x distance + {bias:.3g} m"]


def _plot(out: Path, log, res) -> Path:
    """run_trajectory.png: the path and the beacons placed, each named by its id ('known' for
    a surveyed one), rigidly aligned onto the file's truth when it has one (with the true
    beacons)."""
    from rangeslam.app.plotting import plot_walk_estimate
    from rangeslam.geometry.alignment import align

    placed = np.all(np.isfinite(res.beacons), axis=1)
    path, marks = res.poses[:, :2], res.beacons[placed]
    known = np.zeros(len(placed), bool) if log.known is None else np.isfinite(log.known[:, 0])
    names = [f"beacon {int(b)}" + (" (known)" if k else "")
             for b, k in zip(log.data.beacon_ids[placed], known[placed], strict=True)]  # fmt: skip
    truth = rot = shift = true_marks = None
    if log.truth is not None and np.all(np.isfinite(path)):
        fit = align(path, log.truth[:, :2])
        truth, rot, shift = log.truth[:, :2], fit.rotation, fit.translation
        if log.beacons is not None:
            true_marks = log.beacons[np.all(np.isfinite(log.beacons), axis=1)]
    verdict = "converged" if res.converged else "not converged"
    return plot_walk_estimate(
        out / "run_trajectory.png", receivers=path, sources=marks, true_trajectory=truth,
        rotation=rot, translation=shift, true_landmarks=true_marks, landmark_names=names,
        title=f"{log.path.name}: {res.method}, {verdict}", converged=bool(res.converged),
    )  # fmt: skip


def _write(out: Path, log, res, lines: list[str], extra: dict) -> list[Path]:
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
        **extra,
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
    d, extra = log.data, {}
    lines = [
        f"# Beacon log {log.path.name}",
        "",
        f"- {len(d.odometry)} odometry steps, {len(d.ranges)} ranges to {d.n_beacons} beacons"
        + (
            f" ({int(np.sum(np.isfinite(log.known[:, 0])))} known)" if log.known is not None else ""
        ),
        f"- {res.method}: {res.status.name} in {res.seconds:.1f} s ({res.message})",
        *_outlier_lines(log, res, extra),
        *_calibration_lines(res, extra),
        *_against_truth(log, res),
    ]
    written = _write(args.out, log, res, lines, extra)
    print("\n".join(lines))
    print("\nwritten: " + ", ".join(str(p) for p in written))
    if not res.converged:
        print(f"rangeslam: not converged: {res.message}", file=sys.stderr)
        return 1
    return 0
