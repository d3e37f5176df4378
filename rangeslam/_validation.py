"""Input checks shared by the public functions.

Each helper converts an array-like to a fresh float64 (or bool) array, so callers' arrays are never
mutated, and raises :class:`InvalidInputError` with a message that names the argument, what was
expected and what arrived.
"""

from __future__ import annotations

import inspect

import numpy as np
from numpy.typing import ArrayLike

from rangeslam.errors import InvalidInputError

__all__ = [
    "INT_LIMIT",
    "MAX_METRES",
    "MIN_METRES",
    "as_dim",
    "as_flag",
    "as_float_array",
    "as_mask",
    "as_pair",
    "as_points",
    "as_ranges",
    "as_rng",
    "as_scalar",
    "check_int",
    "check_metres",
    "check_option_keys",
    "check_options_for",
    "check_positive",
    "frozen",
    "shape_str",
]


def shape_str(shape: tuple[int, ...]) -> str:
    """Format a shape as Python prints it: (3,), (4, 2)."""
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


#: Largest magnitude of a coordinate or range the input layer takes, metres (1e12 m is about
#: seven times the Earth-Sun distance): beyond it squared distances lose every digit of the
#: geometry the solvers need and soon overflow (ranges scaled by 1e200 made LinAlgError and
#: OverflowError deep in the solvers).
MAX_METRES = 1e12
#: Smallest scale of coordinates or ranges, metres (a nanometre): an array whose largest entry is
#: positive but below it (a problem scaled by 1e-200) is refused; all zeros are left to the
#: geometry checks.
MIN_METRES = 1e-9


def as_float_array(value: ArrayLike, name: str) -> np.ndarray:
    """``value`` as a fresh float64 array: real numbers only.

    Refused with InvalidInputError naming ``name``: complex numbers (numpy would drop the
    imaginary part with a warning), strings (numpy would parse numeric ones), ragged nesting,
    objects that are not numbers and integers too large for a float.
    """
    try:
        raw = np.array(value, copy=True)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InvalidInputError(
            f"{name} must be an array of real numbers; got {value!r:.80}"
        ) from exc
    kind = raw.dtype.kind
    for v in raw.flat if kind == "O" else ():  # numpy keeps mixed or huge values as objects
        if isinstance(v, str | bytes | complex | np.complexfloating):
            kind = "U" if isinstance(v, str | bytes) else "c"
            break
    if kind == "c":
        raise InvalidInputError(f"{name} must be real numbers, not complex; got {value!r:.80}")
    if kind in "USVMm":
        raise InvalidInputError(
            f"{name} must be an array of real numbers, not {raw.dtype}; got {value!r:.80}"
        )
    try:
        return raw.astype(float, copy=False)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InvalidInputError(
            f"{name} must be an array of real numbers; got {value!r:.80}"
        ) from exc


def check_metres(
    arr: np.ndarray, name: str, what: str = "coordinates", *, min_scale: bool = True
) -> np.ndarray:
    """Refuse (InvalidInputError naming ``name``) finite ``arr`` whose largest magnitude is above
    :data:`MAX_METRES` or (with ``min_scale``: a set of points or ranges, not one point near the
    origin) positive but below :data:`MIN_METRES`; return ``arr``."""
    top = float(np.max(np.abs(arr))) if arr.size else 0.0
    if top > MAX_METRES:
        bad = tuple(int(i) for i in np.argwhere(np.abs(arr) > MAX_METRES)[0])
        raise InvalidInputError(
            f"{name} must be {what} in metres of magnitude <= {MAX_METRES:g}; entry {bad} is "
            f"{arr[bad]:.6g}"
        )
    if min_scale and 0 < top < MIN_METRES:
        raise InvalidInputError(
            f"{name} must be {what} in metres; its largest magnitude is {top:.3g}, below "
            f"{MIN_METRES:g} m (rescale the problem to metres)"
        )
    return arr


