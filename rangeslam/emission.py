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
from scipy.optimize import least_squares, minimize, minimize_scalar

from ._validation import (
    _as_float_array,
    as_mask,
    as_points,
    as_ranges,
    check_int,
    frozen,
    shape_str,
)
from .calibration import (
    _canonical_frame,
    _check_determined,
    _convex_iteration_runs,
    mdu_edm,
    mdu_mask,
    unknowns_up_to_rigid_motion,
)
from .errors import DegenerateGeometryError, InvalidInputError
from .multilateration import affine_rank, multilaterate
from .refinement import unfolding_jacobian, unfolding_residuals
from .room_reconstruction import RoomReconstruction, reconstruct_room

__all__ = [
    "OffsetMultilaterationResult",
    "UnknownEmissionCalibration",
    "UnknownEmissionRoom",
    "calibrate_unknown_emission",
    "multilaterate_with_offset",
    "offsets_from_rank",
    "reconstruct_room_unknown_emission",
]

# Inlier threshold of the robust multilateration, in robust standard deviations (as multilaterate).
_INLIER_K = 2.5
# Smallest singular value of the (scaled, weighted) Jacobian over the largest below which the
# offset and the position cannot be told apart (a rank-deficient fit).
_RANK_RTOL = 1e-8


def _pseudoranges(value: ArrayLike, name: str, shape: tuple[int, ...], observed: np.ndarray):
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
    if sv.size < jac.shape[1] or sv[-1] <= _RANK_RTOL * sv[0]:
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
    r = _pseudoranges(ranges, "ranges", (m,), observed)
    if weights is None:
        w = np.ones(m)
    else:
        w = _as_float_array(weights, "weights")
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
    if sv[-1] <= _RANK_RTOL * sv[0]:
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
    r = _pseudoranges(ranges, "ranges", shape, observed)
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


# --- unknown microphones and unknown emission times (Problem 2) ---------------------------------

# Attempt ladder and acceptance thresholds as in calibrate (see rangeslam.calibration).
_EXACT_RTOL = 1e-8
_CHI2_LEVEL = 0.999
_SAME_RTOL = 1e-5
_MAX_RELATIVE_RMS = 0.02
# Grid of the one-dimensional offset search (see offsets_from_rank).
_GRID = 200


def _rank_tail(r: np.ndarray, offsets_per_col: np.ndarray, dim: int) -> float:
    """Relative energy beyond rank ``dim`` of J (R - b)^2 J (double-centred squared ranges)."""
    d2 = (r - offsets_per_col[None, :]) ** 2
    b = d2 - d2.mean(axis=0, keepdims=True)
    b -= b.mean(axis=1, keepdims=True)
    sv = np.linalg.svd(b, compute_uv=False)
    total = float(sv @ sv)
    return float(sv[dim:] @ sv[dim:]) / total if total > 0 else 0.0


