"""The steps of a long pipeline, logged with their times (``rangeslam -v`` prints them).

:func:`logged_step` wraps a function so that calling it logs ``what ...`` at INFO when it starts
and ``what: done in 1.2 s`` when it returns, on the caller's logger; nothing else changes. The
command's progress lines name the step under way from these records.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from typing import TypeVar

__all__ = ["logged_step"]

F = TypeVar("F", bound=Callable)


def logged_step(logger: logging.Logger, what: str) -> Callable[[F], F]:
    """A decorator: log ``what ...`` before each call of the function and ``what: done in T``
    after it (INFO on ``logger``); an exception is logged as ``what: failed after T``."""

    def wrap(fn: F) -> F:
        @functools.wraps(fn)
        def run(*args, **kwargs):
            if not logger.isEnabledFor(logging.INFO):
                return fn(*args, **kwargs)
            logger.info("%s ...", what)
            t0 = time.perf_counter()
            try:
                out = fn(*args, **kwargs)
            except BaseException:
                logger.info("%s: failed after %.1f s", what, time.perf_counter() - t0)
                raise
            logger.info("%s: done in %.1f s", what, time.perf_counter() - t0)
            return out

        return run  # type: ignore[return-value]

    return wrap
