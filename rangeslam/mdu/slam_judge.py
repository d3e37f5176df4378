"""The judge of a SLAM answer: every alternative the search and the generators made, compared
with the answer on one objective over all the data (:func:`rangeslam.verdict.judge.judge`).

The objective is the estimator's own graph at one range sigma (the search's reference): -2 log
likelihood, twice GTSAM's error over every observed range and every step prior, with the robust
kernel's cost over EVERY range for a robust answer (not over the ranges each candidate kept):
:func:`rangeslam.mdu.slam_graph.graph_deviance`. The answer is the trajectory (the landmarks are
nuisance parameters, as in the verdict's precision test): the information distance is the
trajectory's, in its information with the landmarks profiled out
(:func:`trajectory_information`, from the whitened Jacobian at the lowest candidate: range rows
over sigma, step priors' rows whitened), after the rigid motion (with reflection) that best
brings one trajectory onto the other, against chi-square with M d - d (d + 1) / 2 degrees of
freedom. A landmark of a planar walk fits as well on either side of it (its mirror image,
reported as ``ambiguous_landmarks``) and moves the trajectory by less than its precision: the
same answer, not a rival (over all unknowns, each side flip of a 1 cm lemniscate walk was
another answer, 10^5-10^6 information units away). Alternatives:

- the search's other convex-iteration runs and fits from random starts
  (:func:`rangeslam.mdu.slam_graph.random_start`; the least-squares graph by MINPACK to its end,
  a robust graph by GTSAM from there, :func:`_start_fit`, where a fit that has entered the
  answer's basin, :func:`answer_region`, is judged where it stands: LM from there returns to
  the answer), counted by the stopping rule
  (:func:`rangeslam.verdict.judge.search_complete`) or ended by the budget SEARCH_BUDGET
  (``extra_starts`` when larger);
- leave-one-block-out refits from the answer (:func:`block_proposals` by landmark,
  :func:`window_proposals` by windows of max(2, M // 4) steps): GTSAM without the block's ranges
  (the graph of the other points, :func:`subgraph_fit`), then on the full graph from there
  (unless the fit without the block stayed in the answer's basin).

The landmarks' mirror images (:func:`rangeslam.mdu.alternatives.mirror_proposals`) are not
judged here: they do not move the trajectory on a planar walk and are reported as
``ambiguous_landmarks`` (:mod:`rangeslam.mdu.landmark_mirrors`); off the plane, the random
starts reach either side.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np

from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.alternatives import (
    Proposal,
    block_proposals,
    window_proposals,
)
from rangeslam.mdu.core import step_prior_rows, unknowns_up_to_rigid_motion
from rangeslam.mdu.slam_graph import (
    graph_deviance,
    graph_fit,
    nominal_steps,
    random_start,
    refine_run,
    stacked,
)
from rangeslam.mdu.slam_verdict import SlamProblem, SlamRun
from rangeslam.solvers.gtsam_graph import refine_graph
from rangeslam.solvers.least_squares import unfolding_jacobian
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.judge import (
    Alternative,
    JudgedSearch,
    cost_level,
    distance_level,
    judge,
    marginal_precision,
    random_search,
)
from rangeslam.verdict.thresholds import (
    EXACT_RTOL,
    PRECISION_FRACTION,
    RANK_RTOL,
    SEARCH_BUDGET,
)

__all__ = [
    "FIT_ERRORS",
    "JudgeMetric",
    "answer_region",
    "block_alternatives",
    "counted_as_start",
    "judge_metric",
    "judge_slam",
    "random_minima",
    "subgraph_fit",
    "trajectory_distance",
    "trajectory_information",
]

# what a GTSAM run may raise from a start far off: its own failure, a graph it refuses, or
# gtsam's indeterminant linear system (a RuntimeError)
FIT_ERRORS = (SolverError, InvalidInputError, RuntimeError)
# LM iteration limits of a refit from the answer: first a short run; only when it stopped short of
# its minimum (a Gauss-Newton step still predicting more than STATIONARY_CHI2 of decrease: GraphFit
# not converged) the search's limit from there. A refit that has reached the answer's flat valley
# creeps along it inside the answer's uncertainty (an exact planar walk: 900-1300 iterations a
# refit, 24 refits 25 times the cost of the fit judged) and is judged where it stands.
_REFIT_ITERATIONS = (200, 5000)
# LM iteration limits of a random start's robust stage (GTSAM), run one after another: a fit that
# has reached the answer's basin after one (:func:`answer_region`) is judged where it stands, any
# other goes on until LM ends within a stage; the least-squares stage (MINPACK) has the last one.
# (From random starts on 8-step walks, one run of 5000: median 88 iterations, 11 of 146 fits
# over 500, 2.8 s of their 7.0 s.)
_START_ITERATIONS = (25, 50, 100, 200, 5000)


def _fit_in_stages(fit_from, pts: np.ndarray, limits: Sequence[int], done):
    """LM in stages: ``fit_from(points, limit)`` (a GraphFit from ``points``, at most ``limit``
    iterations) for each limit of ``limits`` in turn, each from where the last one ended, until
    ``done(fit, limit)``. Returns the last fit."""
    for limit in limits:
        fit = fit_from(pts, limit)
        if done(fit, limit):
            break
        pts = stacked(fit)
    return fit


def _converged(fit, limit: int) -> bool:
    return fit.converged


def subgraph_fit(
    problem: SlamProblem, pts: np.ndarray, sigma: float, kept: np.ndarray
) -> np.ndarray:
    """GTSAM from ``pts`` (M + K, d) on the ranges ``kept`` (M, K) alone: the graph of the steps
    and landmarks that keep a range, at range sigma ``sigma`` (the problem's kernel and step
    prior; two kept steps with left-out ones between them bounded by 0 and the sum of the upper
    bounds between), its iterations as :data:`_REFIT_ITERATIONS` says. Returns the points with
    those refitted; a left-out landmark stays where it was, a left-out step moves with the
    nearest kept step before it (after it at the start)."""
    m = problem.ranges.shape[0]
    rows, cols = np.flatnonzero(kept.any(axis=1)), np.flatnonzero(kept.any(axis=0))
    bounds = None
    if problem.bounds is not None:
        lower, upper = problem.bounds.lower, problem.bounds.upper
        gaps = np.diff(rows)
        bounds = (
            np.where(gaps == 1, lower[rows[:-1]], 0.0),
            np.array([upper[a:b].sum() for a, b in itertools.pairwise(rows)]),
        )
    n_rows = len(rows)

    def fit_from(sub: np.ndarray, limit: int):
        return refine_graph(
            sub[:n_rows], sub[n_rows:], problem.ranges[np.ix_(rows, cols)],
            noise_std=sigma, mask=kept[np.ix_(rows, cols)], step_bounds=bounds,
            step_sigma=problem.step_sigma, step_prior=problem.step_prior, robust=problem.robust,
            covariances=False, max_iterations=limit,
        )  # fmt: skip

    sub = np.vstack([pts[rows], pts[m + cols]])
    fit = _fit_in_stages(fit_from, sub, _REFIT_ITERATIONS, _converged)
    out = pts.copy()
    nearest = np.clip(np.searchsorted(rows, np.arange(m), side="right") - 1, 0, None)
    out[:m] += (fit.receivers - pts[rows])[nearest]
    out[rows], out[m + cols] = fit.receivers, fit.sources
    return out


def _block_refit(
    problem: SlamProblem, proposal: Proposal, sigma: float, reached
) -> np.ndarray | None:
    """The refit of a leave-one-block-out proposal: first without its block (at the graph's
    floor at least: LM does not move below it from afar), then, unless that fit stayed in the
    answer's basin (``reached``, :func:`answer_region`: the full graph from there returns to the
    answer), on the full graph from there, at ``sigma`` itself (near the answer, LM moves at any
    sigma: going through the floor first, as :func:`rangeslam.mdu.slam_graph.refine_run` does
    from a distant start, made exact data creep back 900 iterations a refit); each fit as
    :data:`_REFIT_ITERATIONS` says. None when a GTSAM run failed."""
    try:
        pts = subgraph_fit(
            problem,
            proposal.points,
            max(sigma, problem.floor),
            problem.observed & ~proposal.without,
        )
        if reached(pts):
            return pts
        fit = _fit_in_stages(
            lambda p, limit: graph_fit(problem, p, sigma, max_iterations=limit),
            pts, _REFIT_ITERATIONS, _converged,
        )  # fmt: skip
    except FIT_ERRORS:
        return None
    return stacked(fit)


def graph_jacobian(problem: SlamProblem, pts: np.ndarray, sigma: float) -> np.ndarray:
    """(R, (M + K) d) the whitened Jacobian of the graph at ``pts`` (M + K, d) and range sigma
    ``sigma`` (metres): range rows over sigma (for a robust graph, the ranges its kernel weighs,
    within level_sigmas() of sigma) and the step priors' rows
    (:func:`rangeslam.mdu.core.step_prior_rows`, in range-noise units, over sigma)."""
    m, n_points = problem.ranges.shape[0], sum(problem.ranges.shape)
    used = problem.observed
    if problem.robust:  # the ranges the kernel weighs there
        res = range_matrix(pts[:m], pts[m:]) - problem.ranges
        used = used & (np.abs(res) <= level_sigmas() * sigma)
    jac = unfolding_jacobian(pts, m, np.argwhere(used)) / sigma
    prior = step_prior_rows(
        problem.bounds, problem.step_prior, problem.step_sigma, pts[:m], sigma, n_points
    )
    return jac if prior is None else np.vstack([jac, prior / sigma])


def trajectory_information(problem: SlamProblem, pts: np.ndarray, sigma: float) -> np.ndarray:
    """(M d, M d) the information of the trajectory at ``pts`` (M + K, d), the landmarks
    profiled out: the Schur complement F_xx - F_xl F_ll^+ F_lx of F = J^T J, J the whitened
    Jacobian of the graph (:func:`graph_jacobian`) at range sigma ``sigma`` (metres). A landmark
    direction without information (one off a planar walk, at the plane) is left out of F_ll^+
    (singular values under RANK_RTOL of the largest)."""
    jac = graph_jacobian(problem, pts, sigma)
    x = problem.ranges.shape[0] * problem.dim
    info = jac.T @ jac
    f_ll = info[x:, x:]
    return (
        info[:x, :x]
        - info[:x, x:] @ np.linalg.pinv(f_ll, rcond=RANK_RTOL, hermitian=True) @ info[x:, :x]
    )


def trajectory_distance(information: np.ndarray, m: int):
    """``distance2(a, b, skip)`` for :func:`judge`: delta^2 of b's trajectory (the first ``m``
    rows of its points) from a's in the trajectory's ``information`` (M d, M d), b's trajectory
    first brought onto a's by the best rigid motion with reflection (the gauge of ranges and
    step lengths); steps in ``skip`` are left out of the alignment and of the step."""

    def distance2(a: Alternative, b: Alternative, skip=()) -> float:
        ref, pts = np.asarray(a.points[:m], dtype=float), np.asarray(b.points[:m], dtype=float)
        keep = np.setdiff1d(np.arange(m), [r for r in skip if r < m])
        aligned = ref.copy()
        aligned[keep] = align(pts[keep], ref[keep], reflection=True).aligned
        step = (aligned - ref).ravel()
        return float(step @ information @ step)

    return distance2


def _start_fit(problem: SlamProblem, pts: np.ndarray, sigma: float, reached):
    """A fit from a random start ``pts`` (M + K, d) at range sigma ``sigma``: with a robust
    kernel, first by least squares (the graph without the kernel), then on the problem's graph
    from there, as the search's runs start the kernel from the SDP's least-squares answer. (The
    kernel straight from a random start ignores most ranges: on 1 mm walks with a wrong pick,
    LM hit 5000 iterations at 30-50 cm off, 2 s each; from least squares 4 of 6 starts reached
    the right minimum in 0.05 s.) The least-squares graph is fitted by MINPACK to its end
    (:mod:`rangeslam.solvers.graph_minpack`: GTSAM's cost, fewer and cheaper iterations from
    afar); a robust graph by GTSAM in the stages of :data:`_START_ITERATIONS`, until LM ends
    within a stage or the points are in the answer's basin (``reached``,
    :func:`answer_region`). Both at the graph's floor at least; below it the fit is then
    finished at ``sigma`` as :func:`rangeslam.mdu.slam_graph.refine_run` finishes a run (LM
    does not move below the floor from afar: a stage there stopped far off "converged")."""
    graphs = [dataclasses.replace(problem, robust=None), problem] if problem.robust else [problem]
    staged = max(sigma, problem.floor)
    for graph in graphs:
        if graph.robust is None:  # MINPACK, to its end
            fit = graph_fit(graph, pts, staged, max_iterations=_START_ITERATIONS[-1], minpack=True)
        else:
            fit = _fit_in_stages(
                lambda p, limit, graph=graph: graph_fit(graph, p, staged, max_iterations=limit),
                pts, _START_ITERATIONS,
                lambda fit, limit: fit.iterations < limit or reached(stacked(fit)),
            )  # fmt: skip
        pts = stacked(fit)
        if sigma < staged:
            fit = refine_run(graph, pts, sigma, covariances=False)[0]
            pts = stacked(fit)
    return fit


def _random_alternatives(problem: SlamProblem, sigma: float, rng, failures: list[str], reached):
    """Fits from GTSAM-style random starts without end (:func:`_start_fit`, ``reached`` its
    test of the answer's region), each an Alternative (counted), or None where GTSAM failed (the
    failure appended to ``failures``)."""
    r, observed = problem.ranges, problem.observed
    nominal = nominal_steps(problem.bounds, r, observed)
    size = float(np.max(r[observed]))
    for j in itertools.count():
        x0, s0 = random_start(nominal, r.shape[1], problem.dim, size, rng)
        try:
            fit = _start_fit(problem, np.vstack([x0, s0]), sigma, reached)
        except FIT_ERRORS as exc:
            failures.append(f"random start {j}: {exc}")
            yield None
            continue
        pts = stacked(fit)
        yield Alternative(
            pts, graph_deviance(problem, pts, sigma), f"random start {j}", payload=True
        )


def answer_region(problem: SlamProblem, answer: Alternative, sigma: float):
    """``reached(points)``: whether ``points`` (M + K, d) lie in the answer's basin as its
    quadratic model describes it, near enough that no other minimum is nearer:
    - the trajectory within half the radius of the answer's confidence region (delta^2 from
      ``answer`` in the trajectory's information there, the landmarks profiled out,
      :func:`trajectory_distance`, at most a quarter of
      :func:`rangeslam.verdict.judge.distance_level`): nearer the answer than the midpoint
      between it and any minimum outside the region;
    - the deviance above the answer's by at least half of delta^2 and at most delta^2 plus the
      cost level (:func:`rangeslam.verdict.judge.cost_level`): the cost rises from the answer
      as its information says, the landmarks near their best.
    LM from such points descends to the answer's minimum, the same answer to the judge. Not
    reached: points in a flat valley, where the cost rises far less than the information says
    (two minima 0.02 noise variances apart at delta^2 43), and points whose landmarks are far
    from their best (a refit without one landmark turned as a whole, that landmark left behind:
    14 000 noise variances above the answer, its trajectory 20 information units away). Both
    bounds only decide when a fit may stop early: a point not reached goes on to LM's end.
    """
    m = problem.ranges.shape[0]
    distance2 = trajectory_distance(trajectory_information(problem, answer.points, sigma), m)
    q_far = distance_level(unknowns_up_to_rigid_motion(m, problem.dim))

    def reached(points: np.ndarray) -> bool:
        delta2 = distance2(answer, Alternative(points, np.nan, "a fit on its way"))
        if delta2 > q_far / 4:  # farther than half the region's radius
            return False
        gap = graph_deviance(problem, points, sigma) - answer.deviance
        round_off = EXACT_RTOL * max(abs(answer.deviance), 1.0)  # the deviance's own
        return delta2 / 2 - round_off <= gap <= delta2 + cost_level()

    return reached


def block_alternatives(problem: SlamProblem, answer: Alternative, sigma: float, reached):
    """The leave-one-block-out refits of the ``answer``: without one landmark, without one
    window of max(2, M // 4) steps (module docstring; :func:`_block_refit`, ``reached`` its
    :func:`answer_region`); those whose GTSAM run failed are left out."""
    m, observed, points = problem.ranges.shape[0], problem.observed, answer.points
    fixed = itertools.chain(
        block_proposals(points, observed, blocks="columns", names=("step", "landmark")),
        window_proposals(points, observed, max(2, m // 4)),
    )
    alternatives = []
    for proposal in fixed:
        refit = _block_refit(problem, proposal, sigma, reached)
        if refit is not None:
            dev = graph_deviance(problem, refit, sigma)
            alternatives.append(Alternative(refit, dev, proposal.origin, payload=False))
    return alternatives


class JudgeMetric:
    """The judge's ``metric`` and ``precision`` for a walk, at range sigma ``sigma`` (metres):
    at the lowest candidate, the trajectory's distance (:func:`trajectory_distance`) in its
    information (:func:`trajectory_information`, made once per lowest); and the steps' spread
    (:func:`rangeslam.verdict.judge.marginal_precision` of the steps in the graph's whitened
    Jacobian, :func:`graph_jacobian`, the landmarks profiled out: the gauge cut on its singular
    values, where round-off is 1e-16 of the largest, not on the Schur complement's eigenvalues,
    where it is larger), infinite where either candidate's RMS standard deviation fails the
    precision test (PRECISION_FRACTION of the median range)."""

    def __init__(self, problem: SlamProblem, sigma: float):
        self.problem, self.sigma = problem, sigma
        self.m = problem.ranges.shape[0]
        self._at: tuple[Alternative, np.ndarray] | None = None
        self.precision = marginal_precision(
            lambda candidate: graph_jacobian(problem, candidate.points, sigma),
            np.arange(self.m),
            rms_limit=PRECISION_FRACTION * problem.scale,
        )

    def information(self, lowest: Alternative) -> np.ndarray:
        """(M d, M d) the trajectory's information at ``lowest`` (kept for the last one)."""
        if self._at is None or self._at[0] is not lowest:
            self._at = (lowest, trajectory_information(self.problem, lowest.points, self.sigma))
        return self._at[1]

    def __call__(self, lowest: Alternative):
        return trajectory_distance(self.information(lowest), self.m)


