"""The unfolding shared by every MDU estimator (calibrate, slam, unknown emission times).

Eq. (9): the M x K ranges between receivers and sources are the off-diagonal block of an
(M + K) x (M + K) EDM with weight W; :func:`mdu_mask` and :func:`mdu_edm` build W and D-tilde.
The restart schedule of the convex iteration (eq. 10), the count of unknowns up to the gauge (a
rigid motion and a reflection), the canonical frame results are expressed in, the residual test
and verdict, and the rotation of covariances into that frame live here, so that every estimator
applies them the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix

from rangeslam._validation import (
    MAX_METRES,
    as_dim,
    as_float_array,
    as_mask,
    as_ranges,
    as_scalar,
    shape_str,
)
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.rigid_motion import receiver_gauge_projection, rigid_motion_basis
from rangeslam.mdu.landmark_mirrors import LandmarkMirrors, landmark_mirrors
from rangeslam.mdu.planarity import dimension_check, flat_fit_check, flat_rival_check, lifted_ssr
from rangeslam.solvers.least_squares import (
    unfolding_jacobian,
    unfolding_residuals,
)
from rangeslam.status import Status
from rangeslam.verdict import (
    PASSED,
    Check,
    consistency_check,
    first_failure,
    gauge_free_covariance,
    information_check,
    noise_upper_bound,
    point_check,
    probed_failure,
    rms_precision,
    unit_turn_bound,
    verdict_noise,
    weak_moves,
)
from rangeslam.verdict.thresholds import (
    CHI2_LEVEL,
    EXACT_RTOL,
    PRECISION_FRACTION,
    RANK_RTOL,
    RELATIVE_RMS,
    SEARCH_BUDGET,
)

__all__ = [
    "EDM_STARTS",
    "EMBEDDING_RTOL",
    "MAX_ATTEMPTS",
    "MAX_RANDOM_STARTS",
    "MAX_SDP_ITERATIONS",
    "SIGMA_FLOOR",
    "WEIGHT_FACTORS",
    "ConvexIterationOptions",
    "canonical_frame",
    "check_determined",
    "convex_iteration_runs",
    "dimension_check",
    "information_model",
    "least_steps",
    "lifted_ssr",
    "mdu_edm",
    "mdu_mask",
    "moves_that_could_fail",
    "passes_residual_test",
    "points_check",
    "region_check",
    "residual_status",
    "rotated_covariances",
    "step_prior_rows",
    "unfolding_check",
    "unknowns_up_to_rigid_motion",
    "validated_ranges",
]

if TYPE_CHECKING:
    from rangeslam.solvers.gtsam_graph import GraphFit

#: With edm_start="cheap" a convex-iteration run also stops once the rank-d part of G moved by at
#: most this fraction between two SDP solves (the refinement after it takes the points from there).
#: Without step bounds the embedding creeps by 0.3-0.5% per solve for 50 solves; 1e-2 stops such a
#: run after about 3 solves and gave the same refined answers as 1e-3 on 16 slam walks (M = 8,
#: 1 cm, bounds and none) at under half the time without bounds.
EMBEDDING_RTOL = 1e-2

#: How the EDM start is made (:class:`ConvexIterationOptions`): "cheap" or "full".
EDM_STARTS = ("cheap", "full")


# Fit weights of successive attempts, relative to fit_weight. A run that stalls at a wrong
# rank-d point with one weight often reaches the right one with another (measured on Fig. 3).
WEIGHT_FACTORS = (1.0, 10.0, 0.1, 100.0)


def mdu_mask(mask: np.ndarray) -> np.ndarray:
    """W of eq. (9): (M + K, M + K), True on the observed receiver-source pairs only."""
    m, k = mask.shape
    w = np.zeros((m + k, m + k), dtype=bool)
    w[:m, m:] = mask
    w[m:, :m] = mask.T
    return w


def mdu_edm(ranges: np.ndarray) -> np.ndarray:
    """D-tilde of eq. (9): (M + K, M + K) with the squared ranges in the off-diagonal blocks."""
    m, k = ranges.shape
    d = np.zeros((m + k, m + k))
    d[:m, m:] = ranges**2
    d[m:, :m] = (ranges**2).T
    return d


def unknowns_up_to_rigid_motion(n_points: int, dim: int) -> int:
    """Coordinates of ``n_points`` points in ``dim`` dimensions minus the rigid motions."""
    return n_points * dim - dim * (dim + 1) // 2


def check_determined(mask: np.ndarray, dim: int, name: str) -> None:
    """Refuse masks that leave the unfolding under-determined (with a message that says why)."""
    m, k = mask.shape
    n_obs = int(mask.sum())
    need = unknowns_up_to_rigid_motion(m + k, dim)
    if n_obs < need:
        raise InvalidInputError(
            f"{name} leaves the problem under-determined: {n_obs} observed ranges for {need} "
            f"unknowns ({m} receivers and {k} sources in {dim}-D, up to a rigid motion)"
        )
    for axis, what in ((1, "receiver"), (0, "source")):
        counts = mask.sum(axis=axis)
        if np.any(counts < dim):
            i = int(np.argmin(counts))
            raise InvalidInputError(
                f"{name} leaves the problem under-determined: {what} {i} has {int(counts[i])} "
                f"observed ranges; each point needs at least {dim} in {dim}-D"
            )


def canonical_frame(receivers: np.ndarray, sources: np.ndarray):
    """Move the receivers' centroid to 0 and their principal axes (largest variance first) onto
    the coordinates, each pointing so that the receivers' third moment along it is >= 0. Ranges
    cannot tell a reflection, so the frame may be left-handed; it is unique for generic arrays.

    Returns (receivers, sources, rotation): new coordinates are (p - centroid) @ rotation.
    """
    centre = receivers.mean(axis=0)
    _, vec = np.linalg.eigh(np.cov((receivers - centre).T, bias=True))
    rot = vec[:, ::-1]
    rot *= np.where(np.sum(((receivers - centre) @ rot) ** 3, axis=0) < 0, -1.0, 1.0)
    return (receivers - centre) @ rot, (sources - centre) @ rot, rot


def check_noise_std(noise_std) -> float | None:
    """The range noise standard deviation, metres: None or a real number in [0, MAX_METRES]
    (2.2e154 overflowed the chi-square test of calibrate_unknown_emission)."""
    return as_scalar(
        noise_std, "noise_std", low=0.0, high=MAX_METRES, allow_none=True,
        expected=f"in [0, {MAX_METRES:g}] metres, or None",
    )  # fmt: skip


#: Upper limits of the search's counts: beyond them a run that never passes would run for days.
MAX_ATTEMPTS = 1000
MAX_SDP_ITERATIONS = 10_000
MAX_RANDOM_STARTS = 100_000


def validated_ranges(ranges: ArrayLike, mask: ArrayLike | None, dim: int, noise_std):
    """Check the inputs shared by :func:`calibrate` and :func:`rangeslam.mdu.slam`.

    Returns (ranges (M, K) with unobserved entries 0, observed mask (M, K), median observed range).
    """
    as_dim(dim)
    r_in = as_float_array(ranges, "ranges")
    if r_in.ndim != 2:
        raise InvalidInputError(
            f"ranges must be an (M, K) array of distances; got {shape_str(r_in.shape)}"
        )
    observed = as_mask(mask, "mask", shape=r_in.shape)
    r = as_ranges(r_in, "ranges", shape=(None, None), observed=observed)
    check_determined(observed, dim, "mask" if mask is not None else "ranges")
    check_noise_std(noise_std)
    scale = float(np.median(r[observed]))
    if not scale > 0:
        raise InvalidInputError("ranges must not all be zero where observed")
    return r, observed, scale


@dataclass(frozen=True)
class ConvexIterationOptions:
    """Settings of the convex iteration (eq. 10) shared by the MDU estimators.

    Attributes:
        max_attempts: runs at most (the restart schedule of :func:`convex_iteration_runs`).
        fit_weight: lambda of eq. (10), on data scaled to unit median range.
        max_iterations: SDP solves per run.
        gap_tol: a run stops when the N - d smallest eigenvalues of G sum to at most this
            fraction of its trace.
        start: one of :data:`EDM_STARTS`: "full" (the older schedule: every run to
            ``gap_tol`` or a stall) or "cheap" (the estimator stops at the first run its verdict
            accepts, and the first run also stops once its rank-d embedding has settled: see
            :data:`EMBEDDING_RTOL`; with ``every_run_settles`` of
            :func:`convex_iteration_runs`, every run does).
    """

    max_attempts: int = 8
    fit_weight: float = 10.0
    max_iterations: int = 50
    gap_tol: float = 1e-6
    start: str = "full"


def convex_iteration_runs(
    problem,
    d_tilde: np.ndarray,
    w: np.ndarray,
    dim: int,
    *,
    options: ConvexIterationOptions,
    rng: np.random.Generator,
    failures: list[str],
    bounds=None,
    every_run_settles: bool = False,
):
    """Yield the EDMCompletion of up to ``options.max_attempts`` convex-iteration runs (eq. 10).

    "Several weights": the first runs start from Z = I (trace minimisation) with the fit weight
    scaled by each of WEIGHT_FACTORS in turn; later runs start from random Z, cycling them. A
    run whose SDP fails with every solver is lost: its status is appended to ``failures``.
    With ``options.start`` "cheap" the first run stops once its embedding settles
    (:data:`EMBEDDING_RTOL`), and with ``every_run_settles`` every run does: for an estimator
    whose judge compares each run's refined minimum with every alternative, a run is a start.
    """
    from rangeslam.solvers.sdp import complete_edm, random_direction

    n = w.shape[0]

    def settles(attempt: int) -> bool:
        return options.start == "cheap" and (attempt == 0 or every_run_settles)

    for attempt in range(options.max_attempts):
        factor = WEIGHT_FACTORS[attempt % len(WEIGHT_FACTORS)]
        z0 = None if attempt < len(WEIGHT_FACTORS) else random_direction(n, dim, rng)
        try:
            yield complete_edm(
                d_tilde,
                w,
                dim,
                fit_weight=options.fit_weight * factor,
                max_iterations=options.max_iterations,
                tol=options.gap_tol,
                z0=z0,
                bounds=bounds,
                problem=problem,
                # cheap: the first run stops once its embedding settles, later ones (made only
                # when the first was not accepted) run to the gap unless every run settles: on
                # a walk from simulated RIRs (0.35 mm residuals) eight runs stopped early all
                # ended flexible
                embedding_rtol=EMBEDDING_RTOL if settles(attempt) else 0.0,
            )
        except SolverError as exc:
            failures.append(str(exc.status))


def passes_residual_test(
    ssr: float,
    n_ranges: int,
    n_points: int,
    dim: int,
    noise_std: float | None,
    exact_rms: float,
    *,
    n_offsets: int = 0,
) -> bool:
    """Exact data (RMS residual <= exact_rms), or a sum of squared range residuals below the
    0.999 chi-square quantile for the redundancy, in units of noise_std^2.

    ``ssr``, ``noise_std`` and ``exact_rms`` are in one unit (metres, or the scaled units of
    :func:`rangeslam.mdu.emission.calibrate_unknown_emission`); the redundancy is the ranges
    minus the points' coordinates up to a rigid motion minus ``n_offsets`` range offsets."""
    if ssr <= exact_rms**2 * n_ranges:
        return True
    redundancy = n_ranges - (unknowns_up_to_rigid_motion(n_points, dim) + n_offsets)
    if noise_std is None or redundancy <= 0 or noise_std == 0:
        return False
    from scipy.stats import chi2

    return bool(ssr <= chi2.ppf(CHI2_LEVEL, redundancy) * noise_std**2)


