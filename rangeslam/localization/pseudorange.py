"""Pseudorange multilateration: one point and one unknown range offset (Problem 1).

When the emission time of an event is known only up to an error tau (seconds), each range measured
from it is r = ||x - a|| + b with one constant offset b = c tau (metres).
:func:`multilaterate_with_offset` locates one point and b from M >= d + 2 ranges (pseudoranges, as
in GPS). Squaring (r - b)^2 = ||x - a||^2 gives

    r_m^2 - ||a_m||^2 = -2 a_m.x + 2 r_m b + (||x||^2 - b^2)                       (E1)

linear in (x, b, t = ||x||^2 - b^2). The starts are its unconstrained least-squares solution and
Bancroft's (Bancroft, "An algebraic solution of the GPS equations", IEEE Trans. AES 21(1), 1985):
(x, b) = p + t q from the d + 1 columns of (E1) without t, and t from the quadratic
t = ||x(t)||^2 - b(t)^2. Each start is refined by Gauss-Newton (Levenberg-Marquardt) on the range
residuals ||x - a_m|| + b - r_m (the Gaussian ML) and the lowest cost is kept. With ``robust``,
wrong ranges are rejected first by the robust start shared with :func:`rangeslam.multilaterate`
(:mod:`rangeslam.localization.robust_start`, subsets of d + 2 anchors). See
:mod:`rangeslam.localization.emission` for identifiability.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

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
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.localization.multilateration import affine_rank, check_spanning
from rangeslam.localization.robust_start import (
    TRUNCATED_STD,
    Refit,
    check_robust_options,
    offset_range_residuals,
    refine_inliers,
    robust_start,
)
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import (
    PASSED,
    Check,
    ambiguity_check,
    consistency_check,
    expected_mirror_gap,
    first_failure,
    information_check,
    mirror_gap,
    noise_upper_bound,
    verdict_noise,
)
from rangeslam.verdict.breakdown import breakdown_check
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.thresholds import EXACT_RTOL, RANK_RTOL

__all__ = ["OffsetMultilaterationResult", "multilaterate_with_offset"]


def pseudoranges(value: ArrayLike, name: str, shape: tuple[int, ...], observed: np.ndarray):
    """Ranges with an offset: finite where observed, any sign (an offset may make them negative).

    Unobserved entries are set to 0.
    """
    return as_ranges(value, name, shape=shape, observed=observed, signed=True)


# --- one point and one offset (pseudorange multilateration) -------------------------------------


@dataclass(frozen=True)
class OffsetMultilaterationResult(HasStatus):
    """Result of :func:`multilaterate_with_offset`.

    Attributes:
        position: (d,) estimated point, metres.
        offset: estimated range offset b, metres: ranges = ||position - anchor|| + offset.
        residuals: (M,) ||x - a_m|| + b - r_m, metres; NaN where not observed.
        inliers: (M,) True for the ranges used in the final fit.
        cost: weighted sum of squared range residuals over the inliers (m^2 times the weights).
        dop: (d + 1,) square roots of the diagonal of (J^T W J)^-1 at the solution, J the Jacobian
            of the residuals in (position, offset): the standard deviations of the coordinates
            and of the offset per unit range noise (dilution of precision); in metres when the
            weights are 1 / sigma^2.
        status: :class:`rangeslam.status.Status`: CONVERGED only when the verdict of
            :mod:`rangeslam.verdict` passes (the residuals fit the noise, a robust fit kept more
            than half its redundant ranges, the point is determined and its mirror image through
            nearly flat anchors fits worse); OUTLIERS when too few ranges agreed with the robust
            start or it left out too many; NOT_IDENTIFIABLE when the point is undetermined (the
            Jacobian in (position, offset) is rank-deficient, a mirror image fits as well, or a
            wrong range was declared possible with no spare range to find it); INCONSISTENT when
            the residuals do not fit the noise; SOLVER_FAILED when the inlier set kept changing
            or least squares did not converge (``converged`` is ``status is CONVERGED``).
        message: what happened, in words.
    """

    position: np.ndarray
    offset: float
    residuals: np.ndarray
    inliers: np.ndarray
    cost: float
    dop: np.ndarray
    status: Status
    message: str

    @property
    def n_outliers(self) -> int:
        return int(np.sum(~self.inliers & np.isfinite(self.residuals)))


def _offset_residuals(z: np.ndarray, anchors: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """||x - a|| + b - r for z = (x, b) (d + 1,) or (H, d + 1) hypotheses."""
    return offset_range_residuals(z, anchors, ranges, offset=True)


def _offset_jacobian(z: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(M, d + 1) rows [u_m, 1], u_m = (x - a_m) / ||x - a_m||."""
    diff = z[:-1] - anchors
    u = diff / np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-300)
    return np.column_stack([u, np.ones(len(anchors))])


