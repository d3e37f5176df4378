"""GTSAM for a range-aided SLAM problem: Pose2 / Pose3 between factors with the problem's
covariances, range factors pose-landmark and pose-pose, bearing-range factors for 2-D relative
landmark observations, priors; Levenberg-Marquardt from a start (by default the odometry:
:mod:`rangeslam.rangeaided.start`), then the verdict (:func:`judge`).

Keys: ``x`` + pose row, ``l`` + landmark row. GTSAM's Pose3 tangent is (rotation, translation);
the problem's covariances are translation first, so they are permuted (:func:`gtsam_covariance`).
Without priors in the problem, the first pose of the first robot is held at its start by a
prior of :data:`GAUGE_SIGMA` (the gauge: the answer is compared after rigid alignment).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from rangeslam._robust import mad_sigma
from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.poses import positions
from rangeslam.rangeaided.problem import RangeAidedProblem, tangent_width
from rangeslam.rangeaided.start import landmark_start, odometry_start
from rangeslam.status import HasStatus, Status, status_message
from rangeslam.verdict.checks import tail_limit
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = [
    "GAUGE_SIGMA",
    "FactorGroups",
    "RangeAidedResult",
    "build_graph",
    "dead_reckoning_result",
    "gtsam_covariance",
    "judge",
    "position_estimates",
    "solve_gtsam",
]

#: Standard deviation (m and rad) of the prior that fixes the gauge at the first robot's first
#: pose when the problem has no priors.
GAUGE_SIGMA = 1e-6
#: Levenberg-Marquardt's iteration limit and relative error tolerance (GTSAM's defaults are 100
#: and 1e-5).
MAX_ITERATIONS = 200
#: Whitened residuals all below this are exact data fitted to round-off: no tail is judged.
EXACT_SIGMAS = 1e-6
RELATIVE_TOLERANCE = 1e-6


def gtsam_covariance(cov: np.ndarray) -> np.ndarray:
    """(k, k) covariance in GTSAM's tangent order: unchanged in 2-D (x, y, theta); in 3-D the
    problem's (translation, rotation) becomes (rotation, translation)."""
    if len(cov) == 3:
        return cov
    order = [3, 4, 5, 0, 1, 2]
    return cov[np.ix_(order, order)]


def _pose(gtsam, row: np.ndarray):
    if len(row) == 3:
        return gtsam.Pose2(*row)
    q = row[3:] / np.linalg.norm(row[3:])
    return gtsam.Pose3(gtsam.Rot3.Quaternion(q[3], q[0], q[1], q[2]), gtsam.Point3(*row[:3]))


def _pose_row(gtsam, pose, dim: int) -> np.ndarray:
    if dim == 2:
        return np.array([pose.x(), pose.y(), pose.theta()])
    q = pose.rotation().toQuaternion()
    out = np.array([*pose.translation(), q.x(), q.y(), q.z(), q.w()])
    return out * (1.0 if out[6] >= 0 else np.r_[1, 1, 1, -1, -1, -1, -1])


@dataclass(frozen=True)
class FactorGroups:
    """Which factors of the graph are which: index ranges [start, stop) per kind."""

    odometry: range
    ranges: range
    observations: range
    priors: range


def _add_measurements(gtsam, graph, problem: RangeAidedProblem, x, lm) -> tuple[range, ...]:
    dim, o, r, s = problem.dim, problem.odometry, problem.ranges, problem.landmark_observations
    between = gtsam.BetweenFactorPose2 if dim == 2 else gtsam.BetweenFactorPose3
    cov = gtsam.noiseModel.Gaussian.Covariance
    start = graph.size()
    for a, b, value, c in zip(o.pose_a, o.pose_b, o.values, o.covariance, strict=True):
        graph.add(between(x(a), x(b), _pose(gtsam, value), cov(gtsam_covariance(c))))
    odo = range(start, graph.size())
    to_point = gtsam.RangeFactor2D if dim == 2 else gtsam.RangeFactor3D
    to_pose = gtsam.RangeFactorPose2 if dim == 2 else gtsam.RangeFactorPose3
    for a, b, mark, dist, var in zip(r.pose, r.other, r.to_landmark, r.ranges, r.variance,
                                     strict=True):  # fmt: skip
        noise = gtsam.noiseModel.Isotropic.Sigma(1, float(np.sqrt(var)))
        factor = to_point(x(a), lm(b), dist, noise) if mark else to_pose(x(a), x(b), dist, noise)
        graph.add(factor)
    rng_ = range(odo.stop, graph.size())
    for a, b, value, c in zip(s.pose, s.landmark, s.values, s.covariance, strict=True):
        dist = float(np.hypot(*value))  # bearing-range: the same measurement, its covariance
        jac = np.array([[-value[1], value[0]], [value[0] * dist, value[1] * dist]]) / dist**2
        model = cov(jac @ c @ jac.T)  # first-order (bearing [rad], range [m])
        graph.add(gtsam.BearingRangeFactor2D(x(a), lm(b), gtsam.Rot2(np.arctan2(value[1], value[0])),
                                             dist, model))  # fmt: skip
    return odo, rng_, range(rng_.stop, graph.size())


