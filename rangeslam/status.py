"""How a run ended: one status table for every estimator's result.

As SciPy's ``OptimizeResult``, a result carries an integer ``status`` from :class:`Status` and a
``message`` that starts with that status's sentence from :data:`STATUS_MESSAGES` followed by the
details of the run; ``converged`` is derived from the status (``status is Status.CONVERGED``), so
code and tests branch on the status, never on words of the message.
"""

from __future__ import annotations

import enum

__all__ = ["STATUS_MESSAGES", "HasStatus", "Status", "status_message"]


class Status(enum.IntEnum):
    """Outcome of an estimator's run; 0 is the only success."""

    #: Right as far as the data can tell: determined, consistent with the noise, restarts agree.
    CONVERGED = 0
    #: The data leave the unknowns undetermined beyond the gauge (too few ranges or echoes,
    #: degenerate geometry, a landmark or wall that nothing pins down).
    NOT_IDENTIFIABLE = 1
    #: The residuals do not fit the noise (the chi-square or relative-RMS test failed).
    INCONSISTENT = 2
    #: Measurements the model cannot explain remain, or too many were rejected as wrong picks.
    OUTLIERS = 3
    #: An estimate lies outside its physical range (e.g. walls that do not bound a room).
    OUT_OF_RANGE = 4
    #: A numerical solver (SDP, least squares, GTSAM) failed or stalled.
    SOLVER_FAILED = 5
    #: Without a known noise level, no two restarts reached the same answer.
    NO_AGREEMENT = 6

    def __str__(self) -> str:
        """The status by name (``CONVERGED``), as printed, logged and written to tables; the
        integer is ``int(status)``."""
        return self.name

    def __format__(self, spec: str) -> str:
        return format(self.name, spec)


#: The sentence each status's message starts with.
STATUS_MESSAGES: dict[Status, str] = {
    Status.CONVERGED: "converged",
    Status.NOT_IDENTIFIABLE: "not identifiable from these data",
    Status.INCONSISTENT: "the residuals do not fit the noise",
    Status.OUTLIERS: "measurements the model cannot explain remain",
    Status.OUT_OF_RANGE: "an estimate is outside its physical range",
    Status.SOLVER_FAILED: "the solver failed",
    Status.NO_AGREEMENT: "no two restarts agreed",
}


def status_message(status: Status, detail: str = "") -> str:
    """``STATUS_MESSAGES[status]`` followed by ``detail`` (``"<sentence>: <detail>"``)."""
    detail = detail.strip().rstrip(";").strip()
    head = STATUS_MESSAGES[Status(status)]
    return f"{head}: {detail}" if detail else head


class HasStatus:
    """Mixin for frozen result dataclasses that hold a ``status`` field."""

    status: Status

    @property
    def converged(self) -> bool:
        """True when ``status`` is :attr:`Status.CONVERGED`."""
        return self.status is Status.CONVERGED
