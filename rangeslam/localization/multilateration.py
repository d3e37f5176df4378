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

import itertools
import logging
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import eigh
from scipy.optimize import brentq

from rangeslam._validation import as_mask, as_points, as_ranges, frozen, shape_str
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError

__all__ = ["MultilaterationResult", "affine_rank", "minimal_subset_points", "multilaterate"]

log = logging.getLogger(__name__)

WeightSpec = ArrayLike | Literal["uniform", "inverse_range"] | None

# Relative singular-value threshold below which anchors are taken to be affinely dependent.
_AFFINE_RTOL = 1e-8
# Inlier threshold in robust scale units (Rousseeuw and Leroy's 2.5), and the standard deviation
# of a unit normal truncated to +-2.5 (residuals kept by that threshold are that much too tight).
_INLIER_K = 2.5
_TRUNCATED_STD = 0.9546


@dataclass(frozen=True)
class MultilaterationResult:
    """Result of :func:`multilaterate`.

    Attributes:
        position: (d,) estimated point, metres.
        residuals: (M,) range residuals ||x - a_m|| - r_m in metres; NaN where not observed.
        inliers: (M,) True for the ranges used in the final fit (observed and, if robust, accepted).
        cost: weighted squared-range cost of eq. (3) over the inliers, at ``position`` (m^4 times
            the unit of the weights: m^4 for uniform weights, m^2 for the default 1/r^2).
        converged: False when the robust search found too few consistent ranges to trust.
        message: what happened, in words.
        lagrange_multiplier: the GTRS multiplier lam at the solution (dimensionless, scaled problem).
    """

    position: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    cost: float
    converged: bool
    message: str
    lagrange_multiplier: float

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
    w = np.array(weights, dtype=float, copy=True)
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