def build_graph(problem: RangeAidedProblem, start_poses: np.ndarray):
    """(graph, FactorGroups) of ``problem``; the gauge prior holds ``start_poses``' first row
    when the problem has no priors. 3-D landmark observations are refused (no file has them)."""
    import gtsam

    if problem.dim == 3 and len(problem.landmark_observations.time):
        raise InvalidInputError(
            "problem: 3-D relative landmark observations (EDGE_SE3_XYZ) are not used by this "
            "solver; remove them (landmark_observations) to solve the rest"
        )
    x, lm = (lambda i: gtsam.symbol("x", int(i))), (lambda j: gtsam.symbol("l", int(j)))
    graph = gtsam.NonlinearFactorGraph()
    odo, rng_, obs = _add_measurements(gtsam, graph, problem, x, lm)
    pp, lp = problem.pose_priors, problem.landmark_priors
    prior = gtsam.PriorFactorPose2 if problem.dim == 2 else gtsam.PriorFactorPose3
    point_prior = gtsam.PriorFactorPoint2 if problem.dim == 2 else gtsam.PriorFactorPoint3
    cov = gtsam.noiseModel.Gaussian.Covariance
    for i, value, c in zip(pp.pose, pp.values, pp.covariance, strict=True):
        graph.add(prior(x(i), _pose(gtsam, value), cov(gtsam_covariance(c))))
    for j, value, c in zip(lp.landmark, lp.values, lp.covariance, strict=True):
        graph.add(point_prior(lm(j), np.asarray(value, float), cov(c)))
    if not len(pp.time) and not len(lp.time):
        k = tangent_width(problem.dim)
        graph.add(prior(x(0), _pose(gtsam, start_poses[0]),
                        gtsam.noiseModel.Isotropic.Sigma(k, GAUGE_SIGMA)))  # fmt: skip
    return graph, FactorGroups(odo, rng_, obs, range(obs.stop, graph.size()))


@dataclass(frozen=True, eq=False)
class RangeAidedResult(HasStatus):
    """A range-aided SLAM estimate and how it went.

    Attributes:
        poses: (P, 3) or (P, 7) estimated poses, rows as the problem's.
        landmarks: (L, d) estimated landmark positions [m].
        status, message: the verdict (:func:`judge`); ``converged`` derives from the status.
        method: what ran ("gtsam from odometry").
        iterations: Levenberg-Marquardt's iterations.
        initial_error, final_error: GTSAM's cost (half the sum of squared whitened residuals)
            at the start and at the answer.
        seconds: wall time of building and solving (not loading or judging).
        range_chi2, odometry_chi2: sums of squared whitened residuals at the answer, with
            ``range_dof``, ``odometry_dof`` terms.
        worst_range: the largest whitened range residual (in its sigmas).
    """

    poses: np.ndarray
    landmarks: np.ndarray
    status: Status
    message: str
    method: str
    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    range_chi2: float
    range_dof: int
    odometry_chi2: float
    odometry_dof: int
    worst_range: float


def _connected(problem: RangeAidedProblem) -> list[str]:
    """Robots not tied to the first robot (or to a prior) by ranges or shared landmarks."""
    n_r = len(problem.robots)
    parent = list(range(n_r + problem.n_landmarks + 1))  # last: the world (priors, gauge)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def join(a, b):
        parent[find(int(a))] = find(int(b))

    world, robot = len(parent) - 1, problem.pose_robot
    r, s = problem.ranges, problem.landmark_observations
    for a, b, mark in zip(r.pose, r.other, r.to_landmark, strict=True):
        join(robot[a], n_r + b if mark else robot[b])
    for a, b in zip(s.pose, s.landmark, strict=True):
        join(robot[a], n_r + b)
    for i in problem.pose_priors.pose:
        join(robot[i], world)
    for j in problem.landmark_priors.landmark:
        join(n_r + j, world)
    if not len(problem.pose_priors.time) and not len(problem.landmark_priors.time):
        join(0, world)
    return [problem.robots[k] for k in range(n_r) if find(k) != find(world)]


