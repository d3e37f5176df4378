"""Locating one point from its ranges to known anchors (paper, section 2, eq. 3). Pure numpy/scipy.

``multilaterate`` returns the exact global minimiser of the (weighted) squared-range cost

    sum_m w_m (||x - a_m||^2 - r_m^2)^2                                         (eq. 3)

by the SR-LS method of Beck, Stoica and Li, "Exact and approximate solutions of source
localization problems", IEEE Trans. Signal Process. 56(5), 2008: with y = [x, ||x||^2] the cost is
||A y - b||_W^2, a least-squares problem under one quadratic equality y^T D y + 2 f^T y = 0, a
generalised trust-region subproblem (GTRS). Its solution is y(lam) = (A^T W A + lam D)^-1
(A^T W b - lam f) where lam is the unique root of the decreasing function
phi(lam) = y(lam)^T D y(lam) + 2 f^T y(lam) on the interval where A^T W A + lam D is positive
definite (Beck et al., Theorem 3.2), found here by bracketing and Brent's method.

With ``robust=True`` outliers (e.g. wrong echo picks) are rejected first by least median of
squares over minimal anchor subsets (Rousseeuw, "Least median of squares regression", JASA 1984),
then the inliers are chosen by a threshold on the range residual scaled to the robust noise
estimate (reweighted least squares, Rousseeuw and Leroy 1987) and SR-LS is re-solved on them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import eigh
from scipy.optimize import brentq
from scipy.stats import chi2

from rangeslam._robust import robust_mode
from rangeslam._validation import (
    MAX_METRES,
    as_float_array,
    as_mask,
    as_points,
    as_ranges,
    as_rng,
    as_scalar,
    frozen,
    shape_str,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.localization.point_judge import PointObjective, judge_point, region_precision
from rangeslam.localization.robust_start import (
    TRUNCATED_STD,
    Refit,
    check_robust_options,
    minimal_subset_points,
    refine_inliers,
    robust_start,
)
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import (
    Check,
    consistency_check,
    first_failure,
    gauge_free_covariance,
    information_check,
    noise_upper_bound,
    rms_precision,
    verdict_noise,
)
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.judge import LOWER, CheckRecord, JudgedSearch
from rangeslam.verdict.thresholds import (
    CHI2_LEVEL,
    EXACT_RTOL,
    PRECISION_FRACTION,
    RELATIVE_RMS,
)

__all__ = ["MultilaterationResult", "affine_rank", "minimal_subset_points", "multilaterate"]

# minimal_subset_points lives in robust_start beside the LMedS start; it is re-exported here.

log = logging.getLogger(__name__)

WeightSpec = ArrayLike | Literal["uniform", "inverse_range"] | None

# Relative singular-value threshold below which anchors are taken to be affinely dependent.
_AFFINE_RTOL = 1e-8


@dataclass(frozen=True)
class MultilaterationResult(HasStatus):
    """Result of :func:`multilaterate`.

    Attributes:
        position: (d,) estimated point, metres.
        residuals: (M,) range residuals ||x - a_m|| - r_m in metres; NaN where not observed.
        inliers: (M,) True for the ranges used in the final fit (observed and, if robust, accepted).
        cost: weighted squared-range cost of eq. (3) over the inliers, at ``position`` (m^4 times
            the unit of the weights: m^4 for uniform weights, m^2 for the default 1/r^2).
        status: :class:`rangeslam.status.Status`: OUTLIERS when the robust search found too few
            consistent ranges, SOLVER_FAILED when its inlier set kept changing,
            NOT_IDENTIFIABLE in the GTRS hard case (``converged`` is ``status is CONVERGED``).
        message: what happened, in words.
        lagrange_multiplier: the GTRS multiplier lam at the solution (dimensionless, scaled
            problem); NaN when the judge replaced the SR-LS point by a lower minimum.
        checks: every check of the verdict, in order: "residuals", "information" (the precision
            at the answer, metres), "rival minima" (the judge: the least cost gap of another
            minimum, noise variances), "search complete" (the stopping rule of the random
            starts) and "precision over the confidence region" (metres); empty when the verdict
            ended before them (the hard case, a robust search that failed).
        judged: alternatives the judge compared with the answer (the mirror through the
            anchors' plane, refits without one anchor, random starts); ``reached``: starts (the
            answer counted) that reached the answer.
    """

    position: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    cost: float
    status: Status
    message: str
    lagrange_multiplier: float
    checks: tuple[CheckRecord, ...] = ()
    judged: int = 0
    reached: int = 0

    @property
    def n_outliers(self) -> int:
        return int(np.sum(~self.inliers & np.isfinite(self.residuals)))


def affine_rank(points: np.ndarray) -> int:
    """Affine dimension of a point set (N, d): 0 for one point, 1 for collinear, 2 for coplanar..."""
    if len(points) < 2:
        return 0
    centred = points - points.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    return int(np.sum(sv > _AFFINE_RTOL * max(sv[0], np.finfo(float).tiny)))


def _resolve_weights(weights: WeightSpec, ranges: np.ndarray, scale: float) -> np.ndarray:
    n = ranges.shape[0]
    if weights is None or (isinstance(weights, str) and weights == "uniform"):
        return np.ones(n)
    if isinstance(weights, str):
        if weights != "inverse_range":
            raise InvalidInputError(
                f"weights must be 'uniform', 'inverse_range' or an array of shape ({n},); got {weights!r}"
            )
        # The squared-range residual ||x-a||^2 - r^2 ~ 2 r e for range noise e, so 1/r^2 whitens
        # it (Beck et al., sec. II); ranges near zero are floored to keep the weights finite.
        return 1.0 / np.maximum(ranges, 1e-6 * scale) ** 2
    w = as_float_array(weights, "weights")
    if w.shape != (n,):
        raise InvalidInputError(f"weights must have shape ({n},); got {shape_str(w.shape)}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InvalidInputError("weights must be finite and non-negative")
    return w


def _srls(
    anchors: np.ndarray, ranges: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, float, bool]:
    """Exact minimiser of sum w (||x-a||^2 - r^2)^2; anchors already centred and unit-scaled.

    Returns (x, lam, unique). Anchors (with positive weight) must affinely span R^d; ``unique`` is
    False in the hard case, where a set of points attains the minimum.
    """
    n, d = anchors.shape
    a_mat = np.column_stack([-2.0 * anchors, np.ones(n)])
    b = ranges**2 - np.einsum("nd,nd->n", anchors, anchors)
    aw = a_mat * weights[:, None]
    m_mat = a_mat.T @ aw
    g = aw.T @ b
    dmat = np.diag(np.r_[np.ones(d), 0.0])
    f = np.r_[np.zeros(d), -0.5]
    # Generalised eigen-decomposition of the pencil (D, A^T W A): V^T M V = I, V^T D V = diag(e),
    # so (M + lam D)^-1 = V diag(1 / (1 + lam e)) V^T; y(lam) is then cheap for every lam.
    e, v = eigh(dmat, m_mat)
    vg, vf = v.T @ g, v.T @ f
    e_max = float(e[-1])

    def y_of(lam: float) -> np.ndarray:
        return v @ ((vg - lam * vf) / (1.0 + lam * e))

    def phi(lam: float) -> float:
        y = y_of(lam)
        return float(y[:d] @ y[:d] - y[d])

    lam_min = -1.0 / e_max
    lo = None
    for eps in 10.0 ** -np.arange(2, 15):
        cand = lam_min + eps * abs(lam_min)
        if phi(cand) > 0:
            lo = cand
            break
    if lo is None:
        return _srls_hard_case(vg, vf, v, e, lam_min, d), lam_min, False
    hi = max(1.0, abs(lam_min))
    for _ in range(200):
        if phi(hi) < 0:
            break
        hi *= 4.0
    else:
        raise SolverError("SR-LS: could not bracket the GTRS multiplier", status="no sign change")
    lam = brentq(phi, lo, hi, xtol=1e-15, rtol=1e-15, maxiter=500)
    return y_of(lam)[:d], float(lam), True


def _srls_hard_case(vg, vf, v, e, lam_min, d):
    """Beck et al.'s hard case: the optimum sits at lam = -1/e_max, where A^T W A + lam D is
    singular. Any y = y0 + U t in the null space U (the top generalised eigenvectors, possibly
    several when the anchors are symmetric) that satisfies the constraint is a minimiser, so the
    minimiser is not unique; one is returned (along the first null vector with a real root)."""
    null = np.abs(1.0 + lam_min * e) <= 1e-9 * max(1.0, abs(lam_min * e).max())
    c = np.zeros_like(e)
    c[~null] = (vg - lam_min * vf)[~null] / (1.0 + lam_min * e[~null])
    y0 = v @ c
    for u in v[:, null].T:
        qa = float(u[:d] @ u[:d])
        qb = float(2.0 * y0[:d] @ u[:d] - u[d])
        qc = float(y0[:d] @ y0[:d] - y0[d])
        disc = qb * qb - 4.0 * qa * qc
        if qa > 0 and disc >= -1e-12 * max(1.0, qb * qb):
            t = (-qb + math.sqrt(max(disc, 0.0))) / (2.0 * qa)
            return (y0 + t * u)[:d]
    raise SolverError("SR-LS hard case without a feasible point", status="infeasible GTRS")


def _range_residuals(x: np.ndarray, anchors: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    return np.linalg.norm(anchors - x, axis=-1) - ranges


@dataclass(frozen=True)
class ScaledProblem:
    """The inputs of :func:`multilaterate`, parsed once and scaled to unit size.

    Attributes:
        anchors, ranges, observed: (M, d), (M,), (M,) as given (validated).
        centre, scale: the observed anchors' centroid (d,) and RMS radius, metres.
        anchors_s, ranges_s: (M, d), (M,) centred and divided by ``scale``.
        weights: (M,) weights of eq. (3) on the scaled ranges, 0 where unobserved.
    """

    anchors: np.ndarray
    ranges: np.ndarray
    observed: np.ndarray
    centre: np.ndarray
    scale: float
    anchors_s: np.ndarray
    ranges_s: np.ndarray
    weights: np.ndarray

    @property
    def dim(self) -> int:
        return self.anchors.shape[1]

    @property
    def n_observed(self) -> int:
        return int(self.observed.sum())


@dataclass(frozen=True)
class SrlsFit:
    """One SR-LS solve in scaled units: the point (d,), the GTRS multiplier and uniqueness."""

    x: np.ndarray
    lam: float
    unique: bool


@dataclass(frozen=True)
class Verdict:
    """How a run ended: the estimate (scaled units), the inliers, status and message; a robust
    fit's last inlier ``threshold`` (scaled units; None for least squares), the ``checks`` run
    and the judge's counts (see :class:`MultilaterationResult`)."""

    fit: SrlsFit
    inliers: np.ndarray
    status: Status
    message: str
    threshold: float | None = None
    checks: tuple[CheckRecord, ...] = ()
    judged: int = 0
    reached: int = 0


