"""The package's error classes.

Every error rangeslam raises on purpose derives from :class:`RangeSlamError`. Errors about what a
caller passed in are also :class:`ValueError`, so generic ``except ValueError`` handlers keep
working; solver failures are also :class:`RuntimeError` and carry the solver's status.
"""

from __future__ import annotations

__all__ = [
    "DataFormatError",
    "DataNotFoundError",
    "DegenerateGeometryError",
    "InvalidInputError",
    "RangeSlamError",
    "SolverError",
]


class RangeSlamError(Exception):
    """Base class of every error raised on purpose by rangeslam."""


class InvalidInputError(RangeSlamError, ValueError):
    """An argument has the wrong shape, type or value; the message names the argument."""


class DegenerateGeometryError(RangeSlamError, ValueError):
    """The geometry leaves the answer ambiguous (e.g. collinear anchors, an unbounded room)."""


class DataFormatError(InvalidInputError):
    """A data file is malformed; the message names the file and, where it can, the row."""


class DataNotFoundError(InvalidInputError, FileNotFoundError):
    """A data set or data file is not where it was looked for; the message names the paths tried
    and ``$RANGESLAM_DATA``."""


class SolverError(RangeSlamError, RuntimeError):
    """A numerical solver failed; ``status`` holds the solver's own status string."""

    def __init__(self, message: str, *, status: str | None = None) -> None:
        super().__init__(message if status is None else f"{message} (solver status: {status})")
        self.status = status
