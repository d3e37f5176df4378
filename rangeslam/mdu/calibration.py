"""Zero-knowledge calibration (Problem 2): receivers and sources from the ranges between them.

Multidimensional unfolding (MDU, eq. 9): the M x K ranges between receivers (microphones) and
sources (a loudspeaker and its image sources, or acoustic events) are the off-diagonal block of an
(M + K) x (M + K) EDM. :func:`calibrate` completes it with Dattorro's convex iteration (eq. 10,
:mod:`rangeslam.solvers.sdp`), embeds it in ``dim`` dimensions and refines the points by least
squares on the ranges (:mod:`rangeslam.solvers.least_squares`). The problem has local minima (the
convex iteration can stall at a wrong rank-d point), so the iteration is run again from other
weights and random directions Z (until an answer passes the residual test, or every run without
a noise level); the judge (:mod:`rangeslam.mdu.calibration_judge`) then compares the answer with
every alternative, and the verdict checks it against the noise.

Everything is recovered up to a rigid motion *and a reflection* (ranges cannot tell handedness).
The result is expressed with the receivers' centroid at the origin and their principal axes along
the coordinate axes (signs fixed by the receivers' third moments).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._blas import single_blas_thread
from rangeslam._robust import MAD_TO_STD, robust_mode
from rangeslam._validation import as_flag, as_rng, check_int, frozen
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.calibration_judge import (
    ambiguity_words,
    counted_points,
    judge_calibration,
    judged_status,
    objective_scale,
    same_calibration,
    spread,
)
from rangeslam.mdu.core import (
    MAX_ATTEMPTS,
    MAX_RANDOM_STARTS,
    MAX_SDP_ITERATIONS,
    ConvexIterationOptions,
    canonical_frame,
    checked_options,
    passes_residual_test,
    unfolding_check,
    unknowns_up_to_rigid_motion,
    validated_ranges,
)
from rangeslam.mdu.landmark_mirrors import landmark_mirrors
from rangeslam.mdu.robust_unfolding import embedding_fit, reject_outliers, robust_refit
from rangeslam.mdu.subsets import core_runs
from rangeslam.solvers.least_squares import (
    UnfoldingFit,
    refine_unfolding,
    unfolding_residuals,
)
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import (
    consistency_check,
    noise_upper_bound,
    tail_limit,
    verdict_noise,
)
from rangeslam.verdict.breakdown import breakdown_check
from rangeslam.verdict.judge import (
    SAME,
    CheckRecord,
    JudgedSearch,
    ReachedLowest,
    cost_level,
)
from rangeslam.verdict.thresholds import EXACT_RTOL, RELATIVE_RMS, SEARCH_BUDGET

if TYPE_CHECKING:
    from rangeslam.solvers.sdp import EDMCompletion

__all__ = ["Calibration", "calibrate"]

# An RMS residual below this fraction of the median range is exact data (round-off only). The SDP
# alone (refine=False) is accurate to about 1e-6 of the scale with Clarabel's tolerances.
_EXACT_RTOL = {True: EXACT_RTOL, False: 1e-4}


@dataclass(frozen=True)
class Calibration(HasStatus):
    """Result of :func:`calibrate`. M receivers, K sources, d = 2 or 3.

    Attributes:
        receivers: (M, d) receiver positions, metres (centroid at 0, principal axes as axes).
        sources: (K, d) source positions in the same frame, metres.
        residuals: (M, K) fitted minus measured range, metres; NaN where not observed.
        observed: (M, K) the mask that was given (True where a range was observed).
        inliers: (M, K) the ranges used in the final fit (``observed`` unless ``robust``).
        residual_rms: RMS residual over the inliers, metres.
        noise_estimate: sqrt(sum of squared inlier residuals / redundancy), metres; NaN when the
            data have no redundancy.
        redundancy: inlier ranges minus unknowns up to a rigid motion (the chi-square degrees of
            freedom of the residual test).
        status: CONVERGED when the answer passed the residual test against ``noise_std``, or
            without it won the vote of two starts (see :func:`calibrate`); else why not
            (``converged`` is derived from it).
        message: why not, when not converged; empty otherwise.
        attempts: convex-iteration runs made (see ``max_attempts`` of :func:`calibrate`).
        iterations: SDP solves over all attempts.
        random_starts: least-squares runs from random points made after the attempts failed.
        origin: "convex_iteration" or "random_start": where the answer's starting point came from.
        eigen_gap: eigen-gap of the SDP solution the answer was refined from (0 = rank d; NaN
            when the answer came from a random start).
        sdp_status: solver status of that SDP solve ("" for a random start).
        solver: the solver that produced it ("" for a random start).
        ambiguous_sources: (K,) bool, sources whose mirror image through the (coplanar, or d)
            receivers hearing them fits as well; the receivers fit the same either way.
        source_mirrors: (K, d) their other positions, same frame, metres (NaN elsewhere).
        checks: every check of the verdict (name, statistic, level, passed, reason), in order.
        judged: alternatives the judge compared with the answer (random starts, refits without
            one source or one receiver, mirrors, the fold); ``reached``: random starts (the
            answer counted) that reached the answer.
    """

    receivers: np.ndarray
    sources: np.ndarray
    residuals: np.ndarray
    observed: np.ndarray
    inliers: np.ndarray
    residual_rms: float
    noise_estimate: float
    redundancy: int
    status: Status
    message: str
    attempts: int
    iterations: int
    random_starts: int
    origin: str
    eigen_gap: float
    sdp_status: str
    solver: str
    ambiguous_sources: np.ndarray
    source_mirrors: np.ndarray
    checks: tuple[CheckRecord, ...] = ()
    judged: int = 0
    reached: int = 0

    @property
    def n_outliers(self) -> int:
        """Observed ranges left out of the final fit."""
        return int(np.sum(self.observed & ~self.inliers))


@dataclass(frozen=True)
class Candidate:
    """One refined start: its fit, the ranges it used (M, K), the SDP answer it came from (None
    for a random start), its sum of squared inlier residuals (m^2), its ranking key and notes."""

    fit: UnfoldingFit
    inliers: np.ndarray
    completion: EDMCompletion | None
    ssr: float
    key: float
    message: str


@dataclass(frozen=True)
class CalibrationProblem:
    """The validated inputs of :func:`calibrate` (built once by :func:`parse_calibration`)."""

    ranges: np.ndarray  # (M, K) metres, 0 where not observed
    observed: np.ndarray  # (M, K) bool
    scale: float  # median observed range, metres
    dim: int
    noise_std: float | None
    refine: bool
    robust: bool
    random_starts: int
    options: ConvexIterationOptions
    auto_robust: bool = False  # robust="auto": a heavy residual tail ends the search

    @property
    def n_points(self) -> int:
        """M + K."""
        return sum(self.ranges.shape)

    @property
    def exact_rms(self) -> float:
        """RMS residual of exact data (round-off only), metres."""
        return _EXACT_RTOL[bool(self.refine)] * self.scale

    @property
    def unknowns(self) -> int:
        """Coordinates of the M + K points up to a rigid motion."""
        return unknowns_up_to_rigid_motion(self.n_points, self.dim)

    @property
    def redundancy(self) -> int:
        """Observed ranges minus :attr:`unknowns`."""
        return int(self.observed.sum()) - self.unknowns


@dataclass(frozen=True)
class Start:
    """A starting point (M + K, d): a convex-iteration run's (``completion`` set) or random."""

    points: np.ndarray
    completion: EDMCompletion | None


