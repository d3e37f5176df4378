"""The GTSAM graph of :func:`rangeslam.mdu.slam`: one fit of the problem's ranges and step
priors from given points (:func:`graph_fit`, :func:`refine_run`), the noise settled from the
residuals when unknown (:func:`settle_noise`), and the GTSAM-style random starts
(:func:`random_start`). Shared by the search (:mod:`rangeslam.mdu.slam`) and the judge of its
alternatives (:mod:`rangeslam.mdu.slam_judge`).
"""

from __future__ import annotations

import numpy as np

from rangeslam._robust import MAD_TO_STD
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.core import least_steps
from rangeslam.mdu.slam_verdict import EXACT_POLISH, SlamProblem
from rangeslam.solvers.graph_minpack import minpack_refine
from rangeslam.solvers.gtsam_graph import GraphFit, refine_graph

__all__ = [
    "graph_fit",
    "noise_from",
    "nominal_steps",
    "random_start",
    "refine_run",
    "settle_noise",
    "stacked",
]

# Unknown noise: at most this many re-estimates of sigma from the refined fit.
_NOISE_ROUNDS = 5


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


def graph_fit(
    problem: SlamProblem,
    pts: np.ndarray,
    sigma: float,
    *,
    covariances: bool = False,
    max_iterations: int = 5000,
    plane: np.ndarray | None = None,
    minpack: bool = False,
) -> GraphFit:
    """GTSAM on the problem's ranges and step priors from ``pts`` (M + K, d), range sigma
    ``sigma`` metres; with ``plane`` (a (3,) normal) the receivers held in their plane across it
    (:func:`rangeslam.solvers.gtsam_graph.refine_graph`'s ``receiver_plane``). With ``minpack``
    the same Gaussian graph by MINPACK (:func:`rangeslam.solvers.graph_minpack.minpack_refine`:
    no robust kernel or covariances)."""
    m = problem.ranges.shape[0]
    if minpack:  # (a robust kernel is refused by graph_minpack.graph_terms)
        if covariances:
            raise ValueError("graph_fit: minpack fits without covariances")
        return minpack_refine(
            pts[:m], pts[m:], problem.ranges, noise_std=sigma, mask=problem.observed,
            step_bounds=problem.bounds, step_sigma=problem.step_sigma,
            step_prior=problem.step_prior, max_iterations=max_iterations, receiver_plane=plane,
        )  # fmt: skip
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
        receiver_plane=plane,
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


def stacked(fit: GraphFit) -> np.ndarray:
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
        new = max(noise_from(problem, stacked(fit), problem.redundancy), floor)
        settled = abs(new - sigma) <= 0.1 * sigma
        # the latest estimate is kept: at the floor it says exact data (an earlier one, a few
        # % above it, weighed the step prior against mm of noise that is not there: 4.3 mm off)
        sigma = new
        if settled:
            break
        fit = graph_fit(problem, stacked(fit), sigma)
    if sigma <= floor:  # no noise to be seen: exact data
        sigma = 0.0
    return stacked(fit), sigma


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
    # floor would let the step prior pull by up to mm) with the ranges weighed as exact. A
    # sigma below that is exact data too: whitened by 1e-155 m, the graph's error overflowed.
    target = max(sigma, EXACT_POLISH * floor)
    fit = graph_fit(problem, pts, floor)
    return graph_fit(problem, stacked(fit), target, covariances=covariances), target


def graph_deviance(problem: SlamProblem, pts: np.ndarray, sigma: float) -> float:
    """-2 log likelihood of ``pts`` (M + K, d) on the graph of range sigma ``sigma`` (metres),
    dimensionless: twice GTSAM's error (half the whitened squared sum) over every observed range
    and step prior, with the robust kernel's cost where there is one; evaluated where the points
    are (no iteration; a Gaussian graph's by :mod:`rangeslam.solvers.graph_minpack`, the same
    cost without building GTSAM's graph)."""
    gaussian = problem.robust is None
    return 2.0 * graph_fit(problem, pts, sigma, max_iterations=0, minpack=gaussian).error
