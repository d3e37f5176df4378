"""The robust refit of an unfolding (Problem 2 with wrong echo picks): Cauchy-loss least squares
alternated with resection of misplaced points, then studentized outlier rejection.

Used by :func:`rangeslam.mdu.calibration.calibrate` with ``robust``; every function takes the
(M, K) ranges in metres and the (M, K) boolean mask of the ranges observed (or kept).
"""

from __future__ import annotations

import numpy as np

from rangeslam._robust import mad_sigma, studentized
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.edm import range_matrix
from rangeslam.localization.multilateration import multilaterate
from rangeslam.mdu.core import check_determined, unknowns_up_to_rigid_motion
from rangeslam.solvers.least_squares import (
    UnfoldingFit,
    refine_unfolding,
    unfolding_jacobian,
    unfolding_residuals,
)
from rangeslam.status import Status
from rangeslam.verdict.checks import level_sigmas

__all__ = ["agreeing", "embedding_fit", "reject_outliers", "repair_points", "robust_refit"]


def embedding_fit(points: np.ndarray, m: int, ranges: np.ndarray, mask: np.ndarray):
    """``points`` (M + K, d) metres, the first ``m`` receivers, as an UnfoldingFit with their
    residuals on the (M, K) ``ranges`` where ``mask`` holds (NaN elsewhere); no refinement."""
    residuals = np.where(mask, range_matrix(points[:m], points[m:]) - ranges, np.nan)
    return UnfoldingFit(
        receivers=points[:m],
        sources=points[m:],
        residuals=residuals,
        rms=float(np.sqrt(np.mean(residuals[mask] ** 2))),
        status=Status.CONVERGED,
        message="",
        nfev=0,
    )


def reject_outliers(fit, ranges, mask, dim, noise_std):
    """Studentized-residual test (3 sigma), refit without the outliers, until the set is stable.

    sigma is ``noise_std`` when given and positive, else 1.4826 MAD of the studentized residuals. Ranges are
    only dropped while every point keeps at least ``dim`` of them and the data stay redundant.
    """
    m = mask.shape[0]
    use = mask.copy()
    pairs = np.argwhere(mask)
    seen: list[np.ndarray] = []
    for _ in range(20):
        pts = np.vstack([fit.receivers, fit.sources])
        abs_res = np.abs(unfolding_residuals(pts, m, ranges[mask], pairs))
        stud = studentized(abs_res, unfolding_jacobian(pts, m, pairs), use[mask])
        # a working scale: for exact data (0), as when unknown, the MAD (the first Cauchy fit is
        # still pulled by the wrong picks, and round-off would reject every range); the verdict
        # then judges the inliers as exact
        sigma = noise_std if noise_std else mad_sigma(stud)
        new = mask.copy()
        new[mask] = ~(stud > level_sigmas() * sigma)  # untestable (NaN) ranges stay in
        try:
            check_determined(new, dim, "the inlier set")
        except InvalidInputError:
            return fit, use, "outlier rejection stopped: dropping more ranges would leave too few; "
        if int(new.sum()) <= unknowns_up_to_rigid_motion(sum(mask.shape), dim):
            return fit, use, "outlier rejection stopped: no redundancy left; "
        if np.array_equal(new, use) or any(np.array_equal(new, old) for old in seen):
            return fit, use, ""
        seen.append(use)
        use = new
        fit = refine_unfolding(fit.receivers, fit.sources, ranges, use)
    return fit, use, "inlier set still changing after 20 re-fits; "


def agreeing(p, anchors, r, obs, threshold: float) -> int:
    """How many observed ranges ``r`` from ``anchors`` a point p (d,) meets within threshold."""
    return int(np.sum(np.abs(np.linalg.norm(anchors[obs] - p, axis=1) - r[obs]) <= threshold))


def repair_points(fit: UnfoldingFit, ranges, observed, dim: int, threshold: float, rng):
    """Resection: move each point to where a robust multilateration from the others puts it, when
    more of its ranges then agree (within ``threshold``). Returns (fit, number of points moved).

    A robust loss lets a single misplaced point (a receiver or source folded to the wrong side)
    shed its ranges as outliers at a small cost; this step finds and fixes such points.
    """
    m = len(fit.receivers)
    points = np.vstack([fit.receivers, fit.sources])
    moved = 0
    for i in range(len(points)):
        is_receiver = i < m
        anchors = points[m:] if is_receiver else points[:m]
        r = ranges[i] if is_receiver else ranges[:, i - m]
        obs = observed[i] if is_receiver else observed[:, i - m]
        if obs.sum() < dim + 2:
            continue

        try:
            cand = multilaterate(
                anchors,
                r,
                mask=obs,
                robust=True,
                inlier_threshold=threshold,
                max_hypotheses=200,
                rng=rng,
            )
        except (DegenerateGeometryError, InvalidInputError):
            continue
        if agreeing(cand.position, anchors, r, obs, threshold) > agreeing(
            points[i], anchors, r, obs, threshold
        ):
            points[i] = cand.position
            moved += 1
    if moved:
        fit = embedding_fit(points, m, ranges, observed)
    return fit, moved


def robust_refit(fit: UnfoldingFit, ranges, observed, dim: int, scale: float, rng):
    """Cauchy-loss least squares straight from the SDP's points (a Gaussian step first would be
    pulled by the outliers), alternated with resection of misplaced points; ends refined."""
    note = ""
    for _ in range(3):
        fit = refine_unfolding(
            fit.receivers, fit.sources, ranges, observed, loss="cauchy", loss_scale=scale
        )
        fit, moved = repair_points(fit, ranges, observed, dim, 3 * scale, rng)
        if not moved:
            return fit, note
        note += f"{moved} points re-placed by resection; "
    fit = refine_unfolding(
        fit.receivers, fit.sources, ranges, observed, loss="cauchy", loss_scale=scale
    )
    return fit, note