def check_spanning(points: np.ndarray, d: int, name: str, what: str) -> None:
    """Raise DegenerateGeometryError unless ``points`` (N, d) affinely span R^d."""
    rank = affine_rank(points)
    if rank < d:
        kind = {0: "coincident", 1: "collinear", 2: "coplanar"}[rank]
        raise DegenerateGeometryError(
            f"{name} are {kind}: in {d}-D they must not all lie in one "
            f"{'plane' if d == 3 else 'line'}, or {what}"
        )


def _parse_problem(anchors, ranges, weights, mask, robust_options) -> ScaledProblem:
    """Validate anchors (M, d), ranges (M,), mask, the robust options (inlier threshold, number of
    hypotheses) and weights once; centre and scale to unit RMS radius."""
    a = as_points(anchors, "anchors")
    m, d = a.shape
    observed = as_mask(mask, "mask", shape=(m,))
    r = as_ranges(ranges, "ranges", shape=(m,), observed=observed)
    check_robust_options(*robust_options)
    n_obs = int(observed.sum())
    if n_obs < d + 1:
        raise InvalidInputError(
            f"multilateration in {d}-D needs at least {d + 1} observed ranges; got {n_obs} (anchors {shape_str(a.shape)})"
        )
    if affine_rank(a[observed]) < d:
        kind = {1: "collinear", 2: "coplanar"}.get(affine_rank(a[observed]), "coincident")
        raise DegenerateGeometryError(
            f"anchors with observed ranges are {kind}: in {d}-D they must not lie in a common "
            f"{'plane' if d == 3 else 'line'}, or the point is ambiguous (mirror images or a circle)"
        )
    # Scale to unit size before the solver sees the problem (the cost is equivariant).
    centre = a[observed].mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((a[observed] - centre) ** 2, axis=1))))
    r_s = r / scale
    w_all = np.where(observed, _resolve_weights(weights, r_s, 1.0), 0.0)
    if affine_rank(a[observed & (w_all > 0)]) < d:
        raise DegenerateGeometryError("anchors with positive weight must affinely span R^d")
    return ScaledProblem(a, r, observed, centre, scale, (a - centre) / scale, r_s, w_all)


