"""The breakdown check of a robust answer: what its kernel or its outlier rejection left out.

A robust fit is judged on the ranges it kept (a range it discounted is not held against it), so
the verdict must also ask whether it left out too much: past the 50% breakdown point a wrong
answer fits what is left as well as the right one does (Rousseeuw, "Least median of squares
regression", JASA 1984). Two counts, both on the (M, K) masks of the ranges observed and kept:

- more than half of the redundant ranges dropped: the whole answer is past its breakdown point;
- a point (a receiver's row, or a source's column where ``judge_sources``) that kept at most half
  of its own ranges is placed against the other half of its data.

Measured on robust ``slam`` walks (M = 8, 1 mm, 1-2 wrong picks): a wrong answer 16.6 cm off
kept 3 of one step's 7 ranges and 3 of one landmark's 8 (8 of 56 ranges dropped, under half the
17 redundant ones); another placed a landmark on 2 of its 8 ranges. Right answers drop at most
the wrong picks, one or two of a point's ranges.
"""

from __future__ import annotations

import numpy as np

from rangeslam.status import Status
from rangeslam.verdict.checks import PASSED, Check

__all__ = ["breakdown_check", "outvoted_points"]


def outvoted_points(kept: np.ndarray, observed: np.ndarray, axis: int) -> np.ndarray:
    """Indices of the points that kept at most half of their observed ranges: rows
    (``axis=1``: receivers) or columns (``axis=0``: sources) of the (M, K) masks."""
    n_kept, heard = kept.sum(axis=axis), observed.sum(axis=axis)
    return np.flatnonzero((2 * n_kept <= heard) & (heard > 0))


def breakdown_check(
    kept: np.ndarray,
    observed: np.ndarray,
    redundancy: int,
    *,
    judge_sources: bool,
    names: tuple[str, str] = ("receiver", "source"),
) -> Check:
    """OUTLIERS when the robust answer dropped more than half of the ``redundancy`` redundant
    ranges (observed minus unknowns up to a rigid motion), or when a receiver (or, with
    ``judge_sources``, a source) kept at most half of its ranges; a passed check otherwise.

    ``kept``, ``observed``: (M, K) bool, the ranges the answer kept and those observed;
    ``names``: what the rows and columns are called in the reason ("step", "landmark")."""
    n_obs, n_kept = int(observed.sum()), int(kept.sum())
    if n_obs - n_kept > max(redundancy, 0) / 2:  # without redundancy, any range left out
        return Check(
            Status.OUTLIERS,
            f"{n_obs - n_kept} of the {n_obs} ranges were left out as wrong, more than half the "
            f"{redundancy} redundant ones (a wrong answer can be made to fit by leaving out "
            "enough ranges); ",
        )
    axes = ((names[0], 1), (names[1], 0)) if judge_sources else ((names[0], 1),)
    for name, axis in axes:
        outvoted = outvoted_points(kept, observed, axis)
        if outvoted.size:
            i = int(outvoted[0])
            n_in = int(kept.sum(axis=axis)[i])
            n_heard = int(observed.sum(axis=axis)[i])
            more = f" (and {outvoted.size - 1} more)" if outvoted.size > 1 else ""
            return Check(
                Status.OUTLIERS,
                f"{name} {i}: only {n_in} of its {n_heard} ranges agree with the fit{more}, so "
                "half or more of its data disagree with where it is placed; ",
            )
    return PASSED
