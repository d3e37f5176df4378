"""GTSAM for a range-aided SLAM problem: Pose2 / Pose3 between factors with the problem's
covariances, range factors pose-landmark and pose-pose, bearing-range factors for 2-D relative
landmark observations, priors; Levenberg-Marquardt from the EDM windows where the problem is a
beacon log (:mod:`rangeslam.rangeaided.edm_start`), else from the odometry start with each
robot's first pose from the data (:func:`rangeslam.rangeaided.placement.place_robots`; the
reference values are never read), then the verdict: the residual checks (:func:`judge`) and the one judge
of alternative answers (:func:`rangeslam.rangeaided.rivals.judge_answer`).

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
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.rangeaided.edm_start import edm_start
from rangeslam.rangeaided.gtsam_values import MAX_ITERATIONS, gtsam_pose, to_values
from rangeslam.rangeaided.placement import Placement, place_robots
from rangeslam.rangeaided.poses import positions
from rangeslam.rangeaided.problem import RangeAidedProblem, tangent_width
from rangeslam.rangeaided.rivals import candidate, judge_answer
from rangeslam.rangeaided.start import landmark_start, odometry_start
from rangeslam.status import HasStatus, Status, status_message
from rangeslam.verdict.checks import tail_limit
from rangeslam.verdict.judge import LOWER, CheckRecord
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = [
    "GAUGE_SIGMA",
    "INITIALISATIONS",
    "MAX_ITERATIONS",
    "FactorGroups",
    "RangeAidedResult",
    "build_graph",
    "dead_reckoning_result",
    "gtsam_covariance",
    "judge",
    "position_estimates",
    "solve_gtsam",
]

#: The starts :func:`solve_gtsam` knows (its ``initialisation``).
INITIALISATIONS = ("auto", "edm", "odometry")
#: Standard deviation (m and rad) of the prior that fixes the gauge at the first robot's first
#: pose when the problem has no priors.
GAUGE_SIGMA = 1e-6
#: Whitened residuals all below this are exact data fitted to round-off: no tail is judged.
EXACT_SIGMAS = 1e-6


def gtsam_covariance(cov: np.ndarray) -> np.ndarray:
    """(k, k) covariance in GTSAM's tangent order: unchanged in 2-D (x, y, theta); in 3-D the
    problem's (translation, rotation) becomes (rotation, translation)."""
    if len(cov) == 3:
        return cov
    order = [3, 4, 5, 0, 1, 2]
    return cov[np.ix_(order, order)]


@dataclass(frozen=True)
class FactorGroups:
    """Which factors of the graph are which: index ranges [start, stop) per kind; ``gauge``
    the index of the gauge prior (None when the problem's priors fix the frame)."""

    odometry: range
    ranges: range
    observations: range
    priors: range
    gauge: int | None = None


def _add_measurements(gtsam, graph, problem: RangeAidedProblem, x, lm) -> tuple[range, ...]:
    dim, o, r, s = problem.dim, problem.odometry, problem.ranges, problem.landmark_observations
    between = gtsam.BetweenFactorPose2 if dim == 2 else gtsam.BetweenFactorPose3
    cov = gtsam.noiseModel.Gaussian.Covariance
    start = graph.size()
    for a, b, value, c in zip(o.pose_a, o.pose_b, o.values, o.covariance, strict=True):
        graph.add(between(x(a), x(b), gtsam_pose(gtsam, value), cov(gtsam_covariance(c))))
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
        graph.add(prior(x(i), gtsam_pose(gtsam, value), cov(gtsam_covariance(c))))
    for j, value, c in zip(lp.landmark, lp.values, lp.covariance, strict=True):
        graph.add(point_prior(lm(j), np.asarray(value, float), cov(c)))
    gauge = None
    if not len(pp.time) and not len(lp.time):
        k, gauge = tangent_width(problem.dim), graph.size()
        graph.add(prior(x(0), gtsam_pose(gtsam, start_poses[0]),
                        gtsam.noiseModel.Isotropic.Sigma(k, GAUGE_SIGMA)))  # fmt: skip
    return graph, FactorGroups(odo, rng_, obs, range(obs.stop, graph.size()), gauge)