def _srls_on(prob: ScaledProblem, inliers: np.ndarray) -> SrlsFit:
    """SR-LS (eq. 3) on the inlier ranges, scaled units."""
    x, lam, unique = _srls(prob.anchors_s[inliers], prob.ranges_s[inliers], prob.weights[inliers])
    return SrlsFit(x, lam, unique)


def _srls_refit(prob: ScaledProblem, inliers: np.ndarray, fixed: bool) -> Refit:
    """SR-LS on the inliers and, without a fixed threshold, 2.5 times their residual scale."""
    d = prob.dim
    fit = _srls_on(prob, inliers)
    if fixed:
        return Refit(fit.x, fit, None)
    res = _range_residuals(fit.x, prob.anchors_s[inliers], prob.ranges_s[inliers])
    sigma = math.sqrt(float(res @ res) / max(int(inliers.sum()) - d, 1)) / TRUNCATED_STD
    return Refit(fit.x, fit, max(level_sigmas() * sigma, 1e-9))


def _robust_fit(
    prob: ScaledProblem, inlier_threshold: float | None, max_hypotheses: int, rng
) -> Verdict:
    """LMedS (or MSAC) start, then threshold-and-refit with SR-LS until the inliers settle."""
    d, n_obs, scale = prob.dim, prob.n_observed, prob.scale
    idx = np.flatnonzero(prob.observed)
    fixed = inlier_threshold is not None
    thr_s = inlier_threshold / scale if fixed else None
    start = robust_start(
        prob.anchors_s[idx],
        prob.ranges_s[idx],
        max_hypotheses=max_hypotheses,
        rng=rng,
        threshold=thr_s,
    )
    if start is None:
        raise DegenerateGeometryError("every subset of d+1 anchors is affinely dependent")
    # Floor on the threshold (scaled units): exact data has residuals at round-off level.
    thr = thr_s if fixed else max(level_sigmas() * start.sigma, 1e-9)
    search = refine_inliers(
        lambda x: _range_residuals(x, prob.anchors_s, prob.ranges_s),
        lambda inl: _srls_refit(prob, inl, fixed),
        start.z,
        prob.observed,
        thr,
        lambda inl: inl.sum() >= d + 1 and affine_rank(prob.anchors_s[inl]) >= d,
    )
    last = search.fit if search.fit is not None else SrlsFit(search.z, float("nan"), True)
    if search.settled:
        how = "LMedS" if inlier_threshold is None else "MSAC"
        kept = int(search.inliers.sum())
        message = f"SR-LS after {how} outlier rejection: {kept} of {n_obs} ranges kept"
        return Verdict(last, search.inliers, Status.CONVERGED, message, search.threshold)
    failed = SrlsFit(last.x, float("nan"), last.unique)
    if search.rejected is None:
        message = "robust multilateration: the inlier set was still changing after 20 re-fits"
        return Verdict(failed, search.inliers, Status.SOLVER_FAILED, message)
    message = (
        f"robust multilateration failed: only {int(search.rejected.sum())} of {n_obs} ranges agree within "
        f"{search.threshold * scale:.3g} m of the best hypothesis, or they do not span {d}-D"
    )
    return Verdict(failed, search.rejected, Status.OUTLIERS, message)


