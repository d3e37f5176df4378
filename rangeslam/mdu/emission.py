"""Unknown microphones and unknown emission times (Problem 2 with one range offset per event).

:func:`calibrate_unknown_emission`: multidimensional unfolding with one unknown offset per event
(a group of columns, e.g. a loudspeaker and its image sources). The offsets start from a rank test
(:func:`offsets_from_rank`: the double-centred squared corrected ranges have rank d), the points
from the SDP of :func:`rangeslam.calibrate` on the corrected ranges; then points and offsets are
refined jointly by least squares on the ranges. The model and its identifiability are described
in :mod:`rangeslam.localization.emission`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares, minimize, minimize_scalar

from rangeslam._robust import robust_mode
from rangeslam._validation import (
    as_dim,
    as_float_array,
    as_mask,
    as_rng,
    as_speed,
    check_int,
    frozen,
    shape_str,
)
from rangeslam.errors import InvalidInputError
from rangeslam.localization.emission import pseudoranges
from rangeslam.mdu.core import (
    ConvexIterationOptions,
    canonical_frame,
    check_determined,
    check_noise_std,
    checked_options,
    convex_iteration_runs,
    mdu_edm,
    mdu_mask,
    passes_residual_test,
    unfolding_check,
    unknowns_up_to_rigid_motion,
)
from rangeslam.mdu.emission_judge import judged_emission_search, same_emission
from rangeslam.solvers.least_squares import unfolding_jacobian, unfolding_residuals
from rangeslam.status import HasStatus, Status
from rangeslam.verdict.judge import SAME, CheckRecord, JudgedSearch, Judgement, ReachedLowest
from rangeslam.verdict.thresholds import CHI2_LEVEL, EXACT_RTOL, RANK_RTOL, RELATIVE_RMS

# --- unknown microphones and unknown emission times (Problem 2) ---------------------------------

# Attempt ladder and acceptance thresholds as in calibrate (see rangeslam.mdu.calibration).
# Grid of the one-dimensional offset search (see offsets_from_rank).
_GRID = 200
# Search runs at most with receiver offsets (rangeslam.mdu.clock_offsets): at K = 6 events of the
# xtdoa data, 8 - 48 % of the random starts reach the lowest minimum (measured on 5 subsets).
CLOCK_RUNS = 60


def _rank_tail(r: np.ndarray, offsets_per_col: np.ndarray, dim: int) -> float:
    """Relative energy beyond rank ``dim`` of J (R - b)^2 J (double-centred squared ranges)."""
    d2 = (r - offsets_per_col[None, :]) ** 2
    b = d2 - d2.mean(axis=0, keepdims=True)
    b -= b.mean(axis=1, keepdims=True)
    sv = np.linalg.svd(b, compute_uv=False)
    total = float(sv @ sv)
    return float(sv[dim:] @ sv[dim:]) / total if total > 0 else 0.0


def _tail_at(x: float, rr: np.ndarray, gg: np.ndarray, b: np.ndarray, j: int, dim: int) -> float:
    """:func:`_rank_tail` with offset j set to x."""
    bb = b.copy()
    bb[j] = x
    return _rank_tail(rr, bb[gg], dim)


def _search_offset(rr, gg, b: np.ndarray, j: int, dim: int, span: float) -> float:
    """Offset j (metres) minimising the rank tail with the others fixed: a grid over b_j <= min r
    of its columns, then Brent's method in the best grid cell."""
    rmin = float(rr[:, gg == j].min())
    # b_g <= min r; b -> -inf is the far field. A grid uniform in the angle of the distance
    # to the closest source covers [0, inf) with most points at the scale of the spread.
    cand = rmin - span * np.tan(np.linspace(0.0, 0.49 * np.pi, _GRID))
    f = functools.partial(_tail_at, rr=rr, gg=gg, b=b, j=j, dim=dim)
    vals = np.array([f(x) for x in cand])
    i = int(np.argmin(vals))
    lo, hi = cand[min(i + 1, _GRID - 1)], cand[max(i - 1, 0)]
    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12 * span})
    return float(res.x) if res.fun <= vals[i] else float(cand[i])


