"""The judge on a range-aided SLAM answer: does another answer fit the data as well?
(:func:`rangeslam.verdict.judge.judge`, the project's one judge.)

Candidates, each Levenberg-Marquardt on the SAME graph as the answer (the file's factors and
the gauge), scored by the deviance (twice GTSAM's error: the sum of squared whitened residuals
of every factor, Gaussian):

- the placement search's next-best distinct placement of each searched robot
  (:class:`rangeslam.rangeaided.placement.Placement` ``options``), the others as in the answer;
- random starts, counted by the Boender-Rinnooy Kan stopping rule
  (:func:`rangeslam.verdict.judge.search_complete`) or ended by the budget: each searched
  robot placed from a random heading and offset (:func:`place_robots` ``random_start``: its
  rigid least squares from there), the odometry chains as measured, landmarks not observed
  relative to a pose uniform in the box of the start's positions widened by the median range,
  then each moved by least squares on its own ranges with the start's poses held (a small LM
  first, as the placement's: from the raw random landmarks, LM on Plaza1's 9,658 poses ran for
  minutes a start).
  (Perturbing every odometry step by its stated covariance as well made LM from such a start
  take 100-160 iterations, 45-60 s each, on TIERS; left out.)

The budget (:class:`WorkBudget`) is of work as well as of draws: the candidates' Levenberg-Marquardt
iterations together, at most SEARCH_BUDGET times the answer's own (the work of SEARCH_BUDGET
fits like the one judged, so the judge costs what a few fits cost whatever the size: on a
10,000-pose file, LM from a wrong placement runs 100-190 iterations into a far worse minimum).
A run the budget cuts while it is still far above the answer is no candidate (named in the
search's failures); one already within the level is run to its minimum.

The distance: delta^2 = ||J dx||^2 with J the whitened Jacobian of the graph at the lowest
candidate (GTSAM's linearisation, without the gauge prior) and dx the other candidate's
tangent step (``Values.localCoordinates``) after the rigid motion (no reflection: odometry has
a handedness) that best lays its positions on the lowest's, when the gauge is ours (robot A's
first pose); with the file's priors the gauge is data and nothing is aligned. ||J dx||^2 is read
from the linear graph's error as e(dx) + e(-dx) - 2 e(0), no dense matrix. Degrees of freedom:
every pose and landmark coordinate, less the gauge's (3 in 2-D, 6 in 3-D) when it is ours.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from rangeslam.geometry.alignment import align
from rangeslam.mdu.slam_judge import FIT_ERRORS
from rangeslam.rangeaided.gtsam_values import (
    deviance,
    estimates,
    levenberg_marquardt,
    to_values,
)
from rangeslam.rangeaided.placement import Placement, place_robots
from rangeslam.rangeaided.poses import compose, matrix_to_quaternion, positions, relative
from rangeslam.rangeaided.problem import RangeAidedProblem, tangent_width
from rangeslam.rangeaided.start import identity_pose, landmark_start, odometry_start
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.judge import (
    Alternative,
    JudgedSearch,
    cost_level,
    judge,
    random_search,
)
from rangeslam.verdict.thresholds import SEARCH_BUDGET

__all__ = [
    "Fit",
    "WorkBudget",
    "candidate",
    "information_metric",
    "judge_answer",
    "random_start",
]


@dataclass(frozen=True, eq=False)
class Fit:
    """One Levenberg-Marquardt run: ``poses`` (P, w), ``marks`` (L, d) [m], the GTSAM
    ``values``, its ``iterations``, and whether it was a random start (``counted``)."""

    poses: np.ndarray
    marks: np.ndarray
    values: object
    iterations: int
    counted: bool


def candidate(problem: RangeAidedProblem, graph, start, origin: str, counted: bool,
              max_iterations: int) -> Alternative:  # fmt: skip
    """LM on ``graph`` from ``start`` ((P, w) poses, (L, d) landmarks) as an Alternative:
    points (P + L, d) the positions, deviance on the graph, payload the :class:`Fit`."""
    values, iterations = levenberg_marquardt(graph, to_values(*start), max_iterations)
    poses, marks = estimates(values, problem)
    fit = Fit(poses, marks, values, iterations, counted)
    points = np.vstack([positions(poses), marks])
    return Alternative(points, deviance(graph, values), origin, payload=fit)


def _moved(fit: Fit, rot: np.ndarray, t: np.ndarray):
    """GTSAM values of ``fit`` moved by the rigid motion x -> rot x + t."""
    if rot.shape[0] == 2:
        motion = np.r_[t, np.arctan2(rot[1, 0], rot[0, 0])]
    else:
        motion = np.r_[t, matrix_to_quaternion(rot[None])[0]]
    poses = compose(np.broadcast_to(motion, (len(fit.poses), len(motion))), fit.poses)
    return to_values(poses, fit.marks @ rot.T + t)


def information_metric(graph, gauge: int | None):
    """``metric(lowest)`` for :func:`rangeslam.verdict.judge.judge` (module docstring); ``gauge``
    the index of the graph's gauge prior (None: the file's priors fix the frame)."""
    import gtsam

    sub = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        if i != gauge:
            sub.add(graph.at(i))
    cache: dict[int, object] = {}

    def metric(lowest: Alternative):
        if id(lowest) in cache:
            return cache[id(lowest)]
        lin = sub.linearize(lowest.payload.values)
        e0 = lin.error(lowest.payload.values.zeroVectors())

        pairs: dict[tuple[int, int], float] = {}

        def distance2(a: Alternative, b: Alternative, skip=()) -> float:
            if (id(a), id(b)) not in pairs:
                pairs[id(a), id(b)] = measured(a, b)
            return pairs[id(a), id(b)]

        def measured(a: Alternative, b: Alternative) -> float:
            other = b.payload.values
            if gauge is not None:
                motion = align(b.points, a.points, reflection=False)
                other = _moved(
                    b.payload, np.asarray(motion.rotation), np.asarray(motion.translation)
                )
            dx = a.payload.values.localCoordinates(other)
            return max(float(lin.error(dx) + lin.error(dx.scale(-1.0)) - 2.0 * e0), 0.0)

        cache[id(lowest)] = distance2
        return distance2

    return metric


def random_start(problem: RangeAidedProblem, placement: Placement, gauge: int | None, rng):
    """((P, w) poses, (L, d) landmarks) of one random start (module docstring); with our gauge
    the random placement is moved so that robot A's first pose is the answer's."""
    first = place_robots(problem, rng=rng, random_start=True).first  # priors: as the answer's
    if gauge is not None:
        back = relative(first[:1], identity_pose(problem.dim)[None])
        move = compose(placement.first[:1], back)
        first = compose(np.broadcast_to(move, first.shape), first)
    poses, _ = odometry_start(problem, first)
    marks = landmark_start(problem, poses)
    free = np.setdiff1d(np.arange(problem.n_landmarks), problem.landmark_observations.landmark)
    if len(free):
        pos = positions(poses)
        reach = float(np.median(problem.ranges.ranges)) if len(problem.ranges.ranges) else 0.0
        low, high = pos.min(axis=0) - reach, pos.max(axis=0) + reach
        marks[free] = rng.uniform(low, high, (len(free), problem.dim))
        for j in free:
            marks[j] = _landmark_fit(problem, pos, j, marks[j])
    return poses, marks


def _landmark_fit(problem: RangeAidedProblem, pos: np.ndarray, j: int, x0: np.ndarray):
    """(d,) landmark ``j`` by least squares on its ranges from the start's positions ``pos``
    (P, d) held, from ``x0`` [m] (soft-L1 at level_sigmas(), as the placement search)."""
    from scipy.optimize import least_squares

    r = problem.ranges
    mine = r.to_landmark & (r.other == j)
    if not np.any(mine):
        return x0
    ends, dist, sigma = pos[r.pose[mine]], r.ranges[mine], np.sqrt(r.variance[mine])

    def residuals(x):
        return (np.linalg.norm(ends - x, axis=1) - dist) / sigma

    return least_squares(residuals, x0, loss="soft_l1", f_scale=level_sigmas()).x


class WorkBudget:
    """The judge's Levenberg-Marquardt iterations: at most ``SEARCH_BUDGET`` times the answer's
    own (the work of SEARCH_BUDGET fits like the one judged). A candidate's LM is capped at
    what is left; a capped run that is not yet within :func:`cost_level` of the answer's cost
    is no minimum and no rival so far: it is dropped, in words (``cut``). One that is within
    the level, or lower, is run on to its minimum whatever that costs: its place decides."""

    def __init__(self, answer: Alternative, max_iterations: int):
        self.total = SEARCH_BUDGET * max(answer.payload.iterations, 1)
        self.left = self.total
        self.answer = answer
        self.max_iterations = max_iterations
        self.cut: list[str] = []  # candidates cut, not run or failed, in words, in order

    def words(self) -> str:
        """The budget, for the search's message: SEARCH_BUDGET draws, or the work."""
        return (f"the budget (SEARCH_BUDGET draws, or SEARCH_BUDGET fits' Levenberg-Marquardt "
                f"iterations: {self.total}, {self.answer.payload.iterations} the answer's; "
                f"{self.total - self.left} spent)")  # fmt: skip

    def run(self, problem: RangeAidedProblem, graph, start, origin: str, counted: bool
            ) -> Alternative | None:  # fmt: skip
        """:func:`candidate` within the budget; None when it is cut, or not run when nothing is
        left (module docstring); either is noted in ``cut``."""
        if self.left <= 0:
            self.cut.append(f"{origin}: not run, the budget spent")
            return None
        cap = min(self.max_iterations, self.left)
        alt = candidate(problem, graph, start, origin, counted, cap)
        self.left -= alt.payload.iterations
        if cap == self.max_iterations or alt.payload.iterations < cap:
            return alt
        gap = alt.deviance - self.answer.deviance
        if gap > cost_level():
            self.cut.append(f"{origin}: cut by the budget after {cap} iterations, "
                            f"{gap:.3g} noise variances above the answer")  # fmt: skip
            return None
        more = candidate(problem, graph, (alt.payload.poses, alt.payload.marks), origin, counted,
                         self.max_iterations - cap)  # fmt: skip
        self.left -= more.payload.iterations
        fit = more.payload
        whole = Fit(fit.poses, fit.marks, fit.values, cap + fit.iterations, counted)
        return Alternative(more.points, more.deviance, origin, payload=whole)