@dataclass(frozen=True)
class SearchOutcome:
    """The best candidate of the starts tried, whether another start confirmed it, counts, and
    every candidate made."""

    best: Candidate | None
    confirmed: bool
    attempts: int
    iterations: int
    random_starts: int
    solver_failures: tuple[str, ...]
    noise_floor: float | None = None  # robust: the least inlier spread a sound candidate reached
    candidates: tuple[Candidate, ...] = ()  # every refined start, the judge's first alternatives


def parse_calibration(
    ranges, mask, dim, noise_std, refine, robust, random_starts, options: ConvexIterationOptions
) -> CalibrationProblem:
    """The front door of :func:`calibrate`: every input checked once."""
    r, observed, scale = validated_ranges(ranges, mask, dim, noise_std)
    for name, value, low, high in (
        ("max_attempts", options.max_attempts, 1, MAX_ATTEMPTS),
        ("max_iterations", options.max_iterations, 1, MAX_SDP_ITERATIONS),
        ("random_starts", random_starts, 0, MAX_RANDOM_STARTS),
    ):
        check_int(value, name, low, high)
    refine = as_flag(refine, "refine")
    if robust and not refine:
        raise InvalidInputError(
            "robust=True needs refine=True (wrong picks are found by refitting)"
        )
    options = checked_options(options)
    noise_std = None if noise_std is None else float(noise_std)
    return CalibrationProblem(
        r, observed, scale, int(dim), noise_std, refine, robust, int(random_starts), options
    )


