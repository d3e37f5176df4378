"""Small helpers shared by the benchmark scripts (tables and timing). Not part of the library."""

from __future__ import annotations

import platform
import time
from collections.abc import Callable, Sequence

import numpy as np


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table; floats are printed as given (format them before)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def timed(fn: Callable[..., object], *args, **kwargs) -> tuple[object, float]:
    """(result, seconds) of one call fn(*args, **kwargs), with perf_counter."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def machine() -> str:
    import scipy

    return f"Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, {platform.machine()}"


def wrap_parts(parts: dict[str, tuple[object, str]], spent: dict[str, float]) -> Callable[[], None]:
    """Replace each ``parts[name] = (owner, attribute)`` function by one that adds its wall-clock
    seconds to ``spent[name]``; returns the function that puts the originals back."""
    originals = {name: getattr(owner, attr) for name, (owner, attr) in parts.items()}
    for name, (owner, attr) in parts.items():
        inner = originals[name]

        def timed_part(*args, _inner=inner, _name=name, **kwargs):
            t0 = time.perf_counter()
            try:
                return _inner(*args, **kwargs)
            finally:
                spent[_name] = spent.get(_name, 0.0) + time.perf_counter() - t0

        setattr(owner, attr, timed_part)

    def unwrap() -> None:
        for name, (owner, attr) in parts.items():
            setattr(owner, attr, originals[name])

    return unwrap
