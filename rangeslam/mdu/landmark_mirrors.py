"""The landmarks a near-planar walk cannot place: each one's mirror image through the walk.

A microphone that moves in a plane hears a landmark and its reflection through that plane at the
same ranges, so the ranges fix every landmark only up to that reflection; a walk that is nearly
planar leaves the two sides a cost gap of a few noise variances, which the data cannot decide
either (the EDM answer was seen to put every landmark on one side of the walk's plane). Both sides
are tried here, landmark by landmark against the fitted trajectory (the mirror image refined
locally, :func:`rangeslam.verdict.mirror_point`), and a landmark whose mirror image the data
cannot tell apart (:func:`rangeslam.verdict.ambiguity_check`: on the ranges as observed or as the
answer predicts them) is reported as ambiguous with its other position, rather than one side
picked silently.

Held fixed, a flat trajectory (or array) is not quite flat: least squares bends it off its plane
by what the noise pushes it (up to :func:`rangeslam.verdict.flat_limit`, 2.57 sqrt(sigma
scale)) to fit the landmarks on the side they are on, and the mirror image then costs
tens of noise variances more against it (six coplanar microphones of the Fig. 3
scene, 1 mm noise, three of six mirrors flagged though each fits exactly with the microphones
refitted). So where the points hearing a landmark may be flat, a mirror that fails against
them held fixed is judged again with everything refitted (:func:`refitted_gap`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam.geometry.edm import range_matrix
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.verdict import ambiguity_check, expected_mirror_gap, flatness_check, mirror_point

__all__ = ["LandmarkMirrors", "landmark_mirrors", "refitted_gap"]


@dataclass(frozen=True)
class LandmarkMirrors:
    """Per landmark: ``ambiguous`` (K,) bool, its mirror image ``mirrors`` (K, d) metres (NaN
    where it has none or is not ambiguous), and ``cost_gaps`` (K,) how much worse the mirror image
    fits, metres^2 of summed squared range residuals (inf where there is none; with everything
    refitted where that was tried, :func:`refitted_gap`)."""

    ambiguous: np.ndarray
    mirrors: np.ndarray
    cost_gaps: np.ndarray


def landmark_mirrors(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sigma: float | None,
    exact_rms: float,
) -> LandmarkMirrors:
    """Both sides of every landmark: against the trajectory held fixed, and, where the steps
    hearing it may be flat (:func:`rangeslam.verdict.flatness_check` at ``sigma``) and that
    passes, with every point refitted (:func:`refitted_gap`).

    Args:
        receivers: (M, d) the trajectory, metres.
        sources: (K, d) the landmarks, same frame.
        ranges, observed: (M, K) the ranges (metres) and where they were observed.
        sigma: range noise (given or estimated), metres; None or 0 for exact data.
        exact_rms: RMS residual of exact data (round-off), metres.
    """
    k, d = sources.shape
    ambiguous = np.zeros(k, bool)
    mirrors = np.full((k, d), np.nan)
    gaps = np.full(k, np.inf)
    scale = float(np.median(ranges[observed]))
    predicted = range_matrix(receivers, sources)  # the ranges the answer predicts
    for j in range(k):
        heard = observed[:, j]
        anchors, r = receivers[heard], ranges[heard, j]
        mirror = mirror_point(sources[j], anchors, r)
        if mirror is None:
            continue
        res_own = np.linalg.norm(anchors - sources[j], axis=1) - r
        res_mirror = np.linalg.norm(anchors - mirror, axis=1) - r
        gaps[j] = float(res_mirror @ res_mirror - res_own @ res_own)
        expected = expected_mirror_gap(sources[j], anchors)
        what = f"landmark {j}"
        check = ambiguity_check(gaps[j], sigma, exact_rms, what, expected_gap=expected)
        if check.passed and not flatness_check(anchors, sigma, scale, what).passed:
            gaps[j] = min(gaps[j], refitted_gap(receivers, sources, ranges, observed, j, mirror))
            refitted = refitted_gap(receivers, sources, predicted, observed, j, mirror)
            check = ambiguity_check(
                gaps[j], sigma, exact_rms, what, expected_gap=min(expected, refitted)
            )
        if not check.passed:
            ambiguous[j], mirrors[j] = True, mirror
    return LandmarkMirrors(ambiguous, mirrors, gaps)


def refitted_gap(
    receivers: np.ndarray,
    sources: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    j: int,
    mirror: np.ndarray,
) -> float:
    """How much worse landmark ``j`` fits on its other side with every point refitted: least
    squares on the ranges (eq. 9) from the answer with landmark j at ``mirror`` (d,), its sum of
    squared residuals minus the answer's, metres^2. Infinite when the refit fails or returns
    landmark j to its own side (its distances to the other landmarks nearer the answer's than
    the mirror's). ``receivers`` (M, d), ``sources`` (K, d), ``ranges`` and ``observed`` (M, K)
    as for :func:`landmark_mirrors`."""
    start = sources.copy()
    start[j] = mirror
    fit = refine_unfolding(receivers, start, np.where(observed, ranges, 0.0), observed)
    ssr = float(np.sum(fit.residuals[observed] ** 2))
    if not np.isfinite(ssr):
        return float("inf")
    if len(sources) > 1:
        others = np.arange(len(sources)) != j
        reached = range_matrix(fit.sources[j][None], fit.sources[others])[0]
        own = range_matrix(sources[j][None], sources[others])[0]
        flipped = range_matrix(mirror[None], sources[others])[0]
        if np.linalg.norm(reached - own) <= np.linalg.norm(reached - flipped):
            return float("inf")
    own_res = range_matrix(receivers, sources)[observed] - ranges[observed]
    return ssr - float(own_res @ own_res)
