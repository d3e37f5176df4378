"""The landmarks a near-planar walk cannot place: each one's mirror image through the walk.

A microphone that moves in a plane hears a landmark and its reflection through that plane at the
same ranges, so the ranges fix every landmark only up to that reflection; a walk that is nearly
planar leaves the two sides a cost gap of a few noise variances, which the data cannot decide
either (issue 18: the EDM answer put every landmark on one side of the walk's plane). Both sides
are tried here, landmark by landmark against the fitted trajectory (the mirror image refined
locally, :func:`rangeslam.verdict.mirror_point`), and a landmark whose mirror image fits within
:func:`rangeslam.verdict.ambiguity_check`'s margin is reported as ambiguous with its other
position, rather than one side picked silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam.verdict import ambiguity_check, mirror_point

__all__ = ["LandmarkMirrors", "landmark_mirrors"]


@dataclass(frozen=True)
class LandmarkMirrors:
    """Per landmark: ``ambiguous`` (K,) bool, its mirror image ``mirrors`` (K, d) metres (NaN
    where it has none or is not ambiguous), and ``cost_gaps`` (K,) how much worse the mirror image
    fits, metres^2 of summed squared range residuals (inf where there is none)."""

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
    """Both sides of every landmark against the trajectory held fixed.

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
    for j in range(k):
        heard = observed[:, j]
        anchors, r = receivers[heard], ranges[heard, j]
        mirror = mirror_point(sources[j], anchors, r)
        if mirror is None:
            continue
        res_own = np.linalg.norm(anchors - sources[j], axis=1) - r
        res_mirror = np.linalg.norm(anchors - mirror, axis=1) - r
        gaps[j] = float(res_mirror @ res_mirror - res_own @ res_own)
        if not ambiguity_check(gaps[j], sigma, exact_rms, f"landmark {j}").passed:
            ambiguous[j], mirrors[j] = True, mirror
    return LandmarkMirrors(ambiguous, mirrors, gaps)
