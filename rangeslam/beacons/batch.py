"""Batch range-only SLAM with odometry: windowed EDM initialisation, then GTSAM (paper, sec. 4).

Refinement: Pose2 odometry between factors, robust range factors, and the range calibration as
an unknown (:data:`~rangeslam.beacons.options.RANGE_CALIBRATIONS`). The radio ranges of the Plaza
data are about 7 % long (range minus true distance grows as 0.07 times the distance, intercept
within 0.1 m), which a constant bias cannot model, hence a scale and an offset.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_point, check_int, frozen
from rangeslam.beacons.data import RangeOdometry, all_heard_placed, check_data, dead_reckoning
from rangeslam.beacons.defaults import resolve_options
from rangeslam.beacons.graph import (
    beacon_array,
    build_graph,
    calibration_arrays,
    group_of_range,
    initial_values,
    pose_array,
    range_inliers,
)
from rangeslam.beacons.known import check_known_beacons, known_initialisation
from rangeslam.beacons.lm import MAX_LM_ITERATIONS, LMReport, levenberg_marquardt
from rangeslam.beacons.options import BeaconSlamOptions, check_initialisation
from rangeslam.beacons.result import BeaconSlamResult, as_calibration, calibration_check
from rangeslam.beacons.windows import Initialisation, edm_initialisation
from rangeslam.status import Status

__all__ = ["beacon_slam"]


@dataclass(frozen=True, eq=False)
class Refinement:
    """The refined estimate: poses (N + 1, 3), beacons (B, 2) (NaN where not placed), per-beacon
    range scale and offset (B,) (None when not estimated), and the LM report."""

    poses: np.ndarray
    beacons: np.ndarray
    scale: np.ndarray | None
    offset: np.ndarray | None
    report: LMReport


def beacon_slam(
    data: RangeOdometry,
    *,
    start_pose: ArrayLike = (0.0, 0.0, 0.0),
    max_iterations: int = 100,
    initialisation: str = "edm",
    rng: np.random.Generator | None = None,
    beacons: ArrayLike | None = None,
    beacon_sigma: float | None = None,
    **settings,
) -> BeaconSlamResult:
    """Batch range-only SLAM with odometry: windowed EDM initialisation, then GTSAM.

    1. Dead reckoning from ``start_pose`` (the gauge: the map is expressed in its frame).
    2. EDM completion per window of ``window_length`` metres: beacons in each window's frame.
    3. Stitching: a rigid correction per window and one position per beacon; the corrections,
       interpolated along the path (by distance travelled), move the dead-reckoned poses.
    4. GTSAM: Pose2 odometry, robust range factors with the range calibration unknown,
       Levenberg-Marquardt (the loop in Python, see
       :func:`~rangeslam.beacons.lm.levenberg_marquardt`).

    Raises SolverError when no window can place any beacon (e.g. a robot that never moved): there
    is nothing to refine. Beacons that no window places are NaN, their ranges unused (counted in
    ``message``), and the status is NOT_IDENTIFIABLE; a Levenberg-Marquardt run that does not
    converge gives SOLVER_FAILED.

    Args:
        data: the odometry and ranges (:class:`~rangeslam.beacons.data.RangeOdometry`).
        start_pose: pose 0, (x, y, heading); it fixes the gauge.
        max_iterations: Levenberg-Marquardt iterations at most, 1 to MAX_LM_ITERATIONS (100000).
        initialisation: "edm" (steps 2-3) or "random": dead-reckoned poses and beacons drawn
            from N(0, I) m as GTSAM's RangeISAMExample_plaza2 starts them (needs ``rng``): the
            same graph without the EDM, for comparison.
        rng: random generator for ``initialisation="random"``.
        beacons: (B, 2) known beacon positions, NaN rows for those not known (at least two
            known): they fix the frame instead of ``start_pose``, which then only starts the dead
            reckoning (:mod:`rangeslam.beacons.known`); the range calibration is still fitted.
        beacon_sigma: None (known beacons fixed) or their prior sigma [m].
        **settings: the fields of :class:`~rangeslam.beacons.options.BeaconSlamOptions`
            (range_calibration, per_beacon, range_sigma, odometry_sigma, robust,
            calibration_sigma, window_length, keyframes, min_ranges, min_spread, pose_weight).
    """
    t0 = time.perf_counter()
    check_data(data)
    max_iterations = check_int(max_iterations, "max_iterations", 1, MAX_LM_ITERATIONS)
    check_initialisation(initialisation, rng)
    cfg = resolve_options(BeaconSlamOptions.from_settings(settings), data)
    start = as_point(start_pose, "start_pose", dim=3)
    known = check_known_beacons(beacons, beacon_sigma, data)
    dr = dead_reckoning(data.odometry, start)
    start_unknown = (
        edm_initialisation
        if initialisation == "edm"
        else lambda data, dr, _cfg: random_initialisation(data, dr, rng)
    )
    if known is None:
        init = start_unknown(data, dr, cfg)
    else:
        init = known_initialisation(data, dr, cfg, known, start_unknown)
    refined = refine(data, init, cfg, max_iterations, known=known)
    return _verdict(data, init, refined, cfg, initialisation, time.perf_counter() - t0)


def random_initialisation(
    data: RangeOdometry, dr: np.ndarray, rng: np.random.Generator
) -> Initialisation:
    """Dead-reckoned poses and every heard beacon drawn from N(0, I) m (GTSAM's example)."""
    beacons0 = rng.standard_normal((data.n_beacons, 2))
    placed = np.isin(np.arange(data.n_beacons), data.range_beacon)
    beacons0[~placed] = np.nan
    return Initialisation(
        poses=dr, beacons=beacons0, placed=placed, notes=["random beacons, dead-reckoned poses"]
    )


def joint_problem(
    data: RangeOdometry,
    init: Initialisation,
    cfg: BeaconSlamOptions,
    calibration0: np.ndarray | None = None,
    known=None,
):
    """The joint model at ``init``: the factor graph over the ranges to placed beacons (range
    scale and offset unknowns of the graph), its values (calibration ``calibration0`` (G, nc),
    zero when None) and each key's dimension. ``graph.error(values)`` is the joint cost."""
    used = init.placed[data.range_beacon]
    values, dims = initial_values(
        init.poses, init.beacons, init.placed, cfg, data.n_beacons, calibration0
    )
    group, n_groups = group_of_range(data, cfg.per_beacon)
    graph = build_graph(
        init.poses[0],
        data.odometry,
        data.range_pose[used],
        data.range_beacon[used],
        data.ranges[used],
        group[used],
        n_groups,
        cfg,
        known,
    )
    return graph, values, dims


def refine(
    data: RangeOdometry,
    init: Initialisation,
    cfg: BeaconSlamOptions,
    max_iterations: int,
    calibration0: np.ndarray | None = None,
    known=None,
) -> Refinement:
    """Step 4: the factor graph over the ranges to placed beacons (the joint model: the range
    calibration an unknown of the graph), Levenberg-Marquardt from ``init`` and the calibration
    ``calibration0`` (G, nc) (zero when None)."""
    graph, values, dims = joint_problem(data, init, cfg, calibration0, known)
    values, report = levenberg_marquardt(graph, values, dims, max_iterations=max_iterations)
    scale, offset = calibration_arrays(values, cfg, data.n_beacons, init.placed)
    return Refinement(
        poses=pose_array(values, len(data.pose_time)),
        beacons=beacon_array(values, init.placed),
        scale=scale,
        offset=offset,
        report=report,
    )


def _verdict(
    data: RangeOdometry,
    init: Initialisation,
    refined: Refinement,
    cfg: BeaconSlamOptions,
    initialisation: str,
    seconds: float,
) -> BeaconSlamResult:
    """The result: NOT_IDENTIFIABLE when a beacon ranged to was never placed, SOLVER_FAILED when
    Levenberg-Marquardt did not converge, else CONVERGED; the notes as the message."""
    report, placed = refined.report, init.placed
    notes = list(init.notes)
    notes.append(
        f"LM: {report.message} after {report.iterations} iterations "
        f"(cost {report.initial_cost:.4g} -> {report.cost:.4g})"
    )
    if not np.all(placed):
        used = placed[data.range_beacon]
        notes.append(
            f"beacons never placed: {np.flatnonzero(~placed).tolist()} "
            f"({int(np.sum(~used))} of their ranges unused)"
        )
    status = report.status if all_heard_placed(data, placed) else Status.NOT_IDENTIFIABLE
    if status is Status.CONVERGED:
        check = calibration_check(refined.scale, refined.offset, data.ranges, data.range_beacon)
        status = check.status
        notes += [check.reason] if check.reason else []
    return BeaconSlamResult(
        method="edm+gtsam" if initialisation == "edm" else "gtsam random beacons",
        pose_time=data.pose_time,
        poses=frozen(refined.poses),
        beacons=frozen(refined.beacons),
        range_bias=as_calibration(refined.offset, cfg.per_beacon),
        range_inlier=range_inliers(
            data, refined.poses, refined.beacons, refined.scale, refined.offset, cfg
        ),
        status=status,
        message="; ".join(notes),
        range_scale=as_calibration(refined.scale, cfg.per_beacon),
        initial_poses=frozen(init.poses),
        initial_beacons=frozen(init.beacons),
        seconds=seconds,
        cost=float(report.cost),
    )