@dataclass(frozen=True)
class PointVerdictInputs:
    """What the checks of one answer need, in scaled units: the observed ``anchors`` (N, d) and
    ``ranges`` (N,), the answer ``x`` (d,), the ranges it kept ``inl`` (N,), the judge's
    ``objective``, the given noise ``noise_s`` (None if unknown), the median kept range
    ``range_scale``, the exact-data RMS ``exact`` and the noise the precision is judged at,
    ``precision_sigma`` (None: not judged)."""

    anchors: np.ndarray
    ranges: np.ndarray
    x: np.ndarray
    inl: np.ndarray
    objective: PointObjective
    noise_s: float | None
    range_scale: float
    exact: float
    precision_sigma: float | None


def _inputs(prob: ScaledProblem, verdict: Verdict, noise_std: float | None) -> PointVerdictInputs:
    """The answer's checks' inputs. The judge's sigma is the given noise, else the kept
    residuals' estimate sqrt(ssr / redundancy) (as calibrate's), never below the exact-data RMS;
    the precision is judged at the given noise, else at the largest the kept residuals allow
    (:func:`noise_upper_bound`: a few residuals say little about the noise). A robust fit's
    kernel truncates at its last inlier threshold, at least level_sigmas() judge's sigmas."""
    obs = prob.observed
    a, r, inl = prob.anchors_s[obs], prob.ranges_s[obs], verdict.inliers[obs]
    x = verdict.fit.x
    res = _range_residuals(x, a[inl], r[inl])
    range_scale = float(np.median(r[inl]))
    exact = EXACT_RTOL * range_scale
    noise_s = noise_std / prob.scale if noise_std is not None else None
    ssr, redundancy = float(res @ res), int(inl.sum()) - prob.dim
    estimate = float(np.sqrt(ssr / redundancy)) if redundancy > 0 else None
    sigma = max(verdict_noise(noise_s, estimate, exact) or 0.0, exact)
    # the kernel's truncation: the search's last threshold, never within level_sigmas() noise
    # deviations (exact data: the search floors its threshold below the exact-data RMS)
    threshold = (
        None if verdict.threshold is None else max(verdict.threshold, level_sigmas() * sigma)
    )
    objective = PointObjective(a, r, sigma, threshold)
    precision = verdict_noise(noise_s, noise_upper_bound(ssr, redundancy), exact)
    return PointVerdictInputs(a, r, x, inl, objective, noise_s, range_scale, exact, precision)


