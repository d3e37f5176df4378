"""Bounds on the step lengths of a trajectory: lower_i <= |x_(i+1) - x_i| <= upper_i (eq. 11).

One frozen :class:`StepBounds`, parsed once at an estimator's front door (:meth:`StepBounds.parse`)
and passed down: :func:`rangeslam.mdu.slam`, :func:`rangeslam.solvers.gtsam_graph.refine_graph`
and :func:`rangeslam.baselines.ekf_slam.ekf_slam` accept it as well as the (lower, upper) pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam._validation import as_float_array, frozen, shape_str
from rangeslam.errors import InvalidInputError

__all__ = ["KNOWN_STEP_WIDTH", "StepBounds"]

#: Width, relative to the scale of the problem (the median range), given to step bounds with
#: lower = upper (a known step length) by :meth:`StepBounds.widened` at the solvers' doors
#: (:func:`rangeslam.slam`, :func:`rangeslam.solvers.gtsam_graph.refine_graph`): GTSAM's dead zone
#: needs a positive width, and the step factor's sigma then holds the step at the known length.
KNOWN_STEP_WIDTH = 1e-9


@dataclass(frozen=True)
class StepBounds:
    """Bounds on M - 1 step lengths, metres.

    Attributes:
        lower: (M - 1,) finite, >= 0.
        upper: (M - 1,) finite, >= lower.

    Unpacks and indexes as a pair (``lower, upper = bounds``; ``bounds[1]``), as the tuples it
    replaces.
    """

    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def parse(cls, value, n_steps: int, name: str = "step_bounds") -> StepBounds:
        """``value`` (a StepBounds, or a pair (lower, upper) of array-likes) checked for
        ``n_steps`` = M - 1 steps; a StepBounds of that length is returned unchanged. Raises
        InvalidInputError naming ``name``."""
        if isinstance(value, StepBounds):
            lower, upper = value.lower, value.upper
            _check_lengths(lower, upper, n_steps, name)
            return value
        try:
            lower, upper = value
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                f"{name} must be a pair (lower, upper) of arrays of step lengths; got {value!r:.80}"
            ) from exc
        lower, upper = (
            as_float_array(lower, f"{name} lower"),
            as_float_array(upper, f"{name} upper"),
        )
        _check_lengths(lower, upper, n_steps, name)
        _check_order(lower, upper, name)
        return cls(lower=frozen(lower), upper=frozen(upper))

    def __post_init__(self):
        """Bounds built directly are held to the same rules as parsed ones (read-only copies)."""
        lower = as_float_array(self.lower, "step_bounds lower")
        upper = as_float_array(self.upper, "step_bounds upper")
        if lower.ndim != 1 or lower.shape != upper.shape:
            raise InvalidInputError(
                "step_bounds lower and upper must be 1-D arrays of the same length; got "
                f"{shape_str(lower.shape)} and {shape_str(upper.shape)}"
            )
        _check_lengths(lower, upper, len(lower), "step_bounds")
        _check_order(lower, upper, "step_bounds")
        object.__setattr__(self, "lower", frozen(lower))
        object.__setattr__(self, "upper", frozen(upper))

    @property
    def n_steps(self) -> int:
        """M - 1."""
        return len(self.lower)

    @property
    def midpoints(self) -> np.ndarray:
        """(M - 1,) (lower + upper) / 2, metres."""
        return 0.5 * (self.lower + self.upper)

    def widened(self, min_width: float) -> StepBounds:
        """Bounds whose every interval is at least ``min_width`` metres wide: a narrower one
        (lower = upper is a known step length) is widened about its midpoint, lower clipped at 0.
        Solvers whose step prior needs a positive width (GTSAM's dead zone) take these; wider
        intervals are kept exactly. Returns ``self`` when nothing needs widening."""
        narrow = self.upper - self.lower < min_width
        if not narrow.any():
            return self
        mid = self.midpoints
        lower = np.where(narrow, np.maximum(mid - 0.5 * min_width, 0.0), self.lower)
        upper = np.where(narrow, lower + min_width, self.upper)
        return StepBounds(lower=lower, upper=upper)

    def __iter__(self):
        """Yield lower, then upper."""
        yield self.lower
        yield self.upper

    def __getitem__(self, side: int) -> np.ndarray:
        """``bounds[0]`` is lower, ``bounds[1]`` upper, as in the (lower, upper) pairs it replaces."""
        return (self.lower, self.upper)[side]


def _check_lengths(lower: np.ndarray, upper: np.ndarray, n_steps: int, name: str) -> None:
    """Refuse bounds that are not (n_steps,) finite arrays."""
    m = n_steps + 1
    for side, b in (("lower", lower), ("upper", upper)):
        if b.shape != (n_steps,):
            raise InvalidInputError(
                f"{name} {side} must have shape ({n_steps},) (one per step between the {m} "
                f"receivers); got {shape_str(b.shape)}"
            )
        if not np.all(np.isfinite(b)):
            raise InvalidInputError(f"{name} {side} must be finite")


def _check_order(lower: np.ndarray, upper: np.ndarray, name: str) -> None:
    """Refuse negative lower bounds and lower > upper (lower = upper is a known step length)."""
    if np.any(lower < 0):
        i = int(np.argmax(lower < 0))
        raise InvalidInputError(f"{name} lower must be >= 0; step {i} has {lower[i]}")
    if np.any(lower > upper):
        i = int(np.argmax(lower > upper))
        raise InvalidInputError(
            f"{name} must have lower <= upper; step {i} has [{lower[i]}, {upper[i]}]"
        )
