"""Acoustic range-only SLAM (paper, section 4): one moving microphone, a loudspeaker and its images.

The microphone's positions r_1..r_M along an unknown trajectory are the receivers, the loudspeaker
and its image sources the landmarks: the same unfolding as zero-knowledge calibration (eq. 9).
Bounds on the step length |r_{i+1} - r_i| enter the convex iteration as constraints on
K(G)_{i,i+1} (eq. 11), and the EDM solution initialises a GTSAM range-factor graph with the same
bounds as step-length priors (:mod:`rangeslam.solvers.gtsam_graph`), which refines it and gives
covariances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import frozen
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.core import (
    EXACT_RTOL,
    SIGMA_FLOOR,
    canonical_frame,
    convex_iteration_runs,
    least_steps,
    mdu_edm,
    mdu_mask,
    passes_residual_test,
    residual_verdict,
    rotated_covariances,
    unknowns_up_to_rigid_motion,
    validated_ranges,
)
from rangeslam.solvers.gtsam_graph import STEP_PRIORS, GraphFit, check_step_bounds, refine_graph

__all__ = ["SlamResult", "slam"]

# ... after which exact data are finished at this fraction of the floor.
_EXACT_POLISH = 1e-3
# Unknown noise: at most this many re-estimates of sigma from the refined fit.
_NOISE_ROUNDS = 3


@dataclass(frozen=True)
class SlamResult:
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
            for methods without an EDM step, such as the EKF baseline).
        edm_sources: (K, d) likewise.
        residual_rms: RMS range residual, metres.
        converged: the answer passed the residual test (chi-square against ``noise_std``).
        message: why not, when ``converged`` is False.
        attempts: convex-iteration runs made.
        start: where the answer's GTSAM run started: "edm" or "random start j" ("filter" for
            the EKF baseline).
        eigen_gap: eigen-gap of the SDP answer used.
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
    converged: bool
    message: str
    attempts: int
    start: str
    eigen_gap: float


def _check_bounds_against_ranges(bounds, r, observed, noise_std) -> None:
    """Refuse step bounds that no positions can meet: by the triangle inequality, for every
    landmark k heard at steps i and i + 1, |r_ik - r_(i+1)k| <= |x_(i+1) - x_i| <= r_ik + r_(i+1)k
    (with 4 sigma of slack for the noise, or 1% of the range when noise_std is unknown)."""
    lower, upper = bounds
    both = observed[:-1] & observed[1:]
    slack_abs = 0.0 if noise_std is None else 4 * np.sqrt(2) * noise_std
    least_all = least_steps(r, observed)
    for i in np.flatnonzero(both.any(axis=1)):
        a, b = r[i, both[i]], r[i + 1, both[i]]
        slack = slack_abs if noise_std is not None else 0.01 * float(np.max(a + b))
        least, most = float(least_all[i]), float(np.min(a + b))
        if upper[i] < least - slack or lower[i] > most + slack:
            raise InvalidInputError(
                f"step_bounds contradict the ranges at step {i}: [{lower[i]:.4g}, {upper[i]:.4g}] m "
                f"lies outside [{least:.4g}, {most:.4g}] m, what the ranges to the same landmarks "
                "allow (triangle inequality)"
            )


def nominal_steps(bounds, r: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(M - 1,) step lengths for a start: the bounds' midpoints, or without bounds the least
    each step must be by the triangle inequality, max_k |r_(i+1)k - r_ik| (its median where no
    landmark is heard at both steps)."""
    if bounds is not None:
        return 0.5 * (bounds[0] + bounds[1])
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