def _judged(prob: ScaledProblem, verdict: Verdict, inputs: PointVerdictInputs, judged):
    """The verdict with the judge's answer: a lower minimum (LOWER: its cost gap beyond the
    level, outside the answer's confidence region) replaces the SR-LS point, its kept ranges
    the inliers; otherwise the SR-LS point stands (a lower point within its region confirms it)."""
    first = judged.judgement.comparisons[0] if judged.judgement.comparisons else None
    if first is None or first.kind != LOWER:
        return verdict, inputs
    lowest = judged.judgement.answer
    x = np.asarray(lowest.points[0], dtype=float)
    inl = prob.observed.copy()
    inl[prob.observed] = inputs.objective.kept(x)
    note = (
        f"; {lowest.origin} reached a lower minimum of the range likelihood than SR-LS (by "
        f"{first.delta_cost:.3g} noise variances), which replaced it"
    )
    fit = SrlsFit(x, float("nan"), True)
    verdict = dataclasses.replace(verdict, fit=fit, inliers=inl, message=verdict.message + note)
    return verdict, dataclasses.replace(inputs, x=x, inl=inl[prob.observed])


def _residual_record(v: PointVerdictInputs, check: Check, scale: float) -> CheckRecord:
    """The residual test as a record: with a noise level, the sum of squared residuals over its
    variance against the chi-square quantile; without one, the RMS residual (metres) against
    RELATIVE_RMS of the scene."""
    res = _range_residuals(v.x, v.anchors[v.inl], v.ranges[v.inl])
    redundancy = int(v.inl.sum()) - v.x.size
    if v.noise_s and redundancy > 0:
        statistic = float(res @ res) / max(v.noise_s, v.exact) ** 2
        level = float(chi2.ppf(CHI2_LEVEL, redundancy))
    else:
        statistic = scale * float(np.sqrt(np.mean(res**2)))
        level = scale * RELATIVE_RMS * v.range_scale
    return CheckRecord("residuals", statistic, level, check.passed, check.reason)