# The range sigma of the graph never goes below this fraction of the median range: from the EDM
# answer, GTSAM's LM made no step at all at 1e-6 and recovers exact data at 1e-4 ...
SIGMA_FLOOR = 1e-4


def least_steps(r: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(M - 1,) the least each step can be by the triangle inequality, max_k |r_(i+1)k - r_ik|
    over the landmarks heard at both steps (0 where none is)."""
    both = observed[:-1] & observed[1:]
    return np.where(both, np.abs(np.diff(r, axis=0)), 0.0).max(axis=1)


def rotated_covariances(fit: GraphFit, rot: np.ndarray):
    """A fit's receiver (M, d, d), source (K, d, d) and joint trajectory (M d, M d) covariances
    in the frame x -> x @ rot (e.g. :func:`rangeslam.mdu.calibration.canonical_frame`'s); covariances
    rotate with the frame, a translation leaves them unchanged."""
    m, dim = fit.receivers.shape
    cov_r = np.einsum("ji,njk,kl->nil", rot, fit.receiver_cov, rot)
    cov_s = np.einsum("ji,njk,kl->nil", rot, fit.source_cov, rot)
    rot_all = np.kron(np.eye(m), rot)
    return cov_r, cov_s, rot_all.T @ fit.joint_cov[: m * dim, : m * dim] @ rot_all


def residual_status(
    ssr: float,
    observed: np.ndarray,
    dim: int,
    noise_std: float | None,
    scale: float,
    *,
    chi_square: bool,
    bounded: bool,
) -> tuple[Status, str]:
    """The status of a trajectory's range residual (sum of squares ``ssr`` over the ``observed``
    (M, K) ranges), and if not CONVERGED why: INCONSISTENT when the chi-square test against
    ``noise_std`` fails (``chi_square``), or else RMS > 2% of the median range ``scale``;
    NOT_IDENTIFIABLE without redundant ranges unless step bounds are ``bounded``."""
    n_obs = int(observed.sum())
    n = sum(observed.shape)
    rms = float(np.sqrt(ssr / n_obs))
    message = ""
    status = Status.CONVERGED
    if chi_square:
        if not passes_residual_test(ssr, n_obs, n, dim, noise_std, EXACT_RTOL * scale):
            status = Status.INCONSISTENT
            message += (
                f"the residual test failed: RMS residual {rms:.3g} m for noise_std "
                f"{noise_std:.3g} m; "
            )
    elif not rms <= RELATIVE_RMS * scale:
        status = Status.INCONSISTENT
        message += f"RMS residual {rms:.3g} m is more than 2% of the median range; "
    if n_obs - unknowns_up_to_rigid_motion(n, dim) <= 0 and not bounded:
        status = Status.NOT_IDENTIFIABLE
        message += "no redundant ranges and no step bounds: the trajectory is not unique; "
    return status, message


def checked_options(options: ConvexIterationOptions) -> ConvexIterationOptions:
    """The convex-iteration settings checked at the door (InvalidInputError naming each), as
    Python numbers."""
    return ConvexIterationOptions(
        max_attempts=as_scalar(
            options.max_attempts, "max_attempts", low=1, high=MAX_ATTEMPTS, integer=True
        ),
        fit_weight=as_scalar(
            options.fit_weight, "fit_weight", low=0.0, low_open=True, expected="positive and finite"
        ),
        max_iterations=as_scalar(
            options.max_iterations, "max_iterations", low=1, high=MAX_SDP_ITERATIONS, integer=True
        ),
        gap_tol=as_scalar(
            options.gap_tol,
            "gap_tol",
            low=0.0,
            high=1.0,
            low_open=True,
            high_open=True,
            expected="in (0, 1)",
        ),
        start=checked_start(options.start),
    )


def checked_start(start) -> str:
    """``edm_start`` checked at the door: one of :data:`EDM_STARTS`."""
    if not isinstance(start, str) or start not in EDM_STARTS:
        raise InvalidInputError(f"edm_start must be one of {EDM_STARTS}; got {start!r:.80}")
    return start


def unfolding_check(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    noise_std: float | None,
    exact_rms: float,
    *,
    prior_jac: np.ndarray | None = None,
    offset_columns: np.ndarray | None = None,
    what: str = "the configuration",
    judge_sources: str = "all",
    tail: bool = True,
    rivals_judged: bool = False,
    source_mirrors: LandmarkMirrors | None = None,
) -> Check:
    """The verdict of :mod:`rangeslam.verdict` on an unfolding's answer (eq. 9 model).

    Args:
        receivers, sources: (M, d), (K, d) the answer, metres.
        ranges, observed: (M, K) the ranges the answer was fitted to and where they are observed.
        noise_std: the range noise if known (else estimated from the residuals), metres.
        exact_rms: RMS residual of exact data (round-off), metres.
        prior_jac: (P, (M + K) d) extra rows of the information in range-noise units (step
            priors: their Jacobian times noise sigma over the prior's sigma), or None.
        offset_columns: (P, G) derivatives of the P observed (row-major) residuals with respect
            to G unknown range offsets the model also fitted (emission times), or None.
        what: what the points are, for the reason.
        judge_sources: "all": a source that is weakly determined or has a mirror image fails
            the check; "none": both only noted (the receivers are what is judged: they fit the
            same either side of a source's mirror, which a planar walk or array gives each).
        tail: whether the residuals' tail is tested (False for the inliers of a robust fit).
        rivals_judged: the judge compared the fold and mirrors (no flat-rival F-test then).
        source_mirrors: the sources' :func:`landmark_mirrors`, when the caller has them.

    Checks in turn: the residuals, the dimension, whether the points may be flat
    (:func:`flat_fit_check`), the information's rank and the receivers' precision (receiver
    gauge, as :func:`rangeslam.mdu_crlb` bounds them; also along the weakest directions,
    :func:`region_check`), each point against its partners held fixed (precision, mirror image;
    receivers only without priors, which tie them to each other); and, for flat receivers
    without priors, whether a flat scene fits as well (:func:`flat_rival_check`).
    """
    m, d = receivers.shape
    points = np.vstack([receivers, sources])
    pairs = np.argwhere(observed)
    jac = unfolding_jacobian(points, m, pairs)
    residuals = unfolding_residuals(points, m, ranges[observed], pairs)
    n_offsets = 0 if offset_columns is None else offset_columns.shape[1]
    redundancy = int(observed.sum()) - unknowns_up_to_rigid_motion(len(points), d) - n_offsets
    info_jac, gauge, projection = information_model(
        receivers, sources, jac, prior_jac, offset_columns
    )
    ssr = float(residuals @ residuals)
    sigma = verdict_noise(noise_std, noise_upper_bound(ssr, redundancy), exact_rms)
    scale = float(np.median(ranges[observed]))
    # Residuals first: a noise level estimated from residuals that do not fit means nothing.
    consistency = consistency_check(residuals, jac, redundancy, noise_std, scale, exact_rms,
                                    tail=tail)  # fmt: skip
    if not consistency.passed:
        return consistency
    # 3-D data in dim=2 first; what was noted is named with it
    dimension = dimension_check(receivers, sources, ranges, observed, redundancy, exact_rms,
                                noise_std)  # fmt: skip
    source_check, sources_note = sources_verdict(
        receivers, sources, ranges, observed, sigma, exact_rms, judge_sources, source_mirrors
    )
    covariance = gauge_free_covariance(info_jac, gauge)
    information = information_check(info_jac, gauge, sigma, scale, what, dim=d,
                                    rows=np.arange(m * d), projection=projection,
                                    covariance=covariance)  # fmt: skip
    if information.passed:
        model = (covariance[0], projection, prior_jac, offset_columns)
        information = region_check(receivers, sources, pairs, model, sigma, scale, what)
    flat_rival, receivers_check = (PASSED, PASSED) if prior_jac is not None else priorless_checks(
        receivers, sources, ranges, observed, redundancy, sigma, exact_rms, scale,
        rivals_judged=rivals_judged)  # fmt: skip
    flat = PASSED if not dimension.passed else flat_fit_check(  # dimension fails first
        points, m, ranges, observed, sigma, what, offsets=n_offsets > 0)  # fmt: skip
    check = first_failure(dimension, flat, flat_rival, information, source_check, receivers_check)
    return Check(check.status, "; ".join(filter(None, (check.reason, sources_note))))


def priorless_checks(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    redundancy: int,
    sigma: float | None,
    exact_rms: float,
    scale: float,
    *,
    rivals_judged: bool = False,
) -> tuple[Check, Check]:
    """The checks of :func:`unfolding_check` made only without step priors: (the flat rival,
    :func:`flat_rival_check`, which compares range residuals alone and so cannot judge a flat
    scene a prior holds; each receiver against its sources, :func:`points_check`: priors tie
    the receivers to each other, so they are not judged one by one). ``scale``: the median
    observed range, metres, as :func:`unfolding_check` computed it. ``rivals_judged``: the judge
    compared the fold already (the flat rival passes)."""
    return (
        PASSED
        if rivals_judged
        else flat_rival_check(receivers, sources, ranges, observed, redundancy, sigma, scale),
        points_check(receivers, sources, ranges, observed, sigma, exact_rms, "receiver"),
    )


def region_check(
    receivers: np.ndarray,
    sources: np.ndarray,
    pairs: np.ndarray,
    model: tuple,
    sigma: float | None,
    scale: float,
    what: str,
) -> Check:
    """The receivers' precision test of :func:`rangeslam.verdict.information_check` repeated
    where the truth may lie: the answer moved the level's :func:`rangeslam.verdict.level_sigmas`
    standard deviations along each receiver direction (:func:`rangeslam.verdict.weak_moves`).
    A move whose Jacobian change cannot fail the test (:func:`moves_that_could_fail`, Weyl's
    inequality) is not made; of the others those along at most SEARCH_BUDGET directions, weakest
    first (the judge's budget of alternatives).

    Args:
        receivers, sources: (M, d), (K, d) the answer, metres.
        pairs: (P, 2) the observed (receiver, source) index pairs.
        model: the answer's gauge-free covariance for unit noise (:func:`rangeslam.verdict.
            gauge_free_covariance`, None when singular) and receiver-gauge projection
            (:func:`information_model`), then its ``prior_jac`` and ``offset_columns`` (the
            prior rows are held at the answer; the offsets' columns do not depend on the
            points).
        sigma, scale: range noise and scene size, metres.

    The first moved answer that fails the test fails the check; without ``sigma`` or with a
    singular information (information_check's to report) it passes.
    """
    cov, projection, prior_jac, offset_columns = model
    if not sigma or cov is None:
        return PASSED
    m, d = receivers.shape
    points = np.vstack([receivers, sources])
    rows = np.arange(m * d)
    projected = projection @ cov @ projection.T
    own = rms_precision(projected, sigma, d, rows)
    moves = weak_moves(projected, sigma, rows)
    for move in moves_that_could_fail(points, m, pairs, model, sigma, scale, moves)[
        : 2 * SEARCH_BUDGET
    ]:
        moved = points + move[: points.size].reshape(-1, d)
        info_jac, gauge, projection = information_model(
            moved[:m], moved[m:], unfolding_jacobian(moved, m, pairs), prior_jac, offset_columns
        )
        check = information_check(
            info_jac, gauge, sigma, scale, what, dim=d, rows=rows, projection=projection
        )
        if not check.passed:
            return probed_failure(check, own)
    return PASSED


def moves_that_could_fail(
    points: np.ndarray,
    m: int,
    pairs: np.ndarray,
    model: tuple,
    sigma: float,
    scale: float,
    moves: list[np.ndarray],
) -> list[np.ndarray]:
    """The ``moves`` (each (p,), metres, the points' d N entries first) after which the
    receivers' precision test might fail, in their order; a move is left out when a bound shows
    it cannot. The bound, Weyl's inequality: moving ``points`` (N, d) turns the unit vector u of
    each of the (P, 2) receiver-source ``pairs`` (i, j) by |du| <= b (:func:`rangeslam.verdict.
    unit_turn_bound` of |delta_i - delta_j| and r_ij), which changes the unit-noise range Jacobian J (rows [u, -u]) by dJ with
    spectral norm e <= sqrt(||dJ||_1 ||dJ||_inf) <= sqrt(max_i sum_(pairs of i) b * 2 sqrt(d)
    max b) (Hoelder). Every non-zero singular value s of J stays above s - e (the prior rows are
    held at the answer, the offsets' columns are fixed, the rigid motions stay null), so the
    gauge-free covariance's trace grows by at most (s_min / (s_min - e))^2 and its projection's
    by ||P||_2^2. The move cannot fail the test when the RMS standard deviation that allows
    stays within PRECISION_FRACTION of ``scale`` and (s_min - e) / (s_max + e) stays above
    RANK_RTOL. ``model`` as in :func:`region_check`; ``sigma`` the range noise, metres."""
    if not moves:
        return []
    cov, projection, prior_jac, offset_columns = model
    n, d = points.shape
    s_min = 1.0 / np.sqrt(np.linalg.eigvalsh(cov)[-1])
    extra = [a for a in (prior_jac, offset_columns) if a is not None]
    s_max = np.sqrt(2.0 * len(pairs) + sum(float(np.sum(a**2)) for a in extra))  # >= ||J||_2
    spread = sigma * np.linalg.norm(projection, 2) * np.sqrt(np.trace(cov) / m)
    ends = np.column_stack([pairs[:, 0], m + pairs[:, 1]])  # (P, 2) point indices
    r = np.linalg.norm(points[ends[:, 0]] - points[ends[:, 1]], axis=1)
    delta = np.stack(moves, axis=1)[: n * d].reshape(n, d, -1)  # (N, d, n_moves)
    step = np.linalg.norm(delta[ends[:, 0]] - delta[ends[:, 1]], axis=1)  # (P, n_moves)
    turn = unit_turn_bound(step, r[:, None])
    incidence = coo_matrix(
        (np.ones(2 * len(ends)), (ends.T.ravel(), np.tile(np.arange(len(ends)), 2))),
        shape=(n, len(ends)),
    ).tocsr()
    per_point = incidence @ turn  # (N, n_moves) sum over each point's pairs
    e = np.sqrt(per_point.max(axis=0) * 2.0 * np.sqrt(d) * turn.max(axis=0))
    with np.errstate(divide="ignore"):
        grown = np.where(e < s_min, spread * s_min / (s_min - e), np.inf)
    held = (grown <= PRECISION_FRACTION * scale) & (s_min - e > RANK_RTOL * (s_max + e))
    return [move for move, harmless in zip(moves, held, strict=True) if not harmless]


def sources_verdict(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float | None,
    exact_rms: float,
    judge_sources: str,
    mirrors: LandmarkMirrors | None = None,
) -> tuple[Check, str]:
    """The sources' :func:`points_check` as judged (see :func:`unfolding_check`'s
    ``judge_sources``) and the note on what was only noted ("" if nothing); ``mirrors``: the
    sources' :func:`landmark_mirrors` when the caller has them (computed here otherwise)."""
    if judge_sources not in ("all", "none"):
        raise InvalidInputError(f'judge_sources must be "all" or "none"; got {judge_sources!r}')
    if judge_sources == "all":
        return points_check(
            sources, receivers, ranges.T, observed.T, sigma, exact_rms, "source"
        ), ""
    failed = points_failures(sources, receivers, ranges.T, observed.T, sigma, exact_rms, "source")
    # A flat array or walk held fixed is bent towards each source's side: the mirrors judged
    # with everything refitted, so the note names every source reported.
    if mirrors is None:
        mirrors = landmark_mirrors(receivers, sources, ranges, observed, sigma, exact_rms)
    named = {i for i, _ in failed}
    refitted = [j for j in np.flatnonzero(mirrors.ambiguous) if j not in named]
    if not failed and not refitted:
        return PASSED, ""
    first = failed[0][1].reason if failed else refitted_reason(refitted[0], mirrors.cost_gaps)
    rest = sorted([i for i, _ in failed[1:]] + refitted[1 - bool(failed) :])
    also = f" (also noted: sources {', '.join(str(i) for i in rest)})"
    return PASSED, f"noted: {first}" + (also if rest else "")


def refitted_reason(j: int, gaps: np.ndarray) -> str:
    """The note on source ``j`` whose mirror image fits as well only with every point refitted;
    ``gaps`` (K,) the cost gaps of :func:`landmark_mirrors`, metres^2."""
    return (
        f"source {j} and its mirror image fit the data equally well with the receivers refitted "
        f"(their costs differ by {gaps[j]:.3g} m^2; the receivers may be flat)"
    )


def information_model(
    receivers: np.ndarray,
    sources: np.ndarray,
    jac: np.ndarray,
    prior_jac: np.ndarray | None,
    offset_columns: np.ndarray | None,
):
    """The information's Jacobian (range rows ``jac`` (P, (M + K) d), then the prior rows), the
    gauge basis (the rigid motions of the points) and the receiver-gauge projection, each
    extended by the G unknown offsets of ``offset_columns`` (P, G) when given (outside the
    gauge, projected as they are)."""
    info_jac = jac if prior_jac is None else np.vstack([jac, prior_jac])
    gauge = rigid_motion_basis(np.vstack([receivers, sources]))
    projection = receiver_gauge_projection(receivers, sources)
    if offset_columns is None:
        return info_jac, gauge, projection
    n_off, n = offset_columns.shape[1], len(projection)
    extra = np.zeros((info_jac.shape[0] - len(jac), n_off))
    info_jac = np.hstack([info_jac, np.vstack([offset_columns, extra])])
    gauge = np.vstack([gauge, np.zeros((n_off, gauge.shape[1]))])
    projection = np.block(
        [[projection, np.zeros((n, n_off))], [np.zeros((n_off, n)), np.eye(n_off)]]
    )
    return info_jac, gauge, projection


def points_check(
    points: np.ndarray,
    partners: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float | None,
    exact_rms: float,
    kind: str,
) -> Check:
    """:func:`rangeslam.verdict.point_check` of each of ``points`` (N, d) against the
    ``partners`` (P, d) it is ranged to (``ranges`` and ``observed`` (N, P), metres); the first
    failure, its reason naming ``kind`` and the index."""
    failed = points_failures(points, partners, ranges, observed, sigma, exact_rms, kind, first=True)
    return failed[0][1] if failed else PASSED


def points_failures(points, partners, ranges, observed, sigma, exact_rms, kind, *, first=False):
    """[(index, failed Check)] of :func:`points_check`'s per-point checks, in index order (only
    the first when ``first``)."""
    scale = float(np.median(ranges[observed]))
    failed = []
    for i, point in enumerate(points):
        obs = observed[i]
        check = point_check(
            point, partners[obs], ranges[i, obs], sigma, exact_rms, scale, f"{kind} {i}"
        )
        if not check.passed:
            failed.append((i, check))
            if first:
                break
    return failed


def step_prior_rows(
    bounds, kind: str, step_sigma: float | None, receivers: np.ndarray, sigma: float, n_points: int
) -> np.ndarray | None:
    """(P, (M + K) d) the information rows of the step priors the graph used, in range-noise
    units (the step-length Jacobian times sigma over the prior's sigma): with "uniform" every
    step's moment-matched Gaussian (spread max(width / sqrt(12), step sigma)); with "dead_zone"
    only the steps at a bound (within the step sigma), where the prior is active. None without
    bounds or rows. ``bounds``: a StepBounds (M - 1 steps, metres) or None; ``kind``: the
    step prior ("uniform" or "dead_zone"); ``receivers`` (M, d) the trajectory; ``sigma`` the
    range noise and ``step_sigma`` the prior's scale outside the bounds (default sigma), metres;
    ``n_points`` M + K (the columns: (M + K) d)."""
    if bounds is None:
        return None
    lower, upper = bounds.lower, bounds.upper
    step_sigma = step_sigma or sigma
    steps = np.linalg.norm(np.diff(receivers, axis=0), axis=1)
    if kind == "uniform":
        spread = np.maximum((upper - lower) / np.sqrt(12.0), step_sigma)
        active = np.ones(len(steps), dtype=bool)
    else:
        spread = np.full(len(steps), step_sigma)
        active = (steps <= lower + step_sigma) | (steps >= upper - step_sigma)
    index = np.flatnonzero(active)
    if index.size == 0:
        return None
    d = receivers.shape[1]
    unit = np.diff(receivers, axis=0)[index] / np.maximum(steps[index], 1e-300)[:, None]
    jac = np.zeros((len(index), n_points * d))
    rows = np.arange(len(index))[:, None]
    cols = np.arange(d)[None, :]
    jac[rows, (index[:, None] + 1) * d + cols] = unit
    jac[rows, index[:, None] * d + cols] = -unit
    return jac * (sigma / spread[index])[:, None]
