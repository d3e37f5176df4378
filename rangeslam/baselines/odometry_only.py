"""Odometry alone (dead reckoning): the floor every range-only SLAM method on the CMU Plaza data
must beat.

J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground
truth", Journal of Field Robotics 26(9), 2009.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_point, frozen
from rangeslam.beacons.result import BeaconSlamResult
from rangeslam.datasets import PlazaDataset
from rangeslam.errors import InvalidInputError
from rangeslam.status import Status

__all__ = ["odometry_only"]


def odometry_only(data: PlazaDataset, *, start_pose: ArrayLike | None = None) -> BeaconSlamResult:
    """Dead reckoning of ``data``'s odometry from ``start_pose`` (move, then turn).

    Args:
        data: a CMU Plaza data set (:func:`rangeslam.datasets.plaza`).
        start_pose: (3,) x, y [m], heading [rad] of pose 0; default ``data.truth[0]`` (the true
            start, as GTSAM's RangeISAMExample_plaza2 hard-codes it).

    Returns:
        :class:`BeaconSlamResult` with method "odometry": poses (N + 1, 3) from
        ``data.dead_reckoning``, beacons (B, 2) NaN (odometry places none), no range bias, no
        range inliers (the ranges are not used), status CONVERGED.

    Raises InvalidInputError when ``data`` is not a PlazaDataset or ``start_pose`` is not a
    finite (3,) pose.
    """
    start = resolve_start_pose(data, start_pose)
    poses = np.array(data.dead_reckoning(start), dtype=float)
    return BeaconSlamResult(
        method="odometry",
        pose_time=frozen(np.array(data.pose_time, dtype=float)),
        poses=frozen(poses),
        beacons=frozen(np.full((len(data.beacon_ids), 2), np.nan)),
        range_bias=None,
        range_inlier=None,
        status=Status.CONVERGED,
        message="dead reckoning: the ranges are not used",
    )


def resolve_start_pose(data: PlazaDataset, start_pose: ArrayLike | None) -> np.ndarray:
    """Check ``data`` and return the (3,) start pose (default: the ground truth's first pose)."""
    if not isinstance(data, PlazaDataset):
        raise InvalidInputError(
            f"data must be a PlazaDataset (rangeslam.datasets.plaza); got {type(data).__name__}"
        )
    if start_pose is None:
        return np.array(data.truth[0], dtype=float)
    return as_point(start_pose, "start_pose", dim=3)
