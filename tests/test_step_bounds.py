"""StepBounds: step-length bounds (eq. 11) parsed once at an estimator's door and passed down."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rangeslam.errors import InvalidInputError
from rangeslam.solvers import StepBounds


def test_parse_pair_gives_read_only_copies():
    """A (lower, upper) pair becomes read-only float copies; the caller's arrays are untouched."""
    lower, upper = np.array([0.1, 0.2]), np.array([0.3, 0.4])
    b = StepBounds.parse((lower, upper), 2)
    np.testing.assert_array_equal(b.lower, lower)
    np.testing.assert_array_equal(b.upper, upper)
    assert not b.lower.flags.writeable and not b.upper.flags.writeable
    lower[0] = 9.0
    assert b.lower[0] == 0.1
    lo, hi = b  # unpacks as the pair it replaces
    assert lo is b.lower and hi is b.upper
    assert b[0] is b.lower and b[1] is b.upper
    np.testing.assert_allclose(b.midpoints, [0.2, 0.3])
    assert b.n_steps == 2


def test_parse_returns_step_bounds_unchanged():
    """Parsing twice along a call chain costs nothing: the same object comes back."""
    b = StepBounds.parse(([0.1, 0.2, 0.3], [0.2, 0.3, 0.4]), 3)
    assert StepBounds.parse(b, 3) is b


def test_known_step_length_is_allowed():
    """lower == upper states a known step length."""
    b = StepBounds.parse(([0.3, 0.3], [0.3, 0.3]), 2)
    np.testing.assert_array_equal(b.lower, b.upper)


@pytest.mark.parametrize(
    ("value", "n_steps", "match"),
    [
        (3.0, 2, "must be a pair"),
        (([0.1], [0.2]), 2, r"lower must have shape \(2,\)"),
        (([0.1, 0.2], [0.2]), 2, r"upper must have shape \(2,\)"),
        (([0.1, np.nan], [0.2, 0.3]), 2, "lower must be finite"),
        (([-0.1, 0.2], [0.2, 0.3]), 2, "lower must be >= 0; step 0"),
        (([0.1, 0.5], [0.2, 0.3]), 2, r"lower <= upper; step 1 has \[0.5, 0.3\]"),
    ],
)
def test_bad_bounds_are_refused_with_the_argument_named(value, n_steps, match):
    with pytest.raises(InvalidInputError, match=match):
        StepBounds.parse(value, n_steps, "step_bounds")


def test_parsed_bounds_of_another_length_are_refused():
    b = StepBounds.parse(([0.1, 0.2], [0.2, 0.3]), 2)
    with pytest.raises(InvalidInputError, match=r"shape \(3,\)"):
        StepBounds.parse(b, 3)


def test_direct_construction_is_validated():
    """StepBounds(...) built by hand obeys the same rules as parse."""
    with pytest.raises(InvalidInputError, match="lower <= upper"):
        StepBounds(lower=np.array([0.5]), upper=np.array([0.1]))
    with pytest.raises(InvalidInputError, match="same length"):
        StepBounds(lower=np.array([0.1, 0.2]), upper=np.array([0.3]))


@given(
    st.lists(
        st.tuples(st.floats(0, 10, allow_nan=False), st.floats(0, 10, allow_nan=False)),
        min_size=1,
        max_size=20,
    )
)
def test_parse_accepts_exactly_the_ordered_non_negative_pairs(pairs):
    """Property: a pair list parses iff every lower <= upper, and then round-trips exactly;
    otherwise only InvalidInputError escapes."""
    lower = np.array([a for a, _ in pairs])
    upper = np.array([b for _, b in pairs])
    if np.all(lower <= upper):
        b = StepBounds.parse((lower, upper), len(pairs))
        np.testing.assert_array_equal(b.lower, lower)
        np.testing.assert_array_equal(b.upper, upper)
    else:
        with pytest.raises(InvalidInputError):
            StepBounds.parse((lower, upper), len(pairs))


def test_widened_keeps_wide_and_opens_known_steps():
    """widened(w): intervals narrower than w (lower = upper, a known step) become w wide about
    their midpoint, clipped at 0; wider ones are kept exactly; nothing to widen returns self."""
    b = StepBounds(lower=np.array([1.0, 0.0, 0.5]), upper=np.array([1.0, 0.0, 2.0]))
    w = b.widened(1e-3)
    np.testing.assert_allclose(w.lower, [1.0 - 5e-4, 0.0, 0.5])
    np.testing.assert_allclose(w.upper, [1.0 + 5e-4, 1e-3, 2.0])
    wide = StepBounds(lower=np.array([0.5]), upper=np.array([2.0]))
    assert wide.widened(1e-3) is wide
