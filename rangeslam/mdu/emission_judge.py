"""The judge of :func:`rangeslam.mdu.emission.calibrate_unknown_emission`: every start's minimum
against the search's answer by the one test (:func:`rangeslam.verdict.judge.judge`), on the sum
of squared range residuals over sigma^2 (the deviance of Gaussian ranges) and the information
distance of the receivers (the sources and the event offsets profiled out), all in the search's
scaled units (the median corrected range); and the same test alone (:func:`same_emission`) for
the search's vote of two starts.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from rangeslam.mdu.core import unknowns_up_to_rigid_motion
from rangeslam.verdict.judge import Alternative, information_distance, judge, same_answer
from rangeslam.verdict.thresholds import EXACT_RTOL

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
    model = scaled.model
    sigma = emission_sigma(problem, scaled, found.best.ssr)
    answer = emission_alternative(model, found.best, sigma, "the answer")
    others = [
        emission_alternative(model, c, sigma, f"start {i}")
        for i, c in enumerate(found.candidates)
        if c is not found.best
    ]
    dof = unknowns_up_to_rigid_motion(model.m, problem.dim)
    return judge(answer, others, metric=emission_metric(model, sigma), dof=dof)