def minimal_subset_points(
    anchors: np.ndarray,
    ranges: np.ndarray,
    candidates: np.ndarray,
    max_subsets: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points (H, d) from subsets of d+1 of the ``candidates`` (indices into anchors (M, d)).

    Each subset gives the exact solution of the linear system [-2 a^T, 1] [x; t] = r^2 - ||a||^2
    (d+1 equations, d+1 unknowns); all subsets when there are at most ``max_subsets`` of them,
    otherwise that many random ones. Affinely dependent subsets are skipped.
    """
    d = anchors.shape[1]
    p = d + 1
    if math.comb(len(candidates), p) <= max_subsets:
        subsets = np.array(list(itertools.combinations(candidates, p)), dtype=int).reshape(-1, p)
    else:
        subsets = candidates[np.argsort(rng.random((max_subsets, len(candidates))), axis=1)[:, :p]]
    a_sub = np.concatenate([-2.0 * anchors[subsets], np.ones((len(subsets), p, 1))], axis=2)
    b_sub = ranges[subsets] ** 2 - np.einsum("hpd,hpd->hp", anchors[subsets], anchors[subsets])
    sv = np.linalg.svd(a_sub, compute_uv=False)
    ok = sv[:, -1] > 1e-8 * sv[:, 0]
    return np.linalg.solve(a_sub[ok], b_sub[ok][..., None])[..., 0][:, :d]


def _lmeds_start(
    anchors: np.ndarray,
    ranges: np.ndarray,
    max_hypotheses: int,
    rng: np.random.Generator,
    threshold: float | None = None,
) -> tuple[np.ndarray, float]:
    """Least-median-of-squares hypothesis over subsets of d+1 anchors (scaled coordinates).

    Each subset gives the exact linear solution of A y = b (d+1 equations, d+1 unknowns y = [x, t]);
    all subsets are scored at once by the h-th smallest squared range residual over all anchors.
    Returns the best x and the robust scale (standard deviation) of its residuals.
    """
    n, d = anchors.shape
    p = d + 1
    x = minimal_subset_points(anchors, ranges, np.arange(n), max_hypotheses, rng)
    if len(x) == 0:
        raise DegenerateGeometryError("every subset of d+1 anchors is affinely dependent")
    res2 = _range_residuals(x[:, None, :], anchors[None, :, :], ranges[None, :]) ** 2
    h = (n + p + 1) // 2  # Rousseeuw's order statistic for the highest breakdown point
    lmeds = np.partition(res2, h - 1, axis=1)[:, h - 1]
    # With a known threshold, MSAC (Torr and Zisserman 2000): truncated squared residuals, which
    # tolerates more than half wrong ranges when the wrong ones do not agree with each other.
    score = lmeds if threshold is None else np.minimum(res2, threshold**2).sum(axis=1)
    best = int(np.argmin(score))
    # Finite-sample consistency correction of Rousseeuw and Leroy (1987), for the d unknowns of x
    # (the subsets have d + 1 members because the linear system also carries t = ||x||^2).
    sigma = 1.4826 * (1.0 + 5.0 / max(n - d, 1)) * math.sqrt(lmeds[best])
    return x[best], sigma


def multilaterate(
    anchors: ArrayLike,
    ranges: ArrayLike,
    *,
    weights: WeightSpec = "inverse_range",
    mask: ArrayLike | None = None,
    robust: bool = False,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 2000,
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
        rng: random generator (or seed) for the subset draws.

    Returns:
        :class:`MultilaterationResult`.
    """
    rng = np.random.default_rng(rng)
    a = as_points(anchors, "anchors")
    m, d = a.shape
    observed = as_mask(mask, "mask", shape=(m,))
    r = as_ranges(ranges, "ranges", shape=(m,), observed=observed)
    if inlier_threshold is not None and not (
        np.isfinite(inlier_threshold) and inlier_threshold > 0
    ):
        raise InvalidInputError(
            f"inlier_threshold must be a positive number of metres; got {inlier_threshold}"
        )
    if not isinstance(max_hypotheses, int | np.integer) or max_hypotheses < 1:
        raise InvalidInputError(
            f"max_hypotheses must be a positive integer; got {max_hypotheses!r}"
        )

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
    a_s = (a - centre) / scale
    r_s = r / scale
    w_all = _resolve_weights(weights, r_s, 1.0)
    w_all = np.where(observed, w_all, 0.0)
    if affine_rank(a[observed & (w_all > 0)]) < d:
        raise DegenerateGeometryError("anchors with positive weight must affinely span R^d")

    inliers = observed.copy()
    converged, unique = True, True
    message = "SR-LS exact solution"
    if robust and n_obs <= d + 1:
        message = (
            f"SR-LS; no outlier rejection possible with {n_obs} ranges in {d}-D (needs {d + 2})"
        )
    elif robust:
        idx = np.flatnonzero(observed)
        thr_s = None if inlier_threshold is None else inlier_threshold / scale
        x, sigma = _lmeds_start(a_s[idx], r_s[idx], int(max_hypotheses), rng, thr_s)
        fixed = inlier_threshold is not None
        # Floor on the threshold (scaled units): exact data has residuals at round-off level.
        thr = inlier_threshold / scale if fixed else max(_INLIER_K * sigma, 1e-9)
        inliers = np.zeros(m, dtype=bool)
        seen: list[np.ndarray] = []
        for _ in range(20):
            new = observed & (np.abs(_range_residuals(x, a_s, r_s)) <= thr)
            if new.sum() < d + 1 or affine_rank(a_s[new]) < d:
                converged = False
                message = (
                    f"robust multilateration failed: only {int(new.sum())} of {n_obs} ranges agree within "
                    f"{thr * scale:.3g} m of the best hypothesis, or they do not span {d}-D"
                )
                inliers = new
                break
            # Stop when the set repeats: unchanged, or cycling through borderline ranges.
            if np.array_equal(new, inliers) or any(np.array_equal(new, old) for old in seen):
                break
            seen.append(inliers)
            inliers = new
            x, lam, unique = _srls(a_s[inliers], r_s[inliers], w_all[inliers])
            if not fixed:
                fit = _range_residuals(x, a_s[inliers], r_s[inliers])
                sigma = (
                    math.sqrt(float(fit @ fit) / max(int(inliers.sum()) - d, 1)) / _TRUNCATED_STD
                )
                thr = max(_INLIER_K * sigma, 1e-9)
        else:
            converged = False
            message = "robust multilateration: the inlier set was still changing after 20 re-fits"
        if converged:
            how = "LMedS" if inlier_threshold is None else "MSAC"
            message = (
                f"SR-LS after {how} outlier rejection: {int(inliers.sum())} of {n_obs} ranges kept"
            )
        else:
            lam = float("nan")
    if not robust or n_obs <= d + 1:
        x, lam, unique = _srls(a_s[inliers], r_s[inliers], w_all[inliers])
    if not unique:
        converged = False
        message = (
            "the minimiser of eq. (3) is not unique (hard case of the GTRS: symmetric anchors with "
            "inconsistent ranges leave a set of equally good points); one of them is returned"
        )

    pos = centre + scale * x
    residuals = np.where(observed, _range_residuals(pos, a, r), np.nan)
    # Weights back in original units: 1/r^2 was computed on scaled ranges.
    w_orig = w_all / scale**2 if isinstance(weights, str) and weights == "inverse_range" else w_all
    sq = np.linalg.norm(a - pos, axis=1) ** 2 - r**2
    cost = float(np.sum((w_orig * sq**2)[inliers]))
    return MultilaterationResult(
        position=frozen(pos),
        residuals=frozen(residuals),
        inliers=frozen(inliers & observed),
        cost=cost,
        converged=converged,
        message=message,
        lagrange_multiplier=float(lam),
    )
