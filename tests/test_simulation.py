"""Tests of rangeslam.sim.scenes: range matrices, noise, masks, outliers, random rooms and echoes."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.room import Room
from rangeslam.sim.scenes import (
    add_outliers,
    add_range_noise,
    echo_ranges,
    random_convex_room,
    random_mask,
    random_points_in_room,
)


# ---- range_matrix ---------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_range_matrix_matches_double_loop(rng, dim):
    """range_matrix[m, k] is the distance between receiver m and source k."""
    rec = rng.uniform(0.0, 5.0, size=(7, dim))
    src = rng.uniform(0.0, 5.0, size=(4, dim))
    want = np.array([[np.sqrt(np.sum((r - s) ** 2)) for s in src] for r in rec])
    np.testing.assert_allclose(range_matrix(rec, src), want, rtol=1e-14, atol=0)


def test_range_matrix_rejects_mixed_dimensions():
    """Receivers and sources must have the same dimension."""
    with pytest.raises(InvalidInputError, match=r"sources must have shape \(N, d\) with d = 2"):
        range_matrix(np.zeros((3, 2)), np.zeros((2, 3)))


# ---- add_range_noise ------------------------------------------------------------------------------
def test_range_noise_has_the_requested_std(rng):
    """Over 40000 draws the noise has mean ~0 and std within 3% of sigma.

    The standard error of the sample std is sigma / sqrt(2 n) = 0.35% of sigma, so 3% is more
    than 8 standard errors; the mean is checked against 5 standard errors, 5 sigma / sqrt(n).
    """
    sigma, n = 0.02, 40_000
    ranges = rng.uniform(2.0, 8.0, size=(200, n // 200))  # far from 0: no folding
    noise = add_range_noise(ranges, sigma, rng=rng) - ranges
    assert noise.std() == pytest.approx(sigma, rel=0.03)
    assert abs(noise.mean()) < 5 * sigma / np.sqrt(n)


def test_range_noise_zero_sigma_and_no_mutation(rng):
    """sigma = 0 returns the ranges unchanged, in a new array; the input is never modified."""
    ranges = rng.uniform(0.0, 5.0, size=(6, 4))
    before = ranges.copy()
    out = add_range_noise(ranges, 0.0, rng=rng)
    np.testing.assert_array_equal(out, ranges)
    assert out is not ranges
    add_range_noise(ranges, 0.5, rng=rng)
    np.testing.assert_array_equal(ranges, before)


def test_range_noise_reproducible_and_folded(rng):
    """The same seed gives the same noise; ranges near zero stay non-negative (folded)."""
    ranges = np.full((5, 5), 0.01)
    a = add_range_noise(ranges, 0.1, rng=3)
    b = add_range_noise(ranges, 0.1, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, add_range_noise(ranges, 0.1, rng=4))
    assert np.all(a >= 0)


@pytest.mark.parametrize(
    ("ranges", "sigma", "match"),
    [
        (np.ones(3), -0.1, "sigma must be a finite number >= 0; got -0.1"),
        (np.ones(3), np.nan, "sigma must be a finite number >= 0"),
        ([1.0, -1.0], 0.1, r"ranges must be non-negative distances; entry \(1,\) is -1"),
        ([1.0, np.nan], 0.1, "ranges must be finite"),
    ],
)
def test_range_noise_rejects_bad_input(ranges, sigma, match):
    """add_range_noise refuses negative or non-finite sigma and ranges."""
    with pytest.raises(InvalidInputError, match=match):
        add_range_noise(ranges, sigma, rng=0)


# ---- random_mask ----------------------------------------------------------------------------------
@pytest.mark.parametrize("fraction", [0.0, 0.3, 1.0])
def test_random_mask_missing_fraction(rng, fraction):
    """About `fraction` of 100000 entries are missing (within 0.01, > 6 standard errors)."""
    mask = random_mask((250, 400), fraction, rng=rng)
    assert mask.shape == (250, 400) and mask.dtype == bool
    assert abs(np.mean(~mask) - fraction) < 0.01
    if fraction in (0.0, 1.0):
        assert np.all(mask == (fraction == 0.0))


@pytest.mark.parametrize("fraction", [-0.1, 1.5])
def test_random_mask_rejects_bad_fraction(fraction):
    """random_mask refuses a fraction outside [0, 1]."""
    with pytest.raises(InvalidInputError, match=r"missing_fraction must be in \[0, 1\]"):
        random_mask((3, 3), fraction, rng=0)


# ---- add_outliers ---------------------------------------------------------------------------------
def test_outliers_mark_exactly_the_changed_entries(rng):
    """is_outlier is True exactly where the range changed, by |error| in [min_error, max_error]."""
    ranges = rng.uniform(3.0, 10.0, size=(60, 50))  # > max_error: both signs can be applied
    out, is_out = add_outliers(ranges, 0.2, min_error=0.3, max_error=1.5, rng=rng)
    assert out.shape == ranges.shape and is_out.dtype == bool
    np.testing.assert_array_equal(is_out, out != ranges)
    err = np.abs(out - ranges)[is_out]
    assert err.min() >= 0.3 and err.max() <= 1.5
    assert abs(is_out.mean() - 0.2) < 0.03  # 3000 entries: SE 0.7%
    # both signs occur
    signed = (out - ranges)[is_out]
    assert np.any(signed > 0) and np.any(signed < 0)


def test_outliers_near_zero_lengthen_instead_of_going_negative(rng):
    """Near zero a shortening below 0 becomes a lengthening: |change| stays in [min_error, max_error]."""
    ranges = rng.uniform(0.0, 0.3, size=(40, 40))  # < min_error: every shortening would go negative
    out, is_out = add_outliers(ranges, 0.5, min_error=0.5, max_error=1.0, rng=rng)
    assert is_out.any()
    np.testing.assert_array_equal(is_out, out != ranges)
    change = (out - ranges)[is_out]
    assert np.all(change >= 0.5) and np.all(change <= 1.0)
    assert np.all(out >= 0)


def test_outliers_respect_the_mask(rng):
    """Unobserved entries are never corrupted and the input array is not modified."""
    ranges = rng.uniform(3.0, 10.0, size=(30, 30))
    before = ranges.copy()
    mask = random_mask(ranges.shape, 0.5, rng=rng)
    out, is_out = add_outliers(ranges, 1.0, mask=mask, rng=rng)
    np.testing.assert_array_equal(is_out, mask)  # fraction 1: every observed entry
    np.testing.assert_array_equal(out[~mask], ranges[~mask])
    np.testing.assert_array_equal(ranges, before)


def test_outliers_reproducible_by_seed():
    """The same seed gives the same corruption."""
    ranges = np.linspace(1.0, 9.0, 40).reshape(8, 5)
    a = add_outliers(ranges, 0.3, rng=11)
    b = add_outliers(ranges, 0.3, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fraction": 1.5}, r"fraction must be in \[0, 1\]; got 1.5"),
        ({"fraction": 0.1, "min_error": 2.0, "max_error": 1.0}, "need 0 <= min_error <= max_error"),
        ({"fraction": 0.1, "min_error": -0.1}, "need 0 <= min_error <= max_error"),
        ({"fraction": 0.1, "mask": np.ones((3, 4), dtype=int)}, "mask must be a boolean array"),
        ({"fraction": 0.1, "mask": np.ones((4, 3), dtype=bool)}, r"mask must have shape \(3, 4\)"),
    ],
)
def test_outliers_reject_bad_input(kwargs, match):
    """add_outliers refuses bad fractions, error bounds and masks."""
    with pytest.raises(InvalidInputError, match=match):
        add_outliers(np.ones((3, 4)), rng=0, **kwargs)


# ---- random rooms and points ----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("dim", "n_walls"), [(2, 3), (2, 5), (2, 8), (3, 4), (3, 5), (3, 8), (3, 12)]
)
def test_random_convex_room_is_bounded_with_requested_walls(rng, dim, n_walls):
    """random_convex_room has n_walls walls, each with a facet, a finite volume and its interior."""
    room = random_convex_room(dim, n_walls, inner_radius=1.5, radius_spread=0.5, rng=rng)
    assert isinstance(room, Room)
    assert room.dim == dim and room.n_walls == n_walls
    assert np.all(np.isfinite(room.vertices)) and 0 < room.volume < np.inf
    # walls are tangent to spheres of radius in [1.5, 2.0] around one centre: the room holds a
    # 1.5 m ball, and no inscribed ball is larger than 2 m (some wall faces away from its centre)
    dist = room.distance_to_walls(room.interior_point[None, :])[0]
    assert 1.5 - 1e-9 <= dist.min() <= 2.0 + 1e-9
    # every wall touches the room along a facet of d vertices
    on_wall = np.abs(room.vertices @ room.normals.T - room.offsets) < 1e-9 * room.size
    assert np.all(on_wall.sum(axis=0) >= dim)


def test_random_convex_room_reproducible_by_seed():
    """The same seed draws the same room."""
    assert random_convex_room(3, 8, rng=5) == random_convex_room(3, 8, rng=np.random.default_rng(5))


@pytest.mark.parametrize(
    ("dim", "n_walls", "match"),
    [
        (4, 6, "dim must be 2 or 3; got 4"),
        (2, 2, "n_walls must be an integer >= 3; got 2"),
        (3, 3, "n_walls must be an integer >= 4; got 3"),
        (3, 5.0, "n_walls must be an integer >= 4; got 5.0"),
    ],
)
def test_random_convex_room_rejects_bad_input(dim, n_walls, match):
    """random_convex_room refuses dimensions other than 2, 3 and too few walls."""
    with pytest.raises(InvalidInputError, match=match):
        random_convex_room(dim, n_walls, rng=0)


@pytest.mark.parametrize("dim", [2, 3])
def test_random_points_in_room_inside_with_margin(rng, dim):
    """random_points_in_room returns n points, all at least `margin` inside the room."""
    room = random_convex_room(dim, 2 * dim + 1, rng=rng)
    pts = random_points_in_room(room, 500, margin=0.5, rng=rng)
    assert pts.shape == (500, dim)
    assert room.contains(pts, margin=0.5).all()
    assert random_points_in_room(room, 0, rng=rng).shape == (0, dim)
    # uniform: some points come close to the margin
    assert room.distance_to_walls(pts).min() < 0.6


def test_random_points_in_room_rejects_bad_input(rng):
    """random_points_in_room refuses a bad count and a margin wider than the room."""
    room = Room.shoebox([2.0, 2.0])
    with pytest.raises(InvalidInputError, match="n must be a non-negative integer; got -1"):
        random_points_in_room(room, -1, rng=rng)
    with pytest.raises(InvalidInputError, match=r"n must be a non-negative integer; got 2\.5"):
        random_points_in_room(room, 2.5, rng=rng)
    with pytest.raises(InvalidInputError, match=r"could not place 3 points 1\.5 m inside"):
        random_points_in_room(room, 3, margin=1.5, rng=rng, max_tries=20)


# ---- echo_ranges ----------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_echo_ranges_columns_are_direct_then_first_order_echoes(rng, dim):
    """Column 0 is the direct range; column 1 + k the length of the path reflected in wall k."""
    room = random_convex_room(dim, 2 * dim + 1, rng=rng)
    src, *rec = random_points_in_room(room, 6, margin=0.2, rng=rng)
    rec = np.array(rec)
    got = echo_ranges(room, rec, src)
    assert got.shape == (5, 1 + room.n_walls)
    np.testing.assert_allclose(got[:, 0], np.linalg.norm(rec - src, axis=1), rtol=1e-14)
    for k, (n, o) in enumerate(zip(room.normals, room.offsets, strict=True)):
        # independent of image sources: the specular point p on plane k minimises |r - p| + |p - s|;
        # with h_s, h_r the heights of s, r below the plane it splits r - s in the ratio h_s : h_r
        hs, hr = o - src @ n, o - rec @ n
        along = (rec - src) - np.outer((rec - src) @ n, n)  # component parallel to the plane
        p = src + hs * n + (hs / (hs + hr))[:, None] * along
        np.testing.assert_allclose(p @ n, o, rtol=0, atol=1e-12)
        path = np.linalg.norm(rec - p, axis=1) + np.linalg.norm(p - src, axis=1)
        np.testing.assert_allclose(got[:, 1 + k], path, rtol=1e-12)


def test_echo_ranges_rejects_source_outside(rng):
    """echo_ranges refuses a source outside the room."""
    room = Room.shoebox([3.0, 4.0])
    with pytest.raises(InvalidInputError, match="source must be inside the room"):
        echo_ranges(room, rng.uniform(0.5, 2.5, size=(3, 2)), [5.0, 1.0])


def test_add_outliers_rejects_negative_ranges():
    """add_outliers refuses negative ranges (they are distances)."""
    with pytest.raises(InvalidInputError, match="ranges must be non-negative"):
        add_outliers([[1.0, -2.0]], 0.5, rng=0)


def test_random_convex_room_walls_are_not_redundant(rng):
    """Rebuilding a random room from its planes succeeds: no redundant wall slipped through."""
    room = random_convex_room(3, 8, rng=rng)
    rebuilt = Room(room.normals, room.offsets)
    assert rebuilt == room
    with pytest.raises(DegenerateGeometryError, match="does not bound the room"):
        Room(
            np.vstack([room.normals, room.normals[:1]]),
            np.append(room.offsets, room.offsets[0] + 1.0),
        )


def test_add_outliers_ignores_unobserved_placeholders(rng):
    """Unobserved entries may hold NaN; they are neither checked nor corrupted, and stay as given."""
    r = np.full((5, 4), 2.0)
    r[0, 0] = np.nan
    mask = np.ones((5, 4), dtype=bool)
    mask[0, 0] = False
    out, is_out = add_outliers(r, 1.0, mask=mask, rng=rng)
    assert not is_out[0, 0] and is_out[mask].all()
    assert np.isnan(out[0, 0])


def test_echo_ranges_refuse_receivers_outside_the_room():
    """Echo ranges are for receivers inside the room; one outside is refused, naming it."""
    room = Room.shoebox([4.0, 3.0, 2.0])
    with pytest.raises(InvalidInputError, match="receiver 1 is not"):
        echo_ranges(room, [[1.0, 1.0, 1.0], [5.0, 1.0, 1.0]], [2.0, 1.5, 1.0])


def test_walk_in_random_room():
    """A walk of M steps of the given length, the loudspeaker and its n nearest first-order
    images as landmarks (off the walk), the same for the same seed."""
    from rangeslam.sim.scenes import walk_in_random_room
    from rangeslam.sim.trajectories import step_lengths

    traj, landmarks = walk_in_random_room(30, n_images=4, step_length=0.2, rng=7)
    assert traj.shape == (30, 3) and landmarks.shape == (5, 3)
    np.testing.assert_allclose(step_lengths(traj), 0.2, rtol=1e-9)
    assert np.min(np.linalg.norm(traj[:, None] - landmarks[None], axis=2)) > 0
    again, _ = walk_in_random_room(30, n_images=4, step_length=0.2, rng=7)
    np.testing.assert_array_equal(traj, again)