def _closed_form_starts(
    anchors: np.ndarray, ranges: np.ndarray, sw: np.ndarray
) -> list[np.ndarray]:
    """Starting points z = (x, b) from the linearisation (E1), weighted by sw = sqrt(weights).

    The unconstrained least-squares solution in (x, b, t) (when the d + 2 columns are independent)
    and Bancroft's solutions of the constraint t = ||x||^2 - b^2 along the line of least-squares
    solutions (x, b)(t) (real roots; the vertex of the quadratic when the roots are complex).
    """
    n, d = anchors.shape
    y = (ranges**2 - np.einsum("nd,nd->n", anchors, anchors)) * sw
    a1 = np.column_stack([-2.0 * anchors, 2.0 * ranges]) * sw[:, None]
    ones = sw
    starts: list[np.ndarray] = []
    a_full = np.column_stack([a1, ones])
    sv = np.linalg.svd(a_full, compute_uv=False)
    if n >= d + 2 and sv[-1] > 1e-10 * sv[0]:
        starts.append(np.linalg.lstsq(a_full, y, rcond=None)[0][: d + 1])
    sv1 = np.linalg.svd(a1, compute_uv=False)
    if sv1[-1] > 1e-10 * sv1[0]:
        p = np.linalg.lstsq(a1, y, rcond=None)[0]
        q = -np.linalg.lstsq(a1, ones, rcond=None)[0]
        sign = np.r_[np.ones(d), -1.0]  # t = z^T diag(1, ..., 1, -1) z
        qa = float(np.sum(sign * q * q))
        qb = float(2.0 * np.sum(sign * p * q) - 1.0)
        qc = float(np.sum(sign * p * p))
        if abs(qa) > 1e-12 * max(abs(qb), abs(qc), 1e-300):
            disc = qb * qb - 4.0 * qa * qc
            if disc >= 0:
                root = math.sqrt(disc)
                ts = [(-qb + root) / (2.0 * qa), (-qb - root) / (2.0 * qa)]
            else:
                ts = [-qb / (2.0 * qa)]
        elif qb != 0:
            ts = [-qc / qb]
        else:
            ts = []
        starts.extend(p + t * q for t in ts)
    return [s for s in starts if np.all(np.isfinite(s))]


@dataclass(frozen=True)
class OffsetFit:
    """Weighted ML of z = (x, b) (d + 1,) in scaled units: its cost, whether scipy converged, and
    scipy's message."""

    z: np.ndarray
    cost: float
    ok: bool
    message: str


def _fit_offset(anchors: np.ndarray, ranges: np.ndarray, weights: np.ndarray) -> OffsetFit:
    """Weighted ML of (x, b) from all given ranges (scaled units), the best of the closed-form
    starts refined by Levenberg-Marquardt."""
    sw = np.sqrt(weights)
    starts = _closed_form_starts(anchors, ranges, sw)
    if not starts:
        raise DegenerateGeometryError(
            "the linearised pseudorange equations (E1) are rank-deficient for these anchors and "
            "ranges: no starting point"
        )
    best = None
    for z0 in starts:
        fit = least_squares(
            lambda z: sw * _offset_residuals(z, anchors, ranges),
            z0,
            jac=lambda z: sw[:, None] * _offset_jacobian(z, anchors),
            method="lm",
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
        )
        cost = float(fit.fun @ fit.fun)
        if np.all(np.isfinite(fit.x)) and (best is None or cost < best.cost):
            best = OffsetFit(fit.x, cost, fit.status > 0, str(fit.message))
    if best is None:
        raise DegenerateGeometryError("every refinement of the pseudorange starts diverged")
    return best


def _rank_ok(z: np.ndarray, anchors: np.ndarray, weights: np.ndarray) -> tuple[bool, np.ndarray]:
    """Whether the weighted Jacobian has full rank d + 1, and the dop (d + 1,) (inf if not)."""
    jac = np.sqrt(weights)[:, None] * _offset_jacobian(z, anchors)
    if not np.all(np.isfinite(jac)):
        return False, np.full(jac.shape[1], np.inf)
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    if sv.size < jac.shape[1] or sv[-1] <= RANK_RTOL * sv[0]:
        return False, np.full(jac.shape[1], np.inf)
    # the diagonal of (J^T J)^-1 = V S^-2 V^T from the SVD (no inverse of the squared matrix: far
    # anchors made it numerically singular and np.linalg.inv raised)
    return True, np.sqrt(np.sum((vt.T / sv) ** 2, axis=1))


