"""One BLAS thread for the estimators' small dense algebra.

The matrices of an unfolding, a SLAM graph's covariances or a verdict are small (tens to a few
hundred rows), and OpenBLAS's threads cost more than they give there: on this project's 2-core
machine beside one other process, the SVD of a 70 x 45 matrix took about 50 ms with two threads and
2 ms with one, and ``slam`` on 8-step walks ran 1.47x faster in one thread (median of paired
runs). The limit is set for the call only and restored after it (threadpoolctl).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from typing import TypeVar

__all__ = ["one_blas_thread", "single_blas_thread"]

F = TypeVar("F", bound=Callable)

_CONTROLLER: list = []  # the ThreadpoolController, made at first use (after numpy and scipy load)


def one_blas_thread():
    """A context in which BLAS (OpenBLAS, MKL, BLIS) runs on one thread; a null context when
    threadpoolctl is not installed."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - a declared dependency
        return contextlib.nullcontext()
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


def single_blas_thread(func: F) -> F:
    """Decorator: ``func`` runs inside :func:`one_blas_thread`."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
