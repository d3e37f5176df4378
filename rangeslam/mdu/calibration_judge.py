"""The judge of a calibration: every alternative the generators propose, fitted and compared with
the search's answer on one objective over all ranges (:func:`rangeslam.verdict.judge.judge`).

The objective is the estimator's own: the sum of squared residuals over sigma^2 (least squares),
or for a robust calibration the Cauchy deviance 2 sum log(1 + (r / s)^2) over every observed
range at one scale s (``noise_std``, else the least inlier spread the search reached), not over
the ranges each candidate kept. Alternatives: random starts until the stopping rule
(:func:`rangeslam.verdict.judge.search_complete`) or SEARCH_BUDGET starts in all (the
``random_starts`` left, when the answer came from a random start); the answer
refitted without each source and without each receiver (:func:`block_proposals`); each point
mirrored in the plane of the points it is ranged to (:func:`mirror_proposals`); the answer folded
(:func:`fold_proposal`).
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

from rangeslam.mdu.alternatives import (
    Proposal,
    block_proposals,
    fold_proposal,
    mirror_proposals,
    random_proposals,
)
from rangeslam.mdu.core import sources_verdict, unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import (
    refine_unfolding,
    unfolding_jacobian,
    unfolding_residuals,
)
from rangeslam.status import Status
from rangeslam.verdict import noise_upper_bound, verdict_noise
from rangeslam.verdict.judge import (
    DRAWS_BUDGET,
    LOWER,
    RANDOM_STARTS_LIMIT,
    Alternative,
    JudgedSearch,
    information_distance,
    judge,
    marginal_precision,
    random_search,
    same_answer,
)
from rangeslam.verdict.thresholds import PRECISION_FRACTION, SEARCH_BUDGET

if TYPE_CHECKING:
    from rangeslam.mdu.calibration import CalibrationProblem, Candidate

__all__ = [
    "ambiguity_words",
    "counted_points",
    "judge_calibration",
    "judged_status",
    "objective_scale",
    "same_calibration",
    "spread",
]


def objective_scale(problem: CalibrationProblem, ssr: float, n_fit: int, floor=None) -> float:
    """The sigma (metres) of the judge's objective: ``noise_std``; for a robust calibration
    without it the search's least inlier spread ``floor``; else the answer's residual sum of
    squares ``ssr`` over its redundancy; never below the exact-data RMS."""
    if problem.noise_std:
        return max(problem.noise_std, problem.exact_rms)
    if problem.robust and floor:
        return max(floor, problem.exact_rms)
    dof = n_fit - unknowns_up_to_rigid_motion(problem.n_points, problem.dim)
    return max(float(np.sqrt(ssr / dof)) if dof > 0 else 0.0, problem.exact_rms)


def _deviance(points: np.ndarray, problem: CalibrationProblem, sigma: float) -> float:
    """-2 log likelihood of ``points`` (M + K, d) over every observed range at ``sigma``."""
    m, observed = problem.ranges.shape[0], problem.observed
    res = unfolding_residuals(points, m, problem.ranges[observed], np.argwhere(observed)) / sigma
    if problem.robust:
        return float(2.0 * np.sum(np.log1p(res**2)))
    return float(np.sum(res**2))


def _information_jacobian(points: np.ndarray, problem: CalibrationProblem, sigma: float):
    """(P, (M + K) d) the objective's Jacobian at ``points``, whitened: J^T J is the information
    (the Gauss-Newton Hessian of the deviance over 2). Least squares: the range rows over sigma;
    the Cauchy deviance 2 log(1 + u^2), u = r / sigma: each row times sqrt(2 / (1 + u^2)) /
    sigma, its iteratively reweighted weight, so that a range the kernel discounts adds no
    information."""
    m, observed = problem.ranges.shape[0], problem.observed
    pairs = np.argwhere(observed)
    jac = unfolding_jacobian(points, m, pairs) / sigma
    if not problem.robust:
        return jac
    u = unfolding_residuals(points, m, problem.ranges[observed], pairs) / sigma
    return jac * np.sqrt(2.0 / (1.0 + u**2))[:, None]


def same_calibration(problem: CalibrationProblem, answer: np.ndarray, sigma: float):
    """The judge's "same answer" test of a search's start against ``answer`` (M + K, d), metres,
    at the objective's ``sigma`` (metres, :func:`objective_scale`): a predicate of another
    start's points (M + K, d), true when its receivers lie within the answer's confidence
    region (:func:`rangeslam.verdict.judge.same_answer`: delta^2 in the information at the
    answer, the sources profiled out as in :func:`judge_calibration`)."""
    m = problem.ranges.shape[0]
    jac = _information_jacobian(answer, problem, sigma)
    distance2 = information_distance(jac, interest=np.arange(m))
    test = same_answer(
        distance2,
        Alternative(answer, 0.0, "the answer"),
        unknowns_up_to_rigid_motion(m, problem.dim),
    )
    return lambda points: test(Alternative(points, 0.0, "a start"))


def _fitted(proposal: Proposal, problem: CalibrationProblem, sigma: float) -> np.ndarray | None:
    """The estimator's fit from a proposal: first without its block, then on every range (Cauchy
    loss at ``sigma`` when robust); None when a fit diverged."""
    m, r, observed = problem.ranges.shape[0], problem.ranges, problem.observed
    loss = {"loss": "cauchy", "loss_scale": sigma} if problem.robust else {}
    pts = proposal.points
    if proposal.fitted:
        return pts if np.all(np.isfinite(pts)) else None
    try:
        if proposal.without is not None:
            fit = refine_unfolding(pts[:m], pts[m:], r, observed & ~proposal.without, **loss)
            pts = np.vstack([fit.receivers, fit.sources])
        fit = refine_unfolding(pts[:m], pts[m:], r, observed, **loss)
    except (ValueError, np.linalg.LinAlgError):
        return None
    points = np.vstack([fit.receivers, fit.sources])
    return points if np.all(np.isfinite(points)) else None


def _alternative(proposal, problem, sigma) -> Alternative | None:
    """A proposal fitted and scored."""
    points = _fitted(proposal, problem, sigma)
    if points is None:
        return None
    return Alternative(
        points,
        _deviance(points, problem, sigma),
        proposal.origin,
        ambiguous=proposal.ambiguous,
        ambiguity=proposal.ambiguity,
        payload=proposal.counted,
    )


def judge_calibration(
    problem: CalibrationProblem,
    answer: np.ndarray,
    sigma: float,
    rng,
    *,
    inliers=None,
    starts=(),
    draws: int | None = None,
) -> JudgedSearch:
    """The answer (M + K, d) against every alternative, at the objective's ``sigma`` (metres).

    ``starts``: the other fitted starts (M + K, d) (the search's, and in a descent the judged
    answer before and earlier judgements' random starts), counted by the stopping rule with the
    answer; random starts follow until the rule ends them or the budget:
    ``draws`` random starts, or with None SEARCH_BUDGET starts in all (at most
    ``random_starts``). ``inliers``: a robust answer's kept ranges, where random starts make
    their first fit."""
    m, observed = problem.ranges.shape[0], problem.observed
    main = Alternative(answer, _deviance(answer, problem, sigma), "the answer", payload=True)
    jac = _information_jacobian(answer, problem, sigma)

    # the receivers are what is calibrated: the sources are nuisance, profiled out
    receivers = np.arange(m)

    def jacobian_at(candidate: Alternative) -> np.ndarray:
        return jac if candidate is main else _information_jacobian(candidate.points, problem, sigma)

    def metric(lowest: Alternative):
        return information_distance(jacobian_at(lowest), interest=receivers)

    dof = unknowns_up_to_rigid_motion(m, problem.dim)
    precision = marginal_precision(
        jacobian_at, receivers, rms_limit=PRECISION_FRACTION * problem.scale
    )

    def run(alternatives):
        return judge(main, alternatives, metric=metric, dof=dof,
                     counted=lambda a: bool(a.payload), precision=precision)  # fmt: skip

    fixed = itertools.chain(
        block_proposals(answer, observed),
        mirror_proposals(answer, m, problem.ranges, observed),
        [fold_proposal(answer)],
    )
    alternatives = [a for p in fixed if (a := _alternative(p, problem, sigma)) is not None]
    without = None if inliers is None else observed & ~inliers
    counted = [
        Alternative(p, _deviance(p, problem, sigma), f"search start {i}", payload=True)
        for i, p in enumerate(starts)
    ]
    randoms = (
        _alternative(Proposal(p.points, p.origin, without, counted=True), problem, sigma)
        for p in random_proposals(problem.n_points, problem.dim, problem.scale, rng)
    )
    # the answer is a start too: len(counted) + 1 starts in all
    words = DRAWS_BUDGET
    if draws is None:
        budget = min(problem.random_starts, max(SEARCH_BUDGET - len(counted) - 1, 0))
    else:
        budget, words = draws, RANDOM_STARTS_LIMIT
    counted, made = random_search(run, counted, randoms, budget=budget)
    return JudgedSearch.of(run(alternatives + counted), len(counted) + 1, budget=words, draws=made)


def _sources_note(best: Candidate, problem: CalibrationProblem) -> str:
    """The note on the sources the receivers leave undetermined (their mirror images,
    :func:`rangeslam.mdu.core.sources_verdict`), for a verdict that ends before the checks make
    it."""
    n_in = int(best.inliers.sum())
    redundancy = n_in - unknowns_up_to_rigid_motion(problem.n_points, problem.dim)
    sigma = verdict_noise(
        problem.noise_std, noise_upper_bound(best.ssr, redundancy), problem.exact_rms
    )
    fit = best.fit
    return sources_verdict(fit.receivers, fit.sources, problem.ranges, best.inliers, sigma,
                           problem.exact_rms, "none")[1]  # fmt: skip


def judged_status(
    judged: JudgedSearch, best: Candidate, problem: CalibrationProblem, message: str
) -> tuple[Status, str]:
    """The judge's part of the verdict: NOT_IDENTIFIABLE for a rival minimum; NO_AGREEMENT when
    the judge still found a minimum lower than the answer (told apart from it: the search's fit
    from the lowest did not keep it), or for a robust calibration without a noise level whose
    search the budget, not the stopping rule, ended (its inlier residuals pass against their
    own spread wherever it dropped the ranges a wrong minimum misses, as a robust answer once
    had to be reached twice); else CONVERGED."""
    if not judged.judgement.check.passed:
        note = _sources_note(best, problem)
        return judged.judgement.status, message + "; ".join(
            filter(None, (judged.judgement.reason, note))
        )
    lower = judged.judgement.comparisons[0] if judged.judgement.replaced else None
    if lower is not None and lower.kind == LOWER:
        return Status.NO_AGREEMENT, message + (
            f"{judged.judgement.answer.origin} reached a lower minimum than the answer (by "
            f"{lower.delta_cost:.3g} noise variances) that the search's fit from it did not "
            f"keep; {_sources_note(best, problem)}"
        )
    if problem.robust and not problem.noise_std and not judged.complete:
        return Status.NO_AGREEMENT, message + (
            "the search ended before its stopping rule, minima no start reached still expected: "
            "a robust fit without noise_std may drop the ranges a wrong minimum misses (pass "
            f"noise_std, or raise max_attempts); {_sources_note(best, problem)}"
        )
    return Status.CONVERGED, message


def counted_points(judged: JudgedSearch) -> list[np.ndarray]:
    """The points (M + K, d) of the starts a judgement counted (the search's, its random ones
    and the judged answer), its lowest left out: the starts of a judgement at that lowest."""
    return [c.alternative.points for c in judged.judgement.comparisons if c.alternative.payload]


def spread(cand: Candidate) -> float:
    """The noise level a candidate's inlier residuals imply, metres (0 without redundancy)."""
    n_in = int(cand.inliers.sum())
    dof = n_in - unknowns_up_to_rigid_motion(sum(cand.inliers.shape), cand.fit.receivers.shape[1])
    return float(np.sqrt(cand.ssr / dof)) if dof > 0 else 0.0


def ambiguity_words(judgement) -> str:
    """The named ambiguities the judge found, in words ("" if none)."""
    named = sorted({c.alternative.ambiguity for c in judgement.ambiguities})
    return "; ".join(f"ambiguous: {w}" for w in named)
