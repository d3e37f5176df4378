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
- an array (:class:`CalibrationCore`): a random core of receivers and sources; the other points
  are multilaterated, sweep by sweep, from the placed points they have ranges to.

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
from rangeslam.mdu.core import (
    ConvexIterationOptions,
    check_determined,
    convex_iteration_runs,
    mdu_edm,
    mdu_mask,
)

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
#: Random cores drawn at most before the whole problem is taken (a core from which some point
#: cannot be placed is drawn again).
CORE_DRAWS = 5


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
        """Keyframes of the walk with the (M, K) pattern ``observed``, at most max_points
        (default :data:`MAX_SDP_POINTS`) - K of them (every step when that is all of them):
        evenly spread steps, plus, for a landmark heard from fewer than d + 1 of those, d + 1 of
        the steps that hear it, spread over them; the evenly spread ones are as many as leave
        room for those (at least the first and last step: a pattern whose landmarks need more
        rows than that gets them, beyond max_points)."""
        max_points = MAX_SDP_POINTS if max_points is None else max_points
        m, k = observed.shape
        n_key = max(2, max_points - k)
        if m <= n_key:
            return cls(np.arange(m), m)
        for n_even in range(n_key, 1, -1):
            rows = _keyframe_rows(observed, dim, n_even)
            if len(rows) <= n_key:
                break
        return cls(rows, m)

    @property
    def is_subset(self) -> bool:
        """Whether some steps are left out of the SDP."""
        return len(self.rows) < self.m

    def bounds(self, bounds) -> tuple[np.ndarray, np.ndarray] | None:
        """eq. (11) bounds (lower, upper) between consecutive keyframes, from the step bounds
        (a StepBounds or None)."""
        if bounds is None or not self.is_subset:
            return None if bounds is None else (bounds.lower, bounds.upper)
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
        sweeps: the other points in the order they are placed (:func:`placement_sweeps`; empty
            for the whole problem).
    """

    receivers: np.ndarray
    sources: np.ndarray
    shape: tuple[int, int]
    sweeps: tuple[tuple[np.ndarray, np.ndarray], ...] = ()

    @classmethod
    def choose(cls, observed: np.ndarray, dim: int, rng: np.random.Generator,
               max_points: int | None = None):  # fmt: skip
        """A random core of ``max_points`` (default :data:`MAX_SDP_POINTS`) points, split
        between receivers and sources in proportion to M and K (at least d + 2 of each, which
        may exceed ``max_points``), drawn among the receivers and sources with the most observed
        ranges, from which every other point can be placed (:func:`placement_sweeps`; up to
        :data:`CORE_DRAWS` draws). The whole problem when it fits, or when no draw can place
        every point (the SDP is then the full one)."""
        max_points = MAX_SDP_POINTS if max_points is None else max_points
        m, k = observed.shape
        whole = cls(np.arange(m), np.arange(k), (m, k))
        if m + k <= max_points:
            return whole
        m0 = int(np.clip(round(max_points * m / (m + k)), min(m, dim + 2), m))
        k0 = int(np.clip(max_points - m0, min(k, dim + 2), k))
        for _ in range(CORE_DRAWS):
            receivers = np.sort(_heard_most(observed, m0, rng))
            sources = np.sort(_heard_most(observed[receivers].T, k0, rng))
            try:
                check_determined(observed[np.ix_(receivers, sources)], dim, "the core")
            except InvalidInputError:
                continue
            sweeps = placement_sweeps(observed, receivers, sources, dim)
            if sweeps is not None:
                return cls(receivers, sources, (m, k), tuple(sweeps))
        return whole

    @property
    def is_subset(self) -> bool:
        """Whether some points are left out of the SDP."""
        return len(self.receivers) + len(self.sources) < sum(self.shape)

    def expand(self, completion: EDMCompletion, ranges: np.ndarray, observed: np.ndarray, *,
               robust: bool = False, rng: np.random.Generator | None = None):  # fmt: skip
        """The completion of the core as one of every point (M + K, d): the other points placed
        in the core's ``sweeps``, each multilaterated
        (:func:`rangeslam.localization.multilaterate`; ``robust``: with its outlier search, when
        d + 2 ranges allow it) from every placed point it has a range to. Raises SolverError
        when a point cannot be placed (its placed anchors do not span the space)."""
        m, k = self.shape
        m0, dim = len(self.receivers), completion.points.shape[1]
        pts_r, pts_s = np.full((m, dim), np.nan), np.full((k, dim), np.nan)
        pts_r[self.receivers] = completion.points[:m0]
        pts_s[self.sources] = completion.points[m0:]
        for new_r, new_s in self.sweeps:
            for j in new_s:
                pts_s[j] = _placed(pts_r, ranges[:, j], observed[:, j], f"source {j}", robust, rng)
            for i in new_r:
                pts_r[i] = _placed(pts_s, ranges[i], observed[i], f"receiver {i}", robust, rng)
        return expanded_completion(completion, np.vstack([pts_r, pts_s]))


def placement_sweeps(observed: np.ndarray, receivers: np.ndarray, sources: np.ndarray, dim: int):
    """The order in which the points outside a core (``receivers``, ``sources`` placed) are
    placed from the (M, K) pattern ``observed``: a list of sweeps (receivers, sources), each
    point of a sweep ranging to at least d + 1 points placed before it; None when some point is
    never reached."""
    m, k = observed.shape
    placed_r, placed_s = np.zeros(m, bool), np.zeros(k, bool)
    placed_r[receivers], placed_s[sources] = True, True
    sweeps = []
    while not (placed_r.all() and placed_s.all()):
        new_s = ~placed_s & (observed[placed_r].sum(axis=0) > dim)
        new_r = ~placed_r & (observed[:, placed_s].sum(axis=1) > dim)
        if not (new_s.any() or new_r.any()):
            return None
        sweeps.append((np.flatnonzero(new_r), np.flatnonzero(new_s)))
        placed_r |= new_r
        placed_s |= new_s
    return sweeps


def _keyframe_rows(observed: np.ndarray, dim: int, n_even: int) -> np.ndarray:
    """(n,) sorted rows: ``n_even`` evenly spread over the M steps, and d + 1 of the steps that
    hear each landmark heard from fewer than d + 1 of those."""
    m, k = observed.shape
    rows = set(np.round(np.linspace(0, m - 1, n_even)).astype(int).tolist())
    even = sorted(rows)
    for col in range(k):
        heard = np.flatnonzero(observed[:, col])
        if np.count_nonzero(observed[even, col]) <= dim and len(heard):
            picks = np.round(np.linspace(0, len(heard) - 1, min(dim + 1, len(heard))))
            rows.update(heard[picks.astype(int)].tolist())
    return np.array(sorted(rows))


def _heard_most(observed: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` row indices of ``observed`` (R, C) drawn at random among the rows with the most
    observed entries (ties broken at random)."""
    order = np.lexsort((rng.random(observed.shape[0]), -observed.sum(axis=1)))
    return order[:count]


