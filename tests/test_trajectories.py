"""Tests of rangeslam.sim.trajectories: the lemniscate of eq. (12), smooth paths and random walks."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.errors import InvalidInputError
from rangeslam.geometry.room import Room
from rangeslam.sim.trajectories import lemniscate, random_walk, smooth_path, step_lengths


# ---- lemniscate -----------------------------------------------------------------------------------
def test_lemniscate_matches_equation_12(rng):
    """lemniscate() samples eq. (12) (cx = cy = 2, a = 1.5, z = 0.9) at t_n = phase + step * n."""
    phase = rng.uniform(0.0, 2.0 * np.pi)
    traj = lemniscate(40, phase=phase)
    t = phase + 0.3 * np.arange(40)
    den = 1.0 + np.sin(t) ** 2
    want = np.column_stack(
        [2.0 + 1.5 * np.cos(t) / den, 2.0 + np.sin(t) * np.cos(t) / den, np.full(40, 0.9)]
    )
    assert traj.shape == (40, 3)
    np.testing.assert_allclose(traj, want, rtol=0, atol=1e-14)


def test_lemniscate_options(rng):
    """step, centre, half_width and height enter eq. (12) as documented."""
    step = rng.uniform(0.05, 0.5)
    centre = rng.uniform(0.0, 5.0, size=2)
    a, h = rng.uniform(0.5, 3.0), rng.uniform(0.5, 2.0)
    traj = lemniscate(25, step=step, centre=centre, half_width=a, height=h)
    t = step * np.arange(25)
    den = 1.0 + np.sin(t) ** 2
    np.testing.assert_allclose(traj[:, 0], centre[0] + a * np.cos(t) / den, rtol=0, atol=1e-14)
    np.testing.assert_allclose(traj[:, 1], centre[1] + np.sin(t) * np.cos(t) / den, atol=1e-14)
    np.testing.assert_array_equal(traj[:, 2], h)


def test_lemniscate_2d_is_the_3d_projection():
    """dim=2 returns the x, y columns of the 3-D lemniscate, whose z is 0.9 m throughout."""
    t3 = lemniscate(30, phase=0.7)
    t2 = lemniscate(30, phase=0.7, dim=2)
    assert t2.shape == (30, 2)
    np.testing.assert_array_equal(t2, t3[:, :2])
    np.testing.assert_array_equal(t3[:, 2], 0.9)


def test_lemniscate_default_steps_are_about_30_cm():
    """With step 0.3 the mean step over whole periods is 0.33 m: within 12% of 0.3 m, not 10%.

    Computed, not assumed: the mean speed |r'(t)| of eq. (12) over a period is 1.112 m per radian,
    and 0.3 rad chords are a little shorter than the arc, so the mean step is 0.3295 m (9.8% above
    0.3), and 0.3304 m for a single period of 21 steps. A 10% bound would sit on the edge, so the
    bound is 12%; steps range from 0.27 to 0.39 m (narrow loop ends versus the crossing).
    """
    steps = step_lengths(lemniscate(21 * 10 + 1))  # ten periods of 2 pi / 0.3 ~ 21 steps
    assert abs(steps.mean() / 0.3 - 1.0) < 0.12
    assert steps.mean() == pytest.approx(0.3295, abs=1e-3)
    assert steps.min() > 0.25 and steps.max() < 0.40


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_steps": 0}, r"n_steps must be an integer >= 1 \(at most 10000000\); got 0"),
        ({"n_steps": 2.5}, "n_steps must be an integer >= 1"),
        ({"n_steps": 5, "step": 0.0}, "step must be a positive finite number"),
        ({"n_steps": 5, "step": np.inf}, "step must be a positive finite number"),
        ({"n_steps": 5, "half_width": -1.0}, "half_width must be a positive finite number"),
        ({"n_steps": 5, "dim": 4}, "dim must be 2 or 3; got 4"),
        (
            {"n_steps": 5, "centre": (1.0, 2.0, 3.0)},
            r"centre must be 2 finite numbers, shape \(2,\)",
        ),
    ],
)
def test_lemniscate_rejects_bad_input(kwargs, match):
    """lemniscate refuses bad counts, steps, widths, dimensions and centres."""
    with pytest.raises(InvalidInputError, match=match):
        lemniscate(**kwargs)


# ---- step_lengths ---------------------------------------------------------------------------------
def test_step_lengths_of_known_path():
    """step_lengths gives the distances between consecutive rows."""
    np.testing.assert_allclose(
        step_lengths([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [3.0, 4.0, 2.0]]), [5.0, 2.0], rtol=0
    )


def test_step_lengths_rejects_single_point():
    """step_lengths needs at least two positions."""
    with pytest.raises(InvalidInputError, match="at least 2 points"):
        step_lengths([[0.0, 0.0]])


# ---- smooth_path ----------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_smooth_path_on_a_line_is_exactly_equally_spaced(rng, dim):
    """Through collinear waypoints the spline is the line: steps are exactly step_length."""
    u = rng.normal(size=dim)
    u /= np.linalg.norm(u)
    start = rng.uniform(0.0, 3.0, size=dim)
    s = np.cumsum(rng.uniform(2.0, 3.0, size=3))  # unequal spacing, >= 6 m in all
    wp = start + np.concatenate([[0.0], s])[:, None] * u
    path = smooth_path(wp, 20, step_length=0.25)
    np.testing.assert_allclose(path[0], start, rtol=0, atol=1e-12)
    np.testing.assert_allclose(path, start + 0.25 * np.arange(20)[:, None] * u, rtol=0, atol=1e-9)


def _helix_waypoints(rng: np.random.Generator, dim: int) -> tuple[np.ndarray, float]:
    """Waypoints on a circle (2-D) or a helix (3-D) of random radius, with the curve's radius."""
    radius = rng.uniform(1.5, 3.0)
    angles = np.linspace(0.0, 1.5 * np.pi, 13) + rng.uniform(0.0, 2.0 * np.pi)
    wp = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    if dim == 3:
        wp = np.column_stack([wp, np.linspace(0.0, 1.0, 13)])
    return wp, radius


