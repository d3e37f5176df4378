"""Acoustic range-only SLAM (paper, section 4): one moving microphone, a loudspeaker and its images.

The microphone's positions r_1..r_M along an unknown trajectory are the receivers, the loudspeaker
and its image sources the landmarks: the same unfolding as zero-knowledge calibration (eq. 9).
Bounds on the step length |r_{i+1} - r_i| enter the convex iteration as constraints on
K(G)_{i,i+1} (eq. 11), and the EDM solution initialises a GTSAM range-factor graph with the same
bounds as step-length priors (:mod:`rangeslam.solvers.gtsam_graph`), which refines it and gives
covariances.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._blas import single_blas_thread
from rangeslam._robust import ROBUST_KERNELS, robust_mode
from rangeslam._validation import as_flag, as_rng, as_scalar, frozen
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.localization.multilateration import multilaterate
from rangeslam.logsteps import logged_step
from rangeslam.mdu.core import (
    ConvexIterationOptions,
    canonical_frame,
    checked_options,
    rotated_covariances,
    validated_ranges,
)
from rangeslam.mdu.planar_walk import planar_answer
from rangeslam.mdu.robust_unfolding import agreeing
from rangeslam.mdu.slam_graph import graph_deviance, refine_run, stacked
from rangeslam.mdu.slam_judge import judge_slam
from rangeslam.mdu.slam_verdict import (
    SlamProblem,
    SlamRun,
    judged_ranges,
    landmark_ambiguity,
    passes,
    slam_verdict,
)
from rangeslam.mdu.subsets import keyframe_runs
from rangeslam.solvers.gtsam_graph import STEP_PRIORS
from rangeslam.solvers.step_bounds import KNOWN_STEP_WIDTH, StepBounds
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import noise_upper_bound, verdict_noise
from rangeslam.verdict.breakdown import outvoted_points
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.judge import SAME, CheckRecord, JudgedSearch, cost_level
from rangeslam.verdict.thresholds import EXACT_RTOL

if TYPE_CHECKING:
    from rangeslam.solvers.sdp import EDMCompletion

__all__ = ["SlamResult", "slam"]

log = logging.getLogger(__name__)

# Why "uniform" is the default step prior: in the Fig. 5 setting at 1 cm, the dead zone's MAP
# runs to the bounds and has 2.1-3.0x the mean error at M = 5 to 10; with the true steps anywhere
# in the bounds, not at their centres, "uniform" is still 1.7-2.1x below the dead zone's error
# with centred bounds.


@dataclass(frozen=True)
class SlamResult(HasStatus):
    """Result of :func:`slam`. M steps, K landmarks, d = 2 or 3.

    Attributes:
        receivers: (M, d) the trajectory, metres (frame: its centroid at 0, principal axes).
        sources: (K, d) the landmarks (loudspeaker and image sources), same frame.
        receiver_cov: (M, d, d) covariances of the positions in the receiver gauge, m^2 (None
            without refinement).
        source_cov: (K, d, d) the same for the landmarks.
        trajectory_cov: (M d, M d) joint covariance of all positions (rows of ``receivers``
            stacked), receiver gauge, m^2 (None without refinement): for the NEES of the whole
            trajectory, rank :attr:`trajectory_dof` (M d - 3 in 2-D, M d - 6 in 3-D, 2 M - 3
            for a walk in its plane).
        residuals: (M, K) fitted minus measured range, metres; NaN where not observed.
        edm_receivers: (M, d) the EDM (convex iteration) answer before GTSAM, same frame (None
            for methods without an EDM step, such as the EKF baseline); for a walk solved on
            keyframes (:mod:`rangeslam.mdu.subsets`), with the steps between them interpolated.
        edm_sources: (K, d) likewise.
        residual_rms: RMS range residual, metres.
        status: CONVERGED when the answer passed the residual test (chi-square against
            ``noise_std``), else why not (``converged`` is derived from it).
        message: why not, when not converged.
        attempts: convex-iteration runs made.
        sdp_solves: SDP solves those runs made (the budget: ``max_attempts`` runs of at most
            ``max_iterations`` solves each).
        start: where the answer's GTSAM run started: "edm", or the alternative of the judge
            that ended lower than the search's answer and replaced it ("random start j",
            "convex-iteration run j", "the refit without landmark k", "the refit without steps
            i-j"); "filter" for the EKF baseline.
        eigen_gap: eigen-gap of the SDP answer used.
        ambiguous_landmarks: (K,) bool, the landmarks whose mirror image through the walk fits
            as well (a near-planar walk cannot tell the two sides apart: see
            :mod:`rangeslam.mdu.landmark_mirrors`); None without the check (EKF baseline).
        landmark_mirrors: (K, d) the other position of each ambiguous landmark, same frame,
            metres; NaN for the others.
        inliers: (M, K) bool, the ranges the verdict judged: every observed one, or with a
            robust kernel those it kept (residual within
            :func:`rangeslam.verdict.checks.level_sigmas` noise standard deviations); None for methods without it.
        checks: every check of the judge (:func:`rangeslam.mdu.slam_judge.judge_slam`: rival
            minima, search complete) and the verdict, each with its statistic and level; empty
            without refinement.
        judged: alternatives the judge compared with the answer (other convex-iteration runs,
            random starts, refits without one landmark or one window of steps); ``reached``:
            the starts (the answer counted) that reached the answer.
        planar_walk: the trajectory was refitted in its plane (3-D only): the likelihood-ratio
            test of that nested model did not reject it (:mod:`rangeslam.mdu.planar_walk`; its
            record in ``checks``). ``trajectory_cov`` then has rank 2 M - 3
            (:attr:`trajectory_dof`), and each landmark's side of the plane is an ambiguity.
    """

    receivers: np.ndarray
    sources: np.ndarray
    receiver_cov: np.ndarray | None
    source_cov: np.ndarray | None
    trajectory_cov: np.ndarray | None
    residuals: np.ndarray
    edm_receivers: np.ndarray | None
    edm_sources: np.ndarray | None
    residual_rms: float
    status: Status
    message: str
    attempts: int
    start: str
    eigen_gap: float
    sdp_solves: int = 0
    ambiguous_landmarks: np.ndarray | None = None
    landmark_mirrors: np.ndarray | None = None
    inliers: np.ndarray | None = None
    checks: tuple[CheckRecord, ...] = ()
    judged: int = 0
    reached: int = 0
    planar_walk: bool = False

    @property
    def trajectory_dof(self) -> int:
        """Degrees of freedom of the trajectory beyond the rigid motion, the rank of
        ``trajectory_cov``: M d - d (d + 1) / 2, or 2 M - 3 for a walk fitted in its plane."""
        m, d = self.receivers.shape
        return 2 * m - 3 if self.planar_walk else m * d - d * (d + 1) // 2

    @property
    def outliers(self) -> np.ndarray | None:
        """(M, K) bool, the observed ranges left out as wrong (the kernel discounted them)."""
        if self.inliers is None:
            return None
        return ~np.isnan(self.residuals) & ~self.inliers

    @property
    def n_outliers(self) -> int:
        """Observed ranges left out as wrong (0 without a robust kernel)."""
        out = self.outliers
        return 0 if out is None else int(out.sum())


def _check_bounds_against_ranges(bounds, r, observed, noise_std, robust=None) -> None:
    """Refuse step bounds that no positions can meet: by the triangle inequality, for every
    landmark k heard at steps i and i + 1, |r_ik - r_(i+1)k| <= |x_(i+1) - x_i| <= r_ik + r_(i+1)k
    (with 4 sigma of slack for the noise, or 1% of the range when noise_std is unknown). With a
    ``robust`` kernel a landmark that contradicts the bounds may be a wrong pick (the kernel's
    business): the bounds are refused only when most landmarks heard at both steps do."""
    lower, upper = bounds
    both = observed[:-1] & observed[1:]
    slack_abs = 0.0 if noise_std is None else 4 * np.sqrt(2) * noise_std
    for i in np.flatnonzero(both.any(axis=1)):
        a, b = r[i, both[i]], r[i + 1, both[i]]
        slack = slack_abs if noise_std is not None else 0.01 * float(np.max(a + b))
        against = (upper[i] < np.abs(a - b) - slack) | (lower[i] > a + b + slack)
        if (np.any(against) and robust is None) or np.sum(against) > len(a) / 2:
            least, most = float(np.max(np.abs(a - b))), float(np.min(a + b))
            raise InvalidInputError(
                f"step_bounds contradict the ranges at step {i}: [{lower[i]:.4g}, {upper[i]:.4g}] m "
                f"lies outside [{least:.4g}, {most:.4g}] m, what the ranges to the same landmarks "
                f"allow (triangle inequality; {int(np.sum(against))} of {len(a)} landmarks)"
            )


@dataclass(frozen=True)
class EdmSearch:
    """What the convex-iteration runs made: the ``best`` run (lowest key), runs made, SDP
    failures, the sigma runs are ranked on, every refined run (the judge's first
    alternatives) and the SDP solves made."""

    best: SlamRun | None
    attempts: int
    failures: tuple[str, ...]
    sigma_ref: float | None
    runs: tuple[SlamRun, ...] = ()
    solves: int = 0


def parse_slam(
    ranges, step_bounds, mask, dim, refine, noise_std, robust, step_sigma, step_prior,
    extra_starts, options: ConvexIterationOptions,
) -> SlamProblem:  # fmt: skip
    """The front door of :func:`slam`: every input checked once (step bounds into a
    :class:`StepBounds`, refused where the ranges contradict them)."""
    r, observed, scale = validated_ranges(ranges, mask, dim, noise_std)
    m = r.shape[0]
    bounds = None if step_bounds is None else StepBounds.parse(step_bounds, m - 1)
    if bounds is not None:
        _check_bounds_against_ranges(bounds, r, observed, noise_std, robust)
        # lower = upper is a known step length: an interval KNOWN_STEP_WIDTH of the scale wide
        # (the GTSAM dead zone needs a positive width; the step factor's sigma holds it there).
        bounds = bounds.widened(KNOWN_STEP_WIDTH * scale)
    if not isinstance(step_prior, str) or step_prior not in STEP_PRIORS:
        raise InvalidInputError(f"step_prior must be one of {STEP_PRIORS}; got {step_prior!r}")
    extra_starts = as_scalar(extra_starts, "extra_starts", low=0, integer=True)
    options = checked_options(options)
    refine = as_flag(refine, "refine")
    robust = robust_mode(robust, ROBUST_KERNELS, default_kernel="cauchy")
    step_sigma = as_scalar(
        step_sigma, "step_sigma", low=0.0, low_open=True, allow_none=True,
        expected="a positive number of metres or None",
    )  # fmt: skip
    noise_std = None if noise_std is None else float(noise_std)
    return SlamProblem(
        r, observed, scale, dim, bounds, noise_std, robust, step_sigma, step_prior, refine,
        extra_starts, options,
    )  # fmt: skip


def edm_run(problem: SlamProblem, completion: EDMCompletion, sigma_ref: float | None, pts=None):
    """One convex-iteration answer, refined by GTSAM when ``refine``, from the SDP's points or
    from ``pts`` (M + K, d) when given. Returns (SlamRun, the sigma of its graph or None).
    Refined runs are ranked by the graph's cost (ranges and step priors: a low range residual
    bought by breaking the step bounds is no better answer), all on one graph, that of
    ``sigma_ref`` (the first run's; None: this run's)."""
    m = problem.ranges.shape[0]
    pts = completion.points if pts is None else pts
    fit, sigma = None, None
    if problem.refine:
        fit, sigma = refine_run(problem, pts)
        rec, src = fit.receivers, fit.sources
    else:
        rec, src = pts[:m], pts[m:]
    res = range_matrix(rec, src) - problem.ranges
    ssr = float(np.sum(res[problem.observed] ** 2))
    key = ssr if fit is None else fit.error
    run = SlamRun(ssr, rec, src, fit, completion, res, key, sigma=sigma)
    if sigma_ref is not None and sigma != sigma_ref:
        run = rekeyed(problem, run, sigma_ref)  # ranked on the reference graph
    return run, sigma


def rekeyed(problem: SlamProblem, run: SlamRun | None, sigma: float) -> SlamRun | None:
    """``run`` with its key on the graph of range sigma ``sigma`` (its cost there, where it is;
    runs without GTSAM keep their sum of squares)."""
    if run is None or run.fit is None:
        return run
    key = 0.5 * graph_deviance(problem, stacked(run.fit), sigma)  # GTSAM's error, as a key
    return dataclasses.replace(run, key=key)


def stops(problem: SlamProblem, run: SlamRun) -> bool:
    """Whether the search may stop at ``run``: it passes the residual test (:func:`passes`), or,
    with ``edm_start="cheap"`` and no noise level to test against, its GTSAM refinement
    converged: no test of one run can then tell a wrong minimum, and the judge's random starts
    and refits look for a lower one once, after the search
    (:func:`rangeslam.mdu.slam_judge.judge_slam`). (The search used to make runs until the
    verdict passed: 6-8 runs on 4 of 20 walks, 4.3-4.8 s each against a 0.9 s median; their
    first runs sat at a wrong minimum with the noise settled 5x too high, which the judge's
    random starts now replace.)"""
    if passes(problem, run):
        return True
    cheap = problem.options.start == "cheap" and problem.noise_std is None
    return cheap and run.fit is not None and run.fit.converged


@logged_step(log, "slam: EDM starts (convex iteration), each refined with GTSAM")
def search_edm_runs(problem: SlamProblem, rng) -> EdmSearch:
    """Convex-iteration runs (eq. 10, with eq. 11 step bounds), each refined, until the lowest
    so far :func:`stops` the search; every run is kept for the judge."""
    failures: list[str] = []
    best, attempts, sigma_ref, runs, solves = None, 0, None, [], 0
    for completion in keyframe_runs(problem.ranges, problem.observed, problem.dim,
                                    problem.bounds, problem.options, rng, failures):  # fmt: skip
        attempts += 1
        solves += completion.iterations
        run, sigma = edm_run(problem, completion, sigma_ref)
        if sigma is not None and sigma_ref is not None and sigma < sigma_ref:
            # a wrong minimum inflates the noise it settles at: rank on the best-fitting graph
            sigma_ref = sigma
            run, runs = rekeyed(problem, run, sigma), [rekeyed(problem, r, sigma) for r in runs]
        if sigma_ref is None:
            sigma_ref = sigma
        if problem.robust:
            run = resected(problem, run, sigma_ref, rng)
        runs.append(run)
        best = min(runs, key=lambda r: r.key)
        if stops(problem, best):
            break
    return EdmSearch(best, attempts, tuple(failures), sigma_ref, tuple(runs), solves)


def resected(problem: SlamProblem, run: SlamRun, sigma_ref, rng) -> SlamRun:
    """A robust run whose kernel left out half or more of a step's or a landmark's ranges
    (:func:`rangeslam.verdict.breakdown.outvoted_points`) with those points moved to where a
    robust multilateration from the others puts them (when more of their ranges agree there,
    within level_sigmas() of the noise), then refined as an EDM answer is (:func:`edm_run`); kept
    when its graph cost (on the graph of ``sigma_ref``) is lower, else ``run``. A kernel lets a
    landmark sit where 2-3 of its 8 ranges and a wrong pick agree, shedding the right ranges at
    a small cost; the trajectory is right and places it again."""
    if run.fit is None:
        return run
    kept = judged_ranges(problem, run)[0]
    observed, m = problem.observed, problem.ranges.shape[0]
    noise = verdict_noise(problem.noise_std, sigma_ref, EXACT_RTOL * problem.scale)
    threshold = level_sigmas() * max(noise or 0.0, problem.floor)
    pts = np.vstack([run.receivers, run.sources])
    moved = 0
    for axis in (1, 0):  # steps (rows), then landmarks (columns)
        for i in outvoted_points(kept, observed, axis):
            j = i if axis == 1 else m + i
            anchors = pts[m:] if axis == 1 else pts[:m]
            r = problem.ranges[i] if axis == 1 else problem.ranges[:, i]
            obs = observed[i] if axis == 1 else observed[:, i]
            if obs.sum() < problem.dim + 2:
                continue
            try:
                cand = multilaterate(anchors, r, mask=obs, robust=True,
                                     inlier_threshold=threshold, rng=rng)  # fmt: skip
            except (DegenerateGeometryError, InvalidInputError):
                continue
            if agreeing(cand.position, anchors, r, obs, threshold) > agreeing(
                pts[j], anchors, r, obs, threshold
            ):
                pts[j], moved = cand.position, moved + 1
    if not moved:
        return run
    try:
        new = edm_run(problem, run.completion, sigma_ref, pts=pts)[0]
    except SolverError:
        return run
    return new if new.key < run.key else run


def slam_result(
    problem: SlamProblem,
    best: SlamRun,
    attempts: int,
    status: Status,
    message: str,
    judged: JudgedSearch | None = None,
    sdp_solves: int = 0,
    plane: CheckRecord | None = None,
) -> SlamResult:
    """The :class:`SlamResult` of the best run, in the canonical frame (covariances rotated),
    with the judge's checks and counts (``judged``; none without refinement), the nested test
    of the walk's plane (``plane``: :func:`rangeslam.mdu.planar_walk.planar_answer`'s record)
    and the SDP solves the search made."""
    m = problem.ranges.shape[0]
    rec_f, src_f, rot = canonical_frame(best.receivers, best.sources)
    cov_r = cov_s = cov_traj = None
    if best.fit is not None:
        cov_r, cov_s, cov_traj = rotated_covariances(best.fit, rot)
    pts = best.completion.points
    edm_rec, edm_src, _ = canonical_frame(pts[:m], pts[m:])
    mirrors = landmark_ambiguity(problem, best, best.receivers.mean(axis=0), rot)
    kept = judged_ranges(problem, best)[0]
    checks, n_judged, reached = (), 0, 0
    if judged is not None:
        j = judged.judgement
        verdict = CheckRecord("verdict", float("nan"), float("nan"), status is Status.CONVERGED,
                              message)  # fmt: skip
        checks, n_judged, reached = (
            (j.check, judged.record(), *((plane,) if plane else ()), verdict),
            len(j.comparisons),
            j.reached,
        )
        message = "; ".join(filter(None, (message, judged.words())))
    return SlamResult(
        receivers=frozen(rec_f),
        sources=frozen(src_f),
        receiver_cov=None if cov_r is None else frozen(cov_r),
        source_cov=None if cov_s is None else frozen(cov_s),
        trajectory_cov=None if cov_traj is None else frozen(cov_traj),
        residuals=frozen(np.where(problem.observed, best.residuals, np.nan)),
        edm_receivers=frozen(edm_rec),
        edm_sources=frozen(edm_src),
        residual_rms=float(np.sqrt(best.ssr / problem.n_obs)),
        status=status,
        message=message,
        attempts=attempts,
        start=best.start,
        eigen_gap=best.completion.eigen_gap,
        ambiguous_landmarks=frozen(mirrors.ambiguous),
        landmark_mirrors=frozen(mirrors.mirrors),
        inliers=frozen(kept.copy()),
        checks=checks,
        judged=n_judged,
        reached=reached,
        sdp_solves=int(sdp_solves),
        planar_walk=best.planar,
    )


@single_blas_thread
def slam(
    ranges: ArrayLike,
    *,
    step_bounds: StepBounds | tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    dim: int = 3,
    refine: bool = True,
    noise_std: float | None = None,
    robust: str | None = None,
    step_sigma: float | None = None,
    step_prior: str = "uniform",
    max_attempts: int = 8,
    extra_starts: int = 0,
    fit_weight: float = 10.0,
    max_iterations: int = 50,
    edm_start: str = "cheap",
    rng: np.random.Generator | int | None = None,
) -> SlamResult:
    """Trajectory (M, d) and landmarks (K, d) from the ranges (M, K) of a moving microphone.

    Args:
        ranges: (M, K) range from step m to landmark k, metres.
        step_bounds: a :class:`StepBounds` or (lower, upper), each (M - 1,), bounds on
            |r_{i+1} - r_i| in metres: eq. (11) constraints in the SDP and step priors
            (``step_prior``) in the GTSAM refinement.
        mask: (M, K) boolean, True where observed.
        dim: 2 or 3.
        refine: refine the EDM answer with GTSAM (and compute covariances).
        noise_std: range noise standard deviation, metres. Weighs the graph and sets the residual
            test; when None it is estimated from the residuals of the EDM answer; 0 means exact
            data (the graph is finished as exact, the tests allow round-off only).
        robust: GTSAM kernel against wrong echoes: None (or False), "huber", "cauchy" (also
            True) or "tukey" (:data:`rangeslam.solvers.robust_kernels.ROBUST_VALUES`). The
            answer is then judged on the ranges the kernel kept (residual within level_sigmas()
            noise standard deviations; ``SlamResult.inliers``, ``outliers``, ``n_outliers``),
            and is OUTLIERS when it left out more than half the redundant ranges or half of one
            step's or one landmark's (:mod:`rangeslam.verdict.breakdown`).
        step_sigma: scale of the step prior outside the bounds, metres (default: the noise).
        step_prior: how GTSAM reads the bounds: "uniform" (default: the step length uniform on
            [lower, upper], as a dead zone plus its moment-matched Gaussian) or "dead_zone" (no
            cost inside the bounds; its MAP runs to the bounds where the ranges leave the shape
            free).
        max_attempts: convex-iteration runs at most (fit weights x1, x10, x0.1, x100 from Z = I,
            then random Z), until one passes the residual test (see ``edm_start``).
        extra_starts: random GTSAM starts the judge makes at least (default 0: as many as its
            stopping rule asks, at most SEARCH_BUDGET).
        fit_weight, max_iterations: as for :func:`rangeslam.calibrate`.
        edm_start: "cheap" (default): stop at the first convex-iteration run whose refined
            answer passes the residual test (without ``noise_std``: the first run), each run
            also stopped once its rank-d embedding settled; "full": every run to the eigen-gap
            tolerance until one passes the residual test (the older schedule).
        rng: Generator or seed for the random restarts.

    The answer is judged once (with ``refine``) against every alternative on one graph
    (:mod:`rangeslam.mdu.slam_judge`): the lowest is the answer, an equal one far off a rival.

    Size: above :data:`rangeslam.mdu.subsets.MAX_SDP_POINTS` steps plus landmarks, the SDP holds
    keyframes spread along the walk with every landmark, and the steps between them start on
    the segments joining them (:func:`rangeslam.mdu.subsets.keyframe_runs`); GTSAM fits every
    range from there.

    Raises InvalidInputError for bad input: step bounds of the wrong length, lower > upper,
    negative bounds, bounds the ranges contradict (triangle inequality, named by step), an
    under-determined mask. SolverError when the SDP fails in every run.
    """
    options = ConvexIterationOptions(max_attempts, fit_weight, max_iterations, 1e-6, edm_start)
    problem = parse_slam(
        ranges, step_bounds, mask, dim, refine, noise_std, robust, step_sigma, step_prior,
        extra_starts, options,
    )  # fmt: skip
    rng = as_rng(rng)
    found = search_edm_runs(problem, rng)
    if found.best is None:
        raise SolverError(
            "SLAM found no solution: the SDP failed in every run (with step bounds, they may "
            "not hold together with the ranges)",
            status="; ".join(dict.fromkeys(found.failures)),
        )
    best, status, message, judged, plane = judged_answer(problem, found, rng)
    return slam_result(problem, best, found.attempts, status, message, judged, found.solves, plane)


def judged_answer(problem: SlamProblem, found: EdmSearch, rng):
    """The search's best run judged against every alternative (with ``refine``:
    :func:`judge_slam` on the graph of the search's reference sigma): the lowest candidate,
    when lower by more than the level or not the same answer (:func:`replaced`), replaces it
    (refined again as an EDM answer is, :func:`edm_run`, named by where it came from); the verdict (:func:`slam_verdict`) and then
    the judge's status (a rival: NOT_IDENTIFIABLE). A converged 3-D answer is then refitted in
    its plane where the nested test keeps it (:func:`rangeslam.mdu.planar_walk.planar_answer`):
    the plane refines the estimate and its covariance, but the verdict is the 3-D model's (a
    walk the data do not determine in 3-D is not made identifiable by assuming it flat;
    benchmarks/README.md, "slam fits a planar walk in its plane").
    Returns (run, status, message, judgement or None, the plane's check record or None)."""
    best, judged, failures, unrefined, plane = found.best, None, (), (), None
    if problem.refine and best.fit is not None:
        others = [r for r in found.runs if r is not best]
        sigma = judge_sigma(problem, best, found.sigma_ref)
        judged = judge_slam(problem, best, others, sigma, rng)
        best, unrefined = replaced(problem, best, judged, found.sigma_ref)
        failures = judged.failures + unrefined
    status, message = slam_verdict(problem, best, found.failures, failures)
    if status is Status.CONVERGED and unrefined:
        # the lowest candidate could not be refined: the answer kept is not the most likely
        status = Status.SOLVER_FAILED
    if judged is not None and status is Status.CONVERGED:
        status = judged.judgement.status
        message = "; ".join(filter(None, (message, judged.judgement.reason)))
    if judged is not None and status is Status.CONVERGED:
        best, plane = planar_answer(problem, best)
    return best, status, message, judged, plane


def judge_sigma(problem: SlamProblem, best: SlamRun, sigma_ref: float) -> float:
    """The range sigma (metres) the judge weighs every candidate at: the search's reference
    (``noise_std`` when given; without it and without a kernel, the sum of squares over the
    redundancy, a consistent estimate), except for a robust kernel without ``noise_std``: then
    the largest noise the answer's residuals do not rule out
    (:func:`rangeslam.verdict.noise_upper_bound` on the ranges the verdict judges), at least the
    reference. A kernel's fit without a noise level fits many ranges exactly, so its MAD-settled
    sigma is biased low: on ranges tracked from simulated RIRs it settled at 0.44 um with the
    trajectory 1.9 mm off, and judged at that sigma, refits 0.05 mm apart were rivals 269
    information units apart."""
    if problem.noise_std is not None or not problem.robust:
        return sigma_ref
    _, res, redundancy = judged_ranges(problem, best)
    return max(sigma_ref, noise_upper_bound(float(res @ res), redundancy) or 0.0)


def replaced(
    problem: SlamProblem, best: SlamRun, judged: JudgedSearch, sigma_ref
) -> tuple[SlamRun, tuple[str, ...]]:
    """``best``, or the judge's lowest candidate when it replaced the answer and either is not
    the same answer by the judge's test (outside its confidence region and its precision) or
    fits better by more than the level (within both it is the same answer; the landmarks may
    differ where the trajectory does not: replacing it by any lower point of the region made
    Fig. 5's covariances optimistic, benchmarks/README.md). Refined from its points as an EDM
    answer is (the noise settled, covariances), ``start`` its origin. Returns
    (run, failures): when that refinement fails, ``best`` and the failure in words (the caller
    reports it: the answer kept is then not the most likely one)."""
    j = judged.judgement
    own = j.replacement
    if own is None or (own.kind == SAME and own.delta_cost <= cost_level()):
        return best, ()  # the same trajectory, and as likely: the same answer
    lowest = j.answer
    try:
        run = edm_run(problem, best.completion, sigma_ref, pts=lowest.points)[0]
    except SolverError as exc:
        return best, (f"the refinement of the lower minimum of {lowest.origin}: {exc}",)
    log.info("slam: %s reached a lower minimum, which replaced the answer", lowest.origin)
    return dataclasses.replace(run, start=lowest.origin), ()