def offsets_from_rank(
    ranges: ArrayLike, groups: ArrayLike, *, dim: int = 3, sweeps: int = 2
) -> np.ndarray:
    """Offsets (G,) that make the corrected ranges an unfolding in ``dim`` dimensions (a start).

    For receivers x_m and sources s_k, D_mk = ||x_m - s_k||^2 gives J_M D J_K = -2 J_M X S^T J_K
    (J the centring matrices), of rank <= d. With offsets, D = (R - b_g(k))^2 column-wise, and

        J_M (R o R - 2 R diag(b)) J_K                                                     (E2)

    (the b_k^2 terms are constant down a column and vanish under J_M) is linear in the offsets
    and must have rank d at the true ones. The offsets are found by minimising the energy of (E2)
    beyond rank d relative to its total: each group first on its own columns, by a grid over
    b_g <= min r (the distances r - b are >= 0) then Brent's method; then ``sweeps`` coordinate
    sweeps over all columns, then all offsets together (Nelder-Mead). Exact data give the offsets
    to about 1e-9 of the range spread; with noise it is a start for
    :func:`calibrate_unknown_emission`.

    Every group needs d + 2 columns (and M >= d + 2 receivers): with one column per event (TDOA
    self-calibration) or two, the search drifts towards the far field (all b -> -inf), where the
    energy beyond rank d is small too (measured: 0 of 15 draws in 2-D and 3-D recovered).

    Args:
        ranges: (M, K) fully observed ranges (metres), r_mk = ||x_m - s_k|| + b_{groups[k]}.
        groups: (K,) integers 0..G-1, the offset group (event) of each column.
        dim: 2 or 3.
        sweeps: coordinate sweeps over the groups.

    The rank condition determines the offsets only when (M - 1 - d)(K - 1 - d) >= G (the
    codimension of the rank-d matrices); InvalidInputError otherwise, or when a group has fewer
    than d + 2 columns.
    """
    r = _pseudoranges(ranges, "ranges", np.shape(ranges), np.ones(np.shape(ranges), dtype=bool))
    if r.ndim != 2:
        raise InvalidInputError(f"ranges must be an (M, K) array; got {shape_str(r.shape)}")
    g = _as_groups(groups, r.shape[1])
    n_groups = int(g.max()) + 1
    m, k = r.shape
    if (m - 1 - dim) * (k - 1 - dim) < n_groups or m - 1 <= dim or k - 1 <= dim:
        raise InvalidInputError(
            f"the rank test cannot determine {n_groups} offsets from {m} x {k} ranges in "
            f"{dim}-D: needs (M - 1 - d)(K - 1 - d) >= G with M, K >= d + 2"
        )
    sizes = np.bincount(g, minlength=n_groups)
    if np.any((m - 1 - dim) * (sizes - 1 - dim) < 1):
        j = int(np.argmin(sizes))
        raise InvalidInputError(
            f"group {j} has {int(sizes[j])} columns: the rank start needs every group to have at "
            f"least d + 2 = {dim + 2} (one column per event, as in TDOA self-calibration, makes "
            "the far field a near-optimum it drifts to); pass starting offsets instead"
        )
    span = float(np.ptp(r)) or 1.0

    def search(rr: np.ndarray, gg: np.ndarray, b: np.ndarray, j: int) -> float:
        cols = gg == j
        rmin = float(rr[:, cols].min())
        # b_g <= min r; b -> -inf is the far field. A grid uniform in the angle of the distance
        # to the closest source covers [0, inf) with most points at the scale of the spread.
        cand = rmin - span * np.tan(np.linspace(0.0, 0.49 * np.pi, _GRID))

        def f(x: float) -> float:
            bb = b.copy()
            bb[j] = x
            return _rank_tail(rr, bb[gg], dim)

        vals = np.array([f(x) for x in cand])
        i = int(np.argmin(vals))
        lo, hi = cand[min(i + 1, _GRID - 1)], cand[max(i - 1, 0)]
        res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12 * span})
        return float(res.x) if res.fun <= vals[i] else float(cand[i])

    b = np.empty(n_groups)
    for j in range(n_groups):
        cols = g == j
        b[j] = search(r[:, cols], np.zeros(int(cols.sum()), dtype=int), np.zeros(1), 0)
    for _ in range(sweeps):
        for j in range(n_groups):
            b[j] = search(r, g, b, j)
    if n_groups > 1:
        res = minimize(
            lambda x: _rank_tail(r, x[g], dim),
            b,
            method="Nelder-Mead",
            options={"xatol": 1e-12 * span, "fatol": 1e-16, "maxiter": 400 * n_groups},
        )
        if res.fun <= _rank_tail(r, b[g], dim):
            b = res.x
    return b


def _complete_block(observed: np.ndarray, groups: np.ndarray, dim: int):
    """Rows (M,) and columns (K,) of a fully observed block for the rank start.

    Greedy: while fewer than d + 2 receivers observe every kept column, drop the column whose
    removal completes the most receivers, keeping d + 2 columns in every group.
    """
    cols = np.ones(observed.shape[1], dtype=bool)
    while True:
        rows = observed[:, cols].all(axis=1)
        if rows.sum() >= dim + 2:
            return rows, cols
        sizes = np.bincount(groups[cols], minlength=int(groups.max()) + 1)
        best, best_rows = -1, int(rows.sum())
        for j in np.flatnonzero(cols):
            if sizes[groups[j]] <= dim + 2:
                continue
            trial = cols.copy()
            trial[j] = False
            n_rows = int(observed[:, trial].all(axis=1).sum())
            if n_rows > best_rows or best < 0:
                best, best_rows = int(j), n_rows
        if best < 0:
            return rows, cols
        cols[best] = False