def starting_points(problem: CalibrationProblem, rng, failures: list[str]):
    """Yield :class:`Start`: the convex-iteration runs (eq. 10), then, with ``refine`` and not
    ``robust``, up to ``random_starts`` random points (not when every SDP run failed)."""
    loss = "l1" if problem.robust else "l2"
    # refined least-squares runs are starts of the judge: each stops once its embedding settles
    # (the same answers as runs to the gap on 30 Fig. 3 scenes, benchmarks/README.md); without
    # ``refine`` the SDP's points are the answer, and robust runs make 3 solves
    settle = problem.refine and not problem.robust
    for completion in core_runs(problem.ranges, problem.observed, problem.dim, problem.options,
                                rng, failures, loss=loss, every_run_settles=settle):  # fmt: skip
        yield Start(completion.points, completion)
    if len(failures) == problem.options.max_attempts:
        return  # the SDP failed every time: raise below rather than guess
    # Last resort: least squares from random points (measured to rescue most of the 2-4% of
    # Fig. 3 configurations the convex-iteration runs miss).
    if problem.refine and not problem.robust:
        for _ in range(problem.random_starts):
            yield Start(rng.standard_normal((problem.n_points, problem.dim)) * problem.scale, None)


def robust_cauchy_scale(fit: UnfoldingFit, problem: CalibrationProblem) -> float:
    """Cauchy scale from the first SDP's points: MAD_TO_STD times the median |residual| (at
    least the exact-data RMS), metres."""
    mad = float(np.median(np.abs(fit.residuals[problem.observed])))
    return max(MAD_TO_STD * mad, problem.exact_rms)


def fit_start(
    start: Start, problem: CalibrationProblem, cauchy_scale: float | None, rng
) -> Candidate | None:
    """Refine one start: Gaussian least squares, or the robust refit and outlier rejection;
    None when the fit diverged."""
    r, observed, m = problem.ranges, problem.observed, problem.ranges.shape[0]
    fit = embedding_fit(start.points, m, r, observed)
    inliers, note = observed, ""
    if problem.robust:
        fit, note = robust_refit(fit, r, observed, problem.dim, cauchy_scale, rng)
        fit, inliers, rejection_note = reject_outliers(
            fit, r, observed, problem.dim, problem.noise_std
        )
        note += rejection_note
    elif problem.refine:
        fit = refine_unfolding(start.points[:m], start.points[m:], r, observed)
    ssr = float(np.sum(fit.residuals[inliers] ** 2))
    if not np.isfinite(ssr):
        return None  # a diverged fit is no candidate
    # Robust runs are ranked by the Cauchy cost of all observed ranges (inlier sets differ).
    key = _cauchy_cost(fit, r, observed, cauchy_scale) if problem.robust else ssr
    return Candidate(fit, inliers, start.completion, ssr, key, note)


def search(problem: CalibrationProblem, rng) -> SearchOutcome:
    """Fit the starts in turn, keeping the lowest; stop at the first accepted one (not robust),
    or without noise_std once every convex-iteration run is made and the best was reached twice.
    (Stopping once the best was reached twice and the verdict accepts it, before every run is
    made, was measured on Fig. 3 at 1 cm and rejected: two early runs often agree on a minimum
    that a later run undercuts; see benchmarks/README.md, "Cheap EDM start".)"""
    failures: list[str] = []
    # the Cauchy scale must be positive: for exact data (0), as when unknown, the first fit's MAD
    cauchy_scale = problem.noise_std if problem.noise_std else None

    # Votes count refined fits only: raw SDP points from different weights never coincide. Two
    # starts reach one answer when the judge calls them the same (delta^2 in the information at
    # the lowest within its confidence region).
    def same_at(best: Candidate):
        return _same_test(best, problem) if problem.refine else (lambda cand: False)

    lowest = ReachedLowest(same_at, lambda c: c.key)
    candidates: list[Candidate] = []
    iterations = attempts = starts = 0
    for start in starting_points(problem, rng, failures):
        if start.completion is not None:
            attempts += 1
            iterations += start.completion.iterations
        else:
            starts += 1
        if problem.robust and cauchy_scale is None:
            fit0 = embedding_fit(
                start.points, problem.ranges.shape[0], problem.ranges, problem.observed
            )
            cauchy_scale = robust_cauchy_scale(fit0, problem)
        cand = fit_start(start, problem, cauchy_scale, rng)
        if cand is None:
            continue
        candidates.append(cand)
        lowest.add(cand)
        # A robust fit can pass the residual test on a wrong configuration by dropping ranges,
        # so robust runs are all made and ranked by their cost over all ranges.
        if not problem.robust and _accepted(lowest.best, problem):
            break
        # Without a noise level a wrong minimum cannot be told from noise by its residual: every
        # convex-iteration run is made, and the lowest configuration must have been reached twice.
        all_runs = attempts + len(failures) == problem.options.max_attempts
        if problem.noise_std is None and lowest.confirmed and all_runs:
            break
        if problem.auto_robust and heavy_tail(cand, problem, (Status.OUTLIERS,)):
            break  # wrong picks: robust="auto" goes on robustly rather than search further
    floor, best, confirmed = None, lowest.best, lowest.confirmed
    if problem.robust and best is not None:  # ranked again at the noise the data show
        best, confirmed, floor = reranked(candidates, problem)
    return SearchOutcome(
        best, confirmed, attempts, iterations, starts, tuple(failures), floor, tuple(candidates)
    )


