"""Is the scene planar? The checks of :func:`rangeslam.mdu.core.unfolding_check` that compare a
fit in ``dim`` dimensions with one in the other.

- :func:`dimension_check`: a 2-D answer refitted in 3-D (from lifted starts, :func:`lifted_ssr`):
  INCONSISTENT when the F-test says the residual drop is more than noise (3-D data fitted with
  ``dim=2``); NOT_IDENTIFIABLE when the test cannot be made, or without ``noise_std`` is too
  weak to tell (:func:`planarity_power`).
- :func:`flat_rival_check`: a 3-D answer with flat receivers against the flat configuration.
- :func:`flat_fit_check`: any answer against itself refitted in one dimension fewer.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2
from scipy.stats import f as f_dist

from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.solvers.least_squares import refine_unfolding, unfolding_residuals
from rangeslam.status import Status
from rangeslam.verdict import PASSED, Check, flatness_check
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = [
    "blind_power",
    "dimension_check",
    "flat_fit_check",
    "flat_rival_check",
    "flat_ssr",
    "lifted_ssr",
    "planarity_power",
]


def flat_fit_check(
    points: np.ndarray,
    m: int,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float | None,
    what: str,
    *,
    offsets: bool = False,
) -> Check:
    """NOT_IDENTIFIABLE when the answer ``points`` (M + K, d), receivers above sources, may all
    lie in one hyperplane (a plane in 3-D, a line in 2-D): the configuration refitted in d - 1
    dimensions from its projection into its best hyperplane (the fold into fewer dimensions)
    fits the (M, K) ``observed`` ``ranges`` as well, its cost gap over the answer (noise
    variances at range noise ``sigma``, metres) within the chi-square quantile at CHI2_LEVEL of
    the N - d coordinates the flat model lacks (a likelihood-ratio test of nested models). Flat
    points fitted in d dimensions fold out of the hyperplane at second order: the data then fix
    each point's side of it, and its height, not at all. Range costs only: priors (step
    bounds) are left out of both sides, so the answer's range cost is above its range-only
    minimum, which errs towards "may be flat".

    Where the refit cannot be the nested model, the one-range bound of
    :func:`rangeslam.verdict.flatness_check` decides instead: ``offsets`` (the ranges are
    corrected by fitted offsets, emission times or clock offsets, which the flat refit would
    hold fixed: a flat scene fitted with offsets passed as 3-D), or a refit that failed."""
    d = points.shape[1]
    extra = len(points) - d  # one coordinate per point, less d's d extra rigid motions
    if not sigma or d < 2 or extra <= 0:
        return PASSED
    one_range = flatness_check(points, sigma, float(np.median(ranges[observed])), what)
    if offsets:
        return one_range
    pairs = np.argwhere(observed)
    residuals = unfolding_residuals(points, m, ranges[observed], pairs)
    centre = points.mean(axis=0)
    flat = (points - centre) @ np.linalg.svd(points - centre)[2][: d - 1].T
    try:
        flat_cost = flat_ssr(flat, m, np.maximum(ranges, 0.0), observed)
    except (InvalidInputError, SolverError):
        flat_cost = float("nan")
    gap = (flat_cost - residuals @ residuals) / sigma**2
    if not np.isfinite(gap):
        return one_range
    level = float(chi2.ppf(CHI2_LEVEL, extra))
    if gap <= level:
        kind = "plane" if d == 3 else "line"
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"{what} may be flat: refitted in one {kind} it fits the ranges as well (cost gap "
            f"{gap:.3g} <= {level:.3g} noise variances on {extra} degrees of freedom), so the "
            f"points' sides of it are not determined" + (" (fit with dim=2?)" if d == 3 else ""),
        )
    return PASSED


def flat_ssr(flat: np.ndarray, m: int, ranges: np.ndarray, observed: np.ndarray) -> float:
    """The sum of squared range residuals (m^2) of least squares in the dimension of ``flat``
    (N, 1 or 2; receivers above sources) started there, on the (M, K) ``observed`` ``ranges``:
    :func:`refine_unfolding` in a plane; on a line, |t_i - t_j| fitted by SciPy's trust-region
    method (the sign pattern of the start, where the range is not zero)."""
    if flat.shape[1] > 1:
        fit = refine_unfolding(flat[:m], flat[m:], ranges, observed)
        return float(np.sum(fit.residuals[observed] ** 2))
    pairs = np.argwhere(observed)
    rows, i, j = np.arange(len(pairs)), pairs[:, 0], m + pairs[:, 1]
    scale = float(np.median(ranges[observed])) or 1.0

    def residuals(t):
        return np.abs(t[i] - t[j]) - ranges[observed] / scale

    def jacobian(t):
        jac = np.zeros((len(pairs), len(t)))
        sign = np.sign(t[i] - t[j])
        jac[rows, i], jac[rows, j] = sign, -sign
        return jac

    fit = least_squares(residuals, flat[:, 0] / scale, jac=jacobian, method="trf")
    return float(np.sum(fit.fun**2)) * scale**2


def lifted_ssr(points: np.ndarray, m: int, ranges: np.ndarray, observed: np.ndarray) -> float:
    """The least sum of squared range residuals (m^2) of 3-D least squares started from the 2-D
    ``points`` (M + K, 2) lifted off their plane by fixed patterns (alternating, golden-angle and
    slow sine signs, 5%, 20% and 50% of the median range): a 3-D fit has local minima, and a
    start that misses the 3-D one lets 3-D data pass as planar (a 3-D walk fitted with dim=2
    converged once in a full-suite run)."""
    n, scale = len(points), float(np.median(ranges[observed]))
    best = float("inf")
    k = np.arange(n)
    for pattern in ((-1.0) ** k, np.cos(2.39996 * k), np.sin(0.7 * k + 0.3)):
        for lift in (0.05, 0.2, 0.5):
            lifted = np.column_stack([points, lift * scale * pattern])
            fit = refine_unfolding(lifted[:m], lifted[m:], ranges, observed)
            ssr = float(np.sum(fit.residuals[observed] ** 2))
            best = min(best, ssr) if np.isfinite(ssr) else best
    return best


def flat_rival_check(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    redundancy: int,
    sigma: float | None,
    scale: float,
) -> Check:
    """NOT_IDENTIFIABLE when a 3-D answer whose receivers are flat (:func:`flatness_check`)
    fits its ranges no better than the flat configuration refined from its projection into
    the receivers' plane (the F-test of :func:`dimension_check` at CHI2_LEVEL, read the
    other way): a flat scene fitted in 3-D folds its sources out of the plane at no cost, while
    sources truly off a flat array cannot be flattened. ``receivers`` (M, 3), ``sources``
    (K, 3), ``ranges`` and ``observed`` (M, K), ``sigma`` and ``scale`` metres. Ranges already
    corrected by fitted offsets (emission times, clock offsets) keep those offsets in the flat
    fit, which can only make it worse: a folded scene with offsets may pass unseen here."""
    m, d = receivers.shape
    extra = m + len(sources) - 3  # one coordinate per point, less 3-D's three extra motions
    if d != 3 or redundancy <= 0 or flatness_check(receivers, sigma, scale, "").passed:
        return PASSED
    points = np.vstack([receivers, sources])
    pairs = np.argwhere(observed)
    residuals = unfolding_residuals(points, m, ranges[observed], pairs)
    ssr3 = float(residuals @ residuals)
    centre = receivers.mean(axis=0)
    flat = (points - centre) @ np.linalg.svd(receivers - centre)[2][:2].T
    # offset-corrected ranges can dip below 0 (a source at a receiver)
    ssr2 = flat_ssr(flat, m, np.maximum(ranges, 0.0), observed)
    stat = ((ssr2 - ssr3) / extra) / max(ssr3 / redundancy, 1e-300)
    if np.isfinite(ssr2) and stat <= f_dist.ppf(CHI2_LEVEL, extra, redundancy):
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"the receivers are flat and a flat configuration fits the ranges as well (residual "
            f"sum of squares {ssr2:.3g} against {ssr3:.3g} m^2, F = {stat:.3g} on {extra} and "
            f"{redundancy} degrees of freedom): the sources' sides of their plane are not "
            "determined (fit with dim=2?)",
        )
    return PASSED


def dimension_check(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    redundancy: int,
    exact_rms: float,
    noise_std: float | None = None,
) -> Check:
    """INCONSISTENT when a 2-D answer's ranges are fitted significantly better in 3-D (an F-test
    at CHI2_LEVEL of the residual drop against the N - 3 extra unknowns): the data are not
    planar and dim=2 leaves a structured residual that no noise level explains.
    NOT_IDENTIFIABLE when the test cannot be made (no redundant ranges in 3-D), or, without
    ``noise_std`` (metres), when it cannot see 3-D data (:func:`planarity_power` over
    blind_power()): the residual is then all the noise estimate has, and a landmark's height
    folds into it and into its in-plane distances (a walk of 3 steps under 3-D
    landmarks converged with dim=2, landmarks 0.6-3.3 m off). With ``noise_std`` the residual
    test sees a fold over the noise; one under it can still shift a landmark of a nearly
    straight walk by metres, which only a walk of 2 steps (no redundant range in 3-D) showed
    converged in 12 draws (2 of 6 at 2 steps, 0 of 6 at 3). A 3-D answer passes.
    ``receivers`` (M, d), ``sources`` (K, d), ``ranges`` and ``observed`` (M, K), ``exact_rms``
    the RMS residual of exact data, metres."""
    m, d = receivers.shape
    n = m + len(sources)
    pairs = np.argwhere(observed)
    residuals = unfolding_residuals(np.vstack([receivers, sources]), m, ranges[observed], pairs)
    ssr2 = float(residuals @ residuals)
    extra = n - 3  # one coordinate per point, less the three extra rigid motions of 3-D
    if d != 2 or redundancy <= 0 or ssr2 <= exact_rms**2 * residuals.size:
        return PASSED
    dof3 = redundancy - extra
    ssr3 = lifted_ssr(np.vstack([receivers, sources]), m, ranges, observed) if dof3 > 0 else 0.0
    if dof3 > 0 and np.isfinite(ssr3) and ssr3 < ssr2:
        stat = ((ssr2 - ssr3) / extra) / max(ssr3 / dof3, 1e-300)
        if stat > f_dist.ppf(CHI2_LEVEL, extra, dof3):
            return Check(
                Status.INCONSISTENT,
                f"the data are not planar: fitted in 3-D the residual sum of squares drops from "
                f"{ssr2:.3g} to {ssr3:.3g} m^2 (F = {stat:.3g} on {extra} and {dof3} degrees of "
                "freedom); fit with dim=3",
            )
    power = planarity_power(extra, redundancy)
    if dof3 <= 0 or (noise_std is None and power > blind_power()):
        test = (
            f"without noise_std, with {dof3} redundant ranges in 3-D, the planarity F-test "
            f"would miss 3-D data whose 2-D residual is up to {power:.3g} times the noise"
            if dof3 > 0
            else "with no redundant ranges in 3-D a 3-D configuration fits them exactly and the "
            "planarity F-test cannot be made"
        )
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"the data cannot be shown planar: {test} (RMS residual "
            f"{np.sqrt(ssr2 / residuals.size):.3g} m), and a point's height off the plane folds "
            "into its in-plane distances (pass noise_std, fit with dim=3, or give more steps "
            "or ranges)",
        )
    return PASSED


def planarity_power(extra: int, redundancy: int) -> float:
    """How many times the noise in a 2-D residual a fold of 3-D data can be before the F-test
    of :func:`dimension_check` sees it: R = extra F_crit / ``redundancy``, F_crit the CHI2_LEVEL
    quantile of F on ``extra`` and redundancy - extra degrees of freedom (infinite without
    those). 3-D data whose 2-D fit adds a fold of sum of squares D (m^2) to noise sigma give
    F = 1 + D / (extra sigma^2), so the test sees D only beyond extra (F_crit - 1) sigma^2, about
    R times the noise's share redundancy sigma^2 of the residual (the fold is then R / (1 + R)
    of it). Seven landmarks: R = 5e5 for a walk of 4 positions, 17.5 for 5, 5.2 for 6, 1.5 for
    10."""
    dof3 = redundancy - extra
    if dof3 <= 0:
        return float("inf")
    return float(extra * f_dist.ppf(CHI2_LEVEL, extra, dof3) / redundancy)


def blind_power() -> float:
    """The :func:`planarity_power` beyond which the F-test counts as blind without a noise
    level: the odds of the verdicts' level, CHI2_LEVEL / (1 - CHI2_LEVEL) + 1 (1000 at 0.999).
    A fold that many times the noise is as unlikely to be missed as a false alarm is to be
    raised. Seven landmarks: a walk of 4 positions (one redundant range in 3-D, power 5e5) or 3
    (none) is blind; from 5 positions (power 17.5) the test saw every planar walk under 3-D
    landmarks (1 mm noise, 6 of 6 at 5 and 6 positions, F 50-9600)."""
    return 1.0 / (1.0 - CHI2_LEVEL)