def as_points(
    value: ArrayLike,
    name: str,
    *,
    dim: int | None = None,
    min_points: int = 1,
    metres: bool = True,
) -> np.ndarray:
    """Return ``value`` as a float64 array of shape (N, d), d in {2, 3}, all finite, in metres
    (:func:`check_metres`: no coordinate beyond :data:`MAX_METRES`; two or more points not all
    within :data:`MIN_METRES` of the origin unless all zero). ``metres=False`` skips that check,
    for the geometry helpers the estimators also apply to their own (possibly diverged) answers.

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
    return check_metres(arr, name, min_scale=arr.shape[0] > 1) if metres else arr


def as_point(value: ArrayLike, name: str, *, dim: int) -> np.ndarray:
    """Return one point of shape (dim,), finite, no coordinate beyond :data:`MAX_METRES`."""
    arr = as_float_array(value, name)
    if arr.shape != (dim,):
        raise InvalidInputError(f"{name} must have shape ({dim},); got {shape_str(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be finite; got {arr}")
    return check_metres(arr, name)


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
    At least one entry; magnitudes in metres as :func:`check_metres` takes them.
    """
    arr = as_float_array(value, name)
    expected = shape_str(tuple("*" if s is None else s for s in shape))  # type: ignore[misc]
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        raise InvalidInputError(f"{name} must have shape {expected}; got {shape_str(arr.shape)}")
    if arr.size == 0:
        raise InvalidInputError(f"{name} must hold at least one range; got {shape_str(arr.shape)}")
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
    return check_metres(arr, name, "ranges")


def as_mask(value: ArrayLike | None, name: str, *, shape: tuple[int, ...]) -> np.ndarray:
    """Return a boolean mask (True where a measurement was observed) of the given shape.

    ``None`` means everything was observed. Only booleans are accepted: 0/1 integers are refused
    because 0 as a "missing" sentinel is exactly the ambiguity the mask exists to avoid.
    """
    if value is None:
        return np.ones(shape, dtype=bool)
    try:
        arr = np.array(value, copy=True)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"{name} must be a boolean array (True where observed); got {value!r:.80}"
        ) from exc
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


#: Largest integer :func:`check_int` takes when the option states no limit of its own (a count
#: beyond it is never meant, and numpy cannot hold it).
INT_LIMIT = 2**63 - 1