def reranked(cands: list[Candidate], problem: CalibrationProblem):
    """The robust candidates ranked again, at the noise the data show: (best, confirmed, floor).

    The Cauchy scale the runs were ranked by comes from the first, unrefined SDP fit (7.5-27 cm
    on dEchorate-style picks of about 1 cm noise), where a wrong configuration that drops few
    ranges outranks the right one. ``floor`` is the least inlier spread
    (:func:`~rangeslam.mdu.calibration_judge.spread`) of a
    candidate within the breakdown rule (:func:`calibration_breakdown`), metres: every candidate
    is ranked by its Cauchy cost at that scale, and "confirmed" means the judge calls another
    candidate the same answer at that scale (:func:`same_calibration`)."""
    sound = [c for c in cands if calibration_breakdown(c, problem).passed] or cands
    # the least spread is biased low (it is a minimum); a given noise_std is the floor's floor
    floor = max(min(spread(c) for c in sound), problem.exact_rms, problem.noise_std or 0.0)
    r, observed = problem.ranges, problem.observed
    keyed = [dataclasses.replace(c, key=_cauchy_cost(c.fit, r, observed, floor)) for c in cands]
    best = min(keyed, key=lambda c: c.key)
    same_as_best = _same_test(best, problem, floor)
    confirmed = any(c is not best and same_as_best(c) for c in keyed)
    return best, confirmed, floor


def calibration_breakdown(best: Candidate, problem: CalibrationProblem):
    """:func:`rangeslam.verdict.breakdown.breakdown_check` of a robust candidate, receivers only.
    (dEchorate, 30 microphones x 14 sources: the right minima drop at most 5 of a microphone's 14
    ranges; a wrong one 37 cm off, reached by two of four starts, dropped 7.) Sources are not held
    to it: the receivers are what is calibrated, and a source's column may hold picks of several
    reflections (the right dEchorate answer with defaults keeps 15 of source 3's 30 ranges, a
    consistent phantom among them)."""
    return breakdown_check(best.inliers, problem.observed, problem.redundancy, judge_sources=False)


def calibration_verdict(
    outcome: SearchOutcome, problem: CalibrationProblem, judged: JudgedSearch | None
) -> tuple[Status, str]:
    """Status and message of the best candidate: NOT_IDENTIFIABLE without redundancy, OUTLIERS
    when robust dropped over half the redundant ranges or half of a receiver's
    (:func:`calibration_breakdown`), INCONSISTENT when no start passed the residual test against
    ``noise_std``, NO_AGREEMENT without it when the RMS residual explains nothing (over
    RELATIVE_RMS of the scene), SOLVER_FAILED when least squares failed, NOT_IDENTIFIABLE when
    the judge found a rival minimum (``judged``: :func:`judge_calibration`); then the checks of
    :func:`unfolding_check` (information, consistency, flatness)."""
    best, noise_std = outcome.best, problem.noise_std
    unknowns = unknowns_up_to_rigid_motion(problem.n_points, problem.dim)
    n_in = int(best.inliers.sum())
    redundancy = n_in - unknowns
    rms = float(np.sqrt(best.ssr / n_in))
    n_starts = outcome.attempts + outcome.random_starts
    message = best.message
    if outcome.solver_failures:
        failures = outcome.solver_failures
        message += f"{len(failures)} SDP runs failed ({failures[0]}); "
    status = Status.CONVERGED
    if redundancy == 0:
        status = Status.NOT_IDENTIFIABLE
        message += (
            "minimal configuration (no redundant ranges): the unfolding has finitely many exact "
            "solutions and the data cannot tell which is right; "
        )
    elif problem.robust and not (breakdown := calibration_breakdown(best, problem)).passed:
        status = breakdown.status
        message += breakdown.reason
    elif (
        rms <= problem.exact_rms
        or _accepted(best, problem)
        or (
            noise_std is None
            and (judged is not None or outcome.confirmed)
            and rms <= RELATIVE_RMS * problem.scale
        )
    ):
        pass
    elif noise_std is not None:
        status = Status.INCONSISTENT
        message += (
            f"no start in {n_starts} passed the residual test: best RMS residual "
            f"{rms:.3g} m for noise_std {noise_std:.3g} m (a local minimum, or wrong ranges); "
        )
    else:
        status = Status.NO_AGREEMENT
        message += (
            f"no configuration of {n_starts} starts fits: best RMS residual {rms:.3g} m, over "
            f"{RELATIVE_RMS:g} of the scene (or, without refine, none was reached twice); "
        )
    if (problem.refine or problem.robust) and not best.fit.converged:
        status = Status.SOLVER_FAILED if status is Status.CONVERGED else status
        message += f"least squares failed: {best.fit.message}; "
    if status is Status.CONVERGED and judged is not None:
        status, message = judged_status(judged, best, problem, message)
    if status is Status.CONVERGED:
        check = unfolding_check(
            best.fit.receivers,
            best.fit.sources,
            problem.ranges,
            best.inliers,
            noise_std,
            problem.exact_rms,
            what="the calibration",
            judge_sources="none",
            tail=not problem.robust,
            rivals_judged=judged is not None,
        )
        status, message = check.status, message + check.reason
    return status, message.rstrip("; ")


