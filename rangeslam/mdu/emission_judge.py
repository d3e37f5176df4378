"""The judge of :func:`rangeslam.mdu.emission.calibrate_unknown_emission`: every start's minimum
against the search's answer by the one test (:func:`rangeslam.verdict.judge.judge`), on the sum
of squared range residuals over sigma^2 (the deviance of Gaussian ranges) and the information
distance of the receivers (the sources and the event offsets profiled out), all in the search's
scaled units (the median corrected range); and the same test alone (:func:`same_emission`) for
the search's vote of two starts. After the search, least-squares runs of the same model from
random points join the starts until the stopping rule of Boender and Rinnooy Kan or the budget
(:func:`judged_emission_search`), as :func:`rangeslam.calibrate`'s judge makes them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from rangeslam.mdu.core import unknowns_up_to_rigid_motion
from rangeslam.verdict.judge import (
    DRAWS_BUDGET,
    RANDOM_STARTS_LIMIT,
    Alternative,
    JudgedSearch,
    information_distance,
    judge,
    random_search,
    same_answer,
)
from rangeslam.verdict.thresholds import EXACT_RTOL, SEARCH_BUDGET

if TYPE_CHECKING:
    from rangeslam.mdu.emission import (
        EmissionCandidate,
        EmissionProblem,
        EmissionSearch,
        ScaledUnfolding,
    )

__all__ = [
    "emission_alternative",
    "emission_metric",
    "emission_sigma",
    "judge_emission",
    "judged_emission_search",
    "same_emission",
]


def emission_sigma(problem: EmissionProblem, scaled: ScaledUnfolding, ssr: float) -> float:
    """The sigma of the judge's objective in scaled units (the median corrected range,
    ``scaled.scale`` metres): the given ``noise_std`` over the scale, else the fit's
    sqrt(``ssr`` / redundancy) (scaled sum of squares); at least the exact-data RMS,
    EXACT_RTOL."""
    redundancy = int(problem.observed.sum()) - problem.need
    if problem.noise_std:
        return max(problem.noise_std / scaled.scale, EXACT_RTOL)
    return max(math.sqrt(ssr / redundancy) if redundancy > 0 else 0.0, EXACT_RTOL)


def emission_alternative(model, cand: EmissionCandidate, sigma: float, origin: str) -> Alternative:
    """A fit as the judge's :class:`rangeslam.verdict.judge.Alternative`: points (M + K, d) and
    offsets (G,) in scaled units, deviance ssr / sigma^2 (``sigma`` scaled)."""
    pts, b = model.split(cand.fit.x)
    return Alternative(pts, cand.ssr / sigma**2, origin, extra=b, payload=cand)


def emission_metric(model, sigma: float):
    """``metric(lowest)`` of :func:`rangeslam.verdict.judge.judge`: delta^2 in the information
    at ``lowest`` (the model's Jacobian over ``sigma``), the receivers what is calibrated (the
    sources and offsets profiled out)."""

    def metric(lowest: Alternative):
        theta = np.r_[np.ravel(lowest.points), lowest.extra]
        return information_distance(model.jacobian(theta) / sigma, interest=np.arange(model.m))

    return metric


def same_emission(problem: EmissionProblem, scaled: ScaledUnfolding, best: EmissionCandidate):
    """The judge's same-answer test at ``best`` (:func:`rangeslam.verdict.judge.same_answer`,
    at its sigma, :func:`emission_sigma`): a predicate of another :class:`EmissionCandidate`."""
    model = scaled.model
    sigma = emission_sigma(problem, scaled, best.ssr)
    answer = emission_alternative(model, best, sigma, "the answer")
    dof = unknowns_up_to_rigid_motion(model.m, problem.dim)
    test = same_answer(emission_metric(model, sigma)(answer), answer, dof)
    return lambda cand: test(emission_alternative(model, cand, sigma, "a start"))


def judge_emission(problem: EmissionProblem, scaled: ScaledUnfolding, found: EmissionSearch):
    """The search's answer against every other start's minimum by the one judge
    (:func:`rangeslam.verdict.judge.judge`): the sum of squared range residuals over sigma^2
    (:func:`emission_sigma`) as the deviance, delta^2 of the receivers (sources and offsets
    profiled out). A :class:`rangeslam.verdict.judge.Judgement`; every start counts."""
    run, others, _ = _emission_judge(problem, scaled, found)
    return run(others)


def judged_emission_search(
    problem: EmissionProblem,
    scaled: ScaledUnfolding,
    found: EmissionSearch,
    fit_start: Callable[[np.ndarray], EmissionCandidate | None],
    rng: np.random.Generator,
) -> JudgedSearch:
    """:func:`judge_emission` after random starts: ``fit_start(points)`` (the search's fit of
    the model from scaled points (M + K, d) normal about the origin, with the starting offsets;
    None when it diverged) until the stopping rule (:func:`rangeslam.verdict.judge.
    search_complete`, every start of the search counted with the answer) or SEARCH_BUDGET starts
    in all (at most ``problem.random_starts`` draws). A search that stopped at the first
    minimum passing the residual test, unconfirmed, is judged against what those starts
    reach: a lower minimum replaces it, an equal one far off is its rival. Returns the
    judgement, its ``draws`` the draws made (a diverged fit counts as drawn, not as a start)."""
    run, others, sigma = _emission_judge(problem, scaled, found)
    n_points = sum(problem.ranges.shape)

    def randoms():
        for j in itertools.count():
            cand = fit_start(rng.standard_normal((n_points, problem.dim)))
            yield (
                None
                if cand is None
                else emission_alternative(scaled.model, cand, sigma, f"random start {j}")
            )

    left = max(SEARCH_BUDGET - len(others) - 1, 0)
    budget = min(problem.random_starts, left)
    counted, made = random_search(run, others, randoms(), budget=budget)
    words = DRAWS_BUDGET if budget == left else RANDOM_STARTS_LIMIT
    return JudgedSearch.of(run(counted), len(counted) + 1, budget=words, draws=made)


def _emission_judge(problem: EmissionProblem, scaled: ScaledUnfolding, found: EmissionSearch):
    """(run, the other starts as Alternatives, the objective's sigma): ``run(alternatives)``
    judges the answer against them (module docstring)."""
    model = scaled.model
    sigma = emission_sigma(problem, scaled, found.best.ssr)
    answer = emission_alternative(model, found.best, sigma, "the answer")
    others = [
        emission_alternative(model, c, sigma, f"start {i}")
        for i, c in enumerate(found.candidates)
        if c is not found.best
    ]
    dof = unknowns_up_to_rigid_motion(model.m, problem.dim)
    metric = emission_metric(model, sigma)

    def run(alternatives):
        return judge(answer, alternatives, metric=metric, dof=dof)

    return run, others, sigma
