"""The hostile value families of the public-API fuzz, shared by the bad-input tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

__all__ = ["HOSTILE_VALUES", "hostile_values"]

# The families of the fuzz of issue 35: magnitudes far beyond metres (1e-200 .. 1e200), integers
# too large for a float, complex numbers (also with zero imaginary part), numeric strings, and
# arrays of them where a scalar belongs.
HOSTILE_VALUES = [
    10**400, -(10**400), 2**1024, 1e200, -1e200, 1e-200, 1e308, 5e-324, 1 + 0j, np.complex128(2),
    np.array([1 + 0j]), "0.5", "3", " 1e3", "nan", np.array(["0.5", "1"]), np.array([10**400]),
    [1.0, "2"], [1.0, 2j], np.array([1e200, 1.0]),
]  # fmt: skip


def hostile_values():
    """The families of issue 35, drawn: fixed hostile values, huge integers, extreme floats,
    complex numbers, numeric strings."""
    return st.one_of(
        st.sampled_from(HOSTILE_VALUES),
        st.integers(2**1024, 10**500),
        st.floats(1e100, 1e308) | st.floats(1e-320, 1e-100),
        st.complex_numbers(max_magnitude=1e3, allow_nan=False),
        st.floats(-1e3, 1e3).map(repr),
    )
