"""Odometry alone (dead reckoning): the floor every range-only SLAM method must beat; and the
data every beacon baseline reads (a RangeOdometry, as beacon_slam takes, or a CMU Plaza set).

J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground
truth", Journal of Field Robotics 26(9), 2009.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_point, frozen
from rangeslam.beacons.data import RangeOdometry, dead_reckoning
from rangeslam.beacons.result import BeaconSlamResult
from rangeslam.datasets import PlazaDataset
from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.problem import RangeAidedProblem
from rangeslam.status import Status

__all__ = ["BaselineData", "baseline_data", "odometry_only"]


def odometry_only(
    data: RangeOdometry | PlazaDataset | RangeAidedProblem, *, start_pose: ArrayLike | None = None
) -> BeaconSlamResult:
    """Dead reckoning of ``data``'s odometry from ``start_pose`` (move, then turn).

    Args:
        data: the odometry and ranges, as :func:`rangeslam.beacons.beacon_slam` takes them
            (:class:`~rangeslam.beacons.RangeOdometry`), a range-aided problem that is a beacon
            log (:class:`~rangeslam.rangeaided.RangeAidedProblem`, e.g. a PyFG file: one robot
            in 2-D; InvalidInputError naming why where it is not), or a CMU Plaza data set
            (:func:`rangeslam.datasets.plaza`).
        start_pose: (3,) x, y [m], heading [rad] of pose 0; default ``data.truth[0]`` for a Plaza
            set (the true start, as GTSAM's RangeISAMExample_plaza2 hard-codes it), the origin
            facing +x for a RangeOdometry (as beacon_slam).

    Returns:
        :class:`BeaconSlamResult` with method "odometry": poses (N + 1, 3) by dead reckoning,
        beacons (B, 2) NaN (odometry places none), no range bias, no range inliers (the ranges
        are not used), status CONVERGED: it is the floor of the comparisons, and it claims no
        beacon and no range.

    Raises InvalidInputError when ``data`` is neither or ``start_pose`` is not a finite (3,)
    pose.
    """
    d = baseline_data(data, start_pose)
    poses = dead_reckoning(np.asarray(d.odometry, dtype=float), d.start)
    return BeaconSlamResult(
        method="odometry",
        pose_time=frozen(np.array(d.pose_time, dtype=float)),
        poses=frozen(poses),
        beacons=frozen(np.full((len(d.beacon_ids), 2), np.nan)),
        range_bias=None,
        range_inlier=None,
        status=Status.CONVERGED,
        message="dead reckoning: the ranges are not used",
    )


@dataclass(frozen=True, eq=False)  # arrays
class BaselineData:
    """What a baseline reads of its data, from a RangeOdometry or a PlazaDataset alike: pose
    times (N + 1,), odometry (N, 2), each range's pose, beacon row and value (R,), the beacons'
    ids (B,) and the start pose (3,)."""

    pose_time: np.ndarray
    odometry: np.ndarray
    range_pose: np.ndarray
    range_beacon: np.ndarray
    ranges: np.ndarray
    beacon_ids: np.ndarray
    start: np.ndarray


def baseline_data(data, start_pose: ArrayLike | None) -> BaselineData:
    """The fields a baseline uses, and the (3,) start pose (default: a Plaza set's first ground
    truth pose, the origin facing +x for a RangeOdometry). ``data``: a RangeOdometry, a
    PlazaDataset, or a :class:`rangeslam.rangeaided.RangeAidedProblem` that is a beacon log
    (:meth:`RangeOdometry.from_problem`: InvalidInputError naming why where it is not: several
    robots, 3-D, sideways odometry, ranges between robots). A Plaza set is read as it is (not
    validated again: a NaN put into its odometry reaches the filter, which reports it)."""
    if isinstance(data, RangeAidedProblem):
        data = RangeOdometry.from_problem(data)
    if isinstance(data, RangeOdometry):
        start = np.zeros(3) if start_pose is None else as_point(start_pose, "start_pose", dim=3)
        return BaselineData(
            data.pose_time, data.odometry, data.range_pose, data.range_beacon, data.ranges,
            data.beacon_ids, start,
        )  # fmt: skip
    start = resolve_start_pose(data, start_pose)
    return BaselineData(
        data.pose_time, data.odometry, data.range_pose, data.range_beacon_index, data.ranges,
        data.beacon_ids, start,
    )  # fmt: skip


def resolve_start_pose(data: PlazaDataset, start_pose: ArrayLike | None) -> np.ndarray:
    """Check ``data`` and return the (3,) start pose (default: the ground truth's first pose)."""
    if not isinstance(data, PlazaDataset):
        raise InvalidInputError(
            "data must be a RangeOdometry (rangeslam.beacons) or a PlazaDataset "
            f"(rangeslam.datasets.plaza); got {type(data).__name__}"
        )
    if start_pose is None:
        return np.array(data.truth[0], dtype=float)
    return as_point(start_pose, "start_pose", dim=3)