def _point_checks(v: PointVerdictInputs, judged: JudgedSearch, scale: float):
    """The checks of the answer in order (residuals, information, the judge, the precision over
    the confidence region) as (Check, CheckRecord) pairs; the region's precision only when the
    information has full rank. Statistics in metres where they are lengths."""
    d, sigma = v.x.size, v.precision_sigma
    a, r = v.anchors[v.inl], v.ranges[v.inl]
    diff = v.x - a
    jac = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-12)[:, None]
    redundancy = len(r) - d
    consistency = consistency_check(
        _range_residuals(v.x, a, r), jac, redundancy, v.noise_s, v.range_scale, v.exact
    )
    cov, n_zero = gauge_free_covariance(jac, None)
    information = information_check(
        jac, None, sigma, v.range_scale, "the point", dim=d, covariance=(cov, n_zero)
    )
    limit = PRECISION_FRACTION * v.range_scale
    own = rms_precision(cov, sigma or 0.0, d) if cov is not None else float("inf")
    pairs = [
        (consistency, _residual_record(v, consistency, scale)),
        (information, CheckRecord("information", scale * own,
                                  scale * limit, information.passed, information.reason)),
    ]  # fmt: skip
    rival = judged.judgement
    pairs += [(Check(rival.status, rival.reason), rival.check)]
    pairs += [(Check(Status.CONVERGED), judged.record())]  # the budget only records
    if cov is not None and sigma:  # full rank: the precision is judged over the region
        # the region is the judge's (its objective, at its sigma); the precision in it is
        # judged at the information check's sigma: the RMS scales with sigma
        ratio = sigma / v.objective.sigma
        worst = ratio * region_precision(v.objective, v.x, limit / ratio)
        region = _region_check(worst, limit, scale)
        pairs += [(region, CheckRecord("precision over the confidence region", scale * worst,
                                       scale * limit, region.passed, region.reason))]  # fmt: skip
    return pairs


def _region_check(worst: float, limit: float, scale: float) -> Check:
    """NOT_IDENTIFIABLE when the precision fails somewhere in the answer's confidence region
    (``worst``, ``limit``: scaled units; ``scale`` metres per unit)."""
    if worst <= limit:
        return Check(Status.CONVERGED)
    return Check(
        Status.NOT_IDENTIFIABLE,
        f"the point is only weakly determined within its confidence region: somewhere the data "
        f"do not rule out, the information fixes it to {scale * worst:.3g} m RMS or worse, more "
        f"than {PRECISION_FRACTION:.1%} of the scene size {scale * limit / PRECISION_FRACTION:.3g} m",
    )


def _checked(prob: ScaledProblem, verdict: Verdict, noise_std: float | None, rng) -> Verdict:
    """The verdict of one answer: the judge of every alternative
    (:func:`rangeslam.localization.point_judge.judge_point`; a lower minimum replaces the SR-LS
    point), then the checks in order (:func:`_point_checks`); the first that fails sets the
    status, and every check is listed."""
    inputs = _inputs(prob, verdict, noise_std)
    # the random starts draw from a child generator: the caller's stream is not advanced (a
    # pipeline that passes one rng through many calls draws the same numbers as before)
    judged = judge_point(inputs.objective, inputs.x, rng.spawn(1)[0])
    verdict, inputs = _judged(prob, verdict, inputs, judged)
    pairs = _point_checks(inputs, judged, prob.scale)
    check = first_failure(*(c for c, _ in pairs))
    message = verdict.message if check.passed else f"{verdict.message}; {check.reason}"
    return dataclasses.replace(
        verdict,
        status=check.status,
        message=f"{message}; {judged.words()}",
        checks=tuple(record for _, record in pairs),
        judged=len(judged.judgement.comparisons),
        reached=judged.judgement.reached,
    )


def _result(prob: ScaledProblem, verdict: Verdict, weights: WeightSpec) -> MultilaterationResult:
    """Back to the caller's units: position, residuals and the eq. (3) cost over the inliers."""
    a, r, observed, scale = prob.anchors, prob.ranges, prob.observed, prob.scale
    pos = prob.centre + scale * verdict.fit.x
    residuals = np.where(observed, _range_residuals(pos, a, r), np.nan)
    # Weights back in original units: 1/r^2 was computed on scaled ranges.
    inverse_range = isinstance(weights, str) and weights == "inverse_range"
    w_orig = prob.weights / scale**2 if inverse_range else prob.weights
    sq = np.linalg.norm(a - pos, axis=1) ** 2 - r**2
    return MultilaterationResult(
        position=frozen(pos),
        residuals=frozen(residuals),
        inliers=frozen(verdict.inliers & observed),
        cost=float(np.sum((w_orig * sq**2)[verdict.inliers])),
        status=verdict.status,
        message=verdict.message,
        lagrange_multiplier=float(verdict.fit.lam),
        checks=verdict.checks,
        judged=verdict.judged,
        reached=verdict.reached,
    )


