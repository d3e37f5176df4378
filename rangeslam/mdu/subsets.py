"""The EDM start at the sizes people have: the convex iteration (eq. 10) on a subset of the
points, the others placed from its answer.

The SDP of N points holds a PSD variable with N (N + 1) / 2 unknowns and Clarabel factors a dense
block of that size squared: memory of order N^4 (slam with 200 steps was killed at 24 GB; 100
steps took 2 GB and minutes). Above :data:`MAX_SDP_POINTS` points the estimators complete the
EDM of a subset and hand the refinement (GTSAM for :func:`rangeslam.mdu.slam`, least squares for
:func:`rangeslam.calibrate`) a start for every point:

- a walk (:class:`WalkKeyframes`): keyframes spread evenly along it, first and last included,
  with every landmark; eq. (11) bounds the distance between consecutive keyframes by the path
  between them (upper: the sum of its steps' upper bounds; lower: its longest lower bound less the
  other steps' upper bounds, at least 0). A step between keyframes starts on the segment that
  joins them.
- an array (:class:`CalibrationCore`): a random core of receivers and sources; the other sources
  are multilaterated from the core receivers, then the other receivers from every source.

The refinement fits every range from there; the verdict judges the refined answer as for a full
SDP.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.geometry.edm import gram_to_edm
from rangeslam.localization.multilateration import multilaterate
from rangeslam.mdu.core import ConvexIterationOptions, convex_iteration_runs, mdu_edm, mdu_mask

if TYPE_CHECKING:  # the SDP back end (cvxpy) is imported where an SDP is solved
    from rangeslam.solvers.sdp import EDMCompletion

__all__ = [
    "MAX_SDP_POINTS",
    "CalibrationCore",
    "WalkKeyframes",
    "core_runs",
    "expanded_completion",
    "keyframe_runs",
]

#: Points (receivers + sources) one SDP takes at most; larger problems complete the EDM of a
#: subset of this size. An SDP solve of 32 points took 0.3 s, of 40 0.8 s, of 48 1.8 s (an
#: unfolding in 3-D; benchmarks/README.md, "The EDM start at the sizes people have"); every
#: problem of the paper's figures is smaller.
MAX_SDP_POINTS = 32


def expanded_completion(completion: EDMCompletion, points: np.ndarray) -> EDMCompletion:
    """``completion`` (of the subset) with its Gram matrix, EDM and points replaced by those of
    ``points`` (N, d), every point placed (centred). The eigen-gap, solves and status stay the
    subset's: they describe the SDP that was solved."""
    centred = points - points.mean(axis=0)
    gram = centred @ centred.T
    return dataclasses.replace(
        completion,
        gram=gram,
        edm=np.maximum(gram_to_edm(gram), 0.0),
        points=centred,
    )


def path_bounds(lower: np.ndarray, upper: np.ndarray, rows: np.ndarray):
    """Bounds (lower, upper), each (len(rows) - 1,), metres, on the distance between consecutive
    keyframes ``rows`` of a walk whose steps are bounded by ``lower`` and ``upper`` (M - 1,): the
    distance is at most the path's length, and at least its longest step less the others."""
    low, up = [], []
    for a, b in itertools.pairwise(rows):
        lo, hi = lower[a:b], upper[a:b]
        total = float(hi.sum())
        up.append(total)
        low.append(max(0.0, float(np.max(lo + hi - total))))
    return np.array(low), np.array(up)


