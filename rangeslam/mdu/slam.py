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
from rangeslam._robust import MAD_TO_STD, ROBUST_KERNELS, robust_mode
from rangeslam._validation import as_flag, as_rng, as_scalar, frozen
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.localization.multilateration import multilaterate
from rangeslam.logsteps import logged_step
from rangeslam.mdu.core import (
    ConvexIterationOptions,
    canonical_frame,
    checked_options,
    least_steps,
    rotated_covariances,
    validated_ranges,
)
from rangeslam.mdu.robust_unfolding import agreeing
from rangeslam.mdu.slam_verdict import (
    EXACT_POLISH,
    SlamProblem,
    SlamRun,
    judged_ranges,
    landmark_ambiguity,
    passes,
    slam_verdict,
    trajectory_spread,
)
from rangeslam.mdu.subsets import keyframe_runs
from rangeslam.solvers.gtsam_graph import STEP_PRIORS, GraphFit, refine_graph
from rangeslam.solvers.step_bounds import KNOWN_STEP_WIDTH, StepBounds
from rangeslam.status import HasStatus, Status
from rangeslam.verdict import AMBIGUITY_CHI2, RIVAL_SPREADS, verdict_noise
from rangeslam.verdict.breakdown import outvoted_points
from rangeslam.verdict.thresholds import AGREEMENT_STARTS, EXACT_RTOL, KEPT_SIGMAS

if TYPE_CHECKING:
    from rangeslam.solvers.sdp import EDMCompletion

__all__ = ["SlamResult", "slam"]

log = logging.getLogger(__name__)

# Unknown noise: at most this many re-estimates of sigma from the refined fit.
_NOISE_ROUNDS = 5
# Why "uniform" is the default step prior: in the Fig. 5 setting at 1 cm, the dead zone's MAP
# runs to the bounds and has 2.1-3.0x the mean error at M = 5 to 10; with the true steps anywhere
# in the bounds, not at their centres, "uniform" is still 1.7-2.1x below the dead zone's error
# with centred bounds. Why extra_starts defaults to 0: on Fig. 5 the minima reached are of equal
# cost, and picking the lowest picks the one that fits the noise best (measured: no smaller
# error, NEES 1.1-1.2).


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
            trajectory, rank M d - 3 (2-D) or M d - 6 (3-D).
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
        start: where the answer's GTSAM run started: "edm", "random start j" (one of the
            random starts that check the answer ended clearly lower and replaced it) or "extra
            start j" (of ``extra_starts``); "filter" for the EKF baseline.
        eigen_gap: eigen-gap of the SDP answer used.
        ambiguous_landmarks: (K,) bool, the landmarks whose mirror image through the walk fits
            as well (a near-planar walk cannot tell the two sides apart: see
            :mod:`rangeslam.mdu.landmark_mirrors`); None without the check (EKF baseline).
        landmark_mirrors: (K, d) the other position of each ambiguous landmark, same frame,
            metres; NaN for the others.
        inliers: (M, K) bool, the ranges the verdict judged: every observed one, or with a
            robust kernel those it kept (residual within KEPT_SIGMAS noise standard deviations,
            :data:`rangeslam.verdict.thresholds.KEPT_SIGMAS`); None for methods without it.
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
    ambiguous_landmarks: np.ndarray | None = None
    landmark_mirrors: np.ndarray | None = None
    inliers: np.ndarray | None = None

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