def judge_metric(problem: SlamProblem, sigma: float) -> JudgeMetric:
    """The judge's metric and precision for ``problem`` at range sigma ``sigma``
    (:class:`JudgeMetric`)."""
    return JudgeMetric(problem, sigma)


def counted_as_start(alternative: Alternative) -> bool:
    """Whether a candidate samples the basins (the answer, runs, random starts: payload True)."""
    return bool(alternative.payload)


def random_minima(
    problem: SlamProblem,
    answer: Alternative,
    counted: Sequence[Alternative],
    sigma: float,
    rng,
    *,
    budget: int,
    at_least: int = 0,
    failures: list[str] | None = None,
    reached=None,
) -> list[Alternative]:
    """``counted`` (the starts made so far beside ``answer``) and GTSAM from random starts
    (:func:`_random_alternatives`), made until the stopping rule
    (:func:`rangeslam.verdict.judge.search_complete`, ``answer`` counted) is met after
    ``at_least`` of them, or ``budget`` were made (a failed run counts as made, its failure
    appended to ``failures``). ``reached``: when a start's fit may stop early (default
    :func:`answer_region` of ``answer``, which must be a minimum of the graph)."""
    dof = unknowns_up_to_rigid_motion(problem.ranges.shape[0], problem.dim)
    metric = judge_metric(problem, sigma)

    def run(found: list[Alternative]):
        return judge(answer, found, metric=metric, dof=dof, counted=counted_as_start,
                     precision=metric.precision)  # fmt: skip

    if reached is None:
        reached = answer_region(problem, answer, sigma)
    randoms = _random_alternatives(
        problem, sigma, rng, [] if failures is None else failures, reached
    )
    found, _ = random_search(run, counted, randoms, budget=budget, at_least=at_least)
    return found


