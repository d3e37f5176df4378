"""Range-only SLAM with odometry and radio beacons (paper, section 4, on real radio data).

A robot at unknown poses measures its odometry and ranges to beacons at unknown positions; the
ranges carry an unknown constant bias (per beacon, or one for all). The geometry is the acoustic
SLAM's: the poses are the receivers, the beacons the landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BeaconSlamResult"]


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class BeaconSlamResult:
    """A trajectory and beacon map estimated from odometry and ranges. N steps, B beacons, R ranges.

    Attributes:
        method: what produced it (e.g. "edm+gtsam", "isam2", "gtsam example", "odometry", "ekf").
        pose_time: (N + 1,) time of each pose, seconds.
        poses: (N + 1, 3) x, y [m] and heading [rad] of each pose (headings not wrapped).
        beacons: (B, 2) beacon positions [m], same frame; NaN rows for beacons the method did not
            place (e.g. odometry alone, or a beacon never initialised).
        range_bias: (B,) the estimated constant range bias per beacon [m] (one value repeated when
            a global bias is estimated); None when the method does not estimate one.
        range_inlier: (R,) True for ranges the estimate accepts (robust kernel weight or gate);
            None when the method does not use the ranges.
        converged: the estimator ended normally (optimiser converged, filter did not diverge).
        message: why not, or a short description of the stop.
    """

    method: str
    pose_time: np.ndarray
    poses: np.ndarray
    beacons: np.ndarray
    range_bias: np.ndarray | None
    range_inlier: np.ndarray | None
    converged: bool
    message: str = ""