def _joint_offsets(r: np.ndarray, g: np.ndarray, b: np.ndarray, dim: int, span: float):
    """All offsets (G,) together by Nelder-Mead from ``b``; ``b`` when that is no better."""
    res = minimize(
        lambda x: _rank_tail(r, x[g], dim),
        b,
        method="Nelder-Mead",
        options={"xatol": 1e-12 * span, "fatol": 1e-16, "maxiter": 400 * len(b)},
    )
    return res.x if res.fun <= _rank_tail(r, b[g], dim) else b


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
    energy beyond rank d is small too.

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
    g = as_groups(groups, r.shape[1])
    n_groups = int(g.max()) + 1
    m, k = r.shape
    if (m - 1 - dim) * (k - 1 - dim) < n_groups or m - 1 <= dim or k - 1 <= dim:
        raise InvalidInputError(
            f"the rank test cannot determine {n_groups} offsets from {m} x {k} ranges in "
            f"{dim}-D: needs (M - 1 - d)(K - 1 - d) >= G with M, K >= d + 2"
        )
    sizes = np.bincount(g, minlength=n_groups)
    # With fewer than d + 2 columns per group, 0 of 15 draws in 2-D and 3-D were recovered.
    if np.any((m - 1 - dim) * (sizes - 1 - dim) < 1):
        j = int(np.argmin(sizes))
        raise InvalidInputError(
            f"group {j} has {int(sizes[j])} columns: the rank start needs every group to have at "
            f"least d + 2 = {dim + 2} (one column per event, as in TDOA self-calibration, makes "
            "the far field a near-optimum it drifts to); pass starting offsets instead"
        )
    span = float(np.ptp(r)) or 1.0
    b = np.empty(n_groups)
    for j in range(n_groups):
        cols = g == j  # each group first on its own columns
        own = np.zeros(int(cols.sum()), dtype=int)
        b[j] = _search_offset(r[:, cols], own, np.zeros(1), 0, dim, span)
    for _ in range(sweeps):
        for j in range(n_groups):
            b[j] = _search_offset(r, g, b, j, dim, span)
    return _joint_offsets(r, g, b, dim, span) if n_groups > 1 else b


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