@dataclass(frozen=True, eq=False)
class RangeAidedResult(HasStatus):
    """A range-aided SLAM estimate and how it went.

    Attributes:
        poses: (P, 3) or (P, 7) estimated poses, rows as the problem's.
        landmarks: (L, d) estimated landmark positions [m].
        status, message: the verdict; ``converged`` derives from the status.
        method: what ran ("gtsam, first poses from the data").
        iterations: Levenberg-Marquardt's iterations (of the answer kept).
        initial_error, final_error: GTSAM's cost (half the sum of squared whitened residuals)
            at the start and at the answer.
        seconds: wall time of placing the robots, building the graph and solving (not loading
            or judging).
        range_chi2, odometry_chi2: sums of squared whitened residuals at the answer, with
            ``range_dof``, ``odometry_dof`` terms.
        worst_range: the largest whitened range residual (in its sigmas).
        checks: every check the verdict ran, in order (name, statistic, level, passed, reason).
        first_poses: (R, 3) or (R, 7) each robot's first pose the start used.
        placement: how each robot's first pose was found, in words.
        start: where LM started: "edm" (the EDM windows), "odometry" or "given"; "" for a
            result not solved (dead reckoning).
        judge_seconds: wall time of the alternatives and the judge [s].
        alternatives: candidates the judge compared with the answer.
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
    checks: tuple[CheckRecord, ...] = ()
    first_poses: np.ndarray | None = None
    placement: str = ""
    start: str = ""
    judge_seconds: float = 0.0
    alternatives: int = 0


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
          max_iterations: int, *, placement: Placement | None = None,
          search=None) -> tuple[Status, str, dict, tuple[CheckRecord, ...]]:  # fmt: skip
    """(status, message, statistics, checks) of the answer ``values``; the checks in order, the
    first that fails naming the status:

    - "solver" (SOLVER_FAILED): the cost is not finite, or Levenberg-Marquardt used all its
      iterations.
    - "robots placed" (NOT_IDENTIFIABLE): every robot placed by the data (``placement``).
    - "identifiable" (NOT_IDENTIFIABLE): no robot tied to nothing, no landmark with too few
      ranges.
    - "rival minima" (NOT_IDENTIFIABLE): the one judge found no other answer that fits as well
      (``search``, a :class:`rangeslam.verdict.judge.JudgedSearch`).
    - "range outliers" (OUTLIERS): the largest whitened range residual, in units of the
      residuals' own robust scale (1.4826 MAD), within the Bonferroni quantile at 1 - CHI2_LEVEL,
      widened for the MAD's own uncertainty (:func:`rangeslam.verdict.checks.tail_limit`):
      a wrong basin or wrong ranges show here even when the stated noise is loose.
    - "range chi-square", "odometry chi-square" (INCONSISTENT): the whitened residuals' sum of
      squares within its chi-square quantile at CHI2_LEVEL under the stated noise. Residuals far
      *below* it (stated noise conservative, as in CORA's files) pass; the message says by how
      much.
    - "search complete": the stopping rule, not the budget, ended the random starts (reported;
      the status does not depend on it, as in slam). The budget is of work
      (:class:`rangeslam.rangeaided.rivals.WorkBudget`); the candidates it cut are named.
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
    ratios = [np.sqrt(stats["range_chi2"] / max(len(rng_w), 1)),
              np.sqrt(stats["odometry_chi2"] / max(k * len(odo_w), 1))]  # fmt: skip
    detail = (f"residuals / stated sigma (RMS): ranges {ratios[0]:.3g}, odometry {ratios[1]:.3g}; "
              f"worst range {stats['worst_range']:.3g} sigma")  # fmt: skip
    cost = float(graph.error(values))
    ok = bool(np.isfinite(cost)) and iterations < max_iterations
    why = "" if ok else f"Levenberg-Marquardt stopped at {iterations} iterations (cost {cost:.6g})"
    checks = [(CheckRecord("solver", float(iterations), float(max_iterations), ok, why),
               Status.SOLVER_FAILED)]  # fmt: skip
    checks += _identifiability_checks(problem, placement, search)
    checks += _residual_checks(rng_w, stats, k * len(odo_w))
    if search is not None:
        checks.append((search.record(), None))
    failed = [(c, st) for c, st in checks if not c.passed and st is not None]
    status, reason = (failed[0][1], failed[0][0].reason) if failed else (Status.CONVERGED, "")
    text = f"{reason}; {detail}" if reason else detail
    if search is not None:
        text += "; " + search.words()
        if search.failures:
            text += (f"; {len(search.failures)} candidates not judged (the first: "
                     f"{search.failures[0]})")  # fmt: skip
    message = status_message(status, text + "; precision not judged")
    return status, message, stats, tuple(c for c, _ in checks)


def _identifiability_checks(problem: RangeAidedProblem, placement, search) -> list[tuple]:
    """(CheckRecord, status if failed) of the placement, the ties and the judge's rivals."""
    out = []
    if placement is not None:
        why = placement.unplaced_reason(problem.robots)
        out.append((CheckRecord("robots placed", float(np.sum(~placement.placed)), 0.0, not why,
                                why), Status.NOT_IDENTIFIABLE))  # fmt: skip
    why = _identifiable(problem)
    out.append((CheckRecord("identifiable", float(bool(why)), 0.0, not why, why),
                Status.NOT_IDENTIFIABLE))  # fmt: skip
    if search is not None:
        out.append((search.judgement.check, Status.NOT_IDENTIFIABLE))
    return out


def _residual_checks(rng_w: np.ndarray, stats: dict, odo_dof: int) -> list[tuple]:
    """(CheckRecord, status if failed) of the range tail and the two chi-square tests."""
    reason, worst, limit = _tail(rng_w)
    out = [(CheckRecord("range outliers", worst, limit, not reason, reason), Status.OUTLIERS)]
    for name, value, dof in (("range", stats["range_chi2"], len(rng_w)),
                             ("odometry", stats["odometry_chi2"], odo_dof)):  # fmt: skip
        level = float(chi2.ppf(CHI2_LEVEL, max(dof, 1)))
        why = "" if value <= level else "the residuals are larger than the stated noise"
        out.append((CheckRecord(f"{name} chi-square", value, level, not why, why),
                    Status.INCONSISTENT))  # fmt: skip
    return out


def _tail(whitened: np.ndarray) -> tuple[str, float, float]:
    """(why, largest / robust scale, limit) of the (n,) whitened |range residuals|: why the
    largest is an outlier against their own robust scale ('' when it is not, or with fewer
    than 5: then the statistic and limit are nan)."""
    n = len(whitened)
    if n < 5 or np.max(whitened) < EXACT_SIGMAS:  # round-off has no tail to judge
        return "", float("nan"), float("nan")
    robust = mad_sigma(whitened)
    limit = tail_limit(n)
    worst = float(np.max(whitened) / robust)
    if worst <= limit:
        return "", worst, limit
    many = int(np.sum(whitened / robust > limit))
    return (f"{many} ranges lie beyond {limit:.3g} times the residuals' robust scale (the largest "
            f"{worst:.3g}): ranges the fit does not explain (wrong ranges, or a wrong basin)",
            worst, limit)  # fmt: skip


def solve_gtsam(
    problem: RangeAidedProblem,
    *,
    first_poses=None,
    start: tuple[np.ndarray, np.ndarray] | None = None,
    initialisation: str = "auto",
    max_iterations: int = MAX_ITERATIONS,
    rng=None,
) -> RangeAidedResult:
    """Solve ``problem`` with GTSAM's Levenberg-Marquardt and judge the answer. The reference
    values (``truth_poses``, ``truth_landmarks``) are never read.

    Args:
        problem: the range-aided SLAM problem.
        first_poses: (R, 3) or (R, 7) each robot's first pose, when the user knows them (given
            data, 2-D (x, y [m], theta [rad]), 3-D (x, y, z [m], qx, qy, qz, qw)): the odometry
            start from them, robot A's held as the gauge when the problem has no priors, the
            others free (the judge's random starts still try other placements). Default: placed
            from the data (:func:`rangeslam.rangeaided.placement.place_robots`).
        start: (poses (P, w), landmarks (L, d)) to start from instead of the odometry.
        initialisation: without ``start``: "edm" the EDM-windows start of a beacon log
            (:func:`rangeslam.rangeaided.edm_start.edm_start`; InvalidInputError naming why
            when the problem is not one), "odometry" dead reckoning from the first poses, or
            "auto" (default): "edm" where the problem allows it, else "odometry"; an EDM start
            that places no landmark is then replaced by the odometry one, and the method says so.
        max_iterations: Levenberg-Marquardt's limit; reaching it is SOLVER_FAILED.
        rng: numpy Generator or seed of the placement search's and the judge's random starts
            (default seed 0: the same answer on every run).

    Returns:
        RangeAidedResult; ``seconds`` times placing, building the graph and optimising,
        ``judge_seconds`` the alternatives and the judge. A lower alternative replaces the answer.
        The status says whether the answer is right as far as the data can tell (:func:`judge`).
    """
    if not isinstance(problem, RangeAidedProblem):
        raise InvalidInputError(
            f"problem must be a RangeAidedProblem; got {type(problem).__name__}"
        )
    if initialisation not in INITIALISATIONS:
        raise InvalidInputError(
            f"initialisation must be one of {INITIALISATIONS}; got {initialisation!r}"
        )
    rng = np.random.default_rng(0 if rng is None else rng)
    t0 = time.perf_counter()
    if start is None:
        placement = place_robots(problem, first=first_poses, rng=rng)
        poses, marks, method, kind = _start(problem, placement, initialisation,
                                            first_poses is not None)  # fmt: skip
    else:
        poses, marks = (np.asarray(a, dtype=float) for a in start)
        placement = place_robots(problem, first=poses[[problem.robot_rows(r)[0] for r in
                                                       range(len(problem.robots))]])  # fmt: skip
        method, kind = "gtsam from the given start", "given"
    graph, groups = build_graph(problem, poses)
    answer = candidate(problem, graph, (poses, marks), "the answer", True, max_iterations)
    seconds = time.perf_counter() - t0
    search = judge_answer(problem, graph, answer, placement, groups.gauge, rng, max_iterations)
    best = search.judgement.answer.payload
    status, message, stats, checks = judge(
        problem, graph, groups, best.values, best.iterations, max_iterations,
        placement=placement if start is None else None, search=search,
    )  # fmt: skip
    if any(c.kind == LOWER for c in search.judgement.comparisons):
        message += f"; {search.judgement.answer.origin} replaced the first answer (lower cost)"
    return RangeAidedResult(
        poses=best.poses, landmarks=best.marks, status=status, message=message, method=method,
        iterations=best.iterations, initial_error=float(graph.error(to_values(poses, marks))),
        final_error=float(graph.error(best.values)), seconds=seconds, **stats, checks=checks,
        first_poses=placement.first, placement=placement.words(problem.robots), start=kind,
        judge_seconds=time.perf_counter() - t0 - seconds,
        alternatives=len(search.judgement.comparisons),
    )  # fmt: skip


def _start(problem: RangeAidedProblem, placement: Placement, initialisation: str, given: bool
           ) -> tuple[np.ndarray, np.ndarray, str, str]:  # fmt: skip
    """(poses, landmarks, method in words, start kind) of the start ``initialisation`` names
    (solve_gtsam): the EDM windows where asked or allowed, else the odometry."""
    why = ""
    if initialisation != "odometry":
        try:
            found = edm_start(problem, placement.first[0])
            return (found.poses, found.marks, f"gtsam from the EDM windows ({found.notes[0]})",
                    "edm")  # fmt: skip
        except InvalidInputError:  # not a beacon log: the odometry, unless "edm" was asked
            if initialisation == "edm":
                raise
        except SolverError as exc:
            if initialisation == "edm":
                raise
            why = f"; the EDM windows placed no landmark ({exc}): started from the odometry"
    poses, _ = odometry_start(problem, placement.first)
    first = "first poses " + ("given" if given else "from the data")
    return poses, landmark_start(problem, poses), f"gtsam, {first}{why}", "odometry"


def dead_reckoning_result(problem: RangeAidedProblem, *, first_poses=None) -> RangeAidedResult:
    """Odometry alone (the start, not optimised) as a result, for the tables: NOT_IDENTIFIABLE
    (dead reckoning does not use the ranges; nothing judges it). ``first_poses``: (R, w) each
    robot's first pose; default placed from the data
    (:func:`rangeslam.rangeaided.placement.place_robots`, which does use the ranges between
    robots to place them; the reference is not read)."""
    t0 = time.perf_counter()
    placement = place_robots(problem, first=first_poses)
    poses, gaps = odometry_start(problem, placement.first)
    marks = landmark_start(problem, poses)
    seconds = time.perf_counter() - t0
    status = Status.NOT_IDENTIFIABLE
    note = f"dead reckoning, ranges unused ({gaps} missing steps held)"
    return RangeAidedResult(poses, marks, status, status_message(status, note), "odometry alone",
                            0, float("nan"), float("nan"), seconds, float("nan"), 0, float("nan"),
                            0, float("nan"), first_poses=placement.first,
                            placement=placement.words(problem.robots))  # fmt: skip


def position_estimates(result: RangeAidedResult) -> np.ndarray:
    """(P, d) positions of the result's poses."""
    return positions(result.poses)
