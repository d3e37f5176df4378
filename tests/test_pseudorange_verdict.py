"""The verdict of ``multilaterate_with_offset``: CONVERGED only when right as far as the data can
tell (the fuzz's silent wrong answers S1 of the fuzz run).

Scenes as the fuzz drew them: 12 anchors uniform in a 4.4 x 3.4 x 2 m box, the point in its upper
middle, 1 mm of range noise and a 0.4 m offset. Each test draws several scenes; an answer is right
within 3 times its standard deviation (``dop`` at the noise) or 5 mm.
"""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import multilaterate, multilaterate_with_offset
from rangeslam.status import Status

SIGMA = 1e-3  # m, range noise
OFFSET = 0.4  # m, the common range offset


def _scene(rng, m=12, flat_std=None):
    """Anchors (m, 3), point (3,) and noisy pseudoranges (m,); anchors within ``flat_std`` (m)
    of the plane z = 1 when given."""
    anchors = rng.uniform((0.3, 0.3, 0.3), (4.7, 3.7, 2.3), size=(m, 3))
    if flat_std is not None:
        anchors[:, 2] = 1.0 + flat_std * rng.standard_normal(m)
    point = rng.uniform((1.0, 1.0, 1.6), (4.0, 3.0, 2.3))
    ranges = np.linalg.norm(anchors - point, axis=1) + OFFSET + SIGMA * rng.standard_normal(m)
    return anchors, point, ranges


def _wrong(rng, ranges, n_wrong):
    """``ranges`` with ``n_wrong`` of them moved by 0.2-2 m (either sign)."""
    wrong = rng.choice(len(ranges), n_wrong, replace=False)
    moved = ranges.copy()
    moved[wrong] += rng.uniform(0.2, 2.0, n_wrong) * rng.choice([-1.0, 1.0], n_wrong)
    return moved


def _right(res, point) -> bool:
    limit = max(3.0 * SIGMA * float(np.linalg.norm(res.dop[:3])), 5e-3)
    return bool(np.linalg.norm(res.position - point) <= limit)


@pytest.mark.parametrize("noise_std", [None, SIGMA])
def test_robust_past_its_breakdown_is_never_converged_wrong(noise_std):
    """5 wrong ranges of 12 are past LMedS's breakdown with subsets of d + 2 = 5 (it needs 9
    right ones). Before: CONVERGED with "12 of 12 kept", 0.6 m off."""
    rng = np.random.default_rng(35001)
    flagged = 0
    for _ in range(10):
        anchors, point, ranges = _scene(rng)
        moved = _wrong(rng, ranges, 5)
        res = multilaterate_with_offset(anchors, moved, robust=True, noise_std=noise_std, rng=rng)
        assert not res.converged or _right(res, point), res.message
        flagged += not res.converged
    assert flagged >= 5


@pytest.mark.parametrize("noise_std", [None, SIGMA])
def test_robust_with_two_wrong_converges_right(noise_std):
    """Two wrong ranges of 12 are found and left out: right and CONVERGED in nearly every draw
    (the chi-square test at 0.999 and the tail test may flag a few right ones)."""
    rng = np.random.default_rng(35002)
    right = 0
    for _ in range(20):
        anchors, point, ranges = _scene(rng)
        moved = _wrong(rng, ranges, 2)
        res = multilaterate_with_offset(anchors, moved, robust=True, noise_std=noise_std, rng=rng)
        assert not res.converged or _right(res, point), res.message
        right += res.converged
    assert right >= 18


def test_a_wrong_range_without_robust_is_flagged():
    """One range 0.2-2 m off, no rejection asked for: the residuals do not fit the noise."""
    rng = np.random.default_rng(35003)
    for _ in range(10):
        anchors, _point, ranges = _scene(rng)
        moved = _wrong(rng, ranges, 1)
        for noise_std in (None, SIGMA):
            res = multilaterate_with_offset(anchors, moved, noise_std=noise_std)
            assert res.status in (Status.INCONSISTENT, Status.OUTLIERS), res.message


def test_near_flat_anchors_leave_the_mirror_image():
    """Anchors within 0.1 mm of a plane pass the spanning test, but the point's mirror image
    through that plane (with its own offset) fits as well: NOT_IDENTIFIABLE, as
    ``multilaterate`` says on the same anchors. Before: CONVERGED, 1.96 m off at the mirror."""
    rng = np.random.default_rng(35004)
    for _ in range(6):
        anchors, _point, ranges = _scene(rng, flat_std=1e-4)
        res = multilaterate_with_offset(anchors, ranges, noise_std=SIGMA)
        assert res.status is Status.NOT_IDENTIFIABLE, res.message
        assert "mirror" in res.message
        plain = multilaterate(anchors, ranges - OFFSET, noise_std=SIGMA)
        assert plain.status is Status.NOT_IDENTIFIABLE


def test_no_spare_range_with_a_wrong_pick_possible_is_not_identifiable():
    """d + 2 ranges with robust=True: a wrong one would be fitted exactly (before: CONVERGED,
    its message saying no rejection was possible). The same ranges without robust converge."""
    rng = np.random.default_rng(35005)
    anchors, _point, ranges = _scene(rng, m=5)
    moved = _wrong(rng, ranges, 1)
    res = multilaterate_with_offset(anchors, moved, robust=True)
    assert res.status is Status.NOT_IDENTIFIABLE and "no outlier rejection" in res.message
    assert multilaterate_with_offset(anchors, ranges).converged


def test_noise_std_zero_means_exact():
    """Exact ranges with noise_std=0 converge to round-off; 1 mm of noise is then INCONSISTENT."""
    rng = np.random.default_rng(35006)
    anchors, point, ranges = _scene(rng)
    exact = np.linalg.norm(anchors - point, axis=1) + OFFSET
    res = multilaterate_with_offset(anchors, exact, noise_std=0.0)
    assert res.converged and np.linalg.norm(res.position - point) < 1e-9
    noisy = multilaterate_with_offset(anchors, ranges, noise_std=0.0)
    assert noisy.status is Status.INCONSISTENT


@pytest.mark.parametrize("bad", [-1e-3, np.nan, "1mm", [1e-3], 1j])
def test_noise_std_is_checked(bad):
    rng = np.random.default_rng(35007)
    anchors, _, ranges = _scene(rng)
    with pytest.raises(Exception, match="noise_std") as info:
        multilaterate_with_offset(anchors, ranges, noise_std=bad)
    assert type(info.value).__name__ == "InvalidInputError"


def test_repeated_anchors_do_not_make_the_offset_identifiable():
    """Hypothesis (test_entry_points, CI of issue 42's stop): six exact pseudoranges from four
    distinct anchors in 3-D (one anchor three times) converged 2 m from the truth; four distinct
    anchors leave the point and the offset finitely many exact solutions, so NOT_IDENTIFIABLE."""
    anchors = np.array(
        [[2.0, 1.375, 1.0], [1.25, 2, 2], [2, 2, 2], [2, 2, 0], [2, 2, 2], [2, 2, 2]]
    )
    truth = np.array([1.0, 1.0, 1.0])
    ranges = np.linalg.norm(anchors - truth, axis=1) + 0.37
    out = multilaterate_with_offset(anchors, ranges)
    assert out.status is Status.NOT_IDENTIFIABLE, out.message
    assert "distinct anchor positions" in out.message