def judge_answer(problem: RangeAidedProblem, graph, answer: Alternative, placement: Placement,
                 gauge: int | None, rng, max_iterations: int) -> JudgedSearch:  # fmt: skip
    """The answer against the candidates of the module docstring, by the one judge, within
    the :class:`WorkBudget`."""
    budget = WorkBudget(answer, max_iterations)
    failures = budget.cut  # the runs cut, failed or not run, in the order they came
    others = []
    for r, options in enumerate(placement.options):
        for option in options[:1]:
            first = placement.first.copy()
            first[r] = option
            poses, _ = odometry_start(problem, first)
            start = (poses, landmark_start(problem, poses))
            origin = f"robot {problem.robots[r]}'s next placement"
            try:
                alt = budget.run(problem, graph, start, origin, False)
            except FIT_ERRORS as exc:
                failures.append(f"{origin}: {exc}")
                continue
            others += [] if alt is None else [alt]
    metric = information_metric(graph, gauge)
    k = tangent_width(problem.dim)
    dof = problem.n_poses * k + problem.n_landmarks * problem.dim - (k if gauge is not None else 0)

    def counted(alt: Alternative) -> bool:
        return alt.payload.counted

    def run(found: list[Alternative]):
        return judge(answer, others + found, metric=metric, dof=dof, counted=counted)

    def draws():
        for j in itertools.count():
            if budget.left <= 0:
                return
            try:
                start = random_start(problem, placement, gauge, rng)
                yield budget.run(problem, graph, start, f"random start {j}", True)
            except FIT_ERRORS as exc:
                failures.append(f"random start {j}: {exc}")
                yield None

    randoms, _ = random_search(run, [], draws(), budget=SEARCH_BUDGET)
    return JudgedSearch.of(run(randoms), len(randoms) + 1, failures, budget.words())
