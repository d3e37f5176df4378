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

from rangeslam.mdu.core import step_prior_rows, unfolding_check, unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import Status
from rangeslam.verdict import noise_upper_bound, verdict_noise
from rangeslam.verdict.checks import Check
from rangeslam.verdict.judge import cost_level
from rangeslam.verdict.thresholds import (
    AGREEMENT_STARTS,
    CHI2_LEVEL,
    EXACT_RTOL,
    RIVAL_SPREADS,
)

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
    """The agreement :func:`rangeslam.mdu.slam` asks of its answer, on a filter's: the graph
    (ranges at ``sigma``, the step bounds' prior) refined from the filter's answer, then from
    AGREEMENT_STARTS GTSAM-style random starts. A start that ends lower by more than
    half the cost level (:func:`rangeslam.verdict.judge.cost_level`) means the filter ended off
    the data's best minimum (INCONSISTENT); one within it, with a trajectory more than RIVAL_SPREADS times the answer's RMS standard
    deviation away, means the ranges do not decide between them (NOT_IDENTIFIABLE).

    Args:
        receivers, sources: (M, d), (K, d) the filter's answer, metres; ranges, observed: (M, K).
        sigma: the range noise the graph is weighted with, metres (> 0).
        bounds: the step bounds the filter was given, or None; rng: for the random starts.
    """
    from rangeslam.errors import SolverError
    from rangeslam.geometry.alignment import align
    from rangeslam.mdu.slam_graph import nominal_steps, random_start
    from rangeslam.solvers.gtsam_graph import refine_graph

    def fit_from(x0, s0, covariances=False):
        return refine_graph(x0, s0, ranges, noise_std=sigma, mask=observed, step_bounds=bounds,
                            covariances=covariances, max_iterations=5000)  # fmt: skip

    try:
        own = fit_from(receivers, sources, covariances=True)
    except SolverError:
        return Check(Status.CONVERGED, "the graph could not be refined from the filter's answer")
    cov = own.receiver_cov
    spread = float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)))) if cov is not None else sigma
    steps = nominal_steps(bounds, ranges, observed)
    size, margin = float(np.max(ranges[observed])), 0.5 * cost_level()
    for _ in range(AGREEMENT_STARTS):
        x0, s0 = random_start(steps, ranges.shape[1], receivers.shape[1], size, rng)
        try:
            fit = fit_from(x0, s0)
        except SolverError:
            continue
        if not fit.converged or fit.error > own.error + margin:
            continue
        apart = align(fit.receivers, own.receivers, reflection=True).rmse
        if fit.error < own.error - margin:
            return Check(Status.INCONSISTENT, (
                f"a random start of the same graph ends lower (cost {fit.error:.4g} against "
                f"{own.error:.4g} from the filter's answer), {apart:.3g} m RMS away: the filter "
                "ended off the data's best minimum"))  # fmt: skip
        if apart > max(RIVAL_SPREADS * spread, 1e-6 * size):
            return Check(Status.NOT_IDENTIFIABLE, (
                f"a random start of the same graph fits the data as well (cost {fit.error:.4g} "
                f"against {own.error:.4g}) with a trajectory {apart:.3g} m RMS away: the ranges "
                "do not decide between them"))  # fmt: skip
    return Check(Status.CONVERGED)
