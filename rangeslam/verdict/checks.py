"""The checks behind every estimator's verdict: identifiable, consistent with the noise, no
unexplained outliers.

"Converged" must mean right as far as the data can tell, never "a small residual". Each check
takes what an estimator has at its answer (range residuals, their Jacobian, the gauge, the noise
level if known) and returns a :class:`Check`: a :class:`rangeslam.status.Status` and, when it is
not CONVERGED, the reason in words. An estimator runs the checks of its model in the order
identifiable, consistent, outliers and reports the first that fails.

- :func:`information_check`: the Fisher information J^T J / sigma^2 of the model actually solved
  (ranges plus any prior rows), restricted analytically to the complement of the gauge (the rigid
  motions), must have full rank by a tolerance relative to its own spectrum, and the RMS standard
  deviation it implies must be a small fraction of the scene (``PRECISION_FRACTION``): a problem
  determined "to first order" but only to decimetres is not identifiable from these data.
  :func:`weak_moves` gives the points where an estimator repeats that test (the level's
  :func:`level_sigmas` standard deviations along each direction), since near-singular geometry
  can make the bound at the answer far smaller than at the truth.
- :func:`consistency_check`: with ``noise_std``, the chi-square test of the sum of squared residuals
  on the redundancy; without it, the residuals' RMS against the scene size and against their own
  robust (MAD) scale, and the studentised tail (:func:`tail_check`, also on its own), so that a
  fit dragged by wrong picks is caught.
- :func:`ambiguity_check`: a second minimum (a mirror image) that fits the data as well as the
  answer, by the judge's test: the cost difference in units of the noise, on the data and on
  the noise-free ranges the answer predicts (:func:`expected_mirror_gap`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, norm

from rangeslam._robust import mad_sigma, studentized
from rangeslam.status import Status
from rangeslam.verdict.judge import cost_level, indistinguishable
from rangeslam.verdict.thresholds import (
    CHI2_LEVEL,
    NOISE_QUANTILE,
    PRECISION_FRACTION,
    RANK_RTOL,
    RELATIVE_RMS,
    ROBUST_RATIO,
    TAIL_SCALE_FLOOR,
)

__all__ = [
    "PASSED",
    "Check",
    "ambiguity_check",
    "consistency_check",
    "expected_mirror_gap",
    "first_failure",
    "flat_limit",
    "flatness_check",
    "gauge_free_covariance",
    "information_check",
    "level_sigmas",
    "mirror_gap",
    "mirror_point",
    "noise_upper_bound",
    "point_check",
    "probed_failure",
    "range_gauss_newton",
    "reflected",
    "rms_precision",
    "tail_check",
    "tail_limit",
    "unit_turn_bound",
    "verdict_noise",
    "weak_moves",
]


@dataclass(frozen=True)
class Check:
    """One check's outcome: ``status`` (CONVERGED when it passed) and ``reason`` (why not; for a
    passed check, at most a note on what was not judged)."""

    status: Status
    reason: str = ""

    @property
    def passed(self) -> bool:
        return self.status is Status.CONVERGED


PASSED = Check(Status.CONVERGED)


def first_failure(*checks: Check) -> Check:
    """The first check that did not pass, else a passed check."""
    return next((c for c in checks if not c.passed), PASSED)


def gauge_free_covariance(
    jac: np.ndarray, gauge_basis: np.ndarray | None
) -> tuple[np.ndarray | None, int]:
    """(p, p) the pseudo-inverse of J^T J (``jac`` (N, p)) on the orthogonal complement of the
    columns of ``gauge_basis`` (p, g) (directions free by construction), and the number of zero
    directions beyond the gauge (by RANK_RTOL relative to the largest singular value). The
    covariance is None when that number is not 0."""
    if gauge_basis is None or gauge_basis.shape[1] == 0:
        complement = np.eye(jac.shape[1])
    else:
        q, _ = np.linalg.qr(gauge_basis, mode="complete")
        complement = q[:, np.linalg.matrix_rank(gauge_basis) :]
    _, sv, vt = np.linalg.svd(jac @ complement, full_matrices=False)
    n_free = complement.shape[1]
    n_zero = n_free - int(np.sum(sv > RANK_RTOL * (sv[0] if sv.size else 0.0)))
    if n_zero:
        return None, n_zero
    basis = complement @ vt.T / sv
    return basis @ basis.T, 0


def verdict_noise(noise_std: float | None, estimate: float | None, exact_rms: float):
    """The range noise a verdict works with, metres: ``noise_std`` when given, 0 meaning exact
    data (then the exact-data RMS ``exact_rms``: round-off only); else ``estimate`` (from the
    residuals; None when they say nothing). One meaning of ``noise_std`` for every estimator:
    None is unknown, 0 is exact."""
    if noise_std is None:
        return estimate
    return max(float(noise_std), exact_rms)


def noise_upper_bound(ssr: float, redundancy: int) -> float | None:
    """The largest range noise the residuals do not rule out: sqrt(ssr / q) with q the
    NOISE_QUANTILE quantile of chi-square on ``redundancy`` degrees of freedom, metres (1.2 times
    sqrt(ssr / redundancy) at 50, 16 times at 1: a few residuals say little about the noise);
    None without redundancy (the residuals then say nothing about it)."""
    if redundancy <= 0:
        return None
    return float(np.sqrt(ssr / chi2.ppf(NOISE_QUANTILE, redundancy)))


def information_check(
    jac: np.ndarray,
    gauge_basis: np.ndarray | None,
    sigma: float | None,
    scale: float,
    what: str,
    *,
    dim: int,
    rows: np.ndarray | None = None,
    projection: np.ndarray | None = None,
    covariance: tuple[np.ndarray | None, int] | None = None,
) -> Check:
    """Rank of the information beyond the gauge, then the precision it implies.

    Args:
        jac: (N, p) Jacobian of the residuals with respect to the p unknowns at the answer, rows
            scaled so that the information is J^T J / sigma^2 (range rows as they are, prior rows
            multiplied by sigma / their own sigma).
        gauge_basis: (p, g) directions left free by construction (rigid motions), or None.
        sigma: the range noise (given, or estimated from the residuals), metres; None or 0 skips
            the precision test (exact data, or no redundancy to estimate it).
        scale: the scene size (median range), metres.
        what: what the unknowns are, for the reason ("the trajectory", "the point").
        dim: coordinates per point (the precision is an RMS over points).
        rows: (q,) indices of the unknowns whose precision is judged, d per point (default all).
        projection: (p, p) map of an error to the gauge those unknowns are judged in (e.g.
            :func:`rangeslam.geometry.rigid_motion.receiver_gauge_projection`), or None.
        covariance: :func:`gauge_free_covariance` of ``jac`` and ``gauge_basis`` when the
            caller already has it (else computed here).
    """
    cov, n_zero = covariance or gauge_free_covariance(jac, gauge_basis)
    if cov is None:
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"{what} is not determined by these data: the information has {n_zero} zero "
            "direction(s) beyond the rigid motions",
        )
    if not sigma:
        return PASSED
    rms_std = rms_precision(cov, sigma, dim, rows, projection)
    if rms_std > PRECISION_FRACTION * scale:
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"{what} is only weakly determined: the data fix it to {rms_std:.3g} m RMS (1 sigma "
            f"at {sigma:.3g} m range noise), more than {PRECISION_FRACTION:.1%} of the scene "
            f"size {scale:.3g} m",
        )
    return PASSED


def rms_precision(
    cov: np.ndarray,
    sigma: float,
    dim: int,
    rows: np.ndarray | None = None,
    projection: np.ndarray | None = None,
) -> float:
    """RMS standard deviation per point, metres, of the unknowns ``rows`` (d per point, default
    all) under ``sigma`` (metres) times ``cov`` (p, p) (the information's pseudo-inverse for unit
    noise), first mapped by ``projection`` (p, p) into the gauge they are judged in."""
    if projection is not None:
        cov = projection @ cov @ projection.T
    rows = np.arange(cov.shape[0]) if rows is None else rows
    n_points = max(len(rows) // dim, 1)
    return float(sigma * np.sqrt(max(np.trace(cov[np.ix_(rows, rows)]), 0.0) / n_points))


def weak_moves(cov: np.ndarray, sigma: float, rows: np.ndarray) -> list[np.ndarray]:
    """Moves (p,) of all p unknowns by :func:`level_sigmas` standard deviations (``sigma`` times
    the square root of an eigenvalue lambda of the unit-noise ``cov`` (p, p) restricted to
    ``rows``) along each direction u of the unknowns ``rows``, weakest first, both signs: where
    the truth may lie at the verdicts' level. Each move carries the other unknowns along by
    their regression on those rows (the conditional mean: cov[:, rows] u / lambda per unit move
    along u). Eigenvalues under RANK_RTOL of the largest (the gauge's round-off) give no move."""
    block = cov[np.ix_(rows, rows)]
    eigenvalues, vectors = np.linalg.eigh(block)
    keep = eigenvalues > RANK_RTOL * eigenvalues[-1]
    values, directions = eigenvalues[keep][::-1], vectors[:, keep][:, ::-1]
    columns = level_sigmas() * sigma * (cov[:, rows] @ directions) / np.sqrt(values)
    return [sign * move for move in columns.T for sign in (1.0, -1.0)]


def probed_failure(check: Check, own: float) -> Check:
    """``check`` (a failed precision test at an answer moved by :func:`weak_moves`) with its
    reason saying so; ``own`` is the RMS standard deviation at the answer itself, metres."""
    return Check(
        check.status,
        f"{check.reason}, {level_sigmas():.3g} standard deviations from the answer along one of "
        f"its weak directions (at the answer: {own:.3g} m); the precision holds only at the "
        "answer itself",
    )


def consistency_check(
    residuals: np.ndarray,
    jac: np.ndarray | None,
    redundancy: int,
    noise_std: float | None,
    scale: float,
    exact_rms: float,
    *,
    tail: bool = True,
) -> Check:
    """Do the residuals (N,) fit the noise? With ``noise_std`` the chi-square test; without it
    the RMS against ``scale`` and against the robust scale, and the studentised tail.

    ``jac`` (N, p) (the residuals' Jacobian, any scaling) gives the leverages of the studentised
    residuals; None takes them as equal. ``exact_rms`` (metres): residuals at round-off level
    always pass. ``redundancy``: residuals minus unknowns beyond the gauge. ``tail=False``
    skips the tail tests (the inliers of a robust fit: their tail was cut by its rejection)."""
    n = residuals.size
    ssr = float(residuals @ residuals)
    rms = float(np.sqrt(ssr / max(n, 1)))
    if rms <= exact_rms or redundancy <= 0:
        return PASSED
    if noise_std == 0:  # exact data, and these residuals are more than round-off
        return Check(
            Status.INCONSISTENT,
            f"the residual test failed: RMS residual {rms:.3g} m for exact data (noise_std 0)",
        )
    if noise_std:
        tail_result = tail_check(residuals, jac, noise_std, scale) if tail else PASSED
        limit = float(chi2.ppf(CHI2_LEVEL, redundancy)) * noise_std**2
        if tail_result.passed and ssr > limit:
            return Check(
                Status.INCONSISTENT,
                f"the residual test failed: RMS residual {rms:.3g} m for noise_std {noise_std:.3g} m",
            )
        return tail_result
    if rms > RELATIVE_RMS * scale:
        return Check(
            Status.INCONSISTENT,
            f"RMS residual {rms:.3g} m is more than {RELATIVE_RMS:.0%} of the scene size",
        )
    return tail_check(residuals, jac, None, scale) if tail else PASSED


def level_sigmas() -> float:
    """The verdicts' level as a number of standard deviations of one quantity: the two-sided
    normal quantile, sqrt of the chi-square(1) quantile at CHI2_LEVEL (3.29 at 0.999), the
    judge's cost level for one range (:func:`rangeslam.verdict.judge.cost_level`). A range is an
    inlier while its residual is within this many noise standard deviations (every outlier
    rejection, MSAC's hypotheses, a robust kernel's kept ranges); the truth may lie this many
    standard deviations from the answer along any one direction (the probe of
    :func:`weak_moves`)."""
    return float(np.sqrt(cost_level()))


def tail_limit(n: int) -> float:
    """The largest of ``n`` studentised residuals, in units of their robust (MAD) scale, that
    Gaussian noise explains: the Bonferroni quantile at the verdicts' one level (family-wise
    false-alarm rate 1 - CHI2_LEVEL over the n residuals), widened by twice the MAD scale's own
    relative uncertainty (about 1.2 / sqrt(n); measured: 1.4% false alarms on 40 Gaussian
    residuals without the widening, for a nominal 0.1%)."""
    return float(norm.isf((1.0 - CHI2_LEVEL) / (2 * n))) * (1 + 2.4 / np.sqrt(n))


def tail_check(
    residuals: np.ndarray, jac: np.ndarray | None, noise_std: float | None, scale: float
) -> Check:
    """OUTLIERS when the largest studentised residual is beyond the Bonferroni quantile in units
    of the residuals' robust (MAD) scale, or, without a known noise level, the RMS is
    ROBUST_RATIO times that scale. (The level of the noise is the chi-square test's business.)"""
    n = residuals.size
    if n < 5:  # too few residuals for a robust scale or a tail
        return PASSED
    abs_res = np.abs(residuals)
    jac = np.ones((n, 1)) if jac is None else jac
    stud = studentized(abs_res, jac, np.ones(n, dtype=bool))
    finite = stud[np.isfinite(stud)]
    if finite.size < 5:
        return PASSED
    # The tail is judged by the residuals' own scale (its shape), floored at TAIL_SCALE_FLOOR of
    # the scene: echo picks interpolated between samples are exact to a fraction of a sample,
    # so their MAD is near zero, yet they err by millimetres now and then (a 16 kHz sample is
    # 21 mm; measured up to 3 mm on simulated RIRs): no wrong picks.
    robust = max(mad_sigma(finite), TAIL_SCALE_FLOOR * scale)
    limit = tail_limit(finite.size)
    worst = float(np.max(finite)) / robust
    rms = float(np.sqrt(np.mean(finite**2)))
    if worst > limit or (noise_std is None and rms > ROBUST_RATIO * robust):
        return Check(
            Status.OUTLIERS,
            f"the residuals have a heavy tail: the largest is {worst:.3g} standard deviations "
            f"(limit {limit:.3g}), RMS {rms:.3g} m against a robust scale of {robust:.3g} m; wrong "
            "picks are likely (use robust=True, or find them)",
        )
    return PASSED


def ambiguity_check(
    cost_gap: float,
    sigma: float | None,
    exact_rms: float,
    what: str,
    *,
    expected_gap: float | None = None,
) -> Check:
    """NOT_IDENTIFIABLE when a second minimum (e.g. the mirror image) cannot be told from the
    answer by the judge's test (:func:`rangeslam.verdict.judge.indistinguishable`): its cost gap
    on the data, or the gap it shows on the ranges the answer predicts, is within the cost level
    (:func:`rangeslam.verdict.judge.cost_level`) in noise variances.

    ``cost_gap``: its sum of squared range residuals minus the answer's, metres^2;
    ``expected_gap``: the same on the noise-free ranges the answer predicts (its own residuals
    zero), metres^2, None when not made; ``sigma``: the range noise (given or estimated),
    metres; None or 0 (exact data) uses ``exact_rms``."""
    variance = max(sigma or 0.0, exact_rms) ** 2
    expected = None if expected_gap is None else expected_gap / variance
    if indistinguishable(cost_gap / variance, expected):
        shown = "" if expected_gap is None else f", {expected_gap:.3g} m^2 on noise-free ranges"
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"{what} and its mirror image fit the data equally well (their costs differ by "
            f"{cost_gap:.3g} m^2{shown}; the data tell apart {cost_level():.3g} noise "
            f"variances, {cost_level() * variance:.3g} m^2)",
        )
    return PASSED


