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

from rangeslam.mdu.core import unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.verdict import noise_upper_bound
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = ["off_the_batch_minimum"]


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