def as_groups(groups: ArrayLike | None, k: int) -> np.ndarray:
    """``groups`` checked: (K,) integers 0..G-1 with none empty; zeros (one event) for None."""
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
class UnknownEmissionCalibration(HasStatus):
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
        status: CONVERGED when the answer passed the residual test (as
            :func:`rangeslam.calibrate`) and its Jacobian has full rank up to the rigid motions
            (the offsets are determined); else why not (``converged`` is derived from it).
        message: why not, when not converged.
        attempts: convex-iteration runs made; random_starts: least-squares runs from random points.
        receiver_offsets: (M,) range offset of each receiver's clock, metres, with mean 0 (the
            gauge: one common shift between these and ``offsets`` is not observable), when
            ``receiver_offsets=True`` was asked for; None otherwise.
        inliers: (M, K) the arrivals used in the final fit with ``receiver_offsets=True``
            (``observed`` unless ``robust``; an event with none was dropped as a whole and its
            source and residuals are NaN); None otherwise.
        checks: the checks of the verdict (name, statistic, level, passed, reason): the judge
            of the starts' minima (:func:`rangeslam.verdict.judge.judge`), whether the stopping
            rule ended its random starts, then the verdict; empty with ``receiver_offsets=True``.
        judged: the other starts' minima the judge compared with the answer; ``reached``:
            starts (the answer's own counted) that reached the answer.
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
    status: Status
    message: str
    attempts: int
    random_starts: int
    receiver_offsets: np.ndarray | None = None
    inliers: np.ndarray | None = None
    checks: tuple[CheckRecord, ...] = ()
    judged: int = 0
    reached: int = 0


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


@dataclass(frozen=True)
class EmissionProblem:
    """The validated inputs of :func:`calibrate_unknown_emission` (see :func:`parse_emission`)."""

    ranges: np.ndarray  # (M, K) metres (pseudoranges: distance + offset)
    observed: np.ndarray  # (M, K) bool
    groups: np.ndarray  # (K,) event of each column, 0..G-1
    dim: int
    noise_std: float | None
    c: float | None
    random_starts: int
    options: ConvexIterationOptions

    @property
    def n_groups(self) -> int:
        """G."""
        return int(self.groups.max()) + 1

    @property
    def need(self) -> int:
        """Unknowns: the points up to a rigid motion, and the G offsets."""
        return unknowns_up_to_rigid_motion(sum(self.ranges.shape), self.dim) + self.n_groups


@dataclass(frozen=True)
class ScaledUnfolding:
    """The problem in units of the median corrected range ``scale`` (metres): corrected ranges
    (M, K) (metres, 0 where unobserved), starting offsets (G,) and the residual model."""

    scale: float
    corrected: np.ndarray
    offsets0: np.ndarray
    model: _OffsetUnfolding


@dataclass(frozen=True)
class EmissionCandidate:
    """A least-squares fit (scipy result, scaled units) and its sum of squared residuals."""

    ssr: float
    fit: object


@dataclass(frozen=True)
class EmissionSearch:
    """The best fit, whether another start reached it, starts made, SDP failures, and every
    start's fit (the judge's alternatives; the best among them)."""

    best: EmissionCandidate | None
    confirmed: bool
    attempts: int
    random_starts: int
    failures: tuple[str, ...]
    candidates: tuple[EmissionCandidate, ...] = ()


def parse_emission(
    ranges, groups, dim, mask, noise_std, c, random_starts, options: ConvexIterationOptions
) -> EmissionProblem:
    """The front door of :func:`calibrate_unknown_emission`: every input checked once."""
    dim = as_dim(dim)
    shape = as_float_array(ranges, "ranges").shape
    if len(shape) != 2:
        raise InvalidInputError(f"ranges must be an (M, K) array; got {shape_str(shape)}")
    observed = as_mask(mask, "mask", shape=shape)
    r = pseudoranges(ranges, "ranges", shape, observed)
    m, k = shape
    g = as_groups(groups, k)
    n_groups = int(g.max()) + 1
    check_determined(observed, dim, "mask" if mask is not None else "ranges")
    need = unknowns_up_to_rigid_motion(m + k, dim) + n_groups
    if observed.sum() < need:
        raise InvalidInputError(
            f"{int(observed.sum())} observed ranges for {need} unknowns ({m} receivers and {k} "
            f"sources in {dim}-D up to a rigid motion, and {n_groups} offsets)"
        )
    noise_std, c = check_noise_std(noise_std), as_speed(c)
    options = checked_options(options)
    random_starts = check_int(random_starts, "random_starts", 0)
    return EmissionProblem(r, observed, g, dim, noise_std, c, random_starts, options)


def starting_offsets(problem: EmissionProblem, offsets0) -> np.ndarray:
    """Step 1: the offsets (G,) metres, ``offsets0`` checked or the rank start
    (:func:`offsets_from_rank`) on a fully observed block (:func:`_complete_block`)."""
    n_groups, g, dim = problem.n_groups, problem.groups, problem.dim
    if offsets0 is not None:
        b0 = as_float_array(offsets0, "offsets0")
        if b0.shape != (n_groups,) or not np.all(np.isfinite(b0)):
            raise InvalidInputError(
                f"offsets0 must be finite with shape ({n_groups},); got {shape_str(b0.shape)}"
            )
        return b0
    rows, cols = _complete_block(problem.observed, g, dim)
    try:
        return offsets_from_rank(problem.ranges[np.ix_(rows, cols)], g[cols], dim=dim)
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"no starting offsets: {exc} (the rank start uses a fully observed block of "
            f"{int(rows.sum())} receivers and {int(cols.sum())} columns); pass offsets0"
        ) from exc


def scaled_unfolding(problem: EmissionProblem, b0: np.ndarray) -> ScaledUnfolding:
    """The ranges corrected by ``b0`` and the residual model in units of their median."""
    r, observed, g = problem.ranges, problem.observed, problem.groups
    corrected = np.where(observed, r - b0[g][None, :], 0.0)
    scale = float(np.median(np.abs(corrected[observed]))) or 1.0
    model = _OffsetUnfolding(r / scale, observed, g, problem.dim)
    return ScaledUnfolding(scale, corrected, b0 / scale, model)