def range_gauss_newton(
    z: np.ndarray, anchors: np.ndarray, ranges: np.ndarray, *, offset: bool = False, steps=20
) -> np.ndarray:
    """Up to ``steps`` Gauss-Newton steps on the range residuals ||x - a_m|| [+ b] - r_m from
    ``z`` = x (d,), or (x, b) (d + 1,) with ``offset``; anchors (N, d), ranges (N,). Stops once a
    step is below 1e-12 of the largest distance."""
    for _ in range(steps):
        x = z[:-1] if offset else z
        diff = x - anchors
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
        jac = diff / dist[:, None]
        res = dist - ranges
        if offset:
            jac = np.hstack([jac, np.ones((len(anchors), 1))])
            res = res + z[-1]
        step = np.linalg.lstsq(jac, -res, rcond=None)[0]
        z = z + step
        if np.linalg.norm(step) <= 1e-12 * max(float(np.max(dist)), 1e-300):
            break
    return z


def range_cost(z: np.ndarray, anchors: np.ndarray, ranges: np.ndarray) -> float:
    """Sum of squared range residuals ||x - a_m|| [+ b] - r_m at ``z`` = x (d,) or (x, b)
    (d + 1,) (the size tells), anchors (N, d), ranges (N,); NaN where ``z`` is not finite."""
    d = anchors.shape[1]
    res = np.linalg.norm(z[:d] - anchors, axis=1) - ranges + (z[d] if z.size > d else 0.0)
    return float(res @ res)