def _as_groups(groups: ArrayLike | None, k: int) -> np.ndarray:
    if groups is None:
        return np.zeros(k, dtype=int)
    g = np.array(groups, copy=True)
    if g.shape != (k,) or not np.issubdtype(g.dtype, np.integer):
        raise InvalidInputError(
            f"groups must be an integer array of shape ({k},) (the event of each column); got "
            f"dtype {g.dtype}, shape {shape_str(g.shape)}"
        )
    ids = np.unique(g)
    if not np.array_equal(ids, np.arange(len(ids))):
        raise InvalidInputError(
            f"groups must be numbered 0..G-1 with none empty; got {ids.tolist()}"
        )
    return g.astype(int)


@dataclass(frozen=True)
class UnknownEmissionCalibration:
    """Result of :func:`calibrate_unknown_emission`. M receivers, K sources, G events.

    Attributes:
        receivers: (M, d) receivers, metres (centroid at 0, principal axes along the axes, as
            :func:`rangeslam.calibrate`; up to a reflection).
        sources: (K, d) sources in the same frame, metres.
        offsets: (G,) range offset of each event, metres (range = distance + offset).
        offset_times: (G,) offsets / c, seconds; NaN without a speed of sound.
        residuals: (M, K) fitted minus measured range, metres; NaN where not observed.
        observed: (M, K) the mask that was given.
        residual_rms: RMS residual, metres.
        noise_estimate: sqrt(sum of squared residuals / redundancy), metres (NaN without
            redundancy).
        redundancy: observed ranges minus unknowns (points up to a rigid motion, and offsets).
        converged: the answer passed the residual test (as :func:`rangeslam.calibrate`) and its
            Jacobian has full rank up to the rigid motions (the offsets are determined).
        message: why not, when ``converged`` is False.
        attempts: convex-iteration runs made; random_starts: least-squares runs from random points.
    """

    receivers: np.ndarray
    sources: np.ndarray
    offsets: np.ndarray
    offset_times: np.ndarray
    residuals: np.ndarray
    observed: np.ndarray
    residual_rms: float
    noise_estimate: float
    redundancy: int
    converged: bool
    message: str
    attempts: int
    random_starts: int


