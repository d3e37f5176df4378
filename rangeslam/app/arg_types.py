"""Argument types of the ``rangeslam`` command: each converts one option's text or refuses it
with a message in the user's terms (argparse turns it into ``rangeslam: error: ...``, exit 2)."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = [
    "SEED_MAX",
    "SIGMA_MAX",
    "float_in",
    "fraction",
    "int_in",
    "noise_level",
    "non_negative",
    "npz_file",
    "positive_float",
    "positive_int",
    "positive_int_to",
    "seed",
    "shown",
    "writable_dir",
]


def shown(text: str) -> str:
    """``text`` as an error message quotes it: as typed when printable, else Python's repr (a
    control character or newline in a value would break the one-line message)."""
    return text if text.isprintable() else repr(text)


def writable_dir(text: str) -> Path:
    """A directory, created if need be, that can be written to (--out)."""
    path = Path(text)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".rangeslam-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise argparse.ArgumentTypeError(
            f"cannot write to --out {shown(text)}: {exc.strerror}"
        ) from exc
    return path


def non_negative(text: str) -> float:
    """A float >= 0."""
    value = _number(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0; got {shown(text)}")
    return value


#: The largest range noise the simulated benchmarks take, metres: beyond it no scene (rooms of a
#: few metres, beacon fields of a few hundred) is located at all, and 1e300 overflowed a trial.
SIGMA_MAX = 10.0
#: The largest --seed: numpy's generators take any non-negative integer; 2^63 - 1 keeps seeds
#: derived from it (seed + trial) inside a signed 64-bit integer.
SEED_MAX = 2**63 - 1


def noise_level(text: str) -> float:
    """A range noise standard deviation in metres, in [0, SIGMA_MAX]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of metres; got {shown(text)}") from None
    if not 0 <= value <= SIGMA_MAX:
        raise argparse.ArgumentTypeError(f"must be from 0 to {SIGMA_MAX:g} m; got {shown(text)}")
    return value


def seed(text: str) -> int:
    """A random seed: an integer from 0 to SEED_MAX (numpy refuses negative seeds)."""
    parse = int_in(0, SEED_MAX)
    return parse(text)


def fraction(text: str) -> float:
    """A float in [0, 1]."""
    value = _number(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1]; got {shown(text)}")
    return value


def _number(text: str) -> float:
    """``text`` as a float; argparse's "invalid <function name> value" replaced by a message."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number; got {shown(text)}") from None


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {shown(text)}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {shown(text)}")
    return value


def positive_int_to(high: int):
    """An argument type: an integer from 1 to ``high`` ('must be a positive integer' below 1,
    'must be at most high' above)."""

    def parse(text: str) -> int:
        value = positive_int(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"must be at most {high}; got {shown(text)}")
        return value

    parse.__name__ = "integer"
    return parse


def positive_float(text: str) -> float:
    """A finite float > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number; got {shown(text)}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number; got {shown(text)}")
    return value


def float_in(low: float, high: float, unit: str = ""):
    """An argument type: a number in [low, high] (``unit`` after the limits in the message)."""

    def parse(text: str) -> float:
        value = _number(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be from {low:g} to {high:g}{unit}; got {shown(text)}"
            )
        return value

    parse.__name__ = "number"
    return parse


def int_in(low: int, high: int):
    """An argument type: an integer in [low, high], refused otherwise with the range in words
    (not argparse's list of every valid choice)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer; got {shown(text)}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be from {low} to {high}; got {shown(text)}")
        return value

    parse.__name__ = "integer"
    return parse


def npz_file(text: str) -> Path:
    """An output .npz path whose folder is created if need be and can be written to (--out)."""
    path = Path(text)
    if path.suffix.lower() != ".npz":
        raise argparse.ArgumentTypeError(f"must name an .npz file; got {shown(text)}")
    writable_dir(str(path.parent))
    return path