def reflected(points: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """``points`` (P, d) reflected through the best-fit plane (line in 2-D) of ``anchors``
    (N, d): the other side, for anchors that cannot tell the sides apart."""
    centre = anchors.mean(axis=0)
    normal = np.linalg.svd(anchors - centre)[2][-1]
    return points - 2.0 * ((points - centre) @ normal)[:, None] * normal


def mirror_point(
    point: np.ndarray, anchors: np.ndarray, ranges: np.ndarray, offset: float | None = None
) -> np.ndarray | None:
    """The other side of ``point`` (d,): its reflection through the best-fit plane (line in 2-D)
    of ``anchors`` (N, d), refined locally on the ``ranges`` (N,) (with a range ``offset`` b,
    metres, ranges = ||x - a|| + b: the point and b are refined together and (d + 1,) returned);
    None when the refinement returns to the point's basin (within 1% of the anchors' RMS spread)
    or with fewer than d anchors (no plane to reflect through)."""
    if len(anchors) < point.size:
        return None
    start = reflected(point[None], anchors)[0]
    if offset is not None:
        start = np.r_[start, offset]
    mirror = range_gauss_newton(start, anchors, ranges, offset=offset is not None)
    if not range_cost(mirror, anchors, ranges) <= range_cost(start, anchors, ranges):
        # undamped Gauss-Newton overshot (a point near the plane of exactly coplanar anchors has
        # no first-order information across it): the reflection, which fits as well, stands
        mirror = start
    centred = anchors - anchors.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    if np.linalg.norm(mirror[: point.size] - point) < 1e-2 * spread:
        return None
    return mirror


def mirror_gap(
    point: np.ndarray, anchors: np.ndarray, ranges: np.ndarray, offset: float | None = None
) -> float:
    """How much worse the point's mirror image (:func:`mirror_point`) fits: its sum of squared
    range residuals minus the point's own; units of ``ranges`` (N,) squared. With a range
    ``offset`` b (metres) the residuals are ||x - a|| + b - r and the mirror has its own b.
    Infinite when there is no mirror image."""
    mirror = mirror_point(point, anchors, ranges, offset)
    if mirror is None:
        return float("inf")
    own = point if offset is None else np.r_[point, offset]
    return range_cost(mirror, anchors, ranges) - range_cost(own, anchors, ranges)


def expected_mirror_gap(
    point: np.ndarray, anchors: np.ndarray, offset: float | None = None
) -> float:
    """:func:`mirror_gap` on the noise-free ranges the point predicts (||x - a|| [+ b]): the gap
    the data could be expected to show between the point and its mirror image (the
    noncentrality of their likelihood ratio, metres^2). Small where the anchors are nearly
    coplanar, whatever gap the noise happened to give."""
    predicted = np.linalg.norm(anchors - point, axis=1) + (0.0 if offset is None else offset)
    return mirror_gap(point, anchors, predicted, offset)


def point_check(
    point: np.ndarray,
    anchors: np.ndarray,
    ranges: np.ndarray,
    sigma: float | None,
    exact_rms: float,
    scale: float,
    what: str,
    *,
    precision: bool = True,
) -> Check:
    """One point (d,) against its fixed ``anchors`` (N, d) and ``ranges`` (N,): its information
    (rank and, with ``precision``, the precision at ``sigma``) and its mirror image through the
    anchors' plane."""
    if len(anchors) < point.size:
        return Check(Status.NOT_IDENTIFIABLE, f"{what} has only {len(anchors)} ranges")
    diff = point - anchors
    jac = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-300)[:, None]
    return first_failure(
        information_check(jac, None, sigma if precision else None, scale, what, dim=point.size),
        ambiguity_check(
            mirror_gap(point, anchors, ranges),
            sigma,
            exact_rms,
            what,
            expected_gap=expected_mirror_gap(point, anchors),
        ),
    )