def calibration_result(
    outcome: SearchOutcome,
    problem: CalibrationProblem,
    status: Status,
    message: str,
    judged: JudgedSearch | None = None,
) -> Calibration:
    """The :class:`Calibration` of the best candidate, in the canonical frame."""
    best, observed, n_in = outcome.best, problem.observed, int(outcome.best.inliers.sum())
    fit, comp = best.fit, best.completion
    redundancy = n_in - unknowns_up_to_rigid_motion(problem.n_points, problem.dim)
    receivers, sources, _ = canonical_frame(np.asarray(fit.receivers), np.asarray(fit.sources))
    estimate = float(np.sqrt(best.ssr / redundancy)) if redundancy > 0 else float("nan")
    sigma = verdict_noise(
        problem.noise_std, noise_upper_bound(best.ssr, redundancy), problem.exact_rms
    )
    mirrors = landmark_mirrors(receivers, sources, problem.ranges, best.inliers, sigma,
                               problem.exact_rms)  # fmt: skip
    checks, n_judged, reached = (), 0, 0
    if judged is not None:
        j = judged.judgement
        checks = (
            j.check,
            judged.record(),
            CheckRecord("verdict", float("nan"), float("nan"), status is Status.CONVERGED, message),
        )
        n_judged, reached = len(j.comparisons), j.reached
        message = "; ".join(filter(None, (message, judged.words(), ambiguity_words(j))))
    return Calibration(
        receivers=frozen(receivers),
        sources=frozen(sources),
        residuals=frozen(np.where(observed, fit.residuals, np.nan)),
        observed=frozen(observed),
        inliers=frozen(best.inliers.copy()),
        residual_rms=float(np.sqrt(best.ssr / n_in)),
        noise_estimate=estimate,
        redundancy=int(redundancy),
        status=status,
        message=message,
        attempts=outcome.attempts,
        iterations=outcome.iterations,
        random_starts=outcome.random_starts,
        origin="random_start" if comp is None else "convex_iteration",
        eigen_gap=np.nan if comp is None else comp.eigen_gap,
        sdp_status="" if comp is None else comp.status,
        solver="" if comp is None else comp.solver,
        ambiguous_sources=frozen(mirrors.ambiguous),
        source_mirrors=frozen(mirrors.mirrors),
        checks=checks,
        judged=n_judged,
        reached=reached,
    )