def _whitened(graph, values, group: range) -> np.ndarray:
    """(n,) sqrt(2 error) of each factor of ``group``: its whitened residual's norm."""
    return np.sqrt([2.0 * graph.at(i).error(values) for i in group])


def _identifiable(problem: RangeAidedProblem) -> str:
    """Why the data leave something undetermined beyond the gauge ('' when nothing): a robot
    tied to nothing, a landmark with fewer than d + 1 ranges and no observation or prior."""
    loose = _connected(problem)
    if loose:
        return f"robots {', '.join(loose)} are not tied to the map by any range or landmark"
    r = problem.ranges
    counts = np.bincount(r.other[r.to_landmark], minlength=problem.n_landmarks)
    held = np.zeros(problem.n_landmarks, bool)
    held[problem.landmark_observations.landmark] = True
    held[problem.landmark_priors.landmark] = True
    weak = np.flatnonzero((counts < problem.dim + 1) & ~held)
    if len(weak):
        names = ", ".join(problem.landmark_names[j] for j in weak[:5])
        return f"landmarks {names} have fewer than {problem.dim + 1} ranges and nothing else"
    return ""


def judge(problem: RangeAidedProblem, graph, groups: FactorGroups, values, iterations: int,
          max_iterations: int) -> tuple[Status, str, dict]:  # fmt: skip
    """(status, message, statistics) of the answer ``values``; the checks in the order solver,
    identifiable, outliers, consistent:

    - SOLVER_FAILED: the cost is not finite, or Levenberg-Marquardt used all its iterations.
    - NOT_IDENTIFIABLE: a robot tied to nothing, a landmark with too few ranges.
    - INCONSISTENT: the whitened range or odometry residuals' sum of squares is above its
      chi-square quantile at CHI2_LEVEL under the problem's stated noise. Residuals far *below*
      it (stated noise conservative, as in CORA's files) pass, and the message says by how much.
    - OUTLIERS: the largest whitened range residual, in units of the residuals' own robust
      scale (1.4826 MAD), is beyond the Bonferroni quantile at the level (:func:`rangeslam.verdict.checks.tail_limit`), widened for the MAD's
      own uncertainty as :func:`rangeslam.verdict.checks.tail_check` does: a wrong basin or
      wrong ranges show here even when the stated noise is loose.
    The precision of the answer (a gauge-free covariance) is not judged.
    """
    rng_w = _whitened(graph, values, groups.ranges)
    odo_w = _whitened(graph, values, groups.odometry)
    k = tangent_width(problem.dim)
    stats = {
        "range_chi2": float(np.sum(rng_w**2)), "range_dof": len(rng_w),
        "odometry_chi2": float(np.sum(odo_w**2)), "odometry_dof": k * len(odo_w),
        "worst_range": float(np.max(rng_w)) if len(rng_w) else 0.0,
    }  # fmt: skip
    limits = [float(chi2.ppf(CHI2_LEVEL, max(n, 1))) for n in (len(rng_w), k * len(odo_w))]
    ratios = [np.sqrt(stats["range_chi2"] / max(len(rng_w), 1)),
              np.sqrt(stats["odometry_chi2"] / max(k * len(odo_w), 1))]  # fmt: skip
    detail = (f"residuals / stated sigma (RMS): ranges {ratios[0]:.3g}, odometry {ratios[1]:.3g}; "
              f"worst range {stats['worst_range']:.3g} sigma")  # fmt: skip
    tail = _tail(rng_w)
    why = _identifiable(problem)
    if not np.isfinite(graph.error(values)) or iterations >= max_iterations:
        status, reason = (
            Status.SOLVER_FAILED,
            f"Levenberg-Marquardt stopped at {iterations} iterations",
        )
    elif why:
        status, reason = Status.NOT_IDENTIFIABLE, why
    elif tail:  # a heavy tail is named before the sum of squares it inflates (as checks.py)
        status, reason = Status.OUTLIERS, tail
    elif stats["range_chi2"] > limits[0] or stats["odometry_chi2"] > limits[1]:
        status, reason = Status.INCONSISTENT, "the residuals are larger than the stated noise"
    else:
        status, reason = Status.CONVERGED, ""
    text = f"{reason}; {detail}" if reason else detail
    return status, status_message(status, text + "; precision not judged"), stats