@dataclass(frozen=True)
class WalkKeyframes:
    """The keyframes of a walk of M steps heard by K landmarks.

    Attributes:
        rows: (n,) sorted step indices that enter the SDP.
        m: steps M.
    """

    rows: np.ndarray
    m: int

    @classmethod
    def choose(cls, observed: np.ndarray, dim: int, max_points: int | None = None):
        """Keyframes of the walk with the (M, K) pattern ``observed``: max_points (default
        :data:`MAX_SDP_POINTS`) - K of them, evenly spread (every step when that is all of them),
        plus, for a landmark heard from fewer than d + 1 keyframes, d + 1 of the steps that hear
        it, spread over them."""
        max_points = MAX_SDP_POINTS if max_points is None else max_points
        m, k = observed.shape
        n_key = max(2, max_points - k)
        if m <= n_key:
            return cls(np.arange(m), m)
        rows = set(np.round(np.linspace(0, m - 1, n_key)).astype(int).tolist())
        for col in range(k):
            heard = np.flatnonzero(observed[:, col])
            if np.count_nonzero(observed[sorted(rows), col]) <= dim and len(heard):
                picks = np.round(np.linspace(0, len(heard) - 1, min(dim + 1, len(heard))))
                rows.update(heard[picks.astype(int)].tolist())
        return cls(np.array(sorted(rows)), m)

    @property
    def is_subset(self) -> bool:
        """Whether some steps are left out of the SDP."""
        return len(self.rows) < self.m

    def bounds(self, bounds) -> tuple[np.ndarray, np.ndarray] | None:
        """eq. (11) bounds (lower, upper) between consecutive keyframes, from the step bounds
        (a StepBounds or None)."""
        if bounds is None:
            return None
        return path_bounds(np.asarray(bounds.lower), np.asarray(bounds.upper), self.rows)

    def expand(self, completion: EDMCompletion) -> EDMCompletion:
        """The completion of the keyframes (n + K points) as one of the whole walk (M + K): the
        steps between two keyframes on the segment joining them, in proportion to their index."""
        n = len(self.rows)
        key, landmarks = completion.points[:n], completion.points[n:]
        steps = np.arange(self.m)
        walk = np.column_stack(
            [np.interp(steps, self.rows, key[:, j]) for j in range(key.shape[1])]
        )
        return expanded_completion(completion, np.vstack([walk, landmarks]))


@dataclass(frozen=True)
class CalibrationCore:
    """A core of receivers and sources whose EDM block is completed by the SDP.

    Attributes:
        receivers: (m0,) sorted receiver indices.
        sources: (k0,) sorted source indices.
        shape: (M, K) of the whole problem.
    """

    receivers: np.ndarray
    sources: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def choose(cls, observed: np.ndarray, dim: int, rng: np.random.Generator,
               max_points: int | None = None):  # fmt: skip
        """A random core of at most ``max_points`` (default :data:`MAX_SDP_POINTS`) points,
        split between receivers and sources in proportion to M and K (at least d + 2 of each),
        among the receivers and sources with the most observed ranges; the whole problem when
        it fits."""
        max_points = MAX_SDP_POINTS if max_points is None else max_points
        m, k = observed.shape
        if m + k <= max_points:
            return cls(np.arange(m), np.arange(k), (m, k))
        m0 = int(np.clip(round(max_points * m / (m + k)), min(m, dim + 2), m))
        k0 = int(np.clip(max_points - m0, min(k, dim + 2), k))
        receivers = _heard_most(observed, m0, rng)
        sources = _heard_most(observed[receivers].T, k0, rng)
        return cls(np.sort(receivers), np.sort(sources), (m, k))

    @property
    def is_subset(self) -> bool:
        """Whether some points are left out of the SDP."""
        return len(self.receivers) + len(self.sources) < sum(self.shape)

    def expand(self, completion: EDMCompletion, ranges: np.ndarray, observed: np.ndarray):
        """The completion of the core as one of every point (M + K, d): each other source
        multilaterated (:func:`rangeslam.localization.multilaterate`) from the core receivers
        that hear it, then each other receiver from every source it hears. Raises SolverError
        when a point cannot be placed (fewer than d + 1 placed points range to it, or they do
        not span the space)."""
        m, k = self.shape
        m0 = len(self.receivers)
        pts_r = np.full((m, completion.points.shape[1]), np.nan)
        pts_s = np.full((k, completion.points.shape[1]), np.nan)
        pts_r[self.receivers] = completion.points[:m0]
        pts_s[self.sources] = completion.points[m0:]
        for j in np.setdiff1d(np.arange(k), self.sources):
            pts_s[j] = _placed(pts_r, ranges[:, j], observed[:, j], f"source {j}")
        for i in np.setdiff1d(np.arange(m), self.receivers):
            pts_r[i] = _placed(pts_s, ranges[i], observed[i], f"receiver {i}")
        return expanded_completion(completion, np.vstack([pts_r, pts_s]))