@single_blas_thread
def calibrate(
    ranges: ArrayLike,
    *,
    dim: int = 3,
    mask: ArrayLike | None = None,
    noise_std: float | None = None,
    refine: bool = True,
    robust: bool | str | None = "auto",
    max_attempts: int = 8,
    random_starts: int = 100,
    fit_weight: float = 10.0,
    max_iterations: int | None = None,
    gap_tol: float = 1e-6,
    edm_start: str = "cheap",
    rng: np.random.Generator | int | None = None,
) -> Calibration:
    """Locate M receivers and K sources, all unknown, from their ranges (MDU, eqs. 8-10).

    Args:
        ranges: (M, K) range from receiver m to source k, metres; entries outside ``mask`` are
            ignored (they may be NaN).
        dim: 2 or 3.
        mask: (M, K) boolean, True where observed; None means all observed.
        noise_std: standard deviation of the range noise, metres, if known; None: unknown;
            0: exact data (every test then allows round-off only, 1e-8 of the median range). With
            it the search stops at the first start whose sum of squared residuals passes the
            chi-square test at CHI2_LEVEL (:mod:`rangeslam.verdict.thresholds`); without it
            every convex-iteration run is made, the noise is estimated from the answer's
            residuals (their RMS at most RELATIVE_RMS of the median range, no heavy tail), and
            the judge's levels are in that estimate's units: pass ``noise_std`` when you know it.
        refine: refine the SDP's points by least squares on the ranges (Gaussian ML). Without it
            the SDP's points are returned and "exact" means within 1e-4 of the scale.
        robust: for wrong echo picks. The SDP fits with an L1 loss; each run is refined with a
            Cauchy loss (scale ``noise_std``, or 1.4826 MAD of the first fit's residuals), ranges
            beyond 3 sigma are dropped and the rest refit by least squares until the set is
            stable; runs are ranked, and the judge compares every alternative, by the Cauchy
            cost over all ranges. Without ``noise_std``, a robust answer whose search the budget
            (SEARCH_BUDGET), not the stopping rule, ended is NO_AGREEMENT (dropping ranges lets
            a wrong configuration pass). True or "cauchy": always robust. ``"auto"`` (default):
            least squares first; robust once a fit's residuals carry a heavy tail or the search
            ends INCONSISTENT, OUTLIERS or NO_AGREEMENT, given as many redundant ranges as
            unknowns (the message says which, or that there were fewer). ``False``/None: never
            ("huber", "tukey" of :data:`rangeslam.solvers.robust_kernels.ROBUST_VALUES`: refused).
        max_attempts: convex-iteration runs at most (1 to MAX_ATTEMPTS, 1000): four from Z = I
            with the fit weight times 1, 10, 0.1 and 100, then from random Z, the same weights.
        random_starts: when no convex-iteration run passes, least squares from up to this many
            (0 to MAX_RANDOM_STARTS, 100000) random starting points (a last resort; only with
            ``refine``); the judge's are at most this many too (all, unless the stopping rule
            ends them, when the answer came from a random start).
        fit_weight: lambda of eq. (10), on data scaled to unit median range.
        max_iterations: SDP solves per run (1 to MAX_SDP_ITERATIONS); None: 50, 3 if robust.
        gap_tol: a run stops when the N - d smallest eigenvalues of G sum to at most this
            fraction of its trace (it also stops when the gap stalls).
        edm_start: "cheap" (default): each least-squares run also stops once its rank-d
            embedding settles (:data:`rangeslam.mdu.core.EMBEDDING_RTOL`); "full": to the gap.
        rng: numpy Generator (or seed) for the random restarts.

    Size: above :data:`rangeslam.mdu.subsets.MAX_SDP_POINTS` receivers plus sources, the SDP
    holds a random core of them and the others are multilaterated from it
    (:func:`rangeslam.mdu.subsets.core_runs`); least squares fits every range from there.

    Returns a :class:`Calibration`; its ``status`` says why when no attempt passed the check.
    Raises InvalidInputError for bad input or an under-determined mask. An SDP run that fails
    with both Clarabel and the SCS fallback is noted in the message and the others go on;
    SolverError (with the statuses) when no run gives a usable answer.
    """
    iterations = {
        False: DEFAULT_MAX_ITERATIONS if max_iterations is None else max_iterations,
        True: ROBUST_MAX_ITERATIONS if max_iterations is None else max_iterations,
    }
    mode = robust_mode(robust, ("on", "auto", "cauchy"))  # its robust refit is Cauchy's
    auto, robust = mode == "auto", mode in ("on", "cauchy")
    problem = parse_calibration(
        ranges, mask, dim, noise_std, refine, robust, random_starts,
        ConvexIterationOptions(max_attempts, fit_weight, iterations[robust], gap_tol, edm_start),
    )  # fmt: skip
    rng = as_rng(rng)
    if not (auto and problem.refine):
        return solve_calibration(problem, rng)
    return auto_robust_calibration(problem, iterations[True], rng)


def unsearched_note(problem: CalibrationProblem) -> str:
    """robust="auto"'s note when the redundancy is too small to search for wrong picks
    (:func:`enough_for_robust`): least squares spreads a wrong pick over ranges of high leverage,
    where neither the tail test nor the judge sees it."""
    return (
        f"robust='auto': wrong picks not searched for ({problem.redundancy} redundant ranges "
        f"for {problem.unknowns} unknowns; a robust fit needs as many): a wrong pick least "
        "squares absorbs would go unseen; "
    )