def multilaterate(
    anchors: ArrayLike,
    ranges: ArrayLike,
    *,
    weights: WeightSpec = "inverse_range",
    mask: ArrayLike | None = None,
    robust: bool = False,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 2000,
    noise_std: float | None = None,
    rng: np.random.Generator | int | None = None,
) -> MultilaterationResult:
    """Locate a point from its distances to known anchors: SR-LS, the exact minimiser of eq. (3).

    Args:
        anchors: (M, d) known positions (microphones), d = 2 or 3; the observed ones must affinely
            span R^d (not collinear in 3-D or 2-D, not coplanar in 3-D: those leave a mirror or a
            circle of solutions).
        ranges: (M,) measured distances in metres.
        weights: ``"inverse_range"`` (default) weighs each squared-range residual by 1/r^2, which
            makes the cost a first-order approximation of the Gaussian range likelihood, so the
            estimate attains the Cramer-Rao bound at small noise; ``"uniform"`` (or None) is the
            paper's unweighted eq. (3); or an (M,) array of non-negative weights.
        mask: (M,) bool, True where the range was observed (W of eq. 8). Unobserved entries of
            ``ranges`` are ignored, whatever they hold.
        robust: reject outliers first (least median of squares over anchor subsets, then a
            threshold of 2.5 robust standard deviations and a re-fit). Needs M >= d + 2 observed.
            Breaks down when half or more of the ranges are wrong.
        inlier_threshold: with ``robust``, a fixed threshold on |range residual| in metres instead
            of the data-driven one; subsets are then scored by consensus (MSAC) instead of LMedS,
            which copes with more than half wrong ranges as long as those disagree among
            themselves.
        max_hypotheses: with ``robust``, the number of random anchor subsets tried when there are
            more subsets than this (otherwise all are tried).
        noise_std: the range noise's standard deviation in metres, if known: the verdict then
            tests the residuals against it (chi-square); without it, against their own robust scale.
        rng: random generator (or seed) for the subset draws.

    Returns:
        :class:`MultilaterationResult`. Its status is CONVERGED only when the point is determined
        (the anchors' information has full rank and fixes it to a small fraction of the anchors'
        spread; no mirror image through nearly coplanar anchors fits as well), the residuals fit
        the noise, and no heavy tail of residuals is left (see :mod:`rangeslam.verdict`).
    """
    rng = as_rng(rng)
    robust = robust_mode(robust, ("on",)) is not None  # True: on; None or False: off
    noise_std = as_scalar(noise_std, "noise_std", low=0.0, high=MAX_METRES, allow_none=True)
    inlier_threshold, max_hypotheses = check_robust_options(inlier_threshold, max_hypotheses)
    prob = _parse_problem(anchors, ranges, weights, mask, (inlier_threshold, max_hypotheses))
    d, n_obs = prob.dim, prob.n_observed
    if robust and n_obs > d + 1:
        verdict = _robust_fit(prob, inlier_threshold, int(max_hypotheses), rng)
    else:
        message = "SR-LS exact solution"
        if robust:
            message = (
                f"SR-LS; no outlier rejection possible with {n_obs} ranges in {d}-D (needs {d + 2})"
            )
        inliers = prob.observed.copy()
        verdict = Verdict(_srls_on(prob, inliers), inliers, Status.CONVERGED, message)
    if not verdict.fit.unique:
        message = (
            "the minimiser of eq. (3) is not unique (hard case of the GTRS: symmetric anchors with "
            "inconsistent ranges leave a set of equally good points); one of them is returned"
        )
        verdict = Verdict(verdict.fit, verdict.inliers, Status.NOT_IDENTIFIABLE, message)
    elif verdict.status is Status.CONVERGED:
        verdict = _checked(prob, verdict, noise_std, rng)
    return _result(prob, verdict, weights)
