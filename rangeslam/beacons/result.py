"""The result type of every range-only SLAM estimator with odometry (ours and the baselines)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam.status import HasStatus, Status

__all__ = ["BeaconSlamResult"]


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class BeaconSlamResult(HasStatus):
    """A trajectory and beacon map estimated from odometry and ranges. N steps, B beacons, R ranges.

    Attributes:
        method: what produced it (e.g. "edm+gtsam", "edm+isam2", "gtsam example", "odometry",
            "ekf").
        pose_time: (N + 1,) time of each pose, seconds.
        poses: (N + 1, 3) x, y [m] and heading [rad] of each pose (headings not wrapped).
        beacons: (B, 2) beacon positions [m], same frame; NaN rows for beacons the method did not
            place (e.g. odometry alone, or a beacon never initialised).
        range_bias: (B,) the estimated constant range offset per beacon [m] (one value repeated
            when it is shared); None when the method does not estimate one.
        range_inlier: (R,) True for ranges the estimate accepts (beacon_slam: calibrated
            residual within 3 range_sigma; rangeslam.baselines: their kernel weight or gate); None when
            the method does not use the ranges.
        status: how the estimate ended (:class:`~rangeslam.status.Status`). CONVERGED: the
            optimiser converged (batch: Levenberg-Marquardt; incremental: the final iSAM2 updates
            settled; rangeslam.baselines: their own test, e.g. the filter did not diverge) and
            every beacon ranged to was placed. NOT_IDENTIFIABLE: a beacon that was ranged to was
            never placed; SOLVER_FAILED: the optimiser stalled, did not settle, raised or
            diverged. ``converged`` is derived from it.
        message: why not, or a short description of the stop.
        range_scale: (B,) estimated range scale 1 + s per beacon (measured = scale * distance +
            bias); None when not estimated, NaN for beacons not placed (likewise ``range_bias``).
        initial_poses: (N + 1, 3) the initialisation the optimiser started from (None if none).
        initial_beacons: (B, 2) likewise (NaN for beacons not placed).
        seconds: wall time of the whole estimate [s].
    """

    method: str
    pose_time: np.ndarray
    poses: np.ndarray
    beacons: np.ndarray
    range_bias: np.ndarray | None
    range_inlier: np.ndarray | None
    status: Status
    message: str = ""
    range_scale: np.ndarray | None = None
    initial_poses: np.ndarray | None = None
    initial_beacons: np.ndarray | None = None
    seconds: float = float("nan")