@pytest.mark.parametrize("dim", [2, 3])
def test_smooth_path_step_length_gives_equal_arc_spacing(rng, dim):
    """On a gently curved path, chords between points equal step_length to 1e-3 (relative).

    Chord = arc (1 - kappa^2 s^2 / 24): for s = 0.1 m and radius >= 1.5 m that is < 2e-4 short.
    """
    wp, _ = _helix_waypoints(rng, dim)
    path = smooth_path(wp, 50, step_length=0.1)
    assert path.shape == (50, dim)
    np.testing.assert_allclose(path[0], wp[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(step_lengths(path), 0.1, rtol=1e-3)


@pytest.mark.parametrize("dim", [2, 3])
def test_smooth_path_without_step_length_spans_the_curve(rng, dim):
    """Without step_length the points run from the first to the last waypoint, equally spaced."""
    wp, radius = _helix_waypoints(rng, dim)
    path = smooth_path(wp, 60)
    np.testing.assert_allclose(path[0], wp[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(path[-1], wp[-1], rtol=0, atol=1e-9)
    steps = step_lengths(path)
    np.testing.assert_allclose(steps, steps.mean(), rtol=1e-3)
    # the curve is close to the circle through the waypoints
    np.testing.assert_allclose(np.linalg.norm(path[:, :2], axis=1), radius, rtol=1e-2)


def test_smooth_path_raises_when_too_short(rng):
    """Asking for more distance than the path has is refused with the path's length."""
    wp = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    assert smooth_path(wp, 5, step_length=0.5).shape == (5, 2)  # exactly 2 m fits
    with pytest.raises(
        InvalidInputError, match=r"is 2\.000 m long, too short for 6 steps of 0\.5 m"
    ):
        smooth_path(wp, 6, step_length=0.5)


@pytest.mark.parametrize(
    ("waypoints", "n_steps", "kwargs", "match"),
    [
        ([[0.0, 0.0]], 5, {}, "waypoints must hold at least 2 points"),
        (
            [[0.0, 0.0], [1.0, 0.0]],
            1,
            {},
            r"n_steps must be an integer >= 2 \(at most 10000000\); got 1",
        ),
        ([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]], 5, {}, "must not repeat consecutively"),
        ([[0.0, 0.0], [1.0, 1.0]], 5, {"step_length": -0.1}, "step_length must be a positive"),
    ],
)
def test_smooth_path_rejects_bad_input(waypoints, n_steps, kwargs, match):
    """smooth_path refuses too few waypoints or steps, repeated waypoints and bad step lengths."""
    with pytest.raises(InvalidInputError, match=match):
        smooth_path(waypoints, n_steps, **kwargs)


# ---- random_walk ----------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_random_walk_stays_inside_room_with_margin(rng, dim):
    """A long walk in a small room stays `margin` inside it, starting at `start`."""
    room = Room.shoebox([3.0, 2.5, 2.0][:dim])
    start = np.array([1.5, 1.25, 1.0][:dim])
    walk = random_walk(300, start=start, room=room, margin=0.4, step_length=0.3, rng=rng)
    assert walk.shape == (300, dim)
    np.testing.assert_array_equal(walk[0], start)
    assert room.contains(walk, margin=0.4).all()
    # in a 3 m room 300 steps of 0.3 m must have been turned back by the walls
    assert np.ptp(walk[:, 0]) > 1.5


@pytest.mark.parametrize("dim", [2, 3])
def test_random_walk_step_lengths(rng, dim):
    """Without jitter every step is step_length; with jitter the lengths vary around it."""
    start = np.zeros(dim)
    walk = random_walk(50, start=start, step_length=0.2, rng=rng)
    np.testing.assert_allclose(step_lengths(walk), 0.2, rtol=1e-12)
    jittered = step_lengths(
        random_walk(400, start=start, step_length=0.2, step_jitter=0.2, rng=rng)
    )
    assert jittered.std() > 0.01
    assert jittered.mean() == pytest.approx(0.2, rel=0.05)  # 400 draws: SE of the mean is 1%


@pytest.mark.parametrize("dim", [2, 3])
def test_random_walk_is_reproducible_by_seed(dim):
    """The same seed gives the same walk, a different seed a different one."""
    room = Room.shoebox([4.0, 4.0, 3.0][:dim])
    start = np.full(dim, 1.5)
    a = random_walk(40, start=start, room=room, rng=7)
    b = random_walk(40, start=start, room=room, rng=np.random.default_rng(7))
    c = random_walk(40, start=start, room=room, rng=8)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start": [5.0, 1.0]}, r"start \[5\.0, 1\.0\] must be at least 0\.3 m inside the room"),
        ({"start": [0.1, 1.0]}, "must be at least 0.3 m inside the room"),
        ({"start": [1.0, 1.0, 1.0]}, "start has dimension 3 but room has dimension 2"),
        ({"start": [1.0, 1.0], "step_length": 0.0}, "step_length must be a positive"),
        # the allowed square is 1.1 m wide: no 1 m step from its centre stays in it
        ({"start": [1.0, 1.0], "margin": 0.45, "step_length": 1.0}, "could not stay inside"),
    ],
)
def test_random_walk_rejects_bad_input(rng, kwargs, match):
    """random_walk refuses a start outside the room or of another dimension, and impossible walks."""
    room = Room.shoebox([2.0, 2.0])
    with pytest.raises(InvalidInputError, match=match):
        random_walk(5, room=room, rng=rng, **kwargs)