def check_int(value, name: str, low: int, high: int | None = None) -> int:
    """``value`` as an int, refused (naming ``name``) unless an integer in [low, high] (a Python
    or numpy integer, not a bool; ``high`` None: at most :data:`INT_LIMIT`, 64 bits)."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
    top = INT_LIMIT if high is None else high
    if not ok or value < low or value > top:
        what = f">= {low}" if high is None else f"in [{low}, {high}]"
        if high is None and ok and value > top:
            what += " that fits in 64 bits"
        shown = (
            f"an integer of {len(str(value))} digits" if ok and value > 10**30 else f"{value!r:.80}"
        )
        raise InvalidInputError(f"{name} must be an integer {what}; got {shown}")
    return int(value)


def check_positive(value, name: str) -> float:
    """``value`` as a float, refused (naming ``name``) unless a finite number > 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r:.80}")
    if isinstance(value, int) and abs(value) > 2**1000:  # np.isfinite cannot take it
        raise InvalidInputError(f"{name} must be a positive number; got {len(str(value))} digits")
    if not (np.isfinite(float(value)) and value > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return float(value)


RNG_FORMS = "None, a non-negative integer, a numpy SeedSequence, BitGenerator or Generator (SPEC 7)"


def as_rng(rng, name: str = "rng") -> np.random.Generator:
    """``rng`` in any SPEC 7 form as a Generator, exactly as ``np.random.default_rng`` makes it.

    Accepted: None (fresh entropy), a non-negative Python or numpy integer, a
    ``np.random.SeedSequence``, a ``np.random.BitGenerator`` or a ``np.random.Generator`` (returned
    as is, so the caller's stream is advanced). Anything else (strings, floats, bools, negative
    integers, arrays) raises InvalidInputError naming ``name``.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    ok = rng is None or isinstance(rng, np.random.SeedSequence | np.random.BitGenerator)
    if isinstance(rng, int | np.integer) and not isinstance(rng, bool | np.bool_):
        ok = rng >= 0
    if not ok:
        raise InvalidInputError(f"{name} must be {RNG_FORMS}; got {rng!r:.80}")
    return np.random.default_rng(rng)


def real_scalar(value, name: str, what: str):
    """``value`` (a Python or numpy real number, or a 0-d or one-element real array; not a bool)
    as a Python float or int, else InvalidInputError naming ``name``."""
    if isinstance(value, bool | np.bool_ | str | bytes) or value is None:
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")
    if isinstance(value, int | np.integer):
        if abs(int(value)) > 2**1000:  # beyond any float: refused rather than OverflowError later
            raise InvalidInputError(
                f"{name} must be {what}; got an integer of {len(str(value))} digits"
            )
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value)
    arr = value if isinstance(value, np.ndarray) else None
    if arr is None or arr.size != 1 or arr.dtype.kind not in "iuf":
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")
    item = arr.reshape(()).item()
    return int(item) if arr.dtype.kind in "iu" else float(item)


def as_scalar(
    value,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    allow_none: bool = False,
    integer: bool = False,
    expected: str | None = None,
):
    """A scalar option checked at the door: a float (an int with ``integer``), or None.

    Accepts Python and numpy real scalars and 0-d (or one-element) real arrays; refuses strings,
    bools, complex numbers, arrays of size > 1, NaN and infinities, non-integers with ``integer``,
    and values outside [low, high] (``low_open``/``high_open`` exclude the ends), with an
    InvalidInputError naming ``name``, what was expected (``expected`` words it instead of the
    generated "a finite real number >= low") and what arrived. None passes only with
    ``allow_none``.
    """
    if value is None and allow_none:
        return None
    lo = "" if low is None else (f" > {low}" if low_open else f" >= {low}")
    hi = "" if high is None else (f" < {high}" if high_open else f" <= {high}")
    what = ("an integer" if integer else "a finite real number") + lo + ("," if lo and hi else "")
    what += hi + (" or None" if allow_none else "")
    what = what if expected is None else expected
    x = real_scalar(value, name, what)
    if integer and not isinstance(x, int):
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")
    if isinstance(x, float) and not np.isfinite(x):
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")
    too_low = low is not None and (x <= low if low_open else x < low)
    too_high = high is not None and (x >= high if high_open else x > high)
    if too_low or too_high:
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")
    return x if integer else float(x)


def as_pair(value, name: str, *, expected: str) -> tuple[float, float]:
    """``value`` as two finite real numbers (a pair of Python or numpy reals, each as
    :func:`as_scalar` takes it: no strings, bools, complex numbers, NaN or infinities); else
    InvalidInputError naming ``name``, saying ``expected`` and what arrived."""
    items = None
    if not isinstance(value, str | bytes | dict | set):
        try:
            items = list(value)
        except TypeError:
            items = None
    if items is None or len(items) != 2:
        raise InvalidInputError(f"{name} must be {expected}; got {value!r:.80}")
    a, b = (as_scalar(v, name, expected=expected) for v in items)
    return a, b


def as_speed(c, name: str = "c"):
    """An optional speed of sound in m/s: None, or a finite real number > 0."""
    if c is None:
        return None
    value = real_scalar(c, name, "a positive speed of sound in m/s or None")
    if not (value > 0 and (isinstance(value, int) or np.isfinite(value))):
        raise InvalidInputError(f"{name} must be a positive speed of sound in m/s; got {c!r:.80}")
    return float(value)


def as_dim(value, name: str = "dim") -> int:
    """The spatial dimension, 2 or 3 (an integer, not a bool), else InvalidInputError."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
        raise InvalidInputError(f"{name} must be 2 or 3; got {value!r:.80}")
    if value not in (2, 3):
        raise InvalidInputError(f"{name} must be 2 or 3; got {value!r:.80}")
    return int(value)


def as_flag(value, name: str) -> bool:
    """A switch: a Python or numpy bool (or a 0-d bool array), else InvalidInputError."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray) and value.shape == () and value.dtype == bool:
        return bool(value)
    raise InvalidInputError(f"{name} must be True or False; got {value!r:.80}")


def check_option_keys(options, name: str, accepted) -> dict:
    """An options dict (None for none) whose keys are all in ``accepted``, as a new dict.

    Raises InvalidInputError naming the dict, the unknown key and the accepted keys.
    """
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise InvalidInputError(f"{name} must be a dict or None; got {options!r:.80}")
    accepted = sorted(accepted)
    for key in options:
        if key not in accepted:
            raise InvalidInputError(
                f"{name} has an unknown key {key!r:.40}; accepted keys: {', '.join(accepted)}"
            )
    return dict(options)


def check_options_for(options, name: str, func, *, passed=()) -> dict:
    """An options dict (None for none) of keyword arguments for ``func``, as a new dict.

    Accepted keys: the parameters of ``func`` that can be given by keyword, less ``passed`` (the
    ones the caller sets itself: a key among them would collide). Raises InvalidInputError naming
    the dict, the unknown key and the accepted keys (:func:`check_option_keys`), instead of the
    TypeError ``func`` would raise later.
    """
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    accepted = [
        p.name
        for p in inspect.signature(func).parameters.values()
        if p.kind in kinds and p.name not in passed
    ]
    return check_option_keys(options, name, accepted)
