"""The dEchorate-style pick-error simulator (rangeslam.sim.echo_picks): held-out scenes for the
calibration rules, drawn from the error kinds measured on the two real loudspeakers."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.errors import InvalidInputError
from rangeslam.sim.echo_picks import (
    CLEAN,
    GROSS,
    PHANTOM,
    PickErrorModel,
    dechorate_picks,
    echo_ranges_dechorate,
    random_loudspeaker,
    simulate_loudspeakers,
)

ROOM = np.array([5.705, 5.965, 2.355])


def _mics(rng) -> tuple[np.ndarray, np.ndarray]:
    """Six horizontal linear arrays of five microphones 6.4 cm apart, as in dEchorate."""
    centres = rng.uniform([1.0, 1.0, 0.8], [4.7, 5.0, 1.5], size=(6, 3))
    headings = rng.uniform(0, np.pi, 6)
    offsets = (np.arange(5) - 2) * 0.064
    mics = [
        c + np.outer(offsets, [np.cos(h), np.sin(h), 0.0])
        for c, h in zip(centres, headings, strict=True)
    ]
    return np.vstack(mics), np.repeat(np.arange(6), 5)


def test_true_ranges_are_the_loudspeaker_and_its_first_order_images(rng):
    """Column 0 is the direct path; each wall column is the distance to the mirror image."""
    mics, _ = _mics(rng)
    src = random_loudspeaker(ROOM, mics, rng)
    r = echo_ranges_dechorate(mics, src, ROOM)
    assert r.shape == (30, 7)
    np.testing.assert_allclose(r[:, 0], np.linalg.norm(mics - src, axis=1))
    west = src * [-1, 1, 1]  # the image through x = 0
    np.testing.assert_allclose(r[:, 1], np.linalg.norm(mics - west, axis=1))
    assert np.all(src >= 0.5) and np.all(src <= ROOM - 0.5)


def test_picks_are_seeded_and_scenes_nest(rng):
    """The same seed draws the same picks; a scene of 2 loudspeakers is the first half of the
    scene of 4 at that seed."""
    mics, arrays = _mics(rng)
    a = simulate_loudspeakers(mics, arrays, ROOM, 2, 7)
    b = simulate_loudspeakers(mics, arrays, ROOM, 4, 7)
    np.testing.assert_array_equal(a.ranges, b.ranges[:, :14])
    np.testing.assert_array_equal(a.sources, b.sources[:2])
    assert a.ranges.shape == (30, 14) and b.kind.shape == (30, 28)


def test_error_kinds_follow_the_model(rng):
    """Without noise or errors the picks are the true ranges; a phantom column is heard by
    whole arrays with one sign; gross errors are metres and never make a range negative."""
    mics, arrays = _mics(rng)
    true = echo_ranges_dechorate(mics, random_loudspeaker(ROOM, mics, rng), ROOM)
    quiet = PickErrorModel(
        noise_good=(1e-12, 1e-12), noise_walls=(1e-12, 1e-12), bias_std=0.0, bias_slope_std=0.0,
        biased_column_p=0.0, phantom_counts=(1.0, 0.0, 0.0), single_phantom_p=0.0,
        glitch_p=0.0, gross_p=0.0,
    )  # fmt: skip
    clean = dechorate_picks(mics, arrays, true, rng, quiet)
    np.testing.assert_allclose(clean.ranges, true, atol=1e-9)
    assert np.all(clean.kind == CLEAN)
    loud = PickErrorModel(phantom_counts=(0.0, 1.0, 0.0), phantom_array_p=1.0, gross_p=0.2)
    picks = dechorate_picks(mics, arrays, true, rng, loud)
    phantom = picks.kind == PHANTOM
    signs = {
        np.sign(picks.errors[phantom[:, c], c]).mean()
        for c in range(7)
        if phantom[:, c].sum() >= 20
    }
    assert signs <= {-1.0, 1.0}
    assert np.all(np.abs(picks.errors[picks.kind == GROSS]) >= 1.0)
    assert np.all(picks.ranges > 0)
    assert phantom[:, 1:].any(axis=0).sum() >= 1  # one phantom column, heard by every array


def test_bad_input_is_refused(rng):
    mics, arrays = _mics(rng)
    with pytest.raises(InvalidInputError, match=r"need mics \(M, 3\), arrays \(M,\)"):
        dechorate_picks(mics[:, :2], arrays, np.ones((30, 7)), rng)
    with pytest.raises(InvalidInputError, match=r"has no point 3\.0 m from every wall"):
        random_loudspeaker(ROOM, mics, rng, margin=3.0)
    with pytest.raises(InvalidInputError, match="n_loudspeakers must be at least 1"):
        simulate_loudspeakers(mics, arrays, ROOM, 0, rng)