def emission_passes(problem: EmissionProblem, scale: float, ssr: float) -> bool:
    """The residual test of :func:`passes_residual_test` on a scaled sum of squares (noise_std
    in the same units), with the G offsets among the unknowns."""
    n_obs = int(problem.observed.sum())
    noise = None if problem.noise_std is None else problem.noise_std / scale
    return passes_residual_test(
        ssr, n_obs, sum(problem.ranges.shape), problem.dim, noise, EXACT_RTOL,
        n_offsets=problem.n_groups,
    )  # fmt: skip


def emission_starts(problem: EmissionProblem, scaled: ScaledUnfolding, rng, failures: list):
    """Step 2: yield (points (M + K, d) scaled, from_sdp): the SDP on the corrected ranges
    (distances must be >= 0 there), then random points."""
    from rangeslam.solvers.sdp_pool import pooled_sdp

    w = mdu_mask(problem.observed)
    d_tilde = mdu_edm(np.maximum(scaled.corrected, 0.0) / scaled.scale)
    with pooled_sdp(w) as sdp:
        for comp in convex_iteration_runs(
            sdp, d_tilde, w, problem.dim, options=problem.options, rng=rng, failures=failures
        ):
            yield comp.points, True
    for _ in range(problem.random_starts):
        yield rng.standard_normal((sum(problem.ranges.shape), problem.dim)), False


def search_emission(problem: EmissionProblem, scaled: ScaledUnfolding, rng) -> EmissionSearch:
    """Step 3: Levenberg-Marquardt over points and offsets from each start, keeping the lowest,
    until an answer is exact, or passes the residual test and is confirmed by a second start
    (the judge calls them the same answer, :func:`same_emission`), or is the best of all
    convex-iteration runs. Every start's fit is kept for the judge (:func:`judge_emission`)."""
    failures: list[str] = []
    exact_ssr = (EXACT_RTOL**2) * int(problem.observed.sum())
    attempts, n_random = 0, 0
    # the vote of calibrate: the lowest fit is confirmed when another start reached the same
    # answer (the judge's test, in the information at the lowest)
    lowest = ReachedLowest(lambda best: same_emission(problem, scaled, best), lambda c: c.ssr)
    candidates: list[EmissionCandidate] = []
    for pts, from_sdp in emission_starts(problem, scaled, rng, failures):
        attempts += from_sdp
        n_random += not from_sdp
        cand = fit_emission_start(scaled, pts)
        if cand is None:
            continue
        candidates.append(cand)
        lowest.add(cand)
        best, confirmed = lowest.best, lowest.confirmed
        # A wrong local minimum can pass the chi-square test at 1 cm noise (measured: 1 of 40
        # 3-D draws), so a noisy answer must also be reached from a second start, or be the
        # best of all convex-iteration runs.
        done_sdp = attempts + len(failures) >= problem.options.max_attempts
        ok = emission_passes(problem, scaled.scale, best.ssr)
        if best.ssr <= exact_ssr or (ok and (confirmed or done_sdp)):
            break
        if problem.noise_std is None and confirmed and done_sdp:
            break
    return EmissionSearch(
        lowest.best, lowest.confirmed, attempts, n_random, tuple(failures), tuple(candidates)
    )


def fit_emission_start(scaled: ScaledUnfolding, pts: np.ndarray) -> EmissionCandidate | None:
    """Levenberg-Marquardt over points and offsets from ``pts`` (M + K, d) scaled and the
    starting offsets; None when the fit diverged."""
    fit = scaled.model.refine(pts, scaled.offsets0)
    ssr = float(fit.fun @ fit.fun)
    if not (np.all(np.isfinite(fit.x)) and np.isfinite(ssr)):
        return None
    return EmissionCandidate(ssr, fit)