def nominal_steps(bounds, r: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(M - 1,) step lengths for a start: the bounds' midpoints, or without bounds the least
    each step must be by the triangle inequality, max_k |r_(i+1)k - r_ik| (its median where no
    landmark is heard at both steps)."""
    if bounds is not None:
        lower, upper = bounds
        return 0.5 * (lower + upper)
    least = least_steps(r, observed)
    heard = (observed[:-1] & observed[1:]).any(axis=1)
    fill = float(np.median(least[heard])) if heard.any() else 1.0
    return np.where(heard & (least > 0), least, fill)


def random_start(
    steps: np.ndarray, k: int, dim: int, size: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The start GTSAM's range-only examples use when nothing better is known: a random walk with
    the given step lengths, landmarks uniform in [-size, size]^d."""
    directions = rng.standard_normal((len(steps), dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    walk = np.vstack([np.zeros(dim), np.cumsum(directions * steps[:, None], axis=0)])
    return walk, rng.uniform(-size, size, size=(k, dim))


@dataclass(frozen=True)
class EdmSearch:
    """The best run (of the convex-iteration runs and the random starts that replaced them),
    runs made, SDP failures, the sigma runs are ranked on, the run :func:`rival_search` already
    cleared (None if none)."""

    best: SlamRun | None
    attempts: int
    failures: tuple[str, ...]
    sigma_ref: float | None
    rival_checked: SlamRun | None = None


@dataclass(frozen=True)
class RivalSearch:
    """What GTSAM from AGREEMENT_STARTS random starts found beside an answer: ``reason`` when one
    ends as low with a trajectory far off ("" if none), whether one ``confirmed`` the best
    trajectory, and the ``best`` run after them (a start that ends clearly lower replaces the
    answer)."""

    reason: str
    confirmed: bool
    best: SlamRun


@dataclass(frozen=True)
class Acceptance:
    """:func:`accepted`'s decision: ``ok`` to stop, the ``rivals`` searched (None if not), and
    the ``run`` to keep."""

    ok: bool
    rivals: RivalSearch | None
    run: SlamRun


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


def graph_fit(
    problem: SlamProblem,
    pts: np.ndarray,
    sigma: float,
    *,
    covariances: bool = False,
    max_iterations: int = 5000,
) -> GraphFit:
    """GTSAM on the problem's ranges and step priors from ``pts`` (M + K, d), range sigma
    ``sigma`` metres."""
    m = problem.ranges.shape[0]
    return refine_graph(
        pts[:m],
        pts[m:],
        problem.ranges,
        noise_std=sigma,
        mask=problem.observed,
        step_bounds=problem.bounds,
        step_sigma=problem.step_sigma,
        step_prior=problem.step_prior,
        robust=problem.robust,
        covariances=covariances,
        # a planar trajectory leaves landmarks near its plane in a flat valley (their mirror
        # images meet there), and few steps leave the shape itself in one: at M = 5 and
        # 1 mm, 1000 LM iterations are typical
        max_iterations=max_iterations,
    )


def noise_from(problem: SlamProblem, pts: np.ndarray, dof: int) -> float:
    """Range sigma (metres) from the residuals of ``pts`` (M + K, d) over ``dof`` degrees of
    freedom; with a robust kernel MAD_TO_STD times their median |residual| (wrong echoes must not
    set the scale)."""
    m = problem.ranges.shape[0]
    res = (range_matrix(pts[:m], pts[m:]) - problem.ranges)[problem.observed]
    if problem.robust is not None:
        return float(MAD_TO_STD * np.median(np.abs(res)) * np.sqrt(problem.n_obs / dof))
    return float(np.sqrt(np.sum(res**2) / dof))


def _stacked(fit: GraphFit) -> np.ndarray:
    """(M + K, d) the fit's receivers above its sources."""
    return np.vstack([fit.receivers, fit.sources])


def settle_noise(problem: SlamProblem, pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Unknown noise: the range sigma from the EDM answer's RMS residual (biased by the SDP's
    penalty), then from the refined fit's (sum of squares over the redundancy) until it settles.
    Returns (refined points (M + K, d), sigma; 0 for exact data)."""
    floor = problem.floor
    sigma = max(noise_from(problem, pts, problem.n_obs), floor)
    fit = graph_fit(problem, pts, sigma)
    for _ in range(_NOISE_ROUNDS if problem.redundancy > 0 else 0):
        new = max(noise_from(problem, _stacked(fit), problem.redundancy), floor)
        settled = abs(new - sigma) <= 0.1 * sigma
        # the latest estimate is kept: at the floor it says exact data (an earlier one, a few
        # % above it, weighed the step prior against mm of noise that is not there: 4.3 mm off)
        sigma = new
        if settled:
            break
        fit = graph_fit(problem, _stacked(fit), sigma)
    if sigma <= floor:  # no noise to be seen: exact data
        sigma = 0.0
    return _stacked(fit), sigma


def refine_run(
    problem: SlamProblem, pts: np.ndarray, sigma: float | None = None, *, covariances: bool = True
) -> tuple[GraphFit, float]:
    """GTSAM from ``pts`` (with covariances unless ``covariances=False``); the range sigma of its
    final graph. ``sigma``: that of the graph (default: ``noise_std``, or found from the
    residuals when unknown)."""
    if sigma is None and problem.noise_std is None:
        # The weight of the step prior against the ranges depends on the sigma.
        pts, sigma = settle_noise(problem, pts)
    elif sigma is None:
        sigma = problem.noise_std
    floor = problem.floor
    if sigma >= floor:
        return graph_fit(problem, pts, sigma, covariances=covariances), sigma
    # Below the floor LM does not move from a distant start (at 1e-6 of the scale it made no
    # step at all): first at the floor, then at sigma itself, or for exact data (where the
    # floor would let the step prior pull by up to mm) with the ranges weighed as exact.
    target = sigma if sigma > 0 else EXACT_POLISH * floor
    fit = graph_fit(problem, pts, floor)
    return graph_fit(problem, _stacked(fit), target, covariances=covariances), target


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
    run = SlamRun(ssr, rec, src, fit, completion, res, ssr if fit is None else fit.error)
    if sigma_ref is not None and sigma != sigma_ref:
        run = rekeyed(problem, run, sigma_ref)  # ranked on the reference graph
    return run, sigma


def rekeyed(problem: SlamProblem, run: SlamRun | None, sigma: float) -> SlamRun | None:
    """``run`` with its key on the graph of range sigma ``sigma`` (its cost there, where it is;
    runs without GTSAM keep their sum of squares)."""
    if run is None or run.fit is None:
        return run
    key = graph_fit(problem, _stacked(run.fit), sigma, max_iterations=0).error
    return dataclasses.replace(run, key=key)


def accepted(problem: SlamProblem, run: SlamRun, others, sigma_ref, rng) -> Acceptance:
    """Whether the search may stop at ``run`` (or at a lower minimum a random start found).

    It may when the run passes the residual test (:func:`passes`), or, with
    ``edm_start="cheap"`` and GTSAM's refinement, when the verdict accepts it: :func:`slam_verdict`
    (the residuals against the noise or, without ``noise_std``, against the scene and their own
    tail; the trajectory's information and flatness) passes, GTSAM from random starts
    (:func:`rival_search`) ends at no other trajectory of equal cost, and a second start reached
    the same trajectory (one of those random starts, or one of the earlier runs ``others``):
    without a noise level a wrong minimum's residual can pass, so it must be reached twice, as
    calibrate's vote asks. A random start that ends clearly lower replaces the run (the graph's
    cost ranks the EDM answer and the random starts alike), but the search stops there only once
    a convex-iteration run reached it too."""
    if passes(problem, run):
        return Acceptance(True, None, run)
    if problem.options.start != "cheap" or run.fit is None:
        return Acceptance(False, None, run)
    rivals = rival_search(problem, run, sigma_ref, rng)
    best = rivals.best
    if rivals.reason or slam_verdict(problem, best, (), ())[0] is not Status.CONVERGED:
        return Acceptance(False, rivals, best)
    noise = verdict_noise(problem.noise_std, sigma_ref or 0.0, EXACT_RTOL * problem.scale)
    far = max(RIVAL_SPREADS * trajectory_spread(best, noise), 1e-6 * problem.scale)

    def near(other: SlamRun) -> bool:
        return align(other.receivers, best.receivers, reflection=True).rmse <= far

    confirmed = rivals.confirmed or any(near(o) for o in others if o is not best)
    # a random start's minimum that no convex-iteration run reached waits for the next run: two
    # random starts can agree on a wrong minimum that the EDM start avoids (measured: 24 cm off)
    edm_agrees = any(near(o) for o in (run, *others) if o.start == "edm")
    return Acceptance(confirmed and edm_agrees, rivals, best)


@logged_step(log, "slam: EDM starts (convex iteration), each refined with GTSAM")
def search_edm_runs(problem: SlamProblem, rng) -> EdmSearch:
    """Convex-iteration runs (eq. 10, with eq. 11 step bounds) until one is :func:`accepted`;
    the best by its key otherwise."""
    failures: list[str] = []
    best, attempts, sigma_ref, runs, verdict = None, 0, None, [], None
    for completion in keyframe_runs(problem.ranges, problem.observed, problem.dim,
                                    problem.bounds, problem.options, rng, failures):  # fmt: skip
        attempts += 1
        run, sigma = edm_run(problem, completion, sigma_ref)
        if sigma is not None and sigma_ref is not None and sigma < sigma_ref:
            # a wrong minimum inflates the noise it settles at: rank on the best-fitting graph
            sigma_ref, run, best = (
                sigma,
                rekeyed(problem, run, sigma),
                rekeyed(problem, best, sigma),
            )
        if sigma_ref is None:
            sigma_ref = sigma
        if problem.robust:
            run = resected(problem, run, sigma_ref, rng)
        # the lowest answer so far is the one checked (random starts may confirm or beat it)
        candidate = run if best is None or run.key < best.key else best
        verdict = accepted(problem, candidate, runs, sigma_ref, rng)
        runs.extend(r for r in (run, verdict.run) if all(r is not o for o in runs))
        if best is None or verdict.run.key < best.key or verdict.ok:  # one that passes is taken
            best = verdict.run
        if verdict.ok:
            break
    cleared = best if verdict is not None and verdict.ok and verdict.rivals else None
    return EdmSearch(best, attempts, tuple(failures), sigma_ref, cleared)


def resected(problem: SlamProblem, run: SlamRun, sigma_ref, rng) -> SlamRun:
    """A robust run whose kernel left out half or more of a step's or a landmark's ranges
    (:func:`rangeslam.verdict.breakdown.outvoted_points`) with those points moved to where a
    robust multilateration from the others puts them (when more of their ranges agree there,
    within KEPT_SIGMAS of the noise), then refined as an EDM answer is (:func:`edm_run`); kept
    when its graph cost (on the graph of ``sigma_ref``) is lower, else ``run``. A kernel lets a
    landmark sit where 2-3 of its 8 ranges and a wrong pick agree, shedding the right ranges at
    a small cost; the trajectory is right and places it again."""
    if run.fit is None:
        return run
    kept = judged_ranges(problem, run)[0]
    observed, m = problem.observed, problem.ranges.shape[0]
    noise = verdict_noise(problem.noise_std, sigma_ref, EXACT_RTOL * problem.scale)
    threshold = KEPT_SIGMAS * max(noise or 0.0, problem.floor)
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


def try_random_starts(problem: SlamProblem, best: SlamRun, sigma_ref, rng):
    """GTSAM also from ``extra_starts`` GTSAM-style starts (a random walk of the nominal step,
    landmarks uniform in a box of the largest range); the graph's cost decides. Where the ranges
    leave the shape nearly free (few steps, no bounds, a planar path) LM from the EDM answer can
    stop in a valley another start avoids. Returns (best run, failures)."""
    r, observed = problem.ranges, problem.observed
    start_failures = []
    nominal = nominal_steps(problem.bounds, r, observed)
    for j in range(problem.extra_starts):
        x0, s0 = random_start(nominal, r.shape[1], problem.dim, float(np.max(r[observed])), rng)
        try:
            fit_j, _ = refine_run(problem, np.vstack([x0, s0]), sigma_ref, covariances=False)
        except SolverError as exc:  # LM diverged
            start_failures.append(f"extra start {j}: {exc}")
            continue
        if fit_j.error < best.key:
            lower = lower_minimum(problem, fit_j, best, sigma_ref, f"extra start {j}")
            if lower is None:
                start_failures.append(f"extra start {j}: covariances undefined")
                continue
            best = lower
    return best, start_failures


def slam_result(problem: SlamProblem, best: SlamRun, attempts: int, status, message) -> SlamResult:
    """The :class:`SlamResult` of the best run, in the canonical frame (covariances rotated)."""
    m = problem.ranges.shape[0]
    rec_f, src_f, rot = canonical_frame(best.receivers, best.sources)
    cov_r = cov_s = cov_traj = None
    if best.fit is not None:
        cov_r, cov_s, cov_traj = rotated_covariances(best.fit, rot)
    pts = best.completion.points
    edm_rec, edm_src, _ = canonical_frame(pts[:m], pts[m:])
    mirrors = landmark_ambiguity(problem, best, rec_f, src_f)
    kept = judged_ranges(problem, best)[0]
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
            answer is then judged on the ranges the kernel kept (residual within KEPT_SIGMAS
            noise standard deviations; ``SlamResult.inliers``, ``outliers``, ``n_outliers``),
            and is OUTLIERS when it left out more than half the redundant ranges or half of one
            step's or one landmark's (:mod:`rangeslam.verdict.breakdown`).
        step_sigma: scale of the step prior outside the bounds, metres (default: the noise).
        step_prior: how GTSAM reads the bounds: "uniform" (default: the step length uniform on
            [lower, upper], as a dead zone plus its moment-matched Gaussian) or "dead_zone" (no
            cost inside the bounds; its MAP runs to the bounds where the ranges leave the shape
            free).
        max_attempts: convex-iteration runs at most (fit weights x1, x10, x0.1, x100 from Z = I,
            then random Z), until one passes the residual test.
        extra_starts: GTSAM runs from GTSAM-style random starts besides the EDM answer's; the
            lowest graph cost wins (``SlamResult.start`` says which). Default 0, the EDM answer
            only.
        fit_weight, max_iterations: as for :func:`rangeslam.calibrate`.
        edm_start: "cheap" (default): stop at the first convex-iteration run whose refined
            answer the verdict accepts, once GTSAM from AGREEMENT_STARTS random starts found no
            rival and confirmed it (a start that ends clearly lower replaces it), each run also
            stopped once its rank-d embedding settled; "full": every run to the eigen-gap
            tolerance until one passes the residual test (the older schedule).
        rng: Generator or seed for the random restarts.

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
    best, status, message = judged_answer(problem, found, rng)
    return slam_result(problem, best, found.attempts, status, message)


def judged_answer(problem: SlamProblem, found: EdmSearch, rng) -> tuple[SlamRun, Status, str]:
    """The search's best run after the ``extra_starts``, its verdict, and "restarts agree"
    (:func:`rival_search`, unless the search already cleared it): a random start that ends
    clearly lower is judged in its place, a rival of equal cost makes it NOT_IDENTIFIABLE."""
    best, start_failures = found.best, []
    if problem.refine and problem.extra_starts:
        best, start_failures = try_random_starts(problem, best, found.sigma_ref, rng)
    status, message = slam_verdict(problem, best, found.failures, start_failures)
    if status is Status.CONVERGED and problem.refine and best is not found.rival_checked:
        rivals = rival_search(problem, best, found.sigma_ref, rng)
        if rivals.best is not best:
            best = rivals.best
            status, message = slam_verdict(problem, best, found.failures, start_failures)
        if rivals.reason and status is Status.CONVERGED:
            status = Status.NOT_IDENTIFIABLE
            message = "; ".join(filter(None, (message, rivals.reason)))
    return best, status, message


@logged_step(log, "slam: looking for rival minima (verdict)")
def rival_search(problem: SlamProblem, best: SlamRun, sigma_ref, rng) -> RivalSearch:
    """GTSAM from AGREEMENT_STARTS GTSAM-style random starts (:func:`random_start`), on the graph
    of ``sigma_ref``, beside the answer ``best``; the graph's cost ranks them all alike.

    A start that ends lower than the answer by more than AMBIGUITY_CHI2 / 2 replaces it (a
    smaller gain on a trajectory near it is LM's stopping tolerance in the same valley: swapping
    for it raised the lemniscate's mean NEES / dof from inside its 99% band to 1.15) (refined again from there as an EDM answer is,
    :func:`edm_run`); one that ends within AMBIGUITY_CHI2 / 2 of it with a trajectory more than
    RIVAL_SPREADS times its RMS standard deviation off (RMS after the best rigid motion with
    reflection) is a rival: the data cannot tell them apart; one that ends near it confirms it."""
    r, observed = problem.ranges, problem.observed
    nominal = nominal_steps(problem.bounds, r, observed)
    size, margin = float(np.max(r[observed])), 0.5 * AMBIGUITY_CHI2
    confirmed = False
    for j in range(AGREEMENT_STARTS):
        x0, s0 = random_start(nominal, r.shape[1], problem.dim, size, rng)
        try:
            fit, _ = refine_run(problem, np.vstack([x0, s0]), sigma_ref, covariances=False)
        except SolverError:
            continue
        if not fit.converged or fit.error > best.key + margin:
            continue
        apart = align(fit.receivers, best.receivers, reflection=True).rmse
        near = apart <= max(
            RIVAL_SPREADS
            * trajectory_spread(
                best, verdict_noise(problem.noise_std, sigma_ref or 0.0, EXACT_RTOL * problem.scale)
            ),
            1e-6 * problem.scale,  # exact data: round-off apart
        )
        if fit.error < best.key - margin:
            lower = lower_minimum(problem, fit, best, sigma_ref, f"random start {j}")
            if lower is not None and lower.key < best.key:
                best, confirmed = lower, near
            continue
        if not near:
            reason = (
                f"another start fits the data as well (graph cost {fit.error:.4g} against "
                f"{best.key:.4g}) with a trajectory {apart:.3g} m RMS away: the ranges do not "
                "decide between them"
            )
            return RivalSearch(reason, confirmed, best)
        confirmed = True
    return RivalSearch("", confirmed, best)


def lower_minimum(problem: SlamProblem, fit: GraphFit, replaced: SlamRun, sigma_ref, start: str):
    """The :class:`SlamRun` of a random start's ``fit`` that ended lower than ``replaced``:
    refined from there as an EDM answer is (:func:`edm_run`: the noise settled, covariances,
    ranked on the graph of ``sigma_ref``), named ``start``; None when its covariances are
    undefined."""
    try:
        run = edm_run(problem, replaced.completion, sigma_ref, pts=_stacked(fit))[0]
    except SolverError:
        return None
    # its key: the lower of the two costs on the ranking graph (the refinement settles its own
    # noise, so its point is optimal on another graph; the basin is ranked by its lowest cost)
    return dataclasses.replace(run, key=min(run.key, fit.error), start=start)
