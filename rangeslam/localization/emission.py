"""Unknown emission times: every range of one acoustic event carries the same unknown offset.

When the emission time of an event is known only up to an error tau (seconds), each range measured
from it is r = ||x - a|| + b with one constant offset b = c tau (metres) for the whole event: the
direct path and every echo (the paper's "future work"). Here b is estimated jointly with the
geometry.

Known microphones (Problem 1)
    :func:`multilaterate_with_offset` locates one point and b from M >= d + 2 ranges (pseudoranges,
    as in GPS). Squaring (r - b)^2 = ||x - a||^2 gives

        r_m^2 - ||a_m||^2 = -2 a_m.x + 2 r_m b + (||x||^2 - b^2)                       (E1)

    linear in (x, b, t = ||x||^2 - b^2). The starts are its unconstrained least-squares solution
    and Bancroft's (Bancroft, "An algebraic solution of the GPS equations", IEEE Trans. AES 21(1),
    1985): (x, b) = p + t q from the d + 1 columns of (E1) without t, and t from the quadratic
    t = ||x(t)||^2 - b(t)^2. Each start is refined by Gauss-Newton (Levenberg-Marquardt) on the
    range residuals ||x - a_m|| + b - r_m (the Gaussian ML) and the lowest cost is kept.

    :func:`reconstruct_room_unknown_emission`: the source and its K first-order image sources share
    the event's offset. b is estimated by a joint least squares over the K + 1 points as free points
    and one b; then the ranges minus b go to :func:`rangeslam.reconstruct_room`. With one image per
    wall, (source, images) and (source, walls) are two parametrisations of the same points (wall k
    is the bisector of s and its image), so this two-step estimate is the joint ML of (b, source,
    walls): no information is lost by fixing b first.

    The price of the unknown time is one more unknown per event: the Cramer-Rao bound of the
    source grows by a factor of about 2.7 (2-D) and 1.8 (3-D) in RMS, of the wall offsets by 1.8
    and 1.2, of the wall normals by 5-10% (8 microphones uniform in the room, 150 draws), and the
    estimates attain it. The unknown-time result is the known-time one plus the offset error
    propagated through the geometry (tests/test_emission.py).

Unknown microphones (Problem 2)
    :func:`calibrate_unknown_emission`: multidimensional unfolding with one unknown offset per
    event (a group of columns, e.g. a loudspeaker and its image sources). The offsets start from
    a rank test (:func:`offsets_from_rank`: the double-centred squared corrected ranges have rank
    d), the points from the SDP of :func:`rangeslam.calibrate` on the corrected ranges; then
    points and offsets are refined jointly by least squares on the ranges. The SDP's own offset
    model (``range_model="offset"``) does not serve as a start here: with every pair an offset
    range, its relaxation lets the offsets absorb most of the ranges.

Identifiability. An offset is told from geometry only by the curvature of the wavefronts. For one
point the Jacobian rows are [u_m, 1] (u_m the unit vector from anchor m), singular when the u_m
lie on a cone, u_m . n = const (anchors on a cone around the point; in the far field all u_m
nearly coincide and b trades off against the distance). In MDU, the ranges must number at least
(M + K) d - d (d + 1) / 2 + G (G offsets), and then generic configurations are locally
identifiable, even with ONE offset shared by all ranges: ||x - y|| + b is not a Euclidean
distance for b != 0 (no scaling or motion of the points adds a constant to every distance). The
Jacobian of (points, offsets) was measured to have full rank up to the rigid motions for random
points, one or per-column offsets, and for sources with their images, whenever the count allows
(e.g. 5 receivers and 5 sources in 3-D with one offset: 25 ranges, 25 unknowns). Not
identifiable: d = 1 with receivers on one side of the sources, and the far field.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from rangeslam._validation import (
    as_float_array,
    as_mask,
    as_points,
    as_ranges,
    frozen,
    shape_str,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.localization.multilateration import affine_rank, multilaterate
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room

__all__ = [
    "OffsetMultilaterationResult",
    "UnknownEmissionRoom",
    "multilaterate_with_offset",
    "reconstruct_room_unknown_emission",
]

# Inlier threshold of the robust multilateration, in robust standard deviations (as multilaterate).
_INLIER_K = 2.5
# Smallest singular value of the (scaled, weighted) Jacobian over the largest below which the
# offset and the position cannot be told apart (a rank-deficient fit).
RANK_RTOL = 1e-8


def pseudoranges(value: ArrayLike, name: str, shape: tuple[int, ...], observed: np.ndarray):
    """Ranges with an offset: finite where observed, any sign (an offset may make them negative).

    Unobserved entries are set to 0.
    """
    return as_ranges(value, name, shape=shape, observed=observed, signed=True)


# --- one point and one offset (pseudorange multilateration) -------------------------------------


@dataclass(frozen=True)
class OffsetMultilaterationResult:
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
        converged: the fit converged (and, if robust, enough ranges agreed with it).
        message: what happened, in words.
    """

    position: np.ndarray
    offset: float
    residuals: np.ndarray
    inliers: np.ndarray
    cost: float
    dop: np.ndarray
    converged: bool
    message: str

    @property
    def n_outliers(self) -> int:
        return int(np.sum(~self.inliers & np.isfinite(self.residuals)))


