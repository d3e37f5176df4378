"""Compiled EDM completion problems kept for re-use, per thread.

cvxpy compiles an :class:`~rangeslam.solvers.sdp.EDMCompletionSDP` on its first solve (29 ms of
slam's 0.45 s a walk at M = 8). An estimator called on many data sets of one structure (the
walks of a benchmark, the windows of a log) takes its problem from here and compiles it once;
each data set's solves give the same bits as a new problem's
(:meth:`~rangeslam.solvers.sdp.EDMCompletionSDP.restart`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from numpy.typing import ArrayLike

from rangeslam.solvers.sdp import EDMCompletionSDP

__all__ = ["POOL_SIZE", "clear_sdp_pool", "pooled_sdp"]

#: Idle problems kept per thread, in all structures (the least recently returned dropped).
POOL_SIZE = 8
_local = threading.local()


class _Idle:
    """This thread's idle problems: structure key -> problems, keys in the order last returned,
    and their count."""

    def __init__(self) -> None:
        self.by_key: OrderedDict[tuple, list[EDMCompletionSDP]] = OrderedDict()
        self.count = 0

    def take(self, key: tuple) -> EDMCompletionSDP | None:
        """An idle problem of structure ``key``, removed from the pool, or None."""
        stack = self.by_key.get(key)
        if not stack:
            return None
        sdp = stack.pop()
        self.count -= 1
        if not stack:
            del self.by_key[key]
        return sdp

    def put(self, key: tuple, sdp: EDMCompletionSDP) -> None:
        """Keep ``sdp`` (restarted: no solver held), the least recently returned dropped beyond
        POOL_SIZE."""
        sdp.restart()
        self.by_key.setdefault(key, []).append(sdp)
        self.by_key.move_to_end(key)
        self.count += 1
        while self.count > POOL_SIZE:
            oldest = next(iter(self.by_key))
            stack = self.by_key[oldest]
            stack.pop(0)
            self.count -= 1
            if not stack:
                del self.by_key[oldest]


def _idle() -> _Idle:
    if not hasattr(_local, "idle"):
        _local.idle = _Idle()
    return _local.idle


def structure_key(mask: ArrayLike, bounded_pairs: ArrayLike | None, loss: str) -> tuple:
    """What makes two problems the same: the mask as given (shape, dtype, bytes: a mask the
    problem would refuse never matches a valid one), the bounded pairs as the problem reads them
    (integers) and the loss."""
    w = np.asarray(mask)
    pairs = None
    if bounded_pairs is not None:
        p = np.array(bounded_pairs, dtype=int)
        pairs = (p.shape, p.tobytes())
    return (w.shape, w.dtype.str, w.tobytes(), loss, pairs)


@contextmanager
def pooled_sdp(
    mask: ArrayLike, *, bounded_pairs: ArrayLike | None = None, loss: str = "l2"
) -> Iterator[EDMCompletionSDP]:
    """``with pooled_sdp(mask, bounded_pairs=..., loss=...) as sdp``: an
    :class:`~rangeslam.solvers.sdp.EDMCompletionSDP` of that structure, an idle one of this
    thread when there is one, else built (and then checked as
    :class:`~rangeslam.solvers.sdp.EDMCompletionSDP` checks its arguments). It is used by one
    caller at a time: it goes back to the pool, restarted, when the block ends normally or the
    generator using it is closed, and is dropped after any other exception. ``mask`` (N, N),
    ``bounded_pairs`` (P, 2), ``loss`` as for the problem."""
    key = structure_key(mask, bounded_pairs, loss)
    sdp = _idle().take(key)
    if sdp is None:
        sdp = EDMCompletionSDP(mask, bounded_pairs=bounded_pairs, loss=loss)
    try:
        yield sdp
    except GeneratorExit:  # the generator using it was closed: it is whole
        _idle().put(key, sdp)
        raise
    _idle().put(key, sdp)


def clear_sdp_pool() -> None:
    """Drop this thread's idle problems (to free their memory)."""
    _local.idle = _Idle()
