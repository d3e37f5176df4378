"""Robust starts for multilateration: LMedS or MSAC over minimal anchor subsets. Pure numpy.

Squaring ||x - a_m|| + b = r_m linearises the range equations (eq. 3 of the paper; (E1) of
:mod:`rangeslam.localization.emission` with an offset b):

    r_m^2 - ||a_m||^2 = -2 a_m.x [+ 2 r_m b] + t,       t = ||x||^2 [- b^2]

so a subset of d + 1 (d + 2 with the offset) anchors gives the exact solution of a square linear
system. Every subset's point is scored on all anchors by the h-th smallest squared range residual
(least median of squares, Rousseeuw, "Least median of squares regression", JASA 1984) or, with a
known threshold, by the truncated squared residuals (MSAC, Torr and Zisserman 2000), which
tolerates more than half wrong ranges when the wrong ones disagree among themselves.

With a threshold, the best hypotheses are refitted on the ranges near them and scored again
(LO-RANSAC, :func:`locally_optimised`): a minimal subset's point carries its few ranges' noise.

:func:`refine_inliers` then repeats threshold-and-refit (reweighted least squares, Rousseeuw and
Leroy 1987) from that start until the inlier set repeats.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rangeslam._robust import MAD_TO_STD
from rangeslam._validation import as_scalar
from rangeslam.verdict import range_gauss_newton

__all__ = [
    "InlierSearch",
    "Refit",
    "RobustStart",
    "check_robust_options",
    "minimal_subset_points",
    "minimal_subsets",
    "offset_range_residuals",
    "refine_inliers",
    "robust_start",
]

#: Refits of :func:`refine_inliers` before it gives up on a changing inlier set.
MAX_REFITS = 20
#: Standard deviation of a unit normal truncated to +-2.5: residuals kept by a 2.5 sigma
#: threshold are that much too tight.
TRUNCATED_STD = 0.9546
#: Local optimisation of MSAC (LO-RANSAC, Chum, Matas and Kittler 2003): the best LO_HYPOTHESES
#: minimal-subset points are refitted by linear least squares on their ranges within LO_FACTOR x
#: the threshold and scored again. A minimal subset's point carries the noise of d + 1 ranges
#: amplified by their geometry: on a direct path with 6 right picks of 12 (1 mm noise), all 15
#: right subsets gave points 5-70 mm off that missed the other right ranges by more than the
#: 4.3 mm threshold, and 4 wrong picks that agree by chance won.
LO_HYPOTHESES = 20
LO_FACTOR = 10.0


@dataclass(frozen=True)
class RobustStart:
    """The best minimal-subset hypothesis.

    Attributes:
        z: (d,) point x, or (d + 1,) point and offset (x, b) with ``offset``.
        sigma: robust standard deviation of its range residuals (units of the ranges).
    """

    z: np.ndarray
    sigma: float


@dataclass(frozen=True)
class Refit:
    """One refit on an inlier set: the new estimate ``z``, the fit it came from (the caller's
    type) and the new inlier threshold (None keeps the old one)."""

    z: np.ndarray
    fit: object
    threshold: float | None


@dataclass(frozen=True)
class InlierSearch:
    """Outcome of :func:`refine_inliers`.

    Attributes:
        z: the last estimate (the start when nothing was refitted).
        fit: the last :attr:`Refit.fit` (None when nothing was refitted).
        inliers: (M,) the last inlier set that was fitted (all False when none was).
        rejected: (M,) the candidate set that ended the search because ``enough`` refused it;
            None otherwise.
        threshold: the last inlier threshold on |range residual| (units of the ranges).
        settled: True when the inlier set repeated (the search converged).
    """

    z: np.ndarray
    fit: object
    inliers: np.ndarray
    rejected: np.ndarray | None
    threshold: float
    settled: bool


def offset_range_residuals(z: np.ndarray, anchors: np.ndarray, ranges: np.ndarray, offset: bool):
    """||x - a_m|| [+ b] - r_m for z = x (or (x, b) with ``offset``), (q,) or (H, q) hypotheses."""
    x = z[..., :-1] if offset else z
    dist = np.linalg.norm(anchors - x[..., None, :], axis=-1)
    if offset:
        return dist + z[..., -1][..., None] - ranges
    return dist - ranges


def minimal_subsets(candidates: np.ndarray, p: int, max_subsets: int, rng) -> np.ndarray:
    """(H, p) subsets of p of the ``candidates``: all when at most ``max_subsets``, else random."""
    if math.comb(len(candidates), p) <= max_subsets:
        return np.array(list(itertools.combinations(candidates, p)), dtype=int).reshape(-1, p)
    return candidates[np.argsort(rng.random((max_subsets, len(candidates))), axis=1)[:, :p]]


def linearised_system(anchors: np.ndarray, ranges: np.ndarray, offset: bool):
    """The linearised range equations (module docstring) of anchors (..., p, d) and ranges
    (..., p): the matrix (..., p, q + 1) with columns [-2 a, (2 r), 1] for unknowns (x, (b), t)
    and the right-hand side r^2 - ||a||^2 (..., p)."""
    cols = [-2.0 * anchors]
    if offset:
        cols.append(2.0 * ranges[..., None])
    cols.append(np.ones((*anchors.shape[:-1], 1)))
    rhs = ranges**2 - np.einsum("...d,...d->...", anchors, anchors)
    return np.concatenate(cols, axis=-1), rhs


def subset_solutions(
    anchors: np.ndarray, ranges: np.ndarray, subsets: np.ndarray, offset: bool
) -> np.ndarray:
    """(H', q) exact solutions of the linearised range equations of each (H, p) subset
    (:func:`linearised_system`); q = d (+1 with ``offset``). Affinely dependent subsets
    (smallest singular value below 1e-8 of the largest) are skipped.
    """
    d = anchors.shape[1]
    mat, rhs = linearised_system(anchors[subsets], ranges[subsets], offset)
    sv = np.linalg.svd(mat, compute_uv=False)
    ok = sv[:, -1] > 1e-8 * sv[:, 0]
    return np.linalg.solve(mat[ok], rhs[ok][..., None])[..., 0][:, : d + int(offset)]


def minimal_subset_points(
    anchors: np.ndarray,
    ranges: np.ndarray,
    candidates: np.ndarray,
    max_subsets: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points (H, d) from subsets of d+1 of the ``candidates`` (indices into anchors (M, d)).

    Each subset gives the exact solution of the linear system [-2 a^T, 1] [x; t] = r^2 - ||a||^2
    (d+1 equations, d+1 unknowns); all subsets when there are at most ``max_subsets`` of them,
    otherwise that many random ones. Affinely dependent subsets are skipped.
    """
    subsets = minimal_subsets(candidates, anchors.shape[1] + 1, max_subsets, rng)
    return subset_solutions(anchors, ranges, subsets, offset=False)


def robust_start(
    anchors: np.ndarray,
    ranges: np.ndarray,
    *,
    offset: bool = False,
    max_hypotheses: int,
    rng: np.random.Generator,
    threshold: float | None = None,
) -> RobustStart | None:
    """LMedS (or MSAC with ``threshold``) hypothesis over minimal subsets of anchors (M, d).

    Unknowns q = d (x) or d + 1 (x and the range offset b with ``offset``); subsets have q + 1
    members (the linear system also carries t). None when every subset is affinely dependent.
    """
    n, d = anchors.shape
    q = d + int(offset)
    p = q + 1
    subsets = minimal_subsets(np.arange(n), p, max_hypotheses, rng)
    z = subset_solutions(anchors, ranges, subsets, offset)
    if len(z) == 0:
        return None
    res2 = offset_range_residuals(z, anchors, ranges, offset) ** 2
    if threshold is not None:
        refits = locally_optimised(z, res2, anchors, ranges, offset, threshold)
        z = np.vstack([z, refits])
        res2 = np.vstack([res2, offset_range_residuals(refits, anchors, ranges, offset) ** 2])
    h = (n + p + 1) // 2  # Rousseeuw's order statistic for the highest breakdown point
    lmeds = np.partition(res2, h - 1, axis=1)[:, h - 1]
    score = lmeds if threshold is None else np.minimum(res2, threshold**2).sum(axis=1)
    best = int(np.argmin(score))
    # Finite-sample consistency correction of Rousseeuw and Leroy (1987) for the q unknowns.
    sigma = MAD_TO_STD * (1.0 + 5.0 / max(n - q, 1)) * math.sqrt(lmeds[best])
    return RobustStart(z=z[best], sigma=sigma)


def locally_optimised(
    z: np.ndarray,
    res2: np.ndarray,
    anchors: np.ndarray,
    ranges: np.ndarray,
    offset: bool,
    threshold: float,
) -> np.ndarray:
    """(H', q) the best :data:`LO_HYPOTHESES` of the hypotheses ``z`` (H, q) by their MSAC score
    at LO_FACTOR x ``threshold`` (a point a few thresholds off still scores its true inliers
    there; ``res2`` (H, N) their squared range residuals), each refitted on the anchors whose
    range it fits within that (when those are more than the unknowns and not affinely
    dependent): linear least squares on the linearised range equations, then 5 Gauss-Newton
    steps on the ranges (the linearised equations weigh far anchors more: their solution on 6
    right ranges of 1 mm noise was 7 mm off, after these 1 mm)."""
    loose2 = (LO_FACTOR * threshold) ** 2
    top = np.argsort(np.minimum(res2, loose2).sum(axis=1), kind="stable")[:LO_HYPOTHESES]
    refits = []
    for h in top:
        near = np.flatnonzero(res2[h] <= loose2)
        if len(near) > z.shape[1] + 1:
            near_a, near_r = anchors[near], ranges[near]
            mat, rhs = linearised_system(near_a, near_r, offset)
            sol, _, rank, _ = np.linalg.lstsq(mat, rhs, rcond=None)
            if rank == mat.shape[1]:
                refits.append(range_gauss_newton(sol[:-1], near_a, near_r, offset=offset, steps=5))
    return np.array(refits).reshape(-1, z.shape[1])


def refine_inliers(
    residuals: Callable[[np.ndarray], np.ndarray],
    refit: Callable[[np.ndarray], Refit],
    z: np.ndarray,
    candidates: np.ndarray,
    threshold: float,
    enough: Callable[[np.ndarray], bool],
) -> InlierSearch:
    """Keep the ``candidates`` (M,) with |residuals(z)| <= threshold, refit, until the set repeats.

    ``refit(inliers)`` fits the inliers (a :class:`Refit`); ``enough(inliers)`` says whether a
    set can be fitted at all (the search stops when it cannot). A cycle through borderline ranges
    counts as repeating. At most :data:`MAX_REFITS` refits.
    """
    inliers = np.zeros(len(candidates), dtype=bool)
    seen: list[np.ndarray] = []
    fit = None
    for _ in range(MAX_REFITS):
        new = candidates & (np.abs(residuals(z)) <= threshold)
        if not enough(new):
            return InlierSearch(z, fit, inliers, new, threshold, settled=False)
        if any(np.array_equal(new, old) for old in [inliers, *seen]):
            return InlierSearch(z, fit, inliers, None, threshold, settled=True)
        seen.append(inliers)
        inliers = new
        step = refit(inliers)
        z, fit = step.z, step.fit
        if step.threshold is not None:
            threshold = step.threshold
    return InlierSearch(z, fit, inliers, None, threshold, settled=False)


def check_robust_options(inlier_threshold, max_hypotheses) -> tuple[float | None, int]:
    """The robust options checked at the door: (threshold in metres > 0 or None, count >= 1).

    Raises InvalidInputError naming the option (strings, bools, arrays, NaN or inf refused).
    """
    # The ceiling keeps squared thresholds finite (1e100 m is no physical threshold).
    threshold = as_scalar(
        inlier_threshold, "inlier_threshold", low=0.0, low_open=True, high=1e100, allow_none=True
    )
    return threshold, as_scalar(max_hypotheses, "max_hypotheses", low=1, integer=True)
