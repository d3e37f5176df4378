"""The result type of every range-only SLAM estimator with odometry (ours and the baselines)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam._validation import frozen
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import PASSED, Check

__all__ = [
    "MAX_RELATIVE_BIAS",
    "MAX_SCALE_ERROR",
    "BeaconSlamResult",
    "as_calibration",
    "calibration_check",
]


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
        range_bias: the estimated constant range offset [m]: a float when one calibration is
            shared by all beacons (the default), (B,) with one per beacon (``per_beacon``, NaN
            for beacons not placed); None when the method does not estimate one.
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
        range_scale: the estimated range scale 1 + s (measured = scale * distance + bias): a
            float when shared, (B,) per beacon, as ``range_bias``; None when not estimated.
        initial_poses: (N + 1, 3) the initialisation the optimiser started from (None if none).
        initial_beacons: (B, 2) likewise (NaN for beacons not placed).
        seconds: wall time of the whole estimate [s].
        cost: the final cost of the estimator's own objective (GTSAM's graph error: half the sum
            of squared whitened residuals under the robust kernel); NaN when it has none.
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
    cost: float = float("nan")


def as_calibration(values: np.ndarray | None, per_beacon: bool) -> float | np.ndarray | None:
    """A calibration as a result holds it: the (B,) per-beacon ``values`` (NaN for beacons not
    placed) with ``per_beacon``, else the one shared value as a float (NaN when no beacon was
    placed); None stays None."""
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    if per_beacon:
        return frozen(values.copy())
    finite = values[np.isfinite(values)]
    return float(finite[0]) if finite.size else float("nan")


#: A range offset beyond this fraction of a beacon's median range, or a range scale further than
#: this from 1, is outside what a radio ranging chain does (Plaza1 in full: offset 0.04 m, scale
#: 1.065); an estimate there trades the calibration against the beacon positions.
MAX_RELATIVE_BIAS = 0.05
MAX_SCALE_ERROR = 0.2


def calibration_check(
    range_scale: np.ndarray | None,
    range_bias: np.ndarray | None,
    ranges: np.ndarray,
    range_beacon: np.ndarray,
) -> Check:
    """OUT_OF_RANGE when a placed beacon's range offset (B,) exceeds MAX_RELATIVE_BIAS of its
    median range (``ranges`` (R,) metres to beacons ``range_beacon`` (R,)) or its scale (B,) is
    further than MAX_SCALE_ERROR from 1 (NaN entries: beacons not placed)."""
    problems = []
    for b in range(0 if range_bias is None else len(range_bias)):
        heard = ranges[range_beacon == b]
        if heard.size == 0 or not np.isfinite(range_bias[b]):
            continue
        limit = MAX_RELATIVE_BIAS * float(np.median(heard))
        if abs(range_bias[b]) > limit:
            problems.append(f"beacon {b}: range offset {range_bias[b]:.3g} m (limit {limit:.3g} m)")
        if range_scale is not None and abs(range_scale[b] - 1.0) > MAX_SCALE_ERROR:
            problems.append(f"beacon {b}: range scale {range_scale[b]:.3g}")
    if not problems:
        return PASSED
    problems = list(dict.fromkeys(problems))  # a shared calibration repeats per beacon
    return Check(
        Status.OUT_OF_RANGE,
        f"{'; '.join(problems[:3])}{' ...' if len(problems) > 3 else ''}: outside what a ranging "
        "chain does; these data do not pin the calibration down (it trades against the beacon "
        "positions)",
    )