def _offset_residuals(z: np.ndarray, anchors: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """||x - a|| + b - r for z = (x, b) (d + 1,) or (H, d + 1) hypotheses."""
    x, b = z[..., :-1], z[..., -1]
    dist = np.linalg.norm(anchors - x[..., None, :], axis=-1)
    return dist + b[..., None] - ranges


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


def _fit_offset(anchors: np.ndarray, ranges: np.ndarray, weights: np.ndarray):
    """Weighted ML of (x, b) from all given ranges (scaled units). Returns (z, cost, ok, message)."""
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
        if np.all(np.isfinite(fit.x)) and (best is None or cost < best[1]):
            best = (fit.x, cost, fit.status > 0, str(fit.message))
    if best is None:
        raise DegenerateGeometryError("every refinement of the pseudorange starts diverged")
    return best


def _rank_ok(z: np.ndarray, anchors: np.ndarray, weights: np.ndarray) -> tuple[bool, np.ndarray]:
    """Whether the weighted Jacobian has full rank d + 1, and the dop (d + 1,) (inf if not)."""
    jac = np.sqrt(weights)[:, None] * _offset_jacobian(z, anchors)
    sv = np.linalg.svd(jac, compute_uv=False)
    if sv.size < jac.shape[1] or sv[-1] <= RANK_RTOL * sv[0]:
        return False, np.full(jac.shape[1], np.inf)
    cov = np.linalg.inv(jac.T @ jac)
    return True, np.sqrt(np.diag(cov))


def _lmeds_offset(anchors, ranges, max_hypotheses, rng, threshold):
    """Least median of squares (or MSAC with a threshold) over subsets of d + 2 anchors.

    Each subset solves (E1) exactly (d + 2 equations, unknowns (x, b, t)). Returns the best z and
    the robust scale of its residuals (scaled units).
    """
    n, d = anchors.shape
    p = d + 2
    if math.comb(n, p) <= max_hypotheses:
        subsets = np.array(list(itertools.combinations(range(n), p)), dtype=int).reshape(-1, p)
    else:
        subsets = np.argsort(rng.random((max_hypotheses, n)), axis=1)[:, :p]
    a_s, r_s = anchors[subsets], ranges[subsets]
    mat = np.concatenate([-2.0 * a_s, 2.0 * r_s[..., None], np.ones((len(subsets), p, 1))], axis=2)
    rhs = r_s**2 - np.einsum("hpd,hpd->hp", a_s, a_s)
    sv = np.linalg.svd(mat, compute_uv=False)
    ok = sv[:, -1] > 1e-8 * sv[:, 0]
    if not ok.any():
        return None, float("nan")
    z = np.linalg.solve(mat[ok], rhs[ok][..., None])[..., 0][:, : d + 1]
    res2 = _offset_residuals(z, anchors, ranges) ** 2
    h = (n + p + 1) // 2
    lmeds = np.partition(res2, h - 1, axis=1)[:, h - 1]
    score = lmeds if threshold is None else np.minimum(res2, threshold**2).sum(axis=1)
    best = int(np.argmin(score))
    # Rousseeuw and Leroy's finite-sample correction for p = d + 1 unknowns (x, b).
    sigma = 1.4826 * (1.0 + 5.0 / max(n - d - 1, 1)) * math.sqrt(lmeds[best])
    return z[best], sigma


def multilaterate_with_offset(
    anchors: ArrayLike,
    ranges: ArrayLike,
    *,
    weights: ArrayLike | None = None,
    mask: ArrayLike | None = None,
    robust: bool = False,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 2000,
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
        rng: random generator (or seed) for the subset draws.

    Returns:
        :class:`OffsetMultilaterationResult`. Raises DegenerateGeometryError when the anchors do
        not span R^d or the fit's Jacobian is rank-deficient (b cannot be told from the distance:
        anchors on a cone around the point).
    """
    rng = np.random.default_rng(rng)
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
    use = observed & (w > 0)
    n_use = int(use.sum())
    if n_use < d + 2:
        raise InvalidInputError(
            f"multilateration with an unknown offset in {d}-D needs at least {d + 2} observed "
            f"ranges with positive weight (d + 1 leave two solutions); got {n_use} "
            f"(anchors {shape_str(a.shape)})"
        )
    rank = affine_rank(a[use])
    if rank < d:
        kind = {0: "coincident", 1: "collinear", 2: "coplanar"}[rank]
        raise DegenerateGeometryError(
            f"anchors are {kind}: in {d}-D they must not all lie in one "
            f"{'plane' if d == 3 else 'line'}, or the point is ambiguous (mirror images)"
        )

    # Centre on the anchors and scale to unit size; the offset scales with the ranges.
    centre = a[use].mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((a[use] - centre) ** 2, axis=1))))
    a_s, r_s = (a - centre) / scale, r / scale
    w_s = w / np.mean(w[use])

    inliers = use.copy()
    converged = True
    message = "pseudorange least squares"
    if robust and n_use < d + 3:
        message = f"no outlier rejection possible with {n_use} ranges in {d}-D (needs {d + 3})"
    elif robust:
        idx = np.flatnonzero(use)
        thr_fixed = None if inlier_threshold is None else inlier_threshold / scale
        z, sigma = _lmeds_offset(a_s[idx], r_s[idx], int(max_hypotheses), rng, thr_fixed)
        if z is None:
            message = "every subset of d + 2 ranges is rank-deficient: no outlier rejection"
        else:
            thr = thr_fixed if thr_fixed is not None else max(_INLIER_K * sigma, 1e-9)
            inliers = np.zeros(m, dtype=bool)
            seen: list[np.ndarray] = []
            for _ in range(20):
                new = use & (np.abs(_offset_residuals(z, a_s, r_s)) <= thr)
                if new.sum() < d + 2 or affine_rank(a_s[new]) < d:
                    converged = False
                    message = (
                        f"robust multilateration failed: only {int(new.sum())} of {n_use} ranges "
                        f"agree within {thr * scale:.3g} m, or they do not span {d}-D"
                    )
                    break
                if any(np.array_equal(new, old) for old in [inliers, *seen]):
                    break
                seen.append(inliers)
                inliers = new
                z, cost, _, _ = _fit_offset(a_s[inliers], r_s[inliers], w_s[inliers])
                if thr_fixed is None:
                    dof = max(int(inliers.sum()) - d - 1, 1)
                    sigma = math.sqrt(cost / dof) / 0.9546  # truncated normal at 2.5 sigma
                    thr = max(_INLIER_K * sigma, 1e-9)
            else:
                converged = False
                message = (
                    "robust multilateration: the inlier set was still changing after 20 re-fits"
                )
            if converged:
                message = f"pseudorange least squares after outlier rejection: {int(inliers.sum())} of {n_use} kept"
    if not converged:
        inliers = use.copy() if inliers.sum() < d + 2 else inliers
    z, cost, ok, fit_message = _fit_offset(a_s[inliers], r_s[inliers], w_s[inliers])
    if not ok:
        converged = False
        message += f"; least squares did not converge: {fit_message}"
    full_rank, dop = _rank_ok(z, a_s[inliers], w_s[inliers])
    if not full_rank:
        raise DegenerateGeometryError(
            "the offset cannot be told from the distance: the directions from the point to the "
            "anchors lie on a cone (u . n = const), so (position, offset) is a family of fits"
        )
    pos = centre + scale * z[:d]
    b = float(scale * z[d])
    res = np.where(observed, np.linalg.norm(a - pos, axis=1) + b - r, np.nan)
    return OffsetMultilaterationResult(
        position=frozen(pos),
        offset=b,
        residuals=frozen(res),
        inliers=frozen(inliers & observed),
        cost=float(np.sum((w * res**2)[inliers])),
        # dop in metres per unit weight: the scaled Jacobian is unitless, weights were normalised.
        dop=frozen(dop / np.sqrt(np.mean(w[use]))),
        converged=bool(converged),
        message=message,
    )


# --- one event heard through its direct path and first-order echoes (Problem 1) -----------------


@dataclass(frozen=True)
class UnknownEmissionRoom:
    """Result of :func:`reconstruct_room_unknown_emission`.

    Attributes:
        offset: range offset b of the event, metres (measured range = distance + b).
        offset_time: b / c, seconds (the emission time error: the event was emitted that much
            later than assumed); NaN when no speed of sound was given.
        offset_std: standard deviation of b from the joint fit, metres (the residual noise level
            times the square root of the offset's diagonal entry of (J^T J)^-1); 0 for exact data.
        corrected_ranges: (M, 1+K) the ranges minus b (0 where not observed): the input of the
            room reconstruction.
        reconstruction: the :class:`rangeslam.RoomReconstruction` from the corrected ranges (one
            loudspeaker: ``sources`` is (1, d)).
        points: (1+K, d) the source and image sources of the joint offset fit (free points).
        residual_rms: RMS range residual of the joint offset fit over the ranges it used, metres.
        converged: the offset fit converged with a full-rank Jacobian and the reconstruction
            converged; False comes with a reason in ``message``.
        message: what happened.
    """

    offset: float
    offset_time: float
    offset_std: float
    corrected_ranges: np.ndarray
    reconstruction: RoomReconstruction
    points: np.ndarray
    residual_rms: float
    converged: bool
    message: str

    @property
    def room(self):
        """The reconstructed room (or None), as ``reconstruction.room``."""
        return self.reconstruction.room


class _SharedOffsetModel:
    """Residuals ||m - p_c|| + b - r_mc of free points p_c (C, d) sharing one offset b.

    theta = [p_0, ..., p_{C-1}, b]; the Jacobian is analytic: d/dp_c = (p_c - m) / ||p_c - m||,
    d/db = 1.
    """

    def __init__(self, mics: np.ndarray, ranges: np.ndarray, use: np.ndarray) -> None:
        self.mics = mics
        self.d = mics.shape[1]
        self.n_points = ranges.shape[1]
        self.pairs = np.argwhere(use)  # (P, 2): (mic, column)
        self.r = ranges[use]

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        pts = theta[:-1].reshape(self.n_points, self.d)
        m, c = self.pairs[:, 0], self.pairs[:, 1]
        return np.linalg.norm(pts[c] - self.mics[m], axis=1) + theta[-1] - self.r

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        pts = theta[:-1].reshape(self.n_points, self.d)
        m, c = self.pairs[:, 0], self.pairs[:, 1]
        diff = pts[c] - self.mics[m]
        u = diff / np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-300)
        jac = np.zeros((len(self.pairs), theta.size))
        rows = np.arange(len(self.pairs))[:, None]
        jac[rows, c[:, None] * self.d + np.arange(self.d)[None, :]] = u
        jac[:, -1] = 1.0
        return jac


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def _offset_start(mics, r, observed, robust, inlier_threshold, max_hypotheses, rng):
    """Offset and points (C, d) to start the joint fit, from each column on its own.

    Every column with d + 2 observed ranges from microphones spanning R^d is located with its own
    offset (:func:`multilaterate_with_offset`); the start is their median weighted by 1 / dop_b^2
    (the direct path, surrounded by microphones, usually dominates; a mis-picked column is
    outvoted). Columns without their own estimate get a point by SR-LS from the ranges minus b.
    """
    c_n = r.shape[1]
    d = mics.shape[1]
    pts = np.full((c_n, d), np.nan)
    offsets, inv_var = [], []
    for c in range(c_n):
        obs = observed[:, c]
        if obs.sum() < d + 2 or affine_rank(mics[obs]) < d:
            continue
        try:
            res = multilaterate_with_offset(
                mics,
                r[:, c],
                mask=obs,
                robust=robust,
                inlier_threshold=inlier_threshold,
                max_hypotheses=max_hypotheses,
                rng=rng,
            )
        except DegenerateGeometryError:
            continue
        if res.converged:
            pts[c] = res.position
            offsets.append(res.offset)
            inv_var.append(1.0 / res.dop[-1] ** 2)
    if not offsets:
        raise InvalidInputError(
            f"no column of ranges has {d + 2} observed ranges from microphones spanning {d}-D: "
            "an unknown offset needs one more range per point than multilateration"
        )
    b0 = _weighted_median(np.array(offsets), np.array(inv_var))
    for c in range(c_n):
        obs = observed[:, c]
        if np.all(np.isfinite(pts[c])) or obs.sum() < d + 1 or affine_rank(mics[obs]) < d:
            continue
        pts[c] = multilaterate(mics, np.maximum(r[:, c] - b0, 0.0), mask=obs).position
    return b0, pts


def _joint_offset_fit(mics, r, use, b0, pts0):
    """Least squares of (points, b) on the ranges in ``use`` (columns with finite pts0 only).

    Returns (b, points, residual rms, offset std, ok, message).
    """
    cols = np.all(np.isfinite(pts0), axis=1)
    use = use & cols[None, :]
    model = _SharedOffsetModel(mics, r, use)
    theta0 = np.r_[np.where(cols[:, None], pts0, 0.0).ravel(), b0]
    # Columns left out keep their (zero) parameters: their Jacobian columns are zero, so drop
    # them from the optimisation by fitting only the parameters of the columns used.
    free = np.r_[np.repeat(cols, mics.shape[1]), True]

    def fun(t):
        full = theta0.copy()
        full[free] = t
        return model.residuals(full)

    def jac(t):
        full = theta0.copy()
        full[free] = t
        return model.jacobian(full)[:, free]

    n_res, n_par = int(use.sum()), int(free.sum())
    if n_res <= n_par:
        return (
            b0,
            pts0,
            float("nan"),
            float("nan"),
            False,
            (
                f"{n_res} ranges for {n_par} unknowns (points and offset): no redundancy to tell the "
                "offset; "
            ),
        )
    fit = least_squares(fun, theta0[free], jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    theta = theta0.copy()
    theta[free] = fit.x
    pts = np.where(cols[:, None], theta[:-1].reshape(-1, mics.shape[1]), np.nan)
    sv = np.linalg.svd(fit.jac, compute_uv=False)
    ssr = float(fit.fun @ fit.fun)
    rms = math.sqrt(ssr / n_res)
    message = "" if fit.status > 0 else f"offset fit: least squares failed: {fit.message}; "
    if sv[-1] <= RANK_RTOL * sv[0]:
        return (
            theta[-1],
            pts,
            rms,
            float("inf"),
            False,
            (message + "the offset cannot be told from the geometry (rank-deficient joint fit); "),
        )
    _, s, vt = np.linalg.svd(fit.jac, full_matrices=False)
    var_b = float(np.sum((vt[:, -1] / s) ** 2))  # (J^T J)^-1 entry of b
    std_b = math.sqrt(ssr / (n_res - n_par) * var_b)
    return float(theta[-1]), pts, rms, std_b, fit.status > 0, message


def reconstruct_room_unknown_emission(
    mics: ArrayLike,
    ranges: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    c: float | None = None,
    robust: bool = True,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 500,
    rng: np.random.Generator | int | None = None,
) -> UnknownEmissionRoom:
    """Room, source and emission time error of one event heard by a known microphone array.

    Args:
        mics: (M, d) known microphone positions, metres, affinely spanning R^d; at least d + 2.
        ranges: (M, 1+K) ranges from each microphone to the source (column 0) and to its K
            first-order image sources (column k for wall k), all with the same unknown offset b:
            r = distance + b, e.g. c times (arrival time - assumed emission time).
        mask: (M, 1+K) boolean, True where the echo was observed.
        c: speed of sound in m/s, to report b in seconds (``offset_time``); optional.
        robust, inlier_threshold, max_hypotheses: as :func:`rangeslam.reconstruct_room`. With
            ``robust`` the start of b is a weighted median of per-column robust estimates, and b is
            re-estimated on the ranges the reconstruction keeps, until they are stable.
        rng: random generator (or seed) for the robust searches.

    Returns:
        :class:`UnknownEmissionRoom`. b is estimated jointly over the source and every image
        source (one least squares, (1+K) d + 1 unknowns), then the walls by
        :func:`rangeslam.reconstruct_room` on the ranges minus b (the joint ML of b and the room,
        see the module docstring).
    """
    rng = np.random.default_rng(rng)
    m_pts = as_points(mics, "mics")
    m_n, d = m_pts.shape
    if m_n < d + 2:
        raise InvalidInputError(
            f"mics must hold at least d + 2 = {d + 2} microphones in {d}-D with an unknown "
            f"emission time; got {shape_str(m_pts.shape)}"
        )
    rank = affine_rank(m_pts)
    if rank < d:
        kind = {0: "coincident", 1: "collinear", 2: "coplanar"}[rank]
        raise DegenerateGeometryError(
            f"mics are {kind}: in {d}-D they must not all lie in one "
            f"{'plane' if d == 3 else 'line'}, or the image sources are ambiguous"
        )
    shape = np.shape(ranges)
    if len(shape) != 2 or shape[0] != m_n or shape[1] < 2:
        raise InvalidInputError(
            f"ranges must have shape ({m_n}, 1+K) with K >= 1 echo columns; got {shape_str(shape)}"
        )
    observed = as_mask(mask, "mask", shape=shape)
    r = pseudoranges(ranges, "ranges", shape, observed)
    if c is not None and not (np.isfinite(c) and c > 0):
        raise InvalidInputError(f"c must be a positive speed of sound in m/s; got {c!r}")

    # Centre on the microphones and scale to unit size (b scales with the ranges).
    centre = m_pts.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m_pts - centre) ** 2, axis=1))))
    mics_s, r_s = (m_pts - centre) / scale, r / scale
    thr_s = None if inlier_threshold is None else inlier_threshold / scale
    b_s, pts = _offset_start(mics_s, r_s, observed, robust, thr_s, max_hypotheses, rng)

    use = observed.copy()
    message = ""
    room = None
    std_s = rms_s = float("nan")
    ok = True
    for _ in range(5 if robust else 1):
        if robust and room is not None:
            # Re-estimate b on the ranges the reconstruction kept, from its points.
            kept = room.inliers[0]
            if np.array_equal(kept, use):
                break
            use = kept
            pts = (np.vstack([room.sources, room.image_sources[0]]) - centre) / scale
        b_s, pts, rms_s, std_s, ok, message = _joint_offset_fit(mics_s, r_s, use, b_s, pts)
        corrected = np.where(observed, r - b_s * scale, 0.0)
        if np.any(corrected[observed] < 0):
            bad = tuple(int(i) for i in np.argwhere(observed & (corrected < 0))[0])
            raise InvalidInputError(
                f"ranges minus the estimated offset {b_s * scale:.4g} m are negative (entry {bad}): "
                "the ranges are inconsistent with one offset per event"
            )
        room = reconstruct_room(
            m_pts,
            corrected,
            mask=observed,
            robust=robust,
            inlier_threshold=inlier_threshold,
            max_hypotheses=max_hypotheses,
            rng=rng,
        )
        if not robust:
            break
    assert room is not None
    converged = bool(ok and room.converged)
    if not room.converged:
        message += f"room reconstruction: {room.message}; "
    b = float(b_s * scale)
    if converged:
        message = f"converged: offset {b:.4g} m; {room.message}"
    return UnknownEmissionRoom(
        offset=b,
        offset_time=float("nan") if c is None else b / float(c),
        offset_std=float(std_s * scale),
        corrected_ranges=frozen(corrected),
        reconstruction=room,
        points=frozen(centre + scale * pts),
        residual_rms=float(rms_s * scale),
        converged=converged,
        message=message.strip().rstrip(";"),
    )