def lowest_found(found: EmissionSearch, judged: JudgedSearch) -> tuple[EmissionSearch, str]:
    """The search with the judge's answer (its lowest candidate) as the best, and the judge's
    random starts (``judged.draws``) counted in (as the search counts its own: diverged fits
    too); the words saying so when that replaced the search's answer ("" if not)."""
    j = judged.judgement
    found = dataclasses.replace(found, random_starts=found.random_starts + judged.draws)
    own = j.replacement
    if own is None:
        return found, ""
    found = dataclasses.replace(found, best=j.answer.payload)
    if own.kind == SAME:  # the same answer, reached lower: no other answer
        return found, ""
    words = (
        f"{j.answer.origin} reached a lower minimum (by {own.delta_cost:.3g} noise variances): "
        "it replaced the search's answer"
    )
    return found, words


def emission_verdict(
    problem: EmissionProblem, scaled: ScaledUnfolding, found: EmissionSearch, judged: Judgement
):
    """Step 4: (status, message). INCONSISTENT (NO_AGREEMENT without noise_std) when no start
    passed the residual test or, without noise_std, no second start reached the answer (the
    judge's ``reached``); NOT_IDENTIFIABLE without redundancy, with a rank-deficient Jacobian,
    when the judge found a rival minimum among the starts (``judged``: :func:`judge_emission`),
    or with a point its mirror image fits as well."""
    ssr, fit, scale = found.best.ssr, found.best.fit, scaled.scale
    n_obs, need, noise_std = int(problem.observed.sum()), problem.need, problem.noise_std
    redundancy = n_obs - need
    rms = math.sqrt(ssr / n_obs) * scale
    status, message = Status.CONVERGED, ""
    vote = noise_std is None and judged.reached >= 2 and rms <= RELATIVE_RMS * scale
    if not (emission_passes(problem, scale, ssr) or vote):
        status = Status.INCONSISTENT if noise_std is not None else Status.NO_AGREEMENT
        message += f"no start passed the residual test: best RMS residual {rms:.3g} m" + (
            f" for noise_std {noise_std:.3g} m; " if noise_std is not None else "; "
        )
    if redundancy == 0:
        status = Status.NOT_IDENTIFIABLE
        message += (
            "no redundant ranges: finitely many exact solutions, the data cannot tell which; "
        )
    sv = np.linalg.svd(scaled.model.jacobian(fit.x), compute_uv=False)
    rank = int(np.sum(sv > RANK_RTOL * sv[0]))
    if rank < need:
        status = Status.NOT_IDENTIFIABLE
        message += (
            f"the Jacobian has rank {rank} < {need}: the offsets (or points) are not determined "
            "by these ranges (e.g. far-field sources); "
        )
    if judged.rivals:
        status = Status.NOT_IDENTIFIABLE
        message += judged.reason + "; "
    mirrored = mirrored_points(problem, scaled, ssr, fit)
    if mirrored:
        status = Status.NOT_IDENTIFIABLE
        message += (
            f"{', '.join(mirrored)}: mirrored in the plane of the points it is ranged to, it fits "
            "the ranges as well (they are (nearly) coplanar, or too few): its position is ambiguous; "
        )
    if status is Status.CONVERGED:
        check = emission_check(problem, scaled, fit)
        status, message = check.status, message + check.reason + "; "
    if found.failures:
        message += f"{len(found.failures)} SDP runs failed ({found.failures[0]}); "
    return status, "; ".join(part.strip() for part in message.split("; ") if part.strip())


def emission_check(problem: EmissionProblem, scaled: ScaledUnfolding, fit):
    """:func:`rangeslam.mdu.core.unfolding_check` of the fit (metres), the G offsets included
    as unknowns."""
    scale, model = scaled.scale, scaled.model
    pts_s, b_s = model.split(fit.x)
    m = problem.ranges.shape[0]
    corrected = np.where(problem.observed, problem.ranges - scale * b_s[problem.groups], 0.0)
    columns = np.zeros((len(model.pairs), model.n_groups))
    columns[np.arange(len(model.pairs)), model.g_of_pair] = 1.0
    return unfolding_check(
        scale * pts_s[:m],
        scale * pts_s[m:],
        corrected,
        problem.observed,
        problem.noise_std,
        EXACT_RTOL * scale,
        offset_columns=columns,
        what="the calibration",
        judge_sources="none",
    )