@dataclass(frozen=True)
class OffsetProblem:
    """The inputs of :func:`multilaterate_with_offset`, parsed once and scaled to unit size.

    Attributes:
        anchors, ranges, weights: (M, d), (M,), (M,) as given (validated).
        observed: (M,) True where observed; ``use`` also has a positive weight.
        centre, scale: the used anchors' centroid (d,) and RMS radius, metres.
        anchors_s, ranges_s: centred and divided by ``scale``; weights_s: weights over their mean.
    """

    anchors: np.ndarray
    ranges: np.ndarray
    weights: np.ndarray
    observed: np.ndarray
    use: np.ndarray
    centre: np.ndarray
    scale: float
    anchors_s: np.ndarray
    ranges_s: np.ndarray
    weights_s: np.ndarray

    @property
    def dim(self) -> int:
        return self.anchors.shape[1]

    @property
    def n_use(self) -> int:
        return int(self.use.sum())


@dataclass(frozen=True)
class InlierVerdict:
    """The ranges to fit last, with the status and message of the outlier rejection."""

    inliers: np.ndarray
    status: Status
    message: str


def _parse_offset_problem(anchors, ranges, weights, mask, robust_options) -> OffsetProblem:
    """Validate anchors (M, d), ranges (M,), weights, mask and the robust options once; scale."""
    a = as_points(anchors, "anchors")
    m, d = a.shape
    observed = as_mask(mask, "mask", shape=(m,))
    r = pseudoranges(ranges, "ranges", (m,), observed)
    if weights is None:
        w = np.ones(m)
    else:
        w = as_float_array(weights, "weights")
        if w.shape != (m,):
            raise InvalidInputError(f"weights must have shape ({m},); got {shape_str(w.shape)}")
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InvalidInputError("weights must be finite and non-negative")
    check_robust_options(*robust_options)
    use = observed & (w > 0)
    n_use = int(use.sum())
    if n_use < d + 2:
        raise InvalidInputError(
            f"multilateration with an unknown offset in {d}-D needs at least {d + 2} observed "
            f"ranges with positive weight (d + 1 leave two solutions); got {n_use} "
            f"(anchors {shape_str(a.shape)})"
        )
    check_spanning(a[use], d, "anchors", "the point is ambiguous (mirror images)")
    # Centre on the anchors and scale to unit size; the offset scales with the ranges.
    centre = a[use].mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((a[use] - centre) ** 2, axis=1))))
    a_s, r_s = (a - centre) / scale, r / scale
    return OffsetProblem(a, r, w, observed, use, centre, scale, a_s, r_s, w / np.mean(w[use]))


def _offset_refit(prob: OffsetProblem, inliers: np.ndarray, fixed: bool) -> Refit:
    """ML of (x, b) on the inliers and, without a fixed threshold, 2.5 times their noise scale."""
    fit = _fit_offset(prob.anchors_s[inliers], prob.ranges_s[inliers], prob.weights_s[inliers])
    if fixed:
        return Refit(fit.z, fit, None)
    dof = max(int(inliers.sum()) - prob.dim - 1, 1)
    sigma = math.sqrt(fit.cost / dof) / TRUNCATED_STD
    return Refit(fit.z, fit, max(level_sigmas() * sigma, 1e-9))