def _placed(anchors, ranges, heard, what: str, robust: bool, rng) -> np.ndarray:
    """(d,) a point multilaterated from the placed ``anchors`` (A, d; NaN rows not yet placed)
    that it ``heard`` (A,) at ``ranges`` (A,), metres (``robust``: with the outlier search)."""
    use = heard & np.isfinite(anchors[:, 0])
    robust = robust and use.sum() >= anchors.shape[1] + 2
    try:
        return multilaterate(anchors[use], ranges[use], robust=robust, rng=rng).position
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
    from rangeslam.solvers.sdp_pool import pooled_sdp  # cvxpy only where an SDP is solved

    keys = WalkKeyframes.choose(observed, dim)
    n = len(keys.rows)
    w = mdu_mask(observed[keys.rows])
    pairs = None if bounds is None else np.column_stack([np.arange(n - 1), np.arange(1, n)])
    with pooled_sdp(w, bounded_pairs=pairs) as sdp:
        for completion in convex_iteration_runs(
            sdp, mdu_edm(ranges[keys.rows]), w, dim, options=options, rng=rng,
            failures=failures, bounds=keys.bounds(bounds),
        ):  # fmt: skip
            yield keys.expand(completion) if keys.is_subset else completion


def core_runs(
    ranges: np.ndarray, observed: np.ndarray, dim: int, options: ConvexIterationOptions,
    rng: np.random.Generator, failures: list[str], *, loss: str = "l2",
    every_run_settles: bool = False,
):  # fmt: skip
    """Yield the convex-iteration runs (eq. 10) of an unfolding's ranges (M, K) with pattern
    ``observed`` (M, K) on a core of it (:class:`CalibrationCore`), expanded to every point; a
    run whose expansion fails is lost like a failed SDP (its reason appended to ``failures``).
    ``loss``: the SDP's ("l1" for robust runs); ``every_run_settles``: every run stops once its
    embedding settles (:func:`rangeslam.mdu.core.convex_iteration_runs`)."""
    from rangeslam.solvers.sdp_pool import pooled_sdp  # cvxpy only where an SDP is solved

    core = CalibrationCore.choose(observed, dim, rng)
    block = np.ix_(core.receivers, core.sources)
    w = mdu_mask(observed[block])
    with pooled_sdp(w, loss=loss) as sdp:
        runs = convex_iteration_runs(
            sdp, mdu_edm(ranges[block]), w, dim, options=options, rng=rng, failures=failures,
            every_run_settles=every_run_settles,
        )  # fmt: skip
        for completion in runs:
            if core.is_subset:
                try:
                    completion = core.expand(
                        completion, ranges, observed, robust=loss == "l1", rng=rng
                    )
                except SolverError as exc:
                    failures.append(str(exc))
                    continue
            yield completion