def mirrored_points(problem: EmissionProblem, scaled: ScaledUnfolding, ssr: float, fit):
    """Names of the points the data cannot tell from their mirror image (:func:`_mirror_ambiguities`).

    A point whose partners (the sources a receiver hears, or the receivers that hear a source)
    are (nearly) coplanar can be mirrored in their plane at little cost: the source and the
    images of a shoebox lie on three lines through the source, so a receiver that misses two
    echoes may hear only coplanar points. The data cannot tell the two positions apart."""
    from scipy.stats import chi2

    n_obs, scale, noise_std = int(problem.observed.sum()), scaled.scale, problem.noise_std
    redundancy = n_obs - problem.need
    exact_ssr = (EXACT_RTOL**2) * n_obs
    sigma_s = noise_std if noise_std else (math.sqrt(ssr / redundancy) if redundancy > 0 else 0.0)
    tol = max(chi2.ppf(CHI2_LEVEL, 1) * (sigma_s / scale) ** 2, exact_ssr)
    pts_s, b_s = scaled.model.split(fit.x)
    dist = problem.ranges / scale - b_s[problem.groups][None, :]
    return _mirror_ambiguities(pts_s, problem.ranges.shape[0], dist, problem.observed, tol)


def emission_result(problem, scaled, found: EmissionSearch, status, message, judged: JudgedSearch):
    """The :class:`UnknownEmissionCalibration` in metres, in the canonical frame, its checks the
    judge's (rival minima, search complete) and the verdict's; the search in words after the
    message."""
    ssr, fit, scale = found.best.ssr, found.best.fit, scaled.scale
    m, n_groups = problem.ranges.shape[0], problem.n_groups
    n_obs = int(problem.observed.sum())
    redundancy = n_obs - problem.need
    pts_s, b_s = scaled.model.split(fit.x)
    pts = pts_s * scale
    receivers, sources, _ = canonical_frame(pts[:m], pts[m:])
    offsets = b_s * scale
    residuals = np.full(problem.ranges.shape, np.nan)
    residuals[problem.observed] = fit.fun * scale
    c = problem.c
    return UnknownEmissionCalibration(
        receivers=frozen(receivers),
        sources=frozen(sources),
        offsets=frozen(offsets),
        offset_times=frozen(offsets / c if c is not None else np.full(n_groups, np.nan)),
        residuals=frozen(residuals),
        observed=frozen(problem.observed),
        residual_rms=math.sqrt(ssr / n_obs) * scale,
        noise_estimate=math.sqrt(ssr / redundancy) * scale if redundancy > 0 else float("nan"),
        redundancy=int(redundancy),
        status=status,
        message="; ".join(filter(None, (message, judged.words()))),
        attempts=int(found.attempts),
        random_starts=int(found.random_starts),
        checks=(
            judged.judgement.check,
            judged.record(),
            CheckRecord("verdict", math.nan, math.nan, status is Status.CONVERGED, message),
        ),
        judged=len(judged.judgement.comparisons),
        reached=judged.judgement.reached,
    )


