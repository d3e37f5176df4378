"""The verdict of :func:`rangeslam.mdu.slam` on one answer: what it judges and how.

A robust answer (a GTSAM kernel against wrong echoes) is judged on the ranges its kernel kept
(:func:`judged_ranges`): the chi-square test of :func:`rangeslam.mdu.core.residual_status` runs
on those, and :func:`rangeslam.verdict.breakdown.breakdown_check` asks whether it left out too
many (in all, or of one step's or one landmark's ranges). The trajectory's information and
flatness (:func:`trajectory_check`) and the landmarks' mirror images (:func:`landmark_ambiguity`)
are judged on the same ranges at the same noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from rangeslam._robust import mad_sigma, studentized
from rangeslam.mdu.core import (
    SIGMA_FLOOR,
    ConvexIterationOptions,
    passes_residual_test,
    residual_status,
    step_prior_rows,
    unfolding_check,
    unknowns_up_to_rigid_motion,
)
from rangeslam.mdu.landmark_mirrors import LandmarkMirrors, landmark_mirrors
from rangeslam.solvers.gtsam_graph import GraphFit
from rangeslam.solvers.least_squares import unfolding_jacobian
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import Status
from rangeslam.verdict import noise_upper_bound, verdict_noise
from rangeslam.verdict.breakdown import breakdown_check
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.thresholds import EXACT_RTOL, TAIL_SCALE_FLOOR

if TYPE_CHECKING:
    from rangeslam.solvers.sdp import EDMCompletion

__all__ = [
    "EXACT_POLISH",
    "SlamProblem",
    "SlamRun",
    "judged_ranges",
    "kept_ranges",
    "landmark_ambiguity",
    "passes",
    "pinned_coordinates",
    "robust_breakdown",
    "run_mirrors",
    "slam_verdict",
    "trajectory_check",
]

#: The exact-data graph is finished at this fraction of the sigma floor (see
#: :func:`rangeslam.mdu.slam.refine_run`); a robust answer to exact data keeps its ranges
#: against it.
EXACT_POLISH = 1e-3


@dataclass(frozen=True)
class SlamProblem:
    """The validated inputs of :func:`slam` (built once by :func:`parse_slam`), and ``memo``:
    the checks of each run made so far in this call (:func:`trajectory_check`,
    :func:`run_mirrors`), which the verdict and the result share (keyed by the run's identity, the run kept with its entry; a problem made from this one by
    ``dataclasses.replace`` starts with an empty memo)."""

    ranges: np.ndarray  # (M, K) metres, 0 where not observed
    observed: np.ndarray  # (M, K) bool
    scale: float  # median observed range, metres
    dim: int
    bounds: StepBounds | None
    noise_std: float | None
    robust: str | None
    step_sigma: float | None
    step_prior: str
    refine: bool
    extra_starts: int
    options: ConvexIterationOptions
    memo: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    @property
    def n_obs(self) -> int:
        """Observed ranges."""
        return int(self.observed.sum())

    @property
    def redundancy(self) -> int:
        """Observed ranges minus unknowns up to a rigid motion."""
        return self.n_obs - unknowns_up_to_rigid_motion(sum(self.ranges.shape), self.dim)

    @property
    def floor(self) -> float:
        """The least range sigma of the graph, metres (SIGMA_FLOOR of the median range)."""
        return SIGMA_FLOOR * self.scale


@dataclass(frozen=True)
class SlamRun:
    """One answer: squared range residual sum (m^2), trajectory (M, d) and landmarks (K, d), the
    GTSAM fit (None without refinement), the SDP answer it came from, residuals (M, K), the
    key runs are ranked by (the graph's cost, or ``ssr`` without refinement), and where its GTSAM
    run started (:attr:`SlamResult.start`); ``planar``: the trajectory was fitted in its plane
    (M - 3 fewer unknowns: :mod:`rangeslam.mdu.planar_walk`); ``sigma`` the range sigma of the
    fit's graph (None without refinement)."""

    ssr: float
    receivers: np.ndarray
    sources: np.ndarray
    fit: GraphFit | None
    completion: EDMCompletion
    residuals: np.ndarray
    key: float
    start: str = "edm"
    planar: bool = False  # the receivers held in a plane (rangeslam.mdu.planar_walk)
    sigma: float | None = None  # the range sigma of the fit's graph, metres


def passes(problem: SlamProblem, run: SlamRun) -> bool:
    """The residual test (:func:`passes_residual_test`) on the ranges the verdict judges
    (:func:`judged_ranges`: with a robust kernel, those it kept), and, with a kernel, no more
    ranges dropped than the breakdown allows (:func:`robust_breakdown`)."""
    kept, res, _ = judged_ranges(problem, run)
    if problem.robust and not robust_breakdown(problem, kept).passed:
        return False
    n = sum(problem.ranges.shape)
    exact_rms = EXACT_RTOL * problem.scale
    return passes_residual_test(
        float(res @ res), int(kept.sum()), n, problem.dim, problem.noise_std, exact_rms
    )


def slam_verdict(problem: SlamProblem, best: SlamRun, failures, start_failures):
    """(status, message): the residual verdict (:func:`residual_status`) on the ranges the
    verdict judges (:func:`judged_ranges`: with a robust kernel, those it kept), OUTLIERS when
    the kernel discounted more ranges than the breakdown allows, SOLVER_FAILED when GTSAM did
    not converge."""
    message = ""
    if failures:
        message += f"{len(failures)} SDP runs failed ({failures[0]}); "
    if start_failures:
        message += f"GTSAM failed from {'; '.join(start_failures)}; "
    kept, res, redundancy = judged_ranges(problem, best)
    status, why = residual_status(
        float(res @ res),
        kept,
        problem.dim,
        problem.noise_std,
        problem.scale,
        chi_square=problem.noise_std is not None and redundancy > 0,
        bounded=problem.bounds is not None,
    )
    message += why
    breakdown = robust_breakdown(problem, kept) if problem.robust else None
    if breakdown is not None and not breakdown.passed:  # the deeper reason of a failed test
        status, message = breakdown.status, message + breakdown.reason
    if best.fit is not None and not best.fit.converged:
        status = Status.SOLVER_FAILED if status is Status.CONVERGED else status
        message += f"GTSAM: {best.fit.message}; "
    if status is Status.CONVERGED:
        check = trajectory_check(problem, best)
        status, message = check.status, message + check.reason
    return status, message.rstrip("; ")


def robust_breakdown(problem: SlamProblem, kept: np.ndarray):
    """:func:`rangeslam.verdict.breakdown.breakdown_check` of a robust answer that kept the
    (M, K) ranges ``kept``: steps and landmarks alike (each is a point located from its ranges)."""
    return breakdown_check(
        kept, problem.observed, problem.redundancy, judge_sources=True, names=("step", "landmark")
    )


def kept_ranges(problem: SlamProblem, best: SlamRun) -> np.ndarray:
    """(M, K) bool: the observed ranges a robust kernel kept at ``best``, those within
    level_sigmas() standard deviations (3.29) of the noise.

    With ``noise_std`` the test is |residual| <= level_sigmas() noise_std (0 is exact data: the
    sigma the exact graph was finished at, EXACT_POLISH of the floor). Without it the residuals
    are studentized by their leverage in the range fit (:func:`rangeslam._robust.studentized`: a
    point heard by few ranges fits them nearly exactly, and the raw residuals' MAD then
    understates the noise) and tested against 1.4826 times their median, at least
    TAIL_SCALE_FLOOR of the scene as in the tail test: a kernel's fit at a noise level settled
    near the floor is L1-like and fits half the ranges exactly (the first fit of a walk from
    simulated RIRs: median |residual| 0, 90% under 0.22 mm, and 60 of 129 right ranges left out
    against their MAD alone); untestable ranges (leverage near 1) are kept."""
    observed = problem.observed
    exact_rms = EXACT_RTOL * problem.scale
    abs_res = np.abs(best.residuals[observed])
    if problem.noise_std is None:
        pairs = np.argwhere(observed)
        pts = np.vstack([best.receivers, best.sources])
        jac = unfolding_jacobian(pts, problem.ranges.shape[0], pairs)
        test = studentized(abs_res, jac, np.ones(len(pairs), dtype=bool))
        sigma = max(mad_sigma(test), TAIL_SCALE_FLOOR * problem.scale)
    elif problem.noise_std == 0:  # exact data: the sigma their graph was finished at
        test, sigma = abs_res, max(EXACT_POLISH * problem.floor, exact_rms)
    else:
        test, sigma = abs_res, max(problem.noise_std, exact_rms)
    kept = observed.copy()
    kept[observed] = ~(test > level_sigmas() * sigma)  # NaN: untestable, kept
    return kept


def judged_ranges(problem: SlamProblem, best: SlamRun) -> tuple[np.ndarray, np.ndarray, int]:
    """What the verdict judges ``best`` on: the (M, K) ranges (all observed ones; with a robust
    kernel only those it kept, :func:`kept_ranges`), their residuals (metres) and their
    redundancy (of a planar run, M - 3 more)."""
    observed = kept_ranges(problem, best) if problem.robust else problem.observed
    unknowns = unknowns_up_to_rigid_motion(sum(problem.ranges.shape), problem.dim)
    redundancy = int(observed.sum()) - unknowns + pinned_coordinates(problem, best)
    return observed, best.residuals[observed], redundancy


def pinned_coordinates(problem: SlamProblem, run: SlamRun) -> int:
    """Coordinates a planar run's model holds: each step's offset across the plane, less the
    plane's own three (a translation and two tilts, gauge); 0 for a run in 3-D."""
    return problem.ranges.shape[0] - 3 if run.planar else 0


def memoised(problem: SlamProblem, name: str, run: SlamRun, compute):
    """``compute()`` for ``run``, made once per :func:`slam` call (``problem.memo``)."""
    key = (name, id(run))
    hit = problem.memo.get(key)
    if hit is None or hit[0] is not run:  # the run is kept with its entry: ids are not reused
        hit = problem.memo[key] = (run, compute())
    return hit[1]


def trajectory_check(problem: SlamProblem, best: SlamRun):
    """:func:`rangeslam.mdu.core.unfolding_check` of the best run with the step priors' rows, on
    the :func:`judged_ranges` (once per run: :func:`memoised`): a 3-D run's (the verdict is
    made before the walk is refitted in its plane)."""
    return memoised(problem, "trajectory", best, lambda: _trajectory_check(problem, best))


def _trajectory_check(problem: SlamProblem, best: SlamRun):
    observed, res, redundancy = judged_ranges(problem, best)
    estimate = float(np.sqrt(res @ res / redundancy)) if redundancy > 0 else 0.0
    sigma = verdict_noise(problem.noise_std, estimate, EXACT_RTOL * problem.scale)
    n_points = sum(problem.ranges.shape)
    return unfolding_check(
        best.receivers,
        best.sources,
        problem.ranges,
        observed,
        problem.noise_std,
        EXACT_RTOL * problem.scale,
        prior_jac=step_prior_rows(
            problem.bounds, problem.step_prior, problem.step_sigma, best.receivers, sigma, n_points
        )
        if sigma
        else None,
        what="the trajectory",
        judge_sources="none",
        source_mirrors=run_mirrors(problem, best),
    )


def run_mirrors(problem: SlamProblem, best: SlamRun) -> LandmarkMirrors:
    """:func:`landmark_mirrors` of the run (in its own frame) on the ranges and at the noise the
    verdict's note uses (the :func:`judged_ranges`; ``noise_std``, else the largest noise their
    residuals allow), once per run (:func:`memoised`): the verdict's note and the result's
    ``ambiguous_landmarks`` are the same computation."""

    def compute():
        observed, res, redundancy = judged_ranges(problem, best)
        exact_rms = EXACT_RTOL * problem.scale
        sigma = verdict_noise(
            problem.noise_std, noise_upper_bound(float(res @ res), redundancy), exact_rms
        )
        return landmark_mirrors(
            best.receivers, best.sources, problem.ranges, observed, sigma, exact_rms
        )

    return memoised(problem, "mirrors", best, compute)


def landmark_ambiguity(
    problem: SlamProblem, best: SlamRun, centre: np.ndarray, rotation: np.ndarray
) -> LandmarkMirrors:
    """:func:`run_mirrors` with the mirror images in the frame reported: (p - ``centre`` (d,))
    @ ``rotation`` (d, d), as :func:`rangeslam.mdu.core.canonical_frame` moves the points."""
    found = run_mirrors(problem, best)
    return LandmarkMirrors(found.ambiguous, (found.mirrors - centre) @ rotation, found.cost_gaps)
