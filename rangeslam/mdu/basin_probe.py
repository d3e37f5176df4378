"""Is an unfolding the lowest minimum within a few standard deviations of itself?

The chi-square test of :func:`rangeslam.calibrate` accepts any minimum whose residuals fit the
noise, and with little redundancy a wrong one costing a few noise variances more than the right
one passes it. On the paper's Fig. 3 scene (6 microphones, 6 sources, redundancy 6) at 1 mm,
three convex-iteration runs reached a minimum 7.3 cm off at 1.86 times the right cost before any
reached the right one (2.3 cm off, bound 1.9 cm): the two lie about two standard deviations apart
along the answer's weakest direction. The probe refits least squares (the Gaussian ML of eq. 9)
from the answer moved PROBE_SPREADS standard deviations along its PROBE_DIRECTIONS weakest
directions (:func:`rangeslam.verdict.weak_moves`, both signs) and returns the lowest fit that
costs less than the answer.
"""

from __future__ import annotations

import numpy as np

from rangeslam.mdu.core import information_model
from rangeslam.solvers.least_squares import UnfoldingFit, refine_unfolding, unfolding_jacobian
from rangeslam.verdict import gauge_free_covariance, weak_moves
from rangeslam.verdict.thresholds import LOWER_RTOL, PROBE_DIRECTIONS, PROBE_SPREADS

__all__ = ["lower_minimum_nearby"]


def lower_minimum_nearby(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float,
) -> UnfoldingFit | None:
    """The lowest least-squares fit from the answer moved along its weakest directions, when it
    costs less than the answer; None otherwise (or when the answer's information is singular).

    Args:
        receivers, sources: (M, d), (K, d) the answer, metres.
        ranges: (M, K) metres, 0 where not observed; observed: (M, K) bool.
        sigma: range noise the moves are scaled by (given or estimated), metres; > 0.
    """
    m, d = receivers.shape
    points = np.vstack([receivers, sources])
    pairs = np.argwhere(observed)
    info_jac, gauge, _ = information_model(
        receivers, sources, unfolding_jacobian(points, m, pairs), None, None
    )
    cov, _ = gauge_free_covariance(info_jac, gauge)
    if cov is None:
        return None
    ssr = float(np.sum((np.linalg.norm(points[pairs[:, 0]] - points[m + pairs[:, 1]], axis=1)
                        - ranges[observed]) ** 2))  # fmt: skip
    lowest, lowest_ssr = None, ssr * (1.0 - LOWER_RTOL)
    for move in weak_moves(cov, sigma, np.arange(len(cov)), PROBE_DIRECTIONS, PROBE_SPREADS):
        moved = points + move.reshape(-1, d)
        fit = refine_unfolding(moved[:m], moved[m:], ranges, observed)
        new = float(np.sum(fit.residuals[observed] ** 2))
        if np.isfinite(new) and new < lowest_ssr:
            lowest, lowest_ssr = fit, new
    return lowest