def slam(
    ranges: ArrayLike,
    *,
    step_bounds: tuple[ArrayLike, ArrayLike] | None = None,
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
    rng: np.random.Generator | int | None = None,
) -> SlamResult:
    """Trajectory (M, d) and landmarks (K, d) from the ranges (M, K) of a moving microphone.

    Args:
        ranges: (M, K) range from step m to landmark k, metres.
        step_bounds: (lower, upper), each (M - 1,), bounds on |r_{i+1} - r_i| in metres: eq. (11)
            constraints in the SDP and step priors (``step_prior``) in the GTSAM refinement.
        mask: (M, K) boolean, True where observed.
        dim: 2 or 3.
        refine: refine the EDM answer with GTSAM (and compute covariances).
        noise_std: range noise standard deviation, metres. Weighs the graph and sets the residual
            test; when None it is estimated from the residuals of the EDM answer.
        robust: GTSAM kernel against wrong echoes: None, "huber", "cauchy" or "tukey".
        step_sigma: scale of the step prior outside the bounds, metres (default: the noise).
        step_prior: how GTSAM reads the bounds: "uniform" (default: the step length uniform on
            [lower, upper], as a dead zone plus its moment-matched Gaussian) or "dead_zone" (no
            cost inside the bounds; its MAP runs to the bounds where the ranges leave the shape
            free: in the Fig. 5 setting at 1 cm, 2.1-3.0x the mean error at M = 5 to 10; with
            the true steps anywhere in the bounds, not at their centres, "uniform" is still
            1.7-2.1x below the dead zone's error with centred bounds).
        max_attempts: convex-iteration runs at most (fit weights x1, x10, x0.1, x100 from Z = I,
            then random Z), until one passes the residual test.
        extra_starts: GTSAM runs from GTSAM-style random starts besides the EDM answer's; the
            lowest graph cost wins (``SlamResult.start`` says which). Default 0, the EDM answer
            only: on Fig. 5 the minima reached are of equal cost, and picking the lowest picks
            the one that fits the noise best (measured: no smaller error, NEES 1.1-1.2).
        fit_weight, max_iterations: as for :func:`rangeslam.calibrate`.
        rng: Generator or seed for the random restarts.

    Raises InvalidInputError for bad input: step bounds of the wrong length, lower > upper,
    negative bounds, bounds the ranges contradict (triangle inequality, named by step), an
    under-determined mask. SolverError when the SDP fails in every run.
    """
    from rangeslam.solvers.sdp import EDMCompletionSDP

    r, observed, scale = validated_ranges(ranges, mask, dim, noise_std)
    m, k = r.shape
    bounds = None if step_bounds is None else check_step_bounds(step_bounds, m)
    if bounds is not None:
        _check_bounds_against_ranges(bounds, r, observed, noise_std)
    if step_prior not in STEP_PRIORS:
        raise InvalidInputError(f"step_prior must be one of {STEP_PRIORS}; got {step_prior!r}")
    if not (isinstance(extra_starts, int | np.integer) and extra_starts >= 0):
        raise InvalidInputError(f"extra_starts must be an integer >= 0; got {extra_starts!r}")
    if not (isinstance(max_attempts, int | np.integer) and max_attempts >= 1):
        raise InvalidInputError(f"max_attempts must be a positive integer; got {max_attempts!r}")
    rng = np.random.default_rng(rng)
    n = m + k
    n_obs = int(observed.sum())
    exact_rms = EXACT_RTOL * scale
    w = mdu_mask(observed)
    d_tilde = mdu_edm(r)
    pairs = np.column_stack([np.arange(m - 1), np.arange(1, m)]) if bounds else None
    problem = EDMCompletionSDP(w, bounded_pairs=pairs)
    redundancy = n_obs - unknowns_up_to_rigid_motion(n, dim)

    floor = SIGMA_FLOOR * scale

    def graph(
        pts: np.ndarray, sigma: float, *, covariances: bool = False, max_iterations: int = 5000
    ) -> GraphFit:
        return refine_graph(
            pts[:m],
            pts[m:],
            r,
            noise_std=sigma,
            mask=observed,
            step_bounds=bounds,
            step_sigma=step_sigma,
            step_prior=step_prior,
            robust=robust,
            covariances=covariances,
            # a planar trajectory leaves landmarks near its plane in a flat valley (their mirror
            # images meet there), and few steps leave the shape itself in one: at M = 5 and
            # 1 mm, 1000 LM iterations are typical
            max_iterations=max_iterations,
        )

    def noise_from(pts: np.ndarray, dof: int) -> float:
        res = (range_matrix(pts[:m], pts[m:]) - r)[observed]
        if robust is not None:  # wrong echoes must not set the scale: MAD
            return float(1.4826 * np.median(np.abs(res)) * np.sqrt(n_obs / dof))
        return float(np.sqrt(np.sum(res**2) / dof))

    def stacked(fit: GraphFit) -> np.ndarray:
        return np.vstack([fit.receivers, fit.sources])

    def refine_run(pts: np.ndarray, sigma: float | None = None) -> tuple[GraphFit, float]:
        """GTSAM from ``pts`` with covariances; the range sigma of its final graph. ``sigma``:
        that of the graph (default: ``noise_std``, or found from the residuals when unknown)."""
        if sigma is None and noise_std is None:
            # Unknown noise: first the EDM answer's RMS residual (biased by the SDP's penalty),
            # then the refined fit's (sum of squares over the redundancy) until it settles. The
            # weight of the step prior against the ranges depends on it.
            sigma = max(noise_from(pts, n_obs), floor)
            fit = graph(pts, sigma)
            for _ in range(_NOISE_ROUNDS if redundancy > 0 else 0):
                new = max(noise_from(stacked(fit), redundancy), floor)
                if abs(new - sigma) <= 0.1 * sigma:
                    break
                sigma = new
                fit = graph(stacked(fit), sigma)
            pts = stacked(fit)
            if sigma <= floor:  # no noise to be seen: exact data
                sigma = 0.0
        elif sigma is None:
            sigma = noise_std
        if sigma >= floor:
            return graph(pts, sigma, covariances=True), sigma
        # Below the floor LM does not move from a distant start (at 1e-6 of the scale it made no
        # step at all): first at the floor, then at sigma itself, or for exact data (where the
        # floor would let the step prior pull by up to mm) with the ranges weighed as exact.
        target = sigma if sigma > 0 else _EXACT_POLISH * floor
        fit = graph(pts, floor)
        return graph(stacked(fit), target, covariances=True), target

    failures: list[str] = []
    best = None
    attempts = 0
    sigma_ref = None  # runs are compared on one graph: the first run's sigma
    for completion in convex_iteration_runs(
        problem,
        d_tilde,
        w,
        dim,
        max_attempts=max_attempts,
        fit_weight=fit_weight,
        max_iterations=max_iterations,
        gap_tol=1e-6,
        rng=rng,
        failures=failures,
        bounds=bounds,
    ):
        attempts += 1
        pts = completion.points
        fit: GraphFit | None = None
        key = None
        if refine:
            fit, sigma = refine_run(pts)
            rec, src = fit.receivers, fit.sources
            if sigma_ref is None:
                sigma_ref = sigma
            # Runs are ranked by the graph's cost (ranges and step priors), not by the ranges
            # alone: a low range residual bought by breaking the step bounds is no better answer.
            # All on one graph, the first run's.
            key = fit.error
            if sigma != sigma_ref:
                key = graph(stacked(fit), sigma_ref, max_iterations=0).error
        else:
            rec, src = pts[:m], pts[m:]
        res = range_matrix(rec, src) - r
        ssr = float(np.sum(res[observed] ** 2))
        key = ssr if key is None else key
        passes = passes_residual_test(ssr, n_obs, n, dim, noise_std, exact_rms)
        if best is None or key < best[-1] or passes:  # a run that passes is taken as it is
            best = (ssr, rec, src, fit, completion, res, key)
        if passes:
            break
    if best is None:
        raise SolverError(
            "SLAM found no solution: the SDP failed in every run (with step bounds, they may "
            "not hold together with the ranges)",
            status="; ".join(dict.fromkeys(failures)),
        )
    start = "edm"
    start_failures: list[str] = []
    if refine and extra_starts:
        # GTSAM also from GTSAM-style starts (random walk of the nominal step, landmarks uniform
        # in a box of the largest range); the graph's cost decides. Where the ranges leave the
        # shape nearly free (few steps, no bounds, a planar path) LM from the EDM answer can stop
        # in a valley another start avoids.
        nominal = nominal_steps(bounds, r, observed)
        for j in range(extra_starts):
            x0, s0 = random_start(nominal, k, dim, float(np.max(r[observed])), rng)
            try:
                fit_j, _ = refine_run(np.vstack([x0, s0]), sigma_ref)
            except SolverError as exc:  # LM diverged, or the covariances are undefined there
                start_failures.append(f"random start {j}: {exc}")
                continue
            if fit_j.error < best[-1]:
                res_j = range_matrix(fit_j.receivers, fit_j.sources) - r
                ssr_j = float(np.sum(res_j[observed] ** 2))
                best = (ssr_j, fit_j.receivers, fit_j.sources, fit_j, best[4], res_j, fit_j.error)
                start = f"random start {j}"
    ssr, rec, src, fit, completion, res, _ = best
    rms = float(np.sqrt(ssr / n_obs))
    message = ""
    if failures:
        message += f"{len(failures)} SDP runs failed ({failures[0]}); "
    if start_failures:
        message += f"GTSAM failed from {'; '.join(start_failures)}; "
    converged, why = residual_verdict(
        ssr,
        observed,
        dim,
        noise_std,
        scale,
        chi_square=noise_std is not None and redundancy > 0,
        bounded=bounds is not None,
    )
    message += why
    if fit is not None and not fit.converged:
        converged = False
        message += f"GTSAM: {fit.message}; "
    rec_f, src_f, rot = canonical_frame(rec, src)
    cov_r = cov_s = cov_traj = None
    if fit is not None:
        cov_r, cov_s, cov_traj = rotated_covariances(fit, rot)
    pts = completion.points
    edm_rec, edm_src, _ = canonical_frame(pts[:m], pts[m:])
    return SlamResult(
        receivers=frozen(rec_f),
        sources=frozen(src_f),
        receiver_cov=None if cov_r is None else frozen(cov_r),
        source_cov=None if cov_s is None else frozen(cov_s),
        trajectory_cov=None if cov_traj is None else frozen(cov_traj),
        residuals=frozen(np.where(observed, res, np.nan)),
        edm_receivers=frozen(edm_rec),
        edm_sources=frozen(edm_src),
        residual_rms=rms,
        converged=bool(converged),
        message=message.rstrip("; "),
        attempts=attempts,
        start=start,
        eigen_gap=completion.eigen_gap,
    )
