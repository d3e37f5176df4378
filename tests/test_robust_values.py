"""``robust=`` takes one set of values in every estimator (rangeslam._robust.ROBUST_VALUES): None
or False is off, True is on (the estimator's own robust method), "auto" and kernel names where
the estimator has them; a value it cannot honour is an InvalidInputError naming what it takes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import rangeslam as rs
from rangeslam._robust import ROBUST_VALUES, robust_mode
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.edm import range_matrix


def test_robust_mode_reads_every_value_the_same_way():
    """Off, on, auto and kernel names, numpy bools as bools; True is the default kernel when
    the estimator's robust method is a kernel."""
    kernels = ("huber", "cauchy", "tukey")
    assert robust_mode(None, ("on",)) is None
    assert robust_mode(False, ("on",)) is None
    assert robust_mode(np.bool_(False), ("on",)) is None
    assert robust_mode(True, ("on",)) == "on"
    assert robust_mode(np.bool_(True), ("on", "auto")) == "on"
    assert robust_mode("auto", ("on", "auto")) == "auto"
    assert robust_mode(True, kernels, default_kernel="cauchy") == "cauchy"
    assert robust_mode("tukey", kernels, default_kernel="cauchy") == "tukey"
    with pytest.raises(InvalidInputError, match=r"robust='auto' is not available here; it takes"):
        robust_mode("auto", kernels, default_kernel="cauchy")
    with pytest.raises(InvalidInputError, match=r"robust='huber' is not available here"):
        robust_mode("huber", ("on",))


@given(st.one_of(st.text(max_size=8), st.integers(), st.floats(), st.just([1, 2])))
def test_robust_mode_refuses_anything_else(value):
    """Anything outside ROBUST_VALUES (strings, numbers, lists) is an InvalidInputError."""
    if isinstance(value, str) and value in ROBUST_VALUES:
        return
    with pytest.raises(InvalidInputError, match="robust must be one of None, False, True"):
        robust_mode(value, ("on", "auto", "huber"))


@pytest.mark.parametrize("robust", [None, False, True])
def test_multilaterate_takes_off_and_on(robust, rng):
    """None, False and True are accepted alike, and each recovers exact ranges."""
    anchors = rng.uniform(0, 3, size=(8, 3))
    point = rng.uniform(0, 3, size=3)
    fit = rs.multilaterate(anchors, np.linalg.norm(anchors - point, axis=1), robust=robust)
    assert fit.converged, fit.message
    np.testing.assert_allclose(fit.position, point, atol=1e-6)


@pytest.mark.parametrize(
    ("call", "value", "match"),
    [
        (
            "multilaterate",
            "cauchy",
            r"robust='cauchy' is not available here; it takes None, False, True",
        ),
        ("multilaterate", "auto", r"robust='auto' is not available here"),
        ("calibrate", "huber", r"robust='huber' is not available here; it takes .*'auto'"),
        ("slam", "auto", r"robust='auto' is not available here; it takes .*'huber'"),
        ("slam", "yes", r"robust must be one of None, False, True"),
        ("calibrate", 1, r"robust must be one of None, False, True"),
    ],
)
def test_each_estimator_names_what_it_takes(call, value, match, rng):
    """A value an estimator lacks is refused at the door, naming the values it takes."""
    anchors = rng.uniform(0, 3, size=(8, 3))
    sources = rng.uniform(0, 3, size=(6, 3))
    ranges = range_matrix(anchors, sources)
    with pytest.raises(InvalidInputError, match=match):
        if call == "multilaterate":
            rs.multilaterate(anchors, ranges[:, 0], robust=value)
        elif call == "calibrate":
            rs.calibrate(ranges, robust=value)
        else:
            rs.slam(ranges, robust=value)