def _offset_inliers(
    prob: OffsetProblem, inlier_threshold: float | None, max_hypotheses: int, rng
) -> InlierVerdict:
    """LMedS (or MSAC) over subsets of d + 2 anchors, then threshold-and-refit until stable."""
    d, n_use, scale, use = prob.dim, prob.n_use, prob.scale, prob.use
    idx = np.flatnonzero(use)
    fixed = None if inlier_threshold is None else inlier_threshold / scale
    start = robust_start(
        prob.anchors_s[idx],
        prob.ranges_s[idx],
        offset=True,
        max_hypotheses=max_hypotheses,
        rng=rng,
        threshold=fixed,
    )
    if start is None:
        message = (
            "every subset of d + 2 ranges is rank-deficient: a wrong range could not be found, "
            "so the point is not determined when one may be wrong"
        )
        return InlierVerdict(use.copy(), Status.NOT_IDENTIFIABLE, message)
    search = refine_inliers(
        lambda z: _offset_residuals(z, prob.anchors_s, prob.ranges_s),
        lambda inl: _offset_refit(prob, inl, fixed is not None),
        start.z,
        use,
        fixed if fixed is not None else max(level_sigmas() * start.sigma, 1e-9),
        lambda inl: inl.sum() >= d + 2 and affine_rank(prob.anchors_s[inl]) >= d,
    )
    kept = int(search.inliers.sum())
    if search.settled:
        message = f"pseudorange least squares after outlier rejection: {kept} of {n_use} kept"
        return InlierVerdict(search.inliers, Status.CONVERGED, message)
    # Not converged: refit on every used range when too few inliers are left.
    inliers = use.copy() if kept < d + 2 else search.inliers
    if search.rejected is None:
        message = "robust multilateration: the inlier set was still changing after 20 re-fits"
        return InlierVerdict(inliers, Status.SOLVER_FAILED, message)
    message = (
        f"robust multilateration failed: only {int(search.rejected.sum())} of {n_use} ranges "
        f"agree within {search.threshold * scale:.3g} m, or they do not span {d}-D"
    )
    return InlierVerdict(inliers, Status.OUTLIERS, message)


def _offset_checked(
    prob: OffsetProblem,
    verdict: InlierVerdict,
    z: np.ndarray,
    noise_std: float | None,
    breakdown: bool,
) -> InlierVerdict:
    """The verdict of :mod:`rangeslam.verdict` on the fit z = (x, b) (scaled units) of the
    inliers: the residuals against the noise (``noise_std`` metres, None unknown, 0 exact),
    with ``breakdown`` (a data-driven robust fit) no more than half the redundant ranges left
    out, the point determined (its information, the offset a nuisance) and its mirror image
    through the anchors' best-fit plane, with its own offset, fitting worse."""
    d, inl, scale = prob.dim, verdict.inliers, prob.scale
    a, r = prob.anchors_s[inl], prob.ranges_s[inl]
    res = _offset_residuals(z, a, r)
    jac = _offset_jacobian(z, a)
    redundancy = len(r) - d - 1  # unknowns: the point and the offset
    range_scale = float(np.median(np.linalg.norm(a - z[:d], axis=1)))
    exact = EXACT_RTOL * range_scale
    noise_s = None if noise_std is None else noise_std / scale
    sigma_s = verdict_noise(noise_s, noise_upper_bound(float(res @ res), redundancy), exact)
    kept = PASSED
    if breakdown:
        used = prob.use[None]
        kept = breakdown_check(inl[None] & used, used, prob.n_use - d - 1, judge_sources=False)
    check = first_failure(
        _distinct_anchors_check(a, d),
        consistency_check(res, jac, redundancy, noise_s, range_scale, exact),
        kept,
        information_check(jac, None, sigma_s, range_scale, "the point", dim=d, rows=np.arange(d)),
        ambiguity_check(
            mirror_gap(z[:d], a, r, float(z[d])),
            sigma_s,
            exact,
            "the point",
            expected_gap=expected_mirror_gap(z[:d], a, float(z[d])),
        ),
    )
    if check.passed:
        return verdict
    return InlierVerdict(inl, check.status, f"{verdict.message}; {check.reason}")


def _distinct_anchors_check(anchors: np.ndarray, d: int) -> Check:
    """The point and the offset (d + 1 unknowns) from at most d + 1 distinct anchor positions
    (N, d) have finitely many exact solutions however often each range is repeated: repeats
    average the noise, they do not tell the roots apart (hypothesis: 6 ranges from 4 distinct
    anchors in 3-D converged 2 m from the truth on exact data)."""
    distinct = len(np.unique(anchors, axis=0))
    if distinct > d + 1:
        return PASSED
    return Check(
        Status.NOT_IDENTIFIABLE,
        f"only {distinct} distinct anchor positions for the point and the offset ({d + 1} "
        "unknowns): finitely many exact solutions, and repeated ranges cannot tell them apart",
    )


