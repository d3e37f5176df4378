"""Rivals of a calibration's answer: other minima of the same least-squares cost that fit the
ranges as well (within AMBIGUITY_CHI2 noise variances) with receivers elsewhere, so the data do
not decide between them; and lower minima the search missed.

The functions take :mod:`rangeslam.mdu.calibration`'s problem and candidates (duck-typed: the
attributes named in each docstring).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.alignment import align
from rangeslam.mdu.core import unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.verdict import AMBIGUITY_CHI2, RIVAL_SPREADS, verdict_noise
from rangeslam.verdict.crlb import mdu_crlb
from rangeslam.verdict.thresholds import AGREEMENT_STARTS, LOWER_RTOL

if TYPE_CHECKING:
    from rangeslam.mdu.calibration import CalibrationProblem, Candidate

__all__ = ["displaced_rival", "receiver_spread", "rival_configuration", "spread"]


def receiver_spread(best: Candidate, observed: np.ndarray, noise: float) -> float:
    """The receivers' RMS standard deviation at the answer (:func:`mdu_crlb` in the receiver
    gauge at ``noise``), metres; ``noise`` where the bound is undefined."""
    try:
        return mdu_crlb(best.fit.receivers, best.fit.sources, noise, mask=observed).receiver_rmse
    except (DegenerateGeometryError, InvalidInputError):
        return noise


def rival_configuration(
    problem: CalibrationProblem, best: Candidate, rng
) -> tuple[str, np.ndarray | None]:
    """ "Restarts agree": least squares from AGREEMENT_STARTS random points. Returns the reason
    when one ends with a residual sum of squares within AMBIGUITY_CHI2 noise variances of the
    answer's but receivers more than RIVAL_SPREADS times their RMS standard deviation (RMS,
    after the best rigid motion with reflection) away, else "" (flat scenes fitted in 3-D fold
    this way); and the points (M + K, d) of the lowest start that costs less than the answer
    (a lower minimum the search missed), else None."""
    m, r, observed = problem.ranges.shape[0], problem.ranges, problem.observed
    noise = verdict_noise(problem.noise_std, spread(best) or problem.exact_rms, problem.exact_rms)
    far = max(RIVAL_SPREADS * receiver_spread(best, observed, noise), 1e-6 * problem.scale)
    reason, lower, lower_ssr = "", None, best.ssr * (1.0 - LOWER_RTOL)
    for _ in range(AGREEMENT_STARTS):
        points = rng.standard_normal((problem.n_points, problem.dim)) * problem.scale
        fit = refine_unfolding(points[:m], points[m:], r, observed)
        ssr = float(np.sum(fit.residuals[observed] ** 2))
        if not np.isfinite(ssr) or ssr > best.ssr + AMBIGUITY_CHI2 * noise**2:
            continue
        if ssr < lower_ssr:
            lower, lower_ssr = np.vstack([fit.receivers, fit.sources]), ssr
        apart = align(fit.receivers, best.fit.receivers, reflection=True).rmse
        if apart > far and not reason:
            reason = (
                f"another start fits the ranges as well (residual sum of squares {ssr:.3g} "
                f"against {best.ssr:.3g} m^2) with receivers {apart:.3g} m RMS away: the data do "
                "not decide between them"
            )
    return reason, lower


def displaced_rival(problem: CalibrationProblem, before: Candidate, after: Candidate) -> str:
    """Why ``after``, a lower minimum that replaced the answer ``before``, is not determined by
    the data: ``before`` costs at most AMBIGUITY_CHI2 noise variances more with receivers more
    than RIVAL_SPREADS times their RMS standard deviation away (Fig. 3 at 1 mm: a random start
    ended 0.45 noise variances below the search's answer with the microphones 1.39 m away, and
    replacing the answer by it made a wrong one CONVERGED); "" otherwise."""
    if after is before:
        return ""
    noise = verdict_noise(problem.noise_std, spread(after) or problem.exact_rms, problem.exact_rms)
    far = max(RIVAL_SPREADS * receiver_spread(after, problem.observed, noise),
              1e-6 * problem.scale)  # fmt: skip
    apart = align(before.fit.receivers, after.fit.receivers, reflection=True).rmse
    if before.ssr - after.ssr > AMBIGUITY_CHI2 * noise**2 or apart <= far:
        return ""
    return (
        f"the answer it replaced fits the ranges about as well (residual sum of squares "
        f"{before.ssr:.3g} against {after.ssr:.3g} m^2) with receivers {apart:.3g} m RMS away: "
        "the data do not decide between them"
    )


def spread(cand: Candidate) -> float:
    """The noise level a candidate's inlier residuals imply, metres (0 without redundancy)."""
    n_in = int(cand.inliers.sum())
    dof = n_in - unknowns_up_to_rigid_motion(sum(cand.inliers.shape), cand.fit.receivers.shape[1])
    return float(np.sqrt(cand.ssr / dof)) if dof > 0 else 0.0
