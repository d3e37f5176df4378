"""Where another answer of an unfolding may lie: generators of alternatives for the judge.

Each generator yields :class:`Proposal` s, starting points for the estimator's own fit; none holds
a threshold (whether an alternative fits as well is the judge's one test,
:func:`rangeslam.verdict.judge.judge`):

- :func:`random_proposals`: points drawn at random in a box of the scene's size (the starts the
  stopping rule :func:`rangeslam.verdict.judge.search_complete` counts);
- :func:`block_proposals`: the answer refitted without one block of the data (one source's
  ranges, one receiver's, one window of steps), then on all of it from there: a block that holds
  the answer in a wrong basin lets the others move it out (dEchorate: dropping one source reached
  the right basin that no start did);
- :func:`mirror_proposals`: each point reflected in the best plane (line in 2-D) of the points it
  is ranged to: the discrete gauge of a source heard by coplanar receivers;
- :func:`fold_proposal`: the points on one side of the best plane of them all reflected onto the
  other: a flat scene fitted in a dimension more.

Points are rows: the answer is (M + K, d), receivers above sources.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from rangeslam.verdict.checks import range_gauss_newton, reflected

__all__ = [
    "Proposal",
    "block_proposals",
    "fold_proposal",
    "mirror_proposals",
    "random_proposals",
    "window_proposals",
]


@dataclass(frozen=True)
class Proposal:
    """A start for the estimator's fit: ``points`` (M + K, d), the ``origin`` in words, ``without``
    ((M, K) bool or None): ranges to leave out of a first fit, the full fit following from there;
    ``ambiguous`` rows and ``ambiguity`` words when the proposal is a named discrete gauge;
    ``counted``: whether it samples the basins at random (the stopping rule counts those);
    ``fitted``: already fitted (scored as it is)."""

    points: np.ndarray
    origin: str
    without: np.ndarray | None = None
    ambiguous: tuple[int, ...] = ()
    ambiguity: str = ""
    counted: bool = False
    fitted: bool = False


def random_proposals(n_points: int, dim: int, scale: float, rng) -> Iterator[Proposal]:
    """Random starts without end: (n_points, dim) standard normal times ``scale`` metres."""
    j = 0
    while True:
        points = rng.standard_normal((n_points, dim)) * scale
        yield Proposal(points, f"random start {j}", counted=True)
        j += 1


def block_proposals(
    answer: np.ndarray, observed: np.ndarray, *, blocks: str = "both", names=("receiver", "source")
) -> Iterator[Proposal]:
    """The answer (M + K, d) with one block of its (M, K) ``observed`` ranges left out of a first
    fit: each column (a source), then each row (a receiver), as ``blocks`` says ("columns",
    "rows" or "both"); ``names`` says what a row and a column are. Blocks whose removal leaves a
    point with no range are skipped (the point would be free)."""
    m, k = observed.shape
    if blocks in ("columns", "both"):
        for j in range(k):
            without = np.zeros_like(observed)
            without[:, j] = observed[:, j]
            if (observed & ~without).any(axis=1).all():
                yield Proposal(answer, f"the refit without {names[1]} {j}", without)
    if blocks in ("rows", "both"):
        for i in range(m):
            without = np.zeros_like(observed)
            without[i] = observed[i]
            if (observed & ~without).any(axis=0).all():
                yield Proposal(answer, f"the refit without {names[0]} {i}", without)


def window_proposals(answer: np.ndarray, observed: np.ndarray, width: int) -> Iterator[Proposal]:
    """The answer with ``width`` consecutive rows (steps of a walk) left out of a first fit, for
    each window of non-overlapping rows."""
    m = observed.shape[0]
    for start in range(0, m, max(int(width), 1)):
        without = np.zeros_like(observed)
        without[start : start + width] = observed[start : start + width]
        if (observed & ~without).any(axis=0).all():
            stop = min(start + width, m) - 1
            yield Proposal(answer, f"the refit without steps {start}-{stop}", without)


def mirror_proposals(
    answer: np.ndarray,
    m: int,
    ranges: np.ndarray,
    observed: np.ndarray,
    names=("receiver", "source"),
) -> Iterator[Proposal]:
    """Each point of the answer (M + K, d) reflected in the best plane of the points it is
    ranged to (at least d of them) and refitted alone on its (M, K) ``ranges`` with those held
    (a source among its receivers, a receiver among its sources): the discrete gauge of a point
    whose partners are coplanar. ``fitted``: the estimator scores it as it is."""
    d = answer.shape[1]
    for row in range(len(answer)):
        is_receiver = row < m
        heard = observed[row] if is_receiver else observed[:, row - m]
        anchors = answer[m:][heard] if is_receiver else answer[:m][heard]
        if len(anchors) < d:
            continue
        r = ranges[row, heard] if is_receiver else ranges[heard, row - m]
        points = answer.copy()
        points[row] = range_gauss_newton(reflected(answer[[row]], anchors)[0], anchors, r)
        name, index = (names[0], row) if is_receiver else (names[1], row - m)
        words = f"{name} {index}'s side of the plane of the points it is ranged to"
        yield Proposal(points, f"{name} {index} mirrored", None, (row,), words, fitted=True)


def fold_proposal(answer: np.ndarray) -> Proposal:
    """The answer (N, d) with the points on the positive side of its own best plane reflected
    onto the other side: a flat scene fitted in a dimension more folds this way."""
    centre = answer.mean(axis=0)
    normal = np.linalg.svd(answer - centre, full_matrices=False)[2][-1]
    side = (answer - centre) @ normal > 0
    points = answer.copy()
    points[side] = reflected(answer[side], answer)
    return Proposal(points, "the answer folded in its best plane")
