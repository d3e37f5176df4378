"""Unknown microphones and unknown emission times (Problem 2 with one range offset per event).

:func:`calibrate_unknown_emission`: multidimensional unfolding with one unknown offset per event
(a group of columns, e.g. a loudspeaker and its image sources). The offsets start from a rank test
(:func:`offsets_from_rank`: the double-centred squared corrected ranges have rank d), the points
from the SDP of :func:`rangeslam.calibrate` on the corrected ranges; then points and offsets are
refined jointly by least squares on the ranges. The model and its identifiability are described
in :mod:`rangeslam.localization.emission`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares, minimize, minimize_scalar

from rangeslam._validation import (
    as_float_array,
    as_mask,
    check_int,
    frozen,
    shape_str,
)
from rangeslam.errors import InvalidInputError
from rangeslam.localization.emission import RANK_RTOL, pseudoranges
from rangeslam.mdu.core import (
    CHI2_LEVEL,
    EXACT_RTOL,
    MAX_RELATIVE_RMS,
    SAME_RTOL,
    canonical_frame,
    check_determined,
    convex_iteration_runs,
    mdu_edm,
    mdu_mask,
    unknowns_up_to_rigid_motion,
)
from rangeslam.solvers.least_squares import unfolding_jacobian, unfolding_residuals

# --- unknown microphones and unknown emission times (Problem 2) ---------------------------------

# Attempt ladder and acceptance thresholds as in calibrate (see rangeslam.mdu.calibration).
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
    r = pseudoranges(ranges, "ranges", np.shape(ranges), np.ones(np.shape(ranges), dtype=bool))
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
    The SDP's own offset model (:class:`rangeslam.solvers.sdp.EDMCompletionSDP` with
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
    r = pseudoranges(ranges, "ranges", shape, observed)
    m, k = shape
    g = _as_groups(groups, k)
    n_groups = int(g.max()) + 1
    check_determined(observed, dim, "mask" if mask is not None else "ranges")
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
        b0 = as_float_array(offsets0, "offsets0")
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
    exact_ssr = (EXACT_RTOL**2) * n_obs

    def passes(ssr: float) -> bool:
        if ssr <= exact_ssr:
            return True
        if noise_std is None or noise_std == 0 or redundancy <= 0:
            return False
        from scipy.stats import chi2

        return bool(ssr <= chi2.ppf(CHI2_LEVEL, redundancy) * (noise_std / scale) ** 2)

    # 2. Starting points: the SDP on the corrected ranges (distances must be >= 0 there), then
    # random points.
    from rangeslam.solvers.sdp import EDMCompletionSDP

    w = mdu_mask(observed)
    d_tilde = mdu_edm(np.maximum(corrected, 0.0) / scale)
    problem = EDMCompletionSDP(w)
    failures: list[str] = []

    def starts():
        yield from (
            (comp.points, True)
            for comp in convex_iteration_runs(
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
        # the same configuration (squared distances agreeing to SAME_RTOL, scaled units).
        same = best is not None and bool(
            np.max(np.abs(_sq_dists(model.split(fit.x)[0]) - _sq_dists(model.split(best[1].x)[0])))
            <= SAME_RTOL
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
    if passes(ssr) or (noise_std is None and confirmed and rms <= MAX_RELATIVE_RMS * scale):
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
    rank = int(np.sum(sv > RANK_RTOL * sv[0]))
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

    tol = max(chi2.ppf(CHI2_LEVEL, 1) * (sigma_s / scale) ** 2, exact_ssr)
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
    receivers, sources, _ = canonical_frame(pts[:m], pts[m:])
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