def judge_slam(
    problem: SlamProblem, answer: SlamRun, runs: Sequence[SlamRun], sigma: float, rng
) -> JudgedSearch:
    """The answer against every alternative (module docstring) on the graph of range sigma
    ``sigma`` (metres; the search's reference). ``runs``: the search's other refined
    convex-iteration runs, counted by the stopping rule with the answer."""
    m = problem.ranges.shape[0]
    points = np.vstack([answer.receivers, answer.sources])
    main = Alternative(points, graph_deviance(problem, points, sigma), "the answer", payload=True)
    reached = answer_region(problem, main, sigma)
    alternatives = block_alternatives(problem, main, sigma, reached)
    runs_made = [
        Alternative(p, graph_deviance(problem, p, sigma), f"convex-iteration run {i}", payload=True)
        for i, p in enumerate(np.vstack([r.receivers, r.sources]) for r in runs)
    ]
    failures: list[str] = []
    counted = random_minima(
        problem, main, runs_made, sigma, rng,
        budget=max(SEARCH_BUDGET, problem.extra_starts), at_least=problem.extra_starts,
        failures=failures, reached=reached,
    )  # fmt: skip
    metric = judge_metric(problem, sigma)
    judgement = judge(
        main,
        alternatives + counted,
        metric=metric,
        dof=unknowns_up_to_rigid_motion(m, problem.dim),
        counted=counted_as_start,
        precision=metric.precision,
    )
    return JudgedSearch.of(judgement, len(counted) + 1, failures)