def unit_turn_bound(step: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """How far the unit vector between two points ``distance`` apart can move (the chord on the
    unit sphere) when one moves relative to the other by ``step`` (both metres, broadcast):
    2 sin(arcsin(step / distance) / 2) while the step is shorter than the distance (the largest
    angle is then the tangent's), 2 (the diameter) otherwise. The row change of a range Jacobian
    in Weyl's inequality, which bounds how far its singular values can fall
    (:func:`rangeslam.mdu.core.moves_that_could_fail`,
    :func:`rangeslam.localization.point_judge.region_precision`)."""
    step, distance = np.asarray(step, dtype=float), np.asarray(distance, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(distance > step, step / distance, 1.0)
    return np.where(distance > step, 2.0 * np.sin(np.arcsin(ratio) / 2.0), 2.0)


def flat_limit(sigma: float, scale: float) -> float:
    """The thinnest RMS spread (metres) below which points may be flat at range noise ``sigma``
    and scene size ``scale`` (metres): an offset t off a plane changes a range of about
    ``scale`` by t^2 / (2 scale) (second order), which the ranges resolve beyond the level's
    one-range test (:func:`level_sigmas` standard deviations): t = sqrt(2 level_sigmas() sigma
    scale), 2.57 sqrt(sigma scale) at CHI2_LEVEL."""
    return float(np.sqrt(2.0 * level_sigmas() * sigma * scale))


def flatness_check(points: np.ndarray, sigma: float | None, scale: float, what: str) -> Check:
    """NOT_IDENTIFIABLE when ``points`` (N, d) may all lie in one hyperplane (a plane in 3-D, a
    line in 2-D): their thinnest RMS spread is within what range noise ``sigma`` can bend a flat
    configuration by and the ranges not tell (:func:`flat_limit`, metres). Flat points fitted in
    d dimensions can each fold out of the hyperplane, so the data fix them only to second
    order."""
    if not sigma:
        return PASSED
    centred = points - points.mean(axis=0)
    thinnest = float(np.linalg.svd(centred, compute_uv=False)[-1]) / np.sqrt(len(points))
    limit = flat_limit(sigma, scale)
    if thinnest < limit:
        kind = "plane" if points.shape[1] == 3 else "line"
        return Check(
            Status.NOT_IDENTIFIABLE,
            f"{what} may be flat: its thinnest RMS spread {thinnest:.3g} m is under the "
            f"{limit:.3g} m that range noise of {sigma:.3g} m can bend a flat configuration by, "
            f"so the points may all lie in one {kind} (fit with dim={points.shape[1] - 1}?)",
        )
    return PASSED
