"""Input checks shared by the public functions.

Each helper converts an array-like to a fresh float64 (or bool) array, so callers' arrays are never
mutated, and raises :class:`InvalidInputError` with a message that names the argument, what was
expected and what arrived.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam.errors import InvalidInputError

__all__ = [
    "as_mask",
    "as_points",
    "as_ranges",
    "check_int",
    "check_positive",
    "frozen",
    "shape_str",
]


def shape_str(shape: tuple[int, ...]) -> str:
    """Format a shape as Python prints it: (3,), (4, 2)."""
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def as_float_array(value: ArrayLike, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float, copy=True)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"{name} must be an array of real numbers; got {value!r:.80}"
        ) from exc
    return arr


def as_points(
    value: ArrayLike,
    name: str,
    *,
    dim: int | None = None,
    min_points: int = 1,
) -> np.ndarray:
    """Return ``value`` as a float64 array of shape (N, d), d in {2, 3}, all finite.

    A single point of shape (d,) is refused: points are rows, and a bare vector is ambiguous.
    """
    arr = as_float_array(value, name)
    want_d = "d in (2, 3)" if dim is None else f"d = {dim}"
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or (dim is not None and arr.shape[1] != dim):
        raise InvalidInputError(
            f"{name} must have shape (N, d) with {want_d} (points as rows); got {shape_str(arr.shape)}"
        )
    if arr.shape[0] < min_points:
        raise InvalidInputError(
            f"{name} must hold at least {min_points} points (rows); got {shape_str(arr.shape)}"
        )
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InvalidInputError(
            f"{name} must be finite; entry {tuple(int(i) for i in bad)} is {arr[tuple(bad)]}"
        )
    return arr


def as_point(value: ArrayLike, name: str, *, dim: int) -> np.ndarray:
    """Return one point of shape (dim,), finite."""
    arr = as_float_array(value, name)
    if arr.shape != (dim,):
        raise InvalidInputError(f"{name} must have shape ({dim},); got {shape_str(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be finite; got {arr}")
    return arr


def as_ranges(
    value: ArrayLike,
    name: str,
    *,
    shape: tuple[int | None, ...],
    observed: np.ndarray | None = None,
    signed: bool = False,
) -> np.ndarray:
    """Return ranges (distances in metres) as float64 with the given shape; None means any size.

    Observed ranges must be finite and non-negative (any sign with ``signed``: ranges that carry
    an unknown offset, such as an unknown emission time, may be negative). Where ``observed`` (a boolean array of the same
    shape) is False the entry is a placeholder: it is not checked and is set to 0 in the returned
    array, so it can hold NaN in the caller's data. Missing entries are given by the mask only.
    """
    arr = as_float_array(value, name)
    expected = shape_str(tuple("*" if s is None else s for s in shape))  # type: ignore[misc]
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        raise InvalidInputError(f"{name} must have shape {expected}; got {shape_str(arr.shape)}")
    if observed is not None:
        arr = np.where(observed, arr, 0.0)
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise InvalidInputError(
            f"{name} must be finite where observed (mark missing ranges with mask=, not NaN); "
            f"entry {bad} is {arr[bad]}"
        )
    if not signed and np.any(arr < 0):
        bad = tuple(int(i) for i in np.argwhere(arr < 0)[0])
        raise InvalidInputError(f"{name} must be non-negative distances; entry {bad} is {arr[bad]}")
    return arr


def as_mask(value: ArrayLike | None, name: str, *, shape: tuple[int, ...]) -> np.ndarray:
    """Return a boolean mask (True where a measurement was observed) of the given shape.

    ``None`` means everything was observed. Only booleans are accepted: 0/1 integers are refused
    because 0 as a "missing" sentinel is exactly the ambiguity the mask exists to avoid.
    """
    if value is None:
        return np.ones(shape, dtype=bool)
    arr = np.array(value, copy=True)
    if arr.dtype != bool:
        raise InvalidInputError(
            f"{name} must be a boolean array (True where observed); got dtype {arr.dtype}"
        )
    if arr.shape != shape:
        raise InvalidInputError(
            f"{name} must have shape {shape_str(shape)}; got {shape_str(arr.shape)}"
        )
    return arr


def frozen(arr: np.ndarray) -> np.ndarray:
    """Mark an array read-only (result objects hand out arrays that cannot be edited in place)."""
    arr.setflags(write=False)
    return arr


def check_int(value, name: str, low: int) -> int:
    """``value`` as an int, refused (naming ``name``) unless an integer >= ``low`` (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise InvalidInputError(f"{name} must be an integer >= {low}; got {value!r}")
    return int(value)


def check_positive(value, name: str) -> float:
    """``value`` as a float, refused (naming ``name``) unless a finite number > 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    if not (np.isfinite(value) and value > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return float(value)