def calibrate_unknown_emission(
    ranges: ArrayLike,
    groups: ArrayLike | None = None,
    *,
    dim: int = 3,
    mask: ArrayLike | None = None,
    noise_std: float | None = None,
    c: float | None = None,
    offsets0: ArrayLike | None = None,
    receiver_offsets: bool = False,
    robust: bool = False,
    max_attempts: int = 8,
    random_starts: int | None = None,
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
    the residual test, vote and judge of :func:`rangeslam.calibrate`; a rank test of the Jacobian.
    The SDP's own offset model (:class:`rangeslam.solvers.sdp.EDMCompletionSDP` with
    ``range_model="offset"``) is not used: with every pair an offset range, its relaxation
    D = (r - c)^2 + (e - c^2) lets the offsets absorb most of the ranges (errors of metres).

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
        receiver_offsets: True to fit one unknown clock offset per receiver as well, a_m:
            r_mk = ||x_m - s_k|| + a_m + b_{groups[k]} (unsynchronised microphones). One common
            shift a + t, b - t is not observable: the gauge is mean(a) = 0, and the result's
            ``receiver_offsets`` (M,) holds a. The offsets are then eliminated exactly (variable
            projection) and the points found by Levenberg-Marquardt from random starts
            (:mod:`rangeslam.mdu.clock_offsets`); ``offsets0`` must be None and the SDP
            options are not used. Needs at least (M + K) d - d (d + 1) / 2 + G + M - 1 ranges.
        robust: with ``receiver_offsets=True`` only: drop the arrivals and whole events that do
            not fit (:mod:`rangeslam.mdu.offset_outliers`; the result's ``inliers``); status as
            :func:`rangeslam.calibrate` with ``robust=True``.
        random_starts: least-squares runs from random points (offsets from step 1) at most:
            the search's, when no convex-iteration run passes, and the judge's after it
            (default 20); with ``receiver_offsets``, the search runs at most (default
            :data:`CLOCK_RUNS`).
        rng: random generator (or seed).

    Identifiability: the ranges must number at least (M + K) d - d (d + 1) / 2 + G (InvalidInputError
    otherwise), and the Jacobian must have that rank at the answer (generic configurations do,
    even for one offset shared by all ranges; the far field does not).
    """
    if clock_mode(receiver_offsets, robust, offsets0):
        from rangeslam.mdu.clock_offsets import calibrate_with_clock_offsets

        return calibrate_with_clock_offsets(
            ranges, groups, dim=dim, mask=mask, noise_std=noise_std, c=c, rng=rng,
            runs=CLOCK_RUNS if random_starts is None else random_starts, robust=robust,
        )  # fmt: skip
    random_starts = 20 if random_starts is None else random_starts
    rng = as_rng(rng)
    options = ConvexIterationOptions(max_attempts, fit_weight, max_iterations, gap_tol)
    problem = parse_emission(ranges, groups, dim, mask, noise_std, c, random_starts, options)
    scaled = scaled_unfolding(problem, starting_offsets(problem, offsets0))
    found = search_emission(problem, scaled, rng)
    if found.best is None:
        raise InvalidInputError("every fit diverged: no unfolding with offsets found")
    return judged_emission(problem, scaled, found, rng)


def judged_emission(
    problem: EmissionProblem, scaled: ScaledUnfolding, found: EmissionSearch, rng
) -> UnknownEmissionCalibration:
    """Step 4: the search's answer judged after the judge's random starts
    (:func:`judged_emission_search`; its lowest the answer, :func:`lowest_found`), the verdict
    (:func:`emission_verdict`) and the result."""
    judged = judged_emission_search(
        problem, scaled, found, lambda pts: fit_emission_start(scaled, pts), rng
    )
    found, replaced = lowest_found(found, judged)
    status, message = emission_verdict(problem, scaled, found, judged.judgement)
    message = "; ".join(filter(None, (replaced, message)))
    return emission_result(problem, scaled, found, status, message, judged)


def clock_mode(receiver_offsets, robust, offsets0) -> bool:
    """The door checks of the ``receiver_offsets`` and ``robust`` options of
    :func:`calibrate_unknown_emission`: whether the receiver-offset model
    (:mod:`rangeslam.mdu.clock_offsets`) is asked for. Raises InvalidInputError when either is
    not a bool, when ``robust`` comes without ``receiver_offsets`` and when ``offsets0`` comes
    with it."""
    robust = robust_mode(robust, ("on",)) is not None  # True: on; None or False: off
    if receiver_offsets is not True and receiver_offsets is not False:
        raise InvalidInputError(f"receiver_offsets must be True or False; got {receiver_offsets!r}")
    if robust and not receiver_offsets:
        raise InvalidInputError(
            "robust=True needs receiver_offsets=True; got receiver_offsets=False"
        )
    if receiver_offsets and offsets0 is not None:
        raise InvalidInputError(
            "offsets0 must be None with receiver_offsets=True (the offsets are eliminated: "
            f"no starting values are used); got {type(offsets0).__name__}"
        )
    return receiver_offsets


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
