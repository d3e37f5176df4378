"""Unsynchronised receivers and unknown emission times: one range offset per receiver and per event.

Model (the paper's eq. 9 with two offsets; El Badawy, Larsson, Pollefeys, Dokmanic, "Localizing
unsynchronized sensors with unknown sources", arXiv 2102.03565):

    T[m, k] = ||x_m - s_k|| + a_m + b_{g(k)} + noise                                    (C1)

with M receivers x_m, K sources s_k, an unknown clock offset a_m per receiver and an unknown
emission offset b_g per event g (a group of columns), all in metres (times c). One common shift
a + t, b - t leaves (C1) unchanged: it is fixed by the gauge mean(a) = 0.

The offsets enter (C1) linearly through a design matrix A (P, M + G) that does not depend on the
points, so for given points the best offsets are a linear least-squares fit and the residual left
is (I - A A^+)(||x_m - s_k|| - T[m, k]): a loss of the points alone that no offset changes (the
xtdoa paper's "loss invariant to the timings"). Least squares on this profiled loss (variable
projection, Golub and Pereyra 1973; exact here since A is constant) minimises the joint loss over
points and offsets together. It is started from random points in a box of the size the data give
(:func:`spread_from_arrivals`), each run capped, until the stopping rule of Boender and Rinnooy
Kan (:func:`rangeslam.verdict.judge.search_complete`) over the runs that converged (two reaching
one answer by the judge's test, :func:`rangeslam.verdict.judge.same_answer`); the lowest minimum
is judged by :func:`rangeslam.mdu.core.unfolding_check` with the offsets among the unknowns.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

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
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import receiver_gauge_projection, rigid_motion_basis
from rangeslam.localization.pseudorange import pseudoranges
from rangeslam.mdu.core import (
    canonical_frame,
    check_determined,
    check_noise_std,
    passes_residual_test,
    unfolding_check,
    unknowns_up_to_rigid_motion,
)
from rangeslam.mdu.emission import UnknownEmissionCalibration, as_groups
from rangeslam.solvers.least_squares import unfolding_jacobian
from rangeslam.status import Status
from rangeslam.verdict.judge import (
    Alternative,
    ReachedLowest,
    cost_level,
    distance_level,
    information_distance,
    search_complete,
)
from rangeslam.verdict.thresholds import EXACT_RTOL, RANK_RTOL, RELATIVE_RMS

# Function evaluations of one search run: from a start in the right basin, Levenberg-Marquardt
# converges in 40 - 70 evaluations on the xtdoa data (12 microphones, 6 - 11 events); runs from
# the wrong basin wander for thousands (measured), so they are cut short.
SEARCH_NFEV = 100
# Verdicts after which the search goes on for a lower minimum (the residuals reject the fit).
RETRY = (Status.INCONSISTENT, Status.OUTLIERS, Status.NO_AGREEMENT)


def unknowns_with_clock_offsets(m: int, k: int, n_groups: int, dim: int) -> int:
    """Unknowns of (C1): the M + K points up to a rigid motion, M receiver offsets and G event
    offsets less the one common shift: (M + K) d - d (d + 1) / 2 + G + M - 1."""
    return unknowns_up_to_rigid_motion(m + k, dim) + n_groups + m - 1


def offset_design(pairs: np.ndarray, m: int, groups: np.ndarray) -> np.ndarray:
    """(P, M + G) derivative of the P observed arrivals (``pairs`` (P, 2): receiver, column) with
    respect to the offsets [a (M,), b (G,)] of (C1)."""
    n_groups = int(groups.max()) + 1
    design = np.zeros((len(pairs), m + n_groups))
    rows = np.arange(len(pairs))
    design[rows, pairs[:, 0]] = 1.0
    design[rows, m + groups[pairs[:, 1]]] = 1.0
    return design


def spread_from_arrivals(arrivals: np.ndarray, observed: np.ndarray) -> float:
    """A length scale of the scene (metres) that no offset changes: half the largest spread over
    the columns of T[m, k] - T[m', k] (offsets cancel; |d_mk - d_m'k| <= ||x_m - x_m'||, so the
    spread is at most twice the receivers' diameter); 1 when no pair of receivers shares two
    columns."""
    best = 0.0
    for i in range(len(arrivals)):
        both = observed[i][None, :] & observed[i + 1 :]
        diff = np.where(both, arrivals[i][None, :] - arrivals[i + 1 :], np.nan)
        ok = both.sum(axis=1) >= 2
        if np.any(ok):
            best = max(best, float(np.max(np.nanmax(diff[ok], 1) - np.nanmin(diff[ok], 1))))
    return best / 2.0 if best > 0 else 1.0


class ProfiledUnfolding:
    """The loss of (C1) with the offsets profiled out, in units of ``scale`` (metres).

    Residuals (I - U U^T)(||x_m - s_k|| - T_mk) over the P observed pairs (row-major), U an
    orthonormal basis of the offsets' design (:func:`offset_design`); theta = the stacked points
    (M + K, d), receivers first."""

    def __init__(
        self, arrivals: np.ndarray, observed: np.ndarray, groups: np.ndarray, dim: int, scale: float
    ) -> None:
        self.m, self.dim, self.scale = arrivals.shape[0], dim, scale
        self.pairs = np.argwhere(observed)
        self.t = arrivals[observed] / scale
        self.design = offset_design(self.pairs, self.m, groups)
        u, sv, _ = np.linalg.svd(self.design, full_matrices=False)
        self.basis = u[:, sv > RANK_RTOL * sv[0]]

    def _project(self, v: np.ndarray) -> np.ndarray:
        return v - self.basis @ (self.basis.T @ v)

    def distances(self, theta: np.ndarray) -> np.ndarray:
        """(P,) distances of the observed pairs, scaled units."""
        pts = theta.reshape(-1, self.dim)
        return np.linalg.norm(pts[self.pairs[:, 0]] - pts[self.m + self.pairs[:, 1]], axis=1)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        return self._project(self.distances(theta) - self.t)

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        pts = theta.reshape(-1, self.dim)
        return self._project(unfolding_jacobian(pts, self.m, self.pairs))

    def offsets(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The best offsets (a (M,), b (G,)) for the points, scaled units, gauge mean(a) = 0."""
        ab = np.linalg.lstsq(self.design, self.t - self.distances(theta), rcond=None)[0]
        a, b = ab[: self.m], ab[self.m :]
        shift = float(a.mean())
        return a - shift, b + shift


@dataclass(frozen=True)
class ClockFit:
    """A profiled least-squares fit: points (M + K, d) scaled, its sum of squares, whether another
    run reached it or the stopping rule ended the search (``confirmed``), and the runs made."""

    theta: np.ndarray
    ssr: float
    confirmed: bool
    runs: int


def _fit(model: ProfiledUnfolding, theta0: np.ndarray, max_nfev: int | None):
    """Levenberg-Marquardt on the profiled loss from ``theta0``: (theta, ssr, converged), the
    last False when the run was cut at ``max_nfev`` evaluations."""
    method = "lm" if len(model.t) >= theta0.size else "trf"  # MINPACK needs P >= unknowns
    fit = least_squares(
        model.residuals, theta0, jac=model.jacobian, method=method, max_nfev=max_nfev,
        **({} if max_nfev else {"xtol": 1e-15, "ftol": 1e-15, "gtol": 1e-15}),
    )  # fmt: skip
    return fit.x, float(fit.fun @ fit.fun), bool(fit.status > 0)


def clock_sigma(model: ProfiledUnfolding, ssr: float, sigma: float | None = None) -> float:
    """The noise of the judge's objective, scaled units: ``sigma`` (the given noise), else a
    fit's sqrt(``ssr`` / redundancy) (scaled sum of squares); at least EXACT_RTOL."""
    n_pts = model.m + int(model.pairs[:, 1].max()) + 1
    need = unknowns_up_to_rigid_motion(n_pts, model.dim) + model.basis.shape[1]
    redundancy = len(model.t) - need
    if not sigma:
        sigma = math.sqrt(ssr / redundancy) if redundancy > 0 else 0.0
    return max(sigma, EXACT_RTOL)


def clock_distance(model: ProfiledUnfolding, theta: np.ndarray):
    """delta^2 at unit noise of another fit's points ((M + K) d, scaled) from ``theta``: its
    receivers' step after the best rigid motion, in the profiled information at ``theta`` (the
    offsets eliminated, the sources profiled out; :func:`rangeslam.verdict.judge.
    information_distance`); divide by sigma^2 for the judge's delta^2."""
    distance2 = information_distance(model.jacobian(theta), interest=np.arange(model.m))
    ref = Alternative(theta.reshape(-1, model.dim), 0.0, "the answer")
    return lambda other: distance2(ref, Alternative(other.reshape(-1, model.dim), 0.0, "a run"))


def region_bound(model: ProfiledUnfolding, ssr: float, sigma: float | None = None) -> float:
    """The confidence region of the receivers in :func:`clock_distance`'s units (unit noise):
    :func:`rangeslam.verdict.judge.distance_level` of the receivers' unknowns times the
    :func:`clock_sigma` of a fit of sum of squares ``ssr`` (scaled) squared."""
    bound = distance_level(unknowns_up_to_rigid_motion(model.m, model.dim))
    return bound * clock_sigma(model, ssr, sigma) ** 2


def same_clock_answer(model: ProfiledUnfolding, theta: np.ndarray, ssr: float, sigma=None):
    """The judge's same-answer test at the fit ``theta`` (scaled points, (M + K) d) of sum of
    squares ``ssr`` (scaled): a predicate of another fit's points, true when its receivers lie
    in the confidence region of ``theta``'s (:func:`clock_distance` within
    :func:`region_bound`)."""
    bound, distance = region_bound(model, ssr, sigma), clock_distance(model, theta)
    return lambda other: distance(other) <= bound


@dataclass
class _Minima:
    """The search's record: the lowest fit (``lowest.best``, (theta, ssr)) and the runs that
    reached it (:class:`rangeslam.verdict.judge.ReachedLowest`), the converged runs
    (``starts``) and one representative of each distinct minimum they reached (``reps``:
    (ssr, :func:`clock_distance` at it)), all judged at the noise of the lowest (``sigma``
    given, else :func:`clock_sigma` of the best)."""

    lowest: ReachedLowest
    starts: int = 0
    reps: list = dataclasses.field(default_factory=list)

    @classmethod
    def at(cls, model: ProfiledUnfolding, sigma: float | None) -> _Minima:
        """An empty record of a search of ``model`` at noise ``sigma`` (scaled; None unknown)."""

        def same_at(best: tuple):
            same = same_clock_answer(model, *best, sigma)
            return lambda fit: same(fit[0])

        return cls(ReachedLowest(same_at, _ssr))

    def add(self, model, theta, ssr, converged, sigma) -> None:
        """One run's fit (scaled points ``theta``, sum of squares ``ssr``) counted."""
        self.lowest.add((theta, ssr))
        if converged:
            self.starts += 1
            bound = region_bound(model, self.lowest.best[1], sigma)
            if not any(distance(theta) <= bound for _, distance in self.reps):
                self.reps.append((ssr, clock_distance(model, theta)))

    def contending(self, model, sigma) -> int:
        """Distinct minima the converged runs reached that the data do not rule out against
        the lowest: a cost gap within :func:`rangeslam.verdict.judge.cost_level` (the judge's
        same answers and rivals; its worse minima cannot become the answer)."""
        best_ssr = self.lowest.best[1]
        gap = cost_level() * clock_sigma(model, best_ssr, sigma) ** 2
        return sum(ssr - best_ssr <= gap for ssr, _ in self.reps)


def _ssr(fit: tuple) -> float:
    """The sum of squares of a (theta, ssr) fit."""
    return fit[1]


def clock_candidates(model: ProfiledUnfolding, runs: int, rng: np.random.Generator, sigma=None):
    """Yield candidate fits (:class:`ClockFit`, refined to convergence): Levenberg-Marquardt on
    the profiled loss from random points uniform in [-1, 1]^d (scaled units: the size of the
    scene, :func:`spread_from_arrivals`), each run capped at :data:`SEARCH_NFEV` evaluations. A
    The runs end when one is exact, by the stopping rule
    (:func:`rangeslam.verdict.judge.search_complete`: the runs that converged within the cap
    are the starts, their distinct answers that the data do not rule out against the lowest
    the minima, :meth:`_Minima.contending`; two the same by the judge's test,
    :func:`same_clock_answer` with ``sigma`` the noise in scaled units if known), or after
    ``runs`` runs; then the lowest minimum is yielded, refined, "confirmed" when a second run
    reached it or the rule (not the budget) ended the runs (as calibrate's judged search). (A yield as soon as two runs reached the lowest so far stopped one of 30 K = 11
    subsets of the xtdoa data on a minimum 33 cm off, against 10 cm from the whole search;
    counting every distinct minimum, the real data's many worse ones, 24 of 46 converged runs
    at K = 11, kept the rule from ending before the 60 runs: 3.4 times the time at K = 8.)"""
    n_pts = model.m + int(model.pairs[:, 1].max()) + 1
    exact_ssr = EXACT_RTOL**2 * len(model.t)
    seen, n, complete = _Minima.at(model, sigma), 0, False
    for _ in range(runs):
        n += 1
        theta, ssr, converged = _fit(model, rng.uniform(-1.0, 1.0, n_pts * model.dim), SEARCH_NFEV)
        if not np.all(np.isfinite(theta)):
            continue
        seen.add(model, theta, ssr, converged, sigma)
        complete = search_complete(seen.starts, seen.contending(model, sigma))
        if seen.lowest.best[1] <= exact_ssr or complete:
            break
    if seen.lowest.best is None:
        yield ClockFit(np.full(n_pts * model.dim, np.nan), math.inf, False, n)
    else:
        yield _refined(model, seen.lowest.best, seen.lowest.confirmed or complete, n)


def _refined(model: ProfiledUnfolding, best, confirmed: bool, runs: int) -> ClockFit:
    theta, ssr, _ = _fit(model, best[0], None)
    if not ssr <= best[1]:
        theta, ssr = best
    return ClockFit(theta, ssr, confirmed, runs)


def rough_fit(
    arrivals: np.ndarray,
    observed: np.ndarray,
    dim: int,
    runs: int,
    max_nfev: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The lowest of ``runs`` capped least-squares runs (``max_nfev`` evaluations each) of the
    profiled loss, one event offset per column, from random starts: (receivers (M, d), receiver
    offsets (M,)), metres. Not an estimate (no search to convergence, no verdict): a fit of all
    the data, outliers included, whose residuals rank the events for a consensus
    (:func:`rangeslam.mdu.offset_outliers.rank_events`)."""
    m, k = arrivals.shape
    scale = spread_from_arrivals(arrivals, observed)
    model = ProfiledUnfolding(arrivals, observed, np.arange(k), dim, scale)
    best = None
    for _ in range(runs):
        theta, ssr, _ = _fit(model, rng.uniform(-1.0, 1.0, (m + k) * dim), max_nfev)
        if np.all(np.isfinite(theta)) and (best is None or ssr < best[1]):
            best = (theta, ssr)
    if best is None:
        raise SolverError(f"every one of {runs} least-squares runs diverged")
    pts = best[0].reshape(-1, dim) * scale
    return pts[:m], model.offsets(best[0])[0] * scale


def joint_jacobian(model: ProfiledUnfolding, theta: np.ndarray) -> np.ndarray:
    """(P, (M + K) d + M - 1 + G) Jacobian of (C1)'s residuals in points, receiver offsets a_1..
    a_{M-1} (a_0 held: the common shift removed) and event offsets, scaled units."""
    pts = theta.reshape(-1, model.dim)
    jac = unfolding_jacobian(pts, model.m, model.pairs)
    return np.hstack([jac, model.design[:, 1 : model.m], model.design[:, model.m :]])


def clock_verdict(
    model, fit: ClockFit, corrected, observed, noise_std, need: int, *, tail: bool = True
):
    """(status, message) of a fit: the residual test (or, without noise_std, the vote of two runs
    and an RMS below RELATIVE_RMS of the scene), the redundancy, the rank of the joint
    Jacobian beyond the rigid motions (``need``), then
    :func:`rangeslam.mdu.core.unfolding_check` with the M - 1 + G offsets as unknowns (``tail``:
    whether its residual-tail test is made; False on a robust fit's inliers)."""
    scale, m = model.scale, model.m
    n_obs = len(model.t)
    rms = math.sqrt(fit.ssr / n_obs) * scale
    noise = None if noise_std is None else noise_std / scale
    n_off = model.design.shape[1] - 1
    n_pts = len(fit.theta) // model.dim
    passed = passes_residual_test(
        fit.ssr, n_obs, n_pts, model.dim, noise, EXACT_RTOL, n_offsets=n_off
    )
    vote = noise_std is None and fit.confirmed and rms <= RELATIVE_RMS * scale
    if not (passed or vote):
        status = Status.INCONSISTENT if noise_std is not None else Status.NO_AGREEMENT
        return status, f"no run passed the residual test: best RMS residual {rms:.3g} m"
    if n_obs == need:
        return Status.NOT_IDENTIFIABLE, "no redundant arrivals: the data cannot tell the solutions"
    sv = np.linalg.svd(joint_jacobian(model, fit.theta), compute_uv=False)
    rank = int(np.sum(sv > RANK_RTOL * sv[0]))
    if rank < need:
        return Status.NOT_IDENTIFIABLE, (
            f"the Jacobian has rank {rank} < {need}: the points or offsets are not determined"
        )
    pts = fit.theta.reshape(-1, model.dim) * scale
    offset_columns = np.hstack([model.design[:, 1:m], model.design[:, m:]])
    check = unfolding_check(
        pts[:m], pts[m:], corrected, observed, noise_std, EXACT_RTOL * scale,
        offset_columns=offset_columns, what="the calibration", judge_sources="none", tail=tail,
    )  # fmt: skip
    return check.status, check.reason


def clock_offsets_crlb(
    receivers: np.ndarray,
    sources: np.ndarray,
    sigma: float,
    *,
    groups: np.ndarray | None = None,
    mask: np.ndarray | None = None,
) -> float:
    """RMS Cramer-Rao bound (metres) on the receivers of (C1), all offsets unknown.

    The Fisher information of the points with the offsets eliminated (Schur complement: the
    Jacobian projected off the offsets' design, as :class:`ProfiledUnfolding`), its rigid motions
    removed by a pseudo-inverse on their complement, then the receiver gauge of
    :func:`rangeslam.mdu_crlb` (errors after aligning the receivers rigidly).

    Args:
        receivers: (M, d), sources: (K, d), metres; sigma: arrival noise (metres).
        groups: (K,) event of each column (default: one event per column); mask: (M, K).
    """
    x, s = np.asarray(receivers, float), np.asarray(sources, float)
    m, k = len(x), len(s)
    g = np.arange(k) if groups is None else np.asarray(groups)
    observed = np.ones((m, k), bool) if mask is None else np.asarray(mask, bool)
    pairs = np.argwhere(observed)
    design = offset_design(pairs, m, g)
    u, sv, _ = np.linalg.svd(design, full_matrices=False)
    basis = u[:, sv > RANK_RTOL * sv[0]]
    pts = np.vstack([x, s])
    jac = unfolding_jacobian(pts, m, pairs)
    jac = jac - basis @ (basis.T @ jac)
    full = np.linalg.svd(rigid_motion_basis(pts), full_matrices=True)[0]
    q = full[:, rigid_motion_basis(pts).shape[1] :]
    _, sv, vt = np.linalg.svd(jac @ q, full_matrices=False)
    half = q @ (vt.T / sv) * sigma  # F^+ = half half^T, no explicit inverse
    proj = receiver_gauge_projection(x, s)
    half = (proj @ half)[: m * x.shape[1]]
    return float(np.sqrt(np.sum(half**2) / m))


def one_blas_thread():
    """A context with one BLAS thread (threadpoolctl, when installed): the matrices here are
    small, and on a busy 2-core machine OpenBLAS's threads made a K = 18 solve 5x slower (median
    of 4: 4.4 s against 1.6 s, measured beside another process)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scipy's usual stacks
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _search_and_judge(model, observed, groups, noise_std, need: int, runs: int, rng):
    """(fit, status, message): the candidates of :func:`clock_candidates`, each judged by
    :func:`clock_verdict`, until one is not rejected by its residuals (restarts judged by the
    verdict: a minimum the residuals reject is a wrong one)."""
    arrivals = np.zeros(observed.shape)
    arrivals[observed] = model.t * model.scale
    sigma = None if noise_std is None else noise_std / model.scale
    for fit in clock_candidates(model, runs, as_rng(rng), sigma):
        if not np.isfinite(fit.ssr):
            raise SolverError(f"every one of {fit.runs} least-squares runs diverged")
        a, b = (v * model.scale for v in model.offsets(fit.theta))
        corrected = np.where(observed, arrivals - a[:, None] - b[groups][None, :], 0.0)
        status, message = clock_verdict(model, fit, corrected, observed, noise_std, need)
        if status not in RETRY:
            break
    return fit, status, message


def refine_from(model: ProfiledUnfolding, theta0: np.ndarray) -> ClockFit:
    """Levenberg-Marquardt on the profiled loss to convergence from ``theta0`` (scaled points)."""
    theta, ssr, _ = _fit(model, theta0, None)
    return ClockFit(theta, ssr, False, 1)


@dataclass(frozen=True)
class ClockProblem:
    """The validated inputs of :func:`calibrate_with_clock_offsets`."""

    ranges: np.ndarray  # (M, K) metres, 0 where unobserved
    observed: np.ndarray  # (M, K) bool
    groups: np.ndarray  # (K,) 0..G-1
    dim: int
    noise_std: float | None
    c: float | None
    runs: int

    def need(self, kept: np.ndarray | None = None) -> int:
        """Unknowns of the events ``kept`` (K,) bool (default all)."""
        kept = np.ones(len(self.groups), bool) if kept is None else kept
        n_groups = len(np.unique(self.groups[kept]))
        return unknowns_with_clock_offsets(
            self.ranges.shape[0], int(kept.sum()), n_groups, self.dim
        )


def parse_clock_problem(ranges, groups, dim, mask, noise_std, c, runs) -> ClockProblem:
    """The front door: every input checked once; too few arrivals refused with the count."""
    dim = as_dim(dim)
    shape = as_float_array(ranges, "ranges").shape
    if len(shape) != 2:
        raise InvalidInputError(f"ranges must be an (M, K) array; got {shape_str(shape)}")
    observed = as_mask(mask, "mask", shape=shape)
    r = pseudoranges(ranges, "ranges", shape, observed)
    (m, k), g = shape, as_groups(groups, shape[1])
    n_groups = int(g.max()) + 1
    check_determined(observed, dim, "mask" if mask is not None else "ranges")
    need = unknowns_with_clock_offsets(m, k, n_groups, dim)
    if observed.sum() < need:
        raise InvalidInputError(
            f"{int(observed.sum())} observed ranges for {need} unknowns ({m} receivers and {k} "
            f"sources in {dim}-D up to a rigid motion, {n_groups} event offsets and {m} receiver "
            f"offsets less their common shift: (M + K) d - d (d + 1) / 2 + G + M - 1)"
        )
    noise_std, c = check_noise_std(noise_std), as_speed(c)
    runs = check_int(runs, "random_starts", 1)
    return ClockProblem(r, observed, g, dim, noise_std, c, runs)


def calibrate_with_clock_offsets(
    ranges, groups, *, dim, mask, noise_std, c, runs, rng, robust: bool = False
) -> UnknownEmissionCalibration:
    """:func:`rangeslam.mdu.emission.calibrate_unknown_emission` with ``receiver_offsets=True``
    (see there; ``runs``: the search runs of :func:`clock_candidates`; ``robust``: the outliers
    found by :mod:`rangeslam.mdu.offset_outliers`)."""
    problem = parse_clock_problem(ranges, groups, dim, mask, noise_std, c, runs)
    if robust:
        return _robust_calibration(problem, as_rng(rng))
    r, observed, g = problem.ranges, problem.observed, problem.groups
    model = ProfiledUnfolding(r, observed, g, problem.dim, spread_from_arrivals(r, observed))
    with one_blas_thread():
        fit, status, message = _search_and_judge(
            model, observed, g, problem.noise_std, problem.need(), problem.runs, rng
        )
    return clock_result(problem, model, fit, observed, status, message)


def clock_result(problem: ClockProblem, model, fit: ClockFit, inliers, status, message):
    """The :class:`UnknownEmissionCalibration` in metres and the canonical frame, for a fit of
    ``model`` to the ``inliers`` (M, K) of ``problem``; events without inliers get NaN."""
    r, observed, dim, m = problem.ranges, problem.observed, problem.dim, problem.ranges.shape[0]
    kept = inliers.any(axis=0)
    g_all = problem.groups
    n_groups = int(g_all.max()) + 1
    ids, g = np.unique(g_all[kept], return_inverse=True)
    a, b_kept = (v * model.scale for v in model.offsets(fit.theta))
    b = np.full(n_groups, np.nan)
    b[ids] = b_kept
    pts = fit.theta.reshape(-1, dim) * model.scale
    receivers, sources_kept, _ = canonical_frame(pts[:m], pts[m:])
    sources = np.full((len(g_all), dim), np.nan)
    sources[kept] = sources_kept
    fitted = np.full(r.shape, np.nan)
    fitted[:, kept] = range_matrix(pts[:m], pts[m:]) + a[:, None] + b_kept[g][None, :]
    residuals = np.where(observed, fitted - r, np.nan)
    n_obs, need = int(inliers.sum()), problem.need(kept)
    c = problem.c
    return UnknownEmissionCalibration(
        receivers=frozen(receivers),
        sources=frozen(sources),
        offsets=frozen(b),
        offset_times=frozen(b / c if c is not None else np.full(n_groups, np.nan)),
        residuals=frozen(residuals),
        observed=frozen(observed),
        residual_rms=math.sqrt(fit.ssr / n_obs) * model.scale,
        noise_estimate=(
            math.sqrt(fit.ssr / (n_obs - need)) * model.scale if n_obs > need else float("nan")
        ),
        redundancy=int(n_obs - need),
        status=status,
        message=message,
        attempts=0,
        random_starts=int(fit.runs),
        receiver_offsets=frozen(a),
        inliers=frozen(inliers.copy()),
    )


def _inlier_model(problem: ClockProblem, use: np.ndarray) -> ProfiledUnfolding:
    """The profiled loss of the inliers ``use`` (M, K) on the events that keep any."""
    kept = use.any(axis=0)
    _, g = np.unique(problem.groups[kept], return_inverse=True)
    r = problem.ranges[:, kept]
    return ProfiledUnfolding(r, use[:, kept], g, problem.dim, spread_from_arrivals(r, use[:, kept]))


def _robust_rounds(problem: ClockProblem, rng):
    """Steps 2 and 3 of :mod:`rangeslam.mdu.offset_outliers` from the consensus, alternated until
    the inlier set is stable: (model, fit, inliers, consensus, note). After the first refit the
    inlier threshold uses the refit's noise estimate (sum of squares over the inliers' redundancy)
    unless ``noise_std`` is known."""
    from rangeslam.mdu import offset_outliers as oo

    r, observed, dim, m = problem.ranges, problem.observed, problem.dim, problem.ranges.shape[0]
    cons = oo.consensus_search(r, observed, dim, oo.MAX_HYPOTHESES, rng)
    placement, receivers, sigma, last = cons.placement, cons.receivers, problem.noise_std, None
    for _ in range(oo.MAX_ROUNDS):
        use, threshold = oo.grow_inliers(placement, observed, dim, sigma)
        if last is not None and np.array_equal(use, last[2]):
            return (*last, cons, "")
        kept = use.any(axis=0)
        short = _too_few_inliers(problem, use, kept)
        if short:
            if last is None:
                raise SolverError(f"the consensus left too few inliers: {short}")
            return (*last, cons, f"growth stopped ({short}); ")
        model = _inlier_model(problem, use)
        theta0 = np.vstack([receivers, placement.sources[kept]]) / model.scale
        fit = refine_from(model, theta0.ravel())
        pts = fit.theta.reshape(-1, dim) * model.scale
        receivers, a = pts[:m], model.offsets(fit.theta)[0] * model.scale
        if problem.noise_std is None:
            sigma = math.sqrt(fit.ssr / (use.sum() - problem.need(kept))) * model.scale
        placement = oo.place_events(receivers, a, r, observed, threshold, rng)
        last = (model, fit, use)
    return (*last, cons, f"inlier set still changing after {oo.MAX_ROUNDS} rounds; ")


def _too_few_inliers(problem: ClockProblem, use: np.ndarray, kept: np.ndarray) -> str:
    """Why the inliers ``use`` (M, K) cannot be fitted with redundancy, or "" when they can."""
    try:
        check_determined(use[:, kept], problem.dim, "the inlier set")
    except InvalidInputError as exc:
        return str(exc)
    if use.sum() <= problem.need(kept):
        return f"{int(use.sum())} inlier arrivals for {problem.need(kept)} unknowns"
    return ""


def _robust_calibration(problem: ClockProblem, rng) -> UnknownEmissionCalibration:
    """The robust run (:mod:`rangeslam.mdu.offset_outliers`) and its verdict (without
    ``noise_std``, the vote is the consensus's: a second subset reached its answer)."""
    from rangeslam.mdu.offset_outliers import robust_status

    with one_blas_thread():
        model, fit, use, cons, note = _robust_rounds(problem, rng)
        fit = ClockFit(fit.theta, fit.ssr, cons.confirmed, cons.subsets)
        kept = use.any(axis=0)
        a, b = (v * model.scale for v in model.offsets(fit.theta))
        _, g = np.unique(problem.groups[kept], return_inverse=True)
        r = problem.ranges[:, kept]
        corrected = np.where(use[:, kept], r - a[:, None] - b[g][None, :], 0.0)
        status, message = clock_verdict(
            model, fit, corrected, use[:, kept], problem.noise_std, problem.need(kept), tail=False
        )
    n_obs = int(problem.observed.sum())
    status, message = robust_status(
        status, note + message, n_obs - int(use.sum()), n_obs, n_obs - problem.need()
    )
    return clock_result(problem, model, fit, use, status, message)