def auto_robust_calibration(
    problem: CalibrationProblem, robust_iterations: int, rng: np.random.Generator
) -> Calibration:
    """robust="auto": least squares on all ranges unless a first short run shows a heavy
    residual tail, and the robust fit (``robust_iterations`` SDP solves per run) when the tail
    shows or the least-squares search ends in AUTO_ROBUST_STATUSES; the message says which.
    Least squares alone, the message saying so, with too few redundant ranges to look for wrong
    picks (:func:`enough_for_robust`)."""
    if not enough_for_robust(problem):
        result = solve_calibration(problem, rng)
        return dataclasses.replace(result, message=unsearched_note(problem) + result.message)
    robust_problem = dataclasses.replace(
        problem,
        robust=True,
        options=dataclasses.replace(problem.options, max_iterations=robust_iterations),
    )
    if probe_has_tail(problem, rng):
        note = "robust='auto': least squares on all ranges left a heavy residual tail; "
    else:
        result = solve_calibration(dataclasses.replace(problem, auto_robust=True), rng)
        if result.status not in AUTO_ROBUST_STATUSES:
            return result
        note = f"robust='auto': least squares on all ranges ended {result.status.name}; "
    second = solve_calibration(robust_problem, rng)
    message = note + "wrong picks were searched for; " + second.message
    return dataclasses.replace(second, message=message)


#: SDP solves per convex-iteration run by default, and in robust runs (on the dEchorate echoes,
#: 3 reached 1.3-2.2 cm and 10 no better, at three times the cost).
DEFAULT_MAX_ITERATIONS = 50
ROBUST_MAX_ITERATIONS = 3


def enough_for_robust(problem: CalibrationProblem) -> bool:
    """Whether robust="auto" may look for wrong picks: at least as many redundant ranges as
    unknowns. With fewer, dropping ranges lets wrong configurations fit (measured on the Fig. 3
    scene, redundancy 6 of 36: a robust fit of clean ranges ended 0.9 m off), so least squares
    is used and wrong picks are reported, not searched for."""
    return problem.redundancy >= problem.unknowns


def probe_has_tail(problem: CalibrationProblem, rng) -> bool:
    """robust="auto"'s first look: one short robust run (the L1 SDP for ROBUST_MAX_ITERATIONS
    solves, the Cauchy refit and the studentized rejection); True when it dropped ranges whose
    median |residual| is beyond the tail test's limit (:func:`rangeslam.verdict.checks.
    tail_limit` over the observed ranges, in the noise its inliers imply): wrong picks stand
    out. (A least-squares fit spreads wrong picks over every range, and from a short run
    cannot be told from a local minimum.)"""
    options = dataclasses.replace(
        problem.options, max_attempts=1, max_iterations=ROBUST_MAX_ITERATIONS
    )
    probe = dataclasses.replace(problem, options=options, random_starts=0, robust=True)
    start = next(iter(starting_points(probe, rng, [])), None)
    if start is None:
        return False
    m, r, observed = problem.ranges.shape[0], problem.ranges, problem.observed
    fit0 = embedding_fit(start.points, m, r, observed)
    cand = fit_start(start, probe, problem.noise_std or robust_cauchy_scale(fit0, probe), rng)
    if cand is None:
        return False
    dropped = observed & ~cand.inliers
    noise = spread(cand)
    if not dropped.any() or noise <= 0:
        return False
    distances = range_matrix(cand.fit.receivers, cand.fit.sources)
    off = np.abs(distances - r)[dropped]
    return bool(np.median(off) > tail_limit(int(observed.sum())) * noise)


def heavy_tail(cand: Candidate, problem: CalibrationProblem, statuses: tuple[Status, ...]) -> bool:
    """Whether :func:`rangeslam.verdict.consistency_check`, without a noise level, gives a
    candidate's residuals one of ``statuses`` (OUTLIERS: a tail no noise explains)."""
    observed = problem.observed
    residuals = cand.fit.residuals[observed]
    check = consistency_check(
        residuals, None, problem.redundancy, None, problem.scale, problem.exact_rms
    )
    return check.status in statuses


#: Statuses of a least-squares calibration after which robust="auto" searches for wrong picks.
AUTO_ROBUST_STATUSES = (Status.INCONSISTENT, Status.OUTLIERS, Status.NO_AGREEMENT)


def solve_calibration(problem: CalibrationProblem, rng: np.random.Generator) -> Calibration:
    """One calibration of a parsed problem: the search over starts, the judge of every
    alternative (with ``refine``), the verdict, the result. Raises SolverError when no start gives
    a usable answer."""
    outcome = search(problem, rng)
    if outcome.best is None:
        failures = outcome.solver_failures
        raise SolverError(
            "calibration found no usable solution: every SDP run failed"
            if len(failures) == problem.options.max_attempts
            else "calibration found no usable solution: every fit diverged",
            status="; ".join(dict.fromkeys(failures)) or None,
        )
    judged = None
    if problem.refine:
        outcome, judged = judged_outcome(outcome, problem, rng)
    status, message = calibration_verdict(outcome, problem, judged)
    return calibration_result(outcome, problem, status, message, judged)