def _offset_result(
    prob: OffsetProblem, verdict: InlierVerdict, noise_std: float | None, breakdown: bool
) -> OffsetMultilaterationResult:
    """The final ML fit on the inliers, its verdict and the result in the caller's units."""
    inliers = verdict.inliers
    fit = _fit_offset(prob.anchors_s[inliers], prob.ranges_s[inliers], prob.weights_s[inliers])
    z = fit.z
    full_rank, dop = _rank_ok(z, prob.anchors_s[inliers], prob.weights_s[inliers])
    if not fit.ok and verdict.status is Status.CONVERGED:
        message = f"{verdict.message}; least squares did not converge: {fit.message}"
        verdict = InlierVerdict(inliers, Status.SOLVER_FAILED, message)
    elif not full_rank and verdict.status is Status.CONVERGED:
        message = (
            f"{verdict.message}; the offset cannot be told from the distance: the directions "
            "from the point to the anchors lie on a cone (u . n = const), so (position, offset) "
            "is a family of fits"
        )
        verdict = InlierVerdict(inliers, Status.NOT_IDENTIFIABLE, message)
    elif verdict.status is Status.CONVERGED:
        verdict = _offset_checked(prob, verdict, z, noise_std, breakdown)
    d, scale, w = prob.dim, prob.scale, prob.weights
    pos = prob.centre + scale * z[:d]
    b = float(scale * z[d])
    res = np.where(
        prob.observed, np.linalg.norm(prob.anchors - pos, axis=1) + b - prob.ranges, np.nan
    )
    return OffsetMultilaterationResult(
        position=frozen(pos),
        offset=b,
        residuals=frozen(res),
        inliers=frozen(inliers & prob.observed),
        cost=float(np.sum((w * res**2)[inliers])),
        # dop in metres per unit weight: the scaled Jacobian is unitless, weights were normalised.
        dop=frozen(dop / np.sqrt(np.mean(w[prob.use]))),
        status=verdict.status,
        message=verdict.message,
    )


def multilaterate_with_offset(
    anchors: ArrayLike,
    ranges: ArrayLike,
    *,
    weights: ArrayLike | None = None,
    mask: ArrayLike | None = None,
    robust: bool = False,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 2000,
    noise_std: float | None = None,
    rng: np.random.Generator | int | None = None,
) -> OffsetMultilaterationResult:
    """Locate a point and a common range offset from ranges r_m = ||x - a_m|| + b (pseudoranges).

    Args:
        anchors: (M, d) known positions, d = 2 or 3; the observed ones must affinely span R^d and
            number at least d + 2 (d + 1 pseudoranges leave two solutions in general).
        ranges: (M,) measured ranges in metres, each offset by the same unknown b (any sign).
        weights: (M,) non-negative weights of the squared range residuals (1 / sigma_m^2 for the
            ML); None for equal weights.
        mask: (M,) bool, True where observed; unobserved entries are ignored.
        robust: reject wrong ranges (least median of squares over subsets of d + 2 anchors, then
            a threshold of 2.5 robust standard deviations and re-fits). Needs M >= d + 3 observed.
        inlier_threshold: with ``robust``, a fixed bound in metres on |residual| instead (MSAC).
        max_hypotheses: with ``robust``, random subsets tried when there are more than this.
        noise_std: the range noise's standard deviation in metres, if known (0: exact ranges):
            the verdict then tests the residuals against it (chi-square); without it, against
            the scene size and their own robust scale.
        rng: random generator (or seed) for the subset draws.

    Returns:
        :class:`OffsetMultilaterationResult`, CONVERGED only when the verdict passes (see its
        ``status``). With ``robust`` and fewer than d + 3 ranges no wrong range can be found,
        so the point is NOT_IDENTIFIABLE under the model the caller declared. Raises
        DegenerateGeometryError when the anchors do not span R^d.
    """
    rng = as_rng(rng)
    robust = robust_mode(robust, ("on",)) is not None  # True: on; None or False: off
    noise_std = as_scalar(noise_std, "noise_std", low=0.0, high=MAX_METRES, allow_none=True)
    inlier_threshold, max_hypotheses = check_robust_options(inlier_threshold, max_hypotheses)
    prob = _parse_offset_problem(anchors, ranges, weights, mask, (inlier_threshold, max_hypotheses))
    d, n_use = prob.dim, prob.n_use
    if robust and n_use >= d + 3:
        verdict = _offset_inliers(prob, inlier_threshold, int(max_hypotheses), rng)
    elif robust:
        message = (
            f"no outlier rejection possible with {n_use} ranges in {d}-D (needs {d + 3}): a wrong "
            "range, which robust=True declares possible, would be fitted exactly"
        )
        verdict = InlierVerdict(prob.use.copy(), Status.NOT_IDENTIFIABLE, message)
    else:
        verdict = InlierVerdict(prob.use.copy(), Status.CONVERGED, "pseudorange least squares")
    breakdown = robust and inlier_threshold is None
    return _offset_result(prob, verdict, noise_std, breakdown)