class _OffsetUnfolding:
    """Residuals ||x_m - s_k|| + b_g(k) - r_mk over observed pairs; theta = [x, s, b] (scaled)."""

    def __init__(self, r: np.ndarray, observed: np.ndarray, groups: np.ndarray, dim: int) -> None:
        self.m = r.shape[0]
        self.pairs = np.argwhere(observed)
        self.r = r[observed]
        self.g_of_pair = groups[self.pairs[:, 1]]
        self.n_groups = int(groups.max()) + 1
        self.dim = dim

    def split(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return theta[: -self.n_groups].reshape(-1, self.dim), theta[-self.n_groups :]

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        pts, b = self.split(theta)
        return unfolding_residuals(pts, self.m, self.r - b[self.g_of_pair], self.pairs)

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        pts, _ = self.split(theta)
        jb = np.zeros((len(self.pairs), self.n_groups))
        jb[np.arange(len(self.pairs)), self.g_of_pair] = 1.0
        return np.hstack([unfolding_jacobian(pts, self.m, self.pairs), jb])

    def refine(self, pts: np.ndarray, b: np.ndarray):
        theta0 = np.r_[pts.ravel(), b]
        method = "lm" if len(self.pairs) >= theta0.size else "trf"
        fit = least_squares(
            self.residuals,
            theta0,
            jac=self.jacobian,
            method=method,
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
        )
        return fit


def calibrate_unknown_emission(
    ranges: ArrayLike,
    groups: ArrayLike | None = None,
    *,
    dim: int = 3,
    mask: ArrayLike | None = None,
    noise_std: float | None = None,
    c: float | None = None,
    offsets0: ArrayLike | None = None,
    max_attempts: int = 8,
    random_starts: int = 20,
    fit_weight: float = 10.0,
    max_iterations: int = 50,
    gap_tol: float = 1e-6,
    rng: np.random.Generator | int | None = None,
) -> UnknownEmissionCalibration:
    """Receivers, sources and emission time errors, all unknown, from ranges (MDU with offsets).

    r_mk = ||x_m - s_k|| + b_{groups[k]}: the columns of one event (e.g. a loudspeaker and its
    image sources) share one unknown offset b (c times the emission time error).

    Method: (1) offsets from the rank of the double-centred squared ranges
    (:func:`offsets_from_rank`; or ``offsets0``); (2) the unfolding of the ranges minus those
    offsets by the SDP and convex iteration of :func:`rangeslam.calibrate`; (3) Gauss-Newton
    (Levenberg-Marquardt) on the ranges over points and offsets together, analytic Jacobian; (4)
    the residual test and vote of :func:`rangeslam.calibrate`, and a rank test of the Jacobian.
    The SDP's own offset model (:class:`rangeslam.sdp.EDMCompletionSDP` with
    ``range_model="offset"``) is not used: with every pair an offset range, its relaxation
    D = (r - c)^2 + (e - c^2) lets the offsets absorb most of the ranges (measured errors of metres).

    Args:
        ranges: (M, K) ranges, metres (any sign: an offset may make them negative).
        groups: (K,) integers 0..G-1, the event of each column; None for one event (G = 1).
        dim: 2 or 3.
        mask: (M, K) True where observed. The rank start uses a fully observed block (columns
            with missing ranges dropped greedily, keeping d + 2 per group, until d + 2 receivers
            observe all that remain); when there is none, pass ``offsets0``.
        noise_std: range noise standard deviation, metres, if known (chi-square test at 0.999).
        c: speed of sound (m/s), to report the offsets in seconds.
        offsets0: (G,) starting offsets, metres, instead of the rank start.
        max_attempts, fit_weight, max_iterations, gap_tol: as :func:`rangeslam.calibrate`.
        random_starts: least-squares runs from random points (offsets from step 1) when no
            convex-iteration run passes.
        rng: random generator (or seed).

    Identifiability: the ranges must number at least (M + K) d - d (d + 1) / 2 + G (InvalidInputError
    otherwise), and the Jacobian must have that rank at the answer (generic configurations do,
    even for one offset shared by all ranges; the far field does not).
    """
    rng = np.random.default_rng(rng)
    if dim not in (2, 3):
        raise InvalidInputError(f"dim must be 2 or 3; got {dim!r}")
    shape = np.shape(ranges)
    if len(shape) != 2:
        raise InvalidInputError(f"ranges must be an (M, K) array; got {shape_str(shape)}")
    observed = as_mask(mask, "mask", shape=shape)
    r = _pseudoranges(ranges, "ranges", shape, observed)
    m, k = shape
    g = _as_groups(groups, k)
    n_groups = int(g.max()) + 1
    _check_determined(observed, dim, "mask" if mask is not None else "ranges")
    need = unknowns_up_to_rigid_motion(m + k, dim) + n_groups
    if observed.sum() < need:
        raise InvalidInputError(
            f"{int(observed.sum())} observed ranges for {need} unknowns ({m} receivers and {k} "
            f"sources in {dim}-D up to a rigid motion, and {n_groups} offsets)"
        )
    if noise_std is not None and not (np.isfinite(noise_std) and noise_std >= 0):
        raise InvalidInputError(f"noise_std must be non-negative or None; got {noise_std!r}")
    if c is not None and not (np.isfinite(c) and c > 0):
        raise InvalidInputError(f"c must be a positive speed of sound in m/s; got {c!r}")
    for name, value, low in (
        ("max_attempts", max_attempts, 1),
        ("max_iterations", max_iterations, 1),
        ("random_starts", random_starts, 0),
    ):
        check_int(value, name, low)

    # 1. Offsets.
    if offsets0 is not None:
        b0 = _as_float_array(offsets0, "offsets0")
        if b0.shape != (n_groups,) or not np.all(np.isfinite(b0)):
            raise InvalidInputError(
                f"offsets0 must be finite with shape ({n_groups},); got {shape_str(b0.shape)}"
            )
    else:
        rows, cols = _complete_block(observed, g, dim)
        try:
            b0 = offsets_from_rank(r[np.ix_(rows, cols)], g[cols], dim=dim)
        except InvalidInputError as exc:
            raise InvalidInputError(
                f"no starting offsets: {exc} (the rank start uses a fully observed block of "
                f"{int(rows.sum())} receivers and {int(cols.sum())} columns); pass offsets0"
            ) from exc
    corrected = np.where(observed, r - b0[g][None, :], 0.0)
    scale = float(np.median(np.abs(corrected[observed]))) or 1.0
    r_s, b0_s = r / scale, b0 / scale
    model = _OffsetUnfolding(r_s, observed, g, dim)
    n_obs = int(observed.sum())
    redundancy = n_obs - need
    exact_ssr = (_EXACT_RTOL**2) * n_obs

    def passes(ssr: float) -> bool:
        if ssr <= exact_ssr:
            return True
        if noise_std is None or noise_std == 0 or redundancy <= 0:
            return False
        from scipy.stats import chi2

        return bool(ssr <= chi2.ppf(_CHI2_LEVEL, redundancy) * (noise_std / scale) ** 2)

    # 2. Starting points: the SDP on the corrected ranges (distances must be >= 0 there), then
    # random points.
    from .sdp import EDMCompletionSDP

    w = mdu_mask(observed)
    d_tilde = mdu_edm(np.maximum(corrected, 0.0) / scale)
    problem = EDMCompletionSDP(w)
    failures: list[str] = []

    def starts():
        yield from (
            (comp.points, True)
            for comp in _convex_iteration_runs(
                problem,
                d_tilde,
                w,
                dim,
                max_attempts=max_attempts,
                fit_weight=fit_weight,
                max_iterations=max_iterations,
                gap_tol=gap_tol,
                rng=rng,
                failures=failures,
            )
        )
        for _ in range(random_starts):
            yield rng.standard_normal((m + k, dim)), False

    best = None
    confirmed = False
    attempts = n_random = 0
    for pts, from_sdp in starts():
        attempts += from_sdp
        n_random += not from_sdp
        fit = model.refine(pts, b0_s)
        ssr = float(fit.fun @ fit.fun)
        if not np.all(np.isfinite(fit.x)):
            continue
        cand = (ssr, fit)
        # The vote of calibrate: the lowest fit counts as confirmed when another start reached
        # the same configuration (squared distances agreeing to _SAME_RTOL, scaled units).
        same = best is not None and bool(
            np.max(np.abs(_sq_dists(model.split(fit.x)[0]) - _sq_dists(model.split(best[1].x)[0])))
            <= _SAME_RTOL
        )
        confirmed = confirmed or same
        if best is None or ssr < best[0]:
            confirmed = confirmed and same
            best = cand
        # A wrong local minimum can pass the chi-square test at 1 cm noise (measured: 1 of 40
        # 3-D draws), so a noisy answer must also be reached from a second start, or be the
        # best of all convex-iteration runs.
        done_sdp = attempts + len(failures) >= max_attempts
        if best[0] <= exact_ssr or (passes(best[0]) and (confirmed or done_sdp)):
            break
        if noise_std is None and confirmed and done_sdp:
            break
    if best is None:
        raise InvalidInputError("every fit diverged: no unfolding with offsets found")
    ssr, fit = best
    pts_s, b_s = model.split(fit.x)
    message = ""
    rms = math.sqrt(ssr / n_obs) * scale
    if passes(ssr) or (noise_std is None and confirmed and rms <= _MAX_RELATIVE_RMS * scale):
        converged = True
    else:
        converged = False
        message += f"no start passed the residual test: best RMS residual {rms:.3g} m" + (
            f" for noise_std {noise_std:.3g} m; " if noise_std is not None else "; "
        )
    if redundancy == 0:
        converged = False
        message += (
            "no redundant ranges: finitely many exact solutions, the data cannot tell which; "
        )
    sv = np.linalg.svd(model.jacobian(fit.x), compute_uv=False)
    rank = int(np.sum(sv > _RANK_RTOL * sv[0]))
    if rank < need:
        converged = False
        message += (
            f"the Jacobian has rank {rank} < {need}: the offsets (or points) are not determined "
            "by these ranges (e.g. far-field sources); "
        )
    # A point whose partners (the sources a receiver hears, or the receivers that hear a source)
    # are (nearly) coplanar can be mirrored in their plane at little cost: the source and the
    # images of a shoebox lie on three lines through the source, so a receiver that misses two
    # echoes may hear only coplanar points. The data cannot tell the two positions apart.
    sigma_s = noise_std if noise_std else (math.sqrt(ssr / redundancy) if redundancy > 0 else 0.0)
    from scipy.stats import chi2

    tol = max(chi2.ppf(_CHI2_LEVEL, 1) * (sigma_s / scale) ** 2, exact_ssr)
    mirrored = _mirror_ambiguities(pts_s, m, r_s - b_s[g][None, :], observed, tol)
    if mirrored:
        converged = False
        message += (
            f"{', '.join(mirrored)}: mirrored in the plane of the points it is ranged to, it fits "
            "the ranges as well (they are (nearly) coplanar, or too few): its position is ambiguous; "
        )
    if failures:
        message += f"{len(failures)} SDP runs failed ({failures[0]}); "
    pts = pts_s * scale
    receivers, sources, _ = _canonical_frame(pts[:m], pts[m:])
    offsets = b_s * scale
    residuals = np.full(shape, np.nan)
    residuals[observed] = fit.fun * scale
    return UnknownEmissionCalibration(
        receivers=frozen(receivers),
        sources=frozen(sources),
        offsets=frozen(offsets),
        offset_times=frozen(offsets / c if c is not None else np.full(n_groups, np.nan)),
        residuals=frozen(residuals),
        observed=frozen(observed),
        residual_rms=rms,
        noise_estimate=math.sqrt(ssr / redundancy) * scale if redundancy > 0 else float("nan"),
        redundancy=int(redundancy),
        converged=bool(converged),
        message=message.strip().rstrip(";"),
        attempts=int(attempts),
        random_starts=int(n_random),
    )


def _mirror_ambiguities(
    pts: np.ndarray, m: int, dist: np.ndarray, observed: np.ndarray, tol: float
) -> list[str]:
    """Names of the points whose mirror image in the best-fit hyperplane of their partners, moved
    to its own least-squares position with everything else fixed, raises the sum of squared
    residuals by at most ``tol`` (scaled units). ``dist`` (M, K) are the ranges minus offsets."""
    d = pts.shape[1]
    out = []
    for i in range(len(pts)):
        if i < m:
            partners, r, name = pts[m:][observed[i]], dist[i][observed[i]], f"receiver {i}"
        else:
            col = observed[:, i - m]
            partners, r, name = pts[:m][col], dist[:, i - m][col], f"source {i - m}"
        centred = partners - partners.mean(axis=0)
        normal = np.linalg.svd(centred)[2][-1] if len(partners) > 1 else np.eye(d)[0]
        p = pts[i]
        mirror = p - 2.0 * ((p - partners.mean(axis=0)) @ normal) * normal

        def res(x, partners=partners, r=r):
            return np.linalg.norm(partners - x, axis=1) - r

        def jac(x, partners=partners):
            diff = x - partners
            return diff / np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-300)

        here = res(p)
        fit = least_squares(res, mirror, jac=jac, method="trf", xtol=1e-12, ftol=1e-12)
        if np.linalg.norm(fit.x - p) > 1e-6 and fit.fun @ fit.fun - here @ here <= tol:
            out.append(name)
    return out


def _sq_dists(pts: np.ndarray) -> np.ndarray:
    diff = pts[:, None, :] - pts[None, :, :]
    return np.einsum("ijd,ijd->ij", diff, diff)