def judged_outcome(
    outcome: SearchOutcome, problem: CalibrationProblem, rng
) -> tuple[SearchOutcome, JudgedSearch]:
    """The search's answer judged against every alternative (:func:`judge_calibration`); the
    judgement's answer is its lowest. A lowest below the judged points by more than the level
    (:func:`rangeslam.verdict.judge.cost_level`) is judged in turn, its own alternatives (the
    refits without each block among them) generated from it: a descent over minima, at most
    SEARCH_BUDGET judgements. The last lowest, when not the search's answer, replaces it (fitted
    as the search fits a start, the message saying where it came from). An answer from a random
    start (every SDP run missed it) has random starts for its search: the judge draws them to
    ``random_starts`` in all or the stopping rule (a lower minimum may pass the residual test)."""
    best = outcome.best
    sigma = objective_scale(problem, best.ssr, int(best.inliers.sum()), outcome.noise_floor)
    answer = _points(best)
    starts = [_points(c) for c in outcome.candidates if c is not best]
    inliers = best.inliers if problem.robust else None
    draws = None if best.completion is not None else problem.random_starts - outcome.random_starts
    points, hops, settled = answer, [], False
    for _ in range(SEARCH_BUDGET):
        judged = judge_calibration(
            problem, points, sigma, rng, inliers=inliers, starts=starts, draws=draws
        )
        if draws is not None:  # the draws made count against the limit, their minima on
            draws, starts = max(draws - judged.draws, 0), counted_points(judged)
        lowest = judged.judgement.answer
        if lowest.points is points:
            settled = True
            break
        first = judged.judgement.comparisons[0]  # the judged points, against the lowest
        points = lowest.points
        if first.kind != SAME:
            hops.append(f"{lowest.origin} reached a lower minimum (by {first.delta_cost:.3g} "
                        "noise variances)")  # fmt: skip
        if first.delta_cost <= cost_level():
            # within the level: the last judgement compared every alternative with the lowest
            # (those generated from the judged points: the same answer or a rival of it)
            settled = True
            break
    if points is answer:
        return outcome, judged
    cand = fit_start(Start(points, None), problem, sigma if problem.robust else None, rng)
    if cand is None:
        return outcome, judged
    note = f"{', then '.join(hops)}: it replaced the search's answer; " if hops else ""
    cand = dataclasses.replace(cand, message=best.message + note)
    # the answer reported is the one judged: the last judgement's answer is the lowest; the
    # replacement's own fit is judged once more unless the descent settled there and the fit is
    # that least-squares minimum again
    same = settled and not problem.robust
    if not (same and same_calibration(problem, points, sigma)(_points(cand))):
        judged = judge_calibration(
            problem, _points(cand), sigma, rng, inliers=inliers, starts=starts, draws=draws
        )
    return dataclasses.replace(outcome, best=cand), judged


def _cauchy_cost(fit: UnfoldingFit, ranges, observed, scale: float) -> float:
    """Cauchy cost sum log(1 + (res / scale)^2) over the observed ranges."""
    m = len(fit.receivers)
    pts = np.vstack([fit.receivers, fit.sources])
    pairs = np.argwhere(observed)
    res = unfolding_residuals(pts, m, ranges[observed], pairs)
    return float(np.sum(np.log1p((res / scale) ** 2)))


def _points(cand: Candidate) -> np.ndarray:
    """(M + K, d) a candidate's receivers above its sources, metres."""
    return np.vstack([cand.fit.receivers, cand.fit.sources])


def _same_test(best: Candidate, problem: CalibrationProblem, floor: float | None = None):
    """The judge's same-answer test at ``best`` (:func:`same_calibration`), at the objective's
    sigma of that candidate (:func:`objective_scale`; a robust search's scale ``floor``, else
    the candidate's own inlier spread): a predicate of another candidate."""
    if problem.robust and floor is None:
        floor = spread(best)
    sigma = objective_scale(problem, best.ssr, int(best.inliers.sum()), floor)
    test = same_calibration(problem, _points(best), sigma)
    return lambda cand: test(_points(cand))


def _accepted(c: Candidate, problem: CalibrationProblem) -> bool:
    """Whether a candidate passes the residual test (:func:`passes_residual_test`)."""
    return passes_residual_test(
        c.ssr, int(c.inliers.sum()), problem.n_points, problem.dim, problem.noise_std,
        problem.exact_rms,
    )  # fmt: skip