def _heard_most(observed: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` row indices of ``observed`` (R, C) drawn at random among the rows with the most
    observed entries (ties broken at random)."""
    order = np.lexsort((rng.random(observed.shape[0]), -observed.sum(axis=1)))
    return order[:count]


def _placed(anchors: np.ndarray, ranges: np.ndarray, heard: np.ndarray, what: str) -> np.ndarray:
    """(d,) a point multilaterated from the placed ``anchors`` (A, d; NaN rows not yet placed)
    that it ``heard`` (A,) at ``ranges`` (A,), metres."""
    use = heard & np.isfinite(anchors[:, 0])
    if use.sum() <= anchors.shape[1]:
        raise SolverError(
            f"the EDM start could not place {what}: {int(use.sum())} ranges to placed points "
            f"(needs {anchors.shape[1] + 1})"
        )
    try:
        return multilaterate(anchors[use], ranges[use]).position
    except (DegenerateGeometryError, InvalidInputError) as exc:
        raise SolverError(f"the EDM start could not place {what}: {exc}") from exc


def keyframe_runs(
    ranges: np.ndarray, observed: np.ndarray, dim: int, bounds, options: ConvexIterationOptions,
    rng: np.random.Generator, failures: list[str],
):  # fmt: skip
    """Yield the convex-iteration runs (eq. 10 with the eq. 11 bounds, :func:`convex_iteration_runs`)
    of a walk's ranges (M, K) and pattern ``observed`` (M, K), on its keyframes
    (:class:`WalkKeyframes`) and expanded to every step; ``bounds`` a StepBounds or None. SDP
    failures are appended to ``failures``."""
    from rangeslam.solvers.sdp import EDMCompletionSDP  # cvxpy only where an SDP is solved

    keys = WalkKeyframes.choose(observed, dim)
    n = len(keys.rows)
    w = mdu_mask(observed[keys.rows])
    pairs = None if bounds is None else np.column_stack([np.arange(n - 1), np.arange(1, n)])
    sdp = EDMCompletionSDP(w, bounded_pairs=pairs)
    for completion in convex_iteration_runs(
        sdp, mdu_edm(ranges[keys.rows]), w, dim, options=options, rng=rng, failures=failures,
        bounds=keys.bounds(bounds),
    ):  # fmt: skip
        yield keys.expand(completion) if keys.is_subset else completion


def core_runs(
    ranges: np.ndarray, observed: np.ndarray, dim: int, options: ConvexIterationOptions,
    rng: np.random.Generator, failures: list[str], *, loss: str = "l2",
):  # fmt: skip
    """Yield the convex-iteration runs (eq. 10) of an unfolding's ranges (M, K) with pattern
    ``observed`` (M, K) on a core of it (:class:`CalibrationCore`), expanded to every point; a
    run whose expansion fails is lost like a failed SDP (its reason appended to ``failures``).
    ``loss``: the SDP's ("l1" for robust runs)."""
    from rangeslam.solvers.sdp import EDMCompletionSDP  # cvxpy only where an SDP is solved

    core = CalibrationCore.choose(observed, dim, rng)
    block = np.ix_(core.receivers, core.sources)
    w = mdu_mask(observed[block])
    sdp = EDMCompletionSDP(w, loss=loss)
    for completion in convex_iteration_runs(
        sdp, mdu_edm(ranges[block]), w, dim, options=options, rng=rng, failures=failures
    ):
        if not core.is_subset:
            yield completion
            continue
        try:
            yield core.expand(completion, ranges, observed)
        except SolverError as exc:
            failures.append(str(exc))
