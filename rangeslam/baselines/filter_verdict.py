"""Is a filter's answer where the data put it? The batch minimum as the noise yardstick.

Without ``noise_std`` a filter's range residuals are all there is, and a filter that ends off
the batch minimum leaves residuals that look like noise: an EKF answer 14 cm off (bound 4 mm)
had an RMS residual of 2.8 cm on 1 mm ranges, under the 2% of the scene that RELATIVE_RMS
allows, and said CONVERGED. Least squares on the ranges from the filter's answer reaches a
minimum whose residuals bound the noise (:func:`rangeslam.verdict.noise_upper_bound`); the
filter's answer passes only when its own residuals fit that noise (chi-square at CHI2_LEVEL).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from rangeslam.errors import InvalidInputError
from rangeslam.mdu.core import step_prior_rows, unfolding_check, unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import Status
from rangeslam.verdict import noise_upper_bound, verdict_noise
from rangeslam.verdict.checks import Check
from rangeslam.verdict.judge import LOWER, Alternative, judge
from rangeslam.verdict.thresholds import CHI2_LEVEL, EXACT_RTOL, SEARCH_BUDGET

__all__ = ["filter_check", "off_the_batch_minimum", "rival_check"]


def filter_check(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    noise_std: float | None,
    scale: float,
    bounds: StepBounds | None,
    rng: np.random.Generator,
) -> Check:
    """The verdict :func:`rangeslam.mdu.slam` gives its trajectory, on a filter's answer: off the
    batch minimum without ``noise_std`` (:func:`off_the_batch_minimum`); then the residuals
    against the noise, the information of the ranges and the step bounds' prior (read as
    ``slam``'s "uniform" prior) beyond the rigid motions, the receivers' precision along their
    weakest directions, and whether the points are flat (:func:`unfolding_check`, landmarks
    noted, not judged, as for ``slam``); last, no other minimum of the graph as good or better
    (:func:`rival_check`, with ``rng``).

    Args:
        receivers, sources: (M, d), (K, d) the filter's answer, metres.
        ranges: (M, K) metres; observed: (M, K) bool.
        noise_std: the range noise if known, metres; scale: the ranges' median, metres.
        bounds: the step bounds the filter was given, or None.
    """
    r = np.where(observed, ranges, 0.0)
    if noise_std is None:
        off = off_the_batch_minimum(receivers, sources, r, observed)
        if off:
            return Check(Status.INCONSISTENT, off)
    n_obs = int(observed.sum())
    redundancy = n_obs - unknowns_up_to_rigid_motion(sum(observed.shape), receivers.shape[1])
    res = (np.linalg.norm(receivers[:, None] - sources[None], axis=2) - r)[observed]
    exact_rms = EXACT_RTOL * scale
    sigma = verdict_noise(noise_std, noise_upper_bound(float(res @ res), redundancy), exact_rms)
    n_points = sum(observed.shape)
    prior = step_prior_rows(bounds, "uniform", None, receivers, sigma, n_points) if sigma else None
    check = unfolding_check(
        receivers, sources, r, observed, noise_std, exact_rms, prior_jac=prior,
        what="the trajectory", judge_sources="none",
    )  # fmt: skip
    if not check.passed:
        return check
    rival = rival_check(receivers, r, observed, max(sigma or 0.0, exact_rms), bounds, sources, rng)
    if not rival.passed:
        return rival
    return Check(check.status, "; ".join(filter(None, (check.reason, rival.reason))))


def off_the_batch_minimum(
    receivers: np.ndarray, sources: np.ndarray, ranges: np.ndarray, observed: np.ndarray
) -> str:
    """The reason the answer's residuals do not fit the noise that the batch minimum implies,
    or "" when they do (or when the ranges have no redundancy to tell).

    Args:
        receivers, sources: (M, d), (K, d) the filter's answer, metres.
        ranges: (M, K) metres (0 or anything where not observed); observed: (M, K) bool.
    """
    n_obs = int(observed.sum())
    redundancy = n_obs - unknowns_up_to_rigid_motion(sum(observed.shape), receivers.shape[1])
    if redundancy <= 0:
        return ""
    r = np.where(observed, ranges, 0.0)
    res = np.linalg.norm(receivers[:, None] - sources[None], axis=2) - r
    ssr = float(np.sum(res[observed] ** 2))
    batch = refine_unfolding(receivers, sources, r, observed)
    batch_ssr = float(np.sum(batch.residuals[observed] ** 2))
    sigma = noise_upper_bound(batch_ssr, redundancy)
    if not sigma or not np.isfinite(batch_ssr):
        return ""
    limit = float(chi2.ppf(CHI2_LEVEL, n_obs)) * sigma**2
    if ssr <= limit:
        return ""
    return (
        f"the filter's answer is off the batch minimum: RMS residual {np.sqrt(ssr / n_obs):.3g} "
        f"m where least squares from it fits the ranges to a noise of at most {sigma:.3g} m; "
    )


def rival_check(
    receivers: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float,
    bounds: StepBounds | None,
    sources: np.ndarray,
    rng: np.random.Generator,
) -> Check:
    """The judge :func:`rangeslam.mdu.slam` answers to, on a filter's answer: the graph (ranges
    at ``sigma``, the step bounds' "uniform" prior) refined from the filter's answer, against
    GTSAM from GTSAM-style random starts (as many as the stopping rule of
    :func:`rangeslam.verdict.judge.search_complete` asks, at most SEARCH_BUDGET), all scored on
    the graph's deviance and compared by :func:`rangeslam.verdict.judge.judge` (the trajectory's
    information distance, landmarks profiled out). The filter's answer replaced by a lower
    minimum (by more than the cost level, and outside its confidence region) means the filter
    ended off the data's best minimum (INCONSISTENT); a rival means the ranges do not decide
    between them (NOT_IDENTIFIABLE).

    Args:
        receivers, sources: (M, d), (K, d) the filter's answer, metres; ranges, observed: (M, K).
        sigma: the range noise the graph is weighted with, metres (> 0).
        bounds: the step bounds the filter was given, or None; rng: for the random starts.
    """
    from rangeslam.mdu.core import ConvexIterationOptions
    from rangeslam.mdu.slam import parse_slam
    from rangeslam.mdu.slam_graph import graph_deviance, refine_run, stacked
    from rangeslam.mdu.slam_judge import (
        FIT_ERRORS,
        counted_as_start,
        judge_metric,
        random_minima,
    )

    m, d = receivers.shape
    try:
        problem = parse_slam(ranges, bounds, observed, d, True, sigma, None, None, "uniform", 0,
                             ConvexIterationOptions(start="cheap"))  # fmt: skip
    except InvalidInputError as exc:  # the bounds against the ranges at this sigma
        return Check(Status.INCONSISTENT, f"the graph of the filter's data is refused: {exc}")
    try:
        fit = refine_run(problem, np.vstack([receivers, sources]), sigma, covariances=False)[0]
    except FIT_ERRORS:
        return Check(Status.CONVERGED, "the graph could not be refined from the filter's answer")
    own = stacked(fit)
    answer = Alternative(own, graph_deviance(problem, own, sigma), "the filter's answer", payload=1)
    # the answer and the random starts together at most SEARCH_BUDGET; a start's fit stops early
    # in the answer's basin only when the answer is the graph's minimum (its refit converged)
    early = None if fit.converged else (lambda points: False)
    starts = random_minima(problem, answer, [], sigma, rng, budget=SEARCH_BUDGET - 1, reached=early)
    metric = judge_metric(problem, sigma)
    judgement = judge(
        answer,
        starts,
        metric=metric,
        dof=unknowns_up_to_rigid_motion(m, d),
        counted=counted_as_start,
        precision=metric.precision,
    )
    own_comparison = next((c for c in judgement.comparisons if c.alternative is answer), None)
    if own_comparison is not None and own_comparison.kind == LOWER:
        lowest = judgement.answer
        why = (
            f"{lowest.origin} of the same graph ends lower (deviance {lowest.deviance:.4g} "
            f"against {answer.deviance:.4g} from the filter's answer, information distance "
            f"{own_comparison.distance2:.3g}): the filter ended off the data's best minimum"
        )
        return Check(Status.INCONSISTENT, why)
    if judgement.status is Status.NOT_IDENTIFIABLE:
        return Check(Status.NOT_IDENTIFIABLE, judgement.reason)
    return Check(Status.CONVERGED)