def _tail(whitened: np.ndarray) -> str:
    """Why the largest of the (n,) whitened |range residuals| is an outlier against their own
    robust scale ('' when it is not, or with fewer than 5)."""
    n = len(whitened)
    if n < 5 or np.max(whitened) < EXACT_SIGMAS:  # round-off has no tail to judge
        return ""
    robust = mad_sigma(whitened)
    limit = tail_limit(n)
    worst = float(np.max(whitened)) / robust
    if worst <= limit:
        return ""
    many = int(np.sum(whitened / robust > limit))
    return (f"{many} ranges lie beyond {limit:.3g} times the residuals' robust scale (the largest "
            f"{worst:.3g}): ranges the fit does not explain (wrong ranges, or a wrong basin)")  # fmt: skip


def solve_gtsam(
    problem: RangeAidedProblem,
    *,
    first_poses=None,
    start: tuple[np.ndarray, np.ndarray] | None = None,
    max_iterations: int = MAX_ITERATIONS,
) -> RangeAidedResult:
    """Solve ``problem`` with GTSAM's Levenberg-Marquardt and judge the answer.

    Args:
        problem: the range-aided SLAM problem.
        first_poses: (R, 3) or (R, 7) each robot's first pose for the odometry start (default:
            the problem's reference first poses; :func:`rangeslam.rangeaided.start.first_poses`).
        start: (poses (P, w), landmarks (L, d)) to start from instead of the odometry.
        max_iterations: Levenberg-Marquardt's limit; reaching it is SOLVER_FAILED.

    Returns:
        RangeAidedResult; ``seconds`` times building the graph and optimising. The status says
        whether the answer is right as far as the data can tell (:func:`judge`).
    """
    import gtsam

    if not isinstance(problem, RangeAidedProblem):
        raise InvalidInputError(
            f"problem must be a RangeAidedProblem; got {type(problem).__name__}"
        )
    t0 = time.perf_counter()
    if start is None:
        poses, _ = odometry_start(problem, first_poses)
        marks = landmark_start(problem, poses)
        method = "gtsam from odometry"
    else:
        poses, marks = (np.asarray(a, dtype=float) for a in start)
        method = "gtsam from the given start"
    graph, groups = build_graph(problem, poses)
    values = gtsam.Values()
    for i, row in enumerate(poses):
        values.insert(gtsam.symbol("x", i), _pose(gtsam, row))
    for j, point in enumerate(marks):
        values.insert(gtsam.symbol("l", j), np.asarray(point, float))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(RELATIVE_TOLERANCE)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial = graph.error(values)
    answer = optimizer.optimize()
    seconds = time.perf_counter() - t0
    iterations = int(optimizer.iterations())
    status, message, stats = judge(problem, graph, groups, answer, iterations, max_iterations)
    poses, marks = _estimates(answer, problem)
    return RangeAidedResult(
        poses=poses,
        landmarks=marks,
        status=status,
        message=message,
        method=method,
        iterations=iterations,
        initial_error=float(initial),
        final_error=float(graph.error(answer)),
        seconds=seconds,
        **stats,
    )


def _estimates(values, problem: RangeAidedProblem) -> tuple[np.ndarray, np.ndarray]:
    """((P, w) poses, (L, d) landmarks) of GTSAM ``values``."""
    import gtsam

    dim = problem.dim
    poses = np.array([_pose_row(gtsam, _at(values, dim, i), dim) for i in range(problem.n_poses)])
    point = values.atPoint2 if dim == 2 else values.atPoint3
    marks = [point(gtsam.symbol("l", j)) for j in range(problem.n_landmarks)]
    return poses, np.array(marks, dtype=float).reshape(-1, dim)


def _at(values, dim: int, i: int):
    import gtsam

    key = gtsam.symbol("x", i)
    return values.atPose2(key) if dim == 2 else values.atPose3(key)


def dead_reckoning_result(problem: RangeAidedProblem, *, first_poses=None) -> RangeAidedResult:
    """Odometry alone (the start, not optimised) as a result, for the tables: NOT_IDENTIFIABLE
    (dead reckoning does not use the ranges; nothing judges it)."""
    t0 = time.perf_counter()
    poses, gaps = odometry_start(problem, first_poses)
    marks = landmark_start(problem, poses)
    seconds = time.perf_counter() - t0
    status = Status.NOT_IDENTIFIABLE
    note = f"dead reckoning, ranges unused ({gaps} missing steps held)"
    return RangeAidedResult(poses, marks, status, status_message(status, note), "odometry alone",
                            0, float("nan"), float("nan"), seconds, float("nan"), 0, float("nan"),
                            0, float("nan"))  # fmt: skip


def position_estimates(result: RangeAidedResult) -> np.ndarray:
    """(P, d) positions of the result's poses."""
    return positions(result.poses)
