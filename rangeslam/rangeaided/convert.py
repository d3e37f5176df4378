"""A one-robot 2-D beacon log (:class:`~rangeslam.beacons.RangeOdometry`) as a
:class:`~rangeslam.rangeaided.RangeAidedProblem`, and back where the problem fits one.

The odometry step (distance d, heading change dtheta) is the relative pose Pose2(d, 0, dtheta)
(move, then turn: :func:`rangeslam.beacons.dead_reckoning`); beacons are landmarks; a range's
time is its pose's (a RangeOdometry keeps no range times).
"""

from __future__ import annotations

import numpy as np

from rangeslam.beacons.data import RangeOdometry
from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.problem import RangeAidedProblem, RangeMeasurements, RelativePoses

__all__ = ["problem_from_range_odometry", "range_odometry_from_problem"]


def _sigmas(data: RangeOdometry, odometry_sigma, range_sigma) -> tuple[np.ndarray, float]:
    from rangeslam.beacons.defaults import odometry_noise, range_noise

    odo = odometry_noise(data) if odometry_sigma is None else np.asarray(odometry_sigma, float)
    if odo.shape != (3,) or not np.all(np.isfinite(odo)) or np.any(odo <= 0):
        raise InvalidInputError(
            f"odometry_sigma must be 3 positive numbers (along [m], across [m], heading [rad]); "
            f"got {odometry_sigma!r:.80}"
        )
    r = range_noise(data) if range_sigma is None else range_sigma
    if isinstance(r, bool) or not isinstance(r, int | float | np.floating) or not r > 0:
        raise InvalidInputError(f"range_sigma must be a positive number [m]; got {range_sigma!r}")
    return odo, float(r)


def problem_from_range_odometry(
    data: RangeOdometry,
    *,
    odometry_sigma=None,
    range_sigma: float | None = None,
    truth_poses=None,
    truth_beacons=None,
) -> RangeAidedProblem:
    """``data`` as a RangeAidedProblem: robot "A" with poses 0..N, landmarks the beacons (ids
    ``beacon_ids``, rows in the same order).

    Args:
        data: the odometry and ranges.
        odometry_sigma: (3,) per step: along, across [m] and heading [rad] standard deviations
            (default: :func:`rangeslam.beacons.defaults.odometry_noise` of ``data``).
        range_sigma: the ranges' standard deviation [m] (default: derived from the data,
            :func:`rangeslam.beacons.defaults.range_noise`).
        truth_poses: (N + 1, 3) reference poses, or None. truth_beacons: (B, 2), or None.
    """
    if not isinstance(data, RangeOdometry):
        raise InvalidInputError(f"data must be a RangeOdometry; got {type(data).__name__}")
    odo_sigma, r_sigma = _sigmas(data, odometry_sigma, range_sigma)
    n = len(data.odometry)
    steps = np.column_stack([data.odometry[:, 0], np.zeros(n), data.odometry[:, 1]])
    r = len(data.ranges)
    return RangeAidedProblem(
        dim=2,
        robots=("A",),
        pose_robot=np.zeros(n + 1, np.int64),
        pose_index=np.arange(n + 1, dtype=np.int64),
        pose_time=data.pose_time,
        landmark_ids=data.beacon_ids,
        odometry=RelativePoses(
            np.arange(n),
            np.arange(1, n + 1),
            steps,
            np.broadcast_to(np.diag(odo_sigma**2), (n, 3, 3)),
            data.pose_time[1:],
        ),
        ranges=RangeMeasurements(
            data.range_pose,
            data.range_beacon,
            np.ones(r, bool),
            data.ranges,
            np.full(r, r_sigma**2),
            data.pose_time[data.range_pose],
        ),
        truth_poses=truth_poses,
        truth_landmarks=truth_beacons,
    )


def range_odometry_from_problem(problem: RangeAidedProblem) -> RangeOdometry:
    """The beacon log a RangeAidedProblem is, when it is one: one robot in 2-D, one odometry
    step from each pose to the next with no sideways motion (dy = 0), ranges to landmarks only,
    no landmark observations. Ranges are put in time order of their poses (stable); the noise
    the problem states is not carried (a RangeOdometry holds none).

    Raises:
        InvalidInputError naming what does not fit (the problem type holds more than a beacon
        log: several robots, 3-D, sideways odometry, ranges between robots).
    """
    if not isinstance(problem, RangeAidedProblem):
        raise InvalidInputError(
            f"problem must be a RangeAidedProblem; got {type(problem).__name__}"
        )
    o, r = problem.odometry, problem.ranges
    n = problem.n_poses
    reasons = []
    if problem.dim != 2 or len(problem.robots) != 1:
        robots = f"{len(problem.robots)} robot" + ("s" if len(problem.robots) > 1 else "")
        reasons.append(f"{problem.dim}-D with {robots} (one, in 2-D)")
    if len(o.time) != n - 1 or np.any(o.pose_b != o.pose_a + 1) or np.any(np.diff(o.pose_a) != 1):
        reasons.append("the odometry is not one step from each pose to the next, in order")
    elif np.any(o.values[:, 1] != 0):
        reasons.append("the odometry moves sideways (dy != 0)")
    if not np.all(r.to_landmark) or len(problem.landmark_observations.time):
        reasons.append("ranges between poses or landmark observations")
    if reasons:
        raise InvalidInputError("problem is not a beacon log: " + "; ".join(reasons))
    order = np.argsort(r.pose, kind="stable")
    return RangeOdometry(
        problem.pose_time, o.values[:, [0, 2]], r.pose[order], r.other[order],
        r.ranges[order], problem.n_landmarks, problem.landmark_ids,
    )  # fmt: skip
