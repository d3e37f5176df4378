"""GTSAM values of a range-aided SLAM problem and Levenberg-Marquardt on its graph: pose rows
to Pose2 / Pose3 and back, (poses, landmarks) arrays to ``gtsam.Values`` and back, the cost in
deviance units.

Keys: ``x`` + pose row, ``l`` + landmark row. Pose rows as the problem's: (x, y, theta) [m, m,
rad] in 2-D, (x, y, z, qx, qy, qz, qw) [m, unit quaternion, scalar last] in 3-D.
"""

from __future__ import annotations

import numpy as np

from rangeslam.rangeaided.problem import RangeAidedProblem

__all__ = [
    "MAX_ITERATIONS",
    "RELATIVE_TOLERANCE",
    "deviance",
    "estimates",
    "gtsam_pose",
    "levenberg_marquardt",
    "pose_row",
    "to_values",
]

#: Levenberg-Marquardt's iteration limit and relative error tolerance (GTSAM's defaults are 100
#: and 1e-5).
MAX_ITERATIONS = 200
RELATIVE_TOLERANCE = 1e-6


def gtsam_pose(gtsam, row: np.ndarray):
    """A gtsam Pose2 of a (3,) row, or Pose3 of a (7,) row (quaternion normalised)."""
    if len(row) == 3:
        return gtsam.Pose2(*row)
    q = row[3:] / np.linalg.norm(row[3:])
    return gtsam.Pose3(gtsam.Rot3.Quaternion(q[3], q[0], q[1], q[2]), gtsam.Point3(*row[:3]))


def pose_row(gtsam, pose, dim: int) -> np.ndarray:
    """(3,) or (7,) row of a gtsam Pose2 / Pose3 (quaternion with qw >= 0)."""
    if dim == 2:
        return np.array([pose.x(), pose.y(), pose.theta()])
    q = pose.rotation().toQuaternion()
    out = np.array([*pose.translation(), q.x(), q.y(), q.z(), q.w()])
    return out * (1.0 if out[6] >= 0 else np.r_[1, 1, 1, -1, -1, -1, -1])


def to_values(poses: np.ndarray, marks: np.ndarray):
    """gtsam.Values of (P, w) pose rows (keys x0 ...) and (L, d) landmarks [m] (keys l0 ...)."""
    import gtsam

    values = gtsam.Values()
    for i, row in enumerate(np.asarray(poses, dtype=float)):
        values.insert(gtsam.symbol("x", i), gtsam_pose(gtsam, row))
    for j, point in enumerate(np.asarray(marks, dtype=float)):
        values.insert(gtsam.symbol("l", j), np.asarray(point, float))
    return values


def estimates(values, problem: RangeAidedProblem) -> tuple[np.ndarray, np.ndarray]:
    """((P, w) poses, (L, d) landmarks [m]) of GTSAM ``values``."""
    import gtsam

    dim = problem.dim
    at = values.atPose2 if dim == 2 else values.atPose3
    poses = np.array(
        [pose_row(gtsam, at(gtsam.symbol("x", i)), dim) for i in range(problem.n_poses)]
    )
    point = values.atPoint2 if dim == 2 else values.atPoint3
    marks = [point(gtsam.symbol("l", j)) for j in range(problem.n_landmarks)]
    return poses, np.array(marks, dtype=float).reshape(-1, dim)


def levenberg_marquardt(graph, values, max_iterations: int = MAX_ITERATIONS):
    """(answer values, iterations) of GTSAM's Levenberg-Marquardt on ``graph`` from ``values``
    (relative error tolerance :data:`RELATIVE_TOLERANCE`)."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(RELATIVE_TOLERANCE)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    answer = optimizer.optimize()
    return answer, int(optimizer.iterations())


def deviance(graph, values) -> float:
    """-2 log likelihood of ``values`` on ``graph`` up to a constant (dimensionless): twice
    GTSAM's error (half the sum of squared whitened residuals) for Gaussian factors."""
    return 2.0 * float(graph.error(values))
