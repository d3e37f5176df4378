"""Least-squares unfolding (rangeslam.solvers.least_squares.refine_unfolding) and the gauge rows
that let MINPACK's Levenberg-Marquardt take a fit with fewer ranges than coordinates."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from rangeslam import InvalidInputError
from rangeslam.app.experiments import fig3_scene
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.solvers.least_squares import (
    gauge_rows,
    refine_unfolding,
    unfolding_jacobian,
    unfolding_residuals,
)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 12), d=st.sampled_from([2, 3]))
def test_gauge_rows_vanish_at_the_procrustes_alignment(seed, n, d):
    """The rows are zero for any configuration moved onto the start by its best rotation and
    translation (the stationarity of Procrustes), and not for a small rotation of it."""
    rng = np.random.default_rng(seed)
    start = rng.standard_normal((n, d))
    other = start + 0.3 * rng.standard_normal((n, d))
    rows = gauge_rows(start)
    assert rows.shape == (d * (d + 1) // 2, n * d)
    moved = align(other, start, reflection=False).aligned
    assert np.abs(rows @ (moved - start).ravel()).max() < 1e-9 * max(1.0, np.abs(start).max())
    angle = 0.05
    spin = np.eye(d)
    spin[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    centre = start.mean(0)
    spun = (moved - centre) @ spin.T + centre
    # to first order the rotation row moves by angle * sum |q_i|^2 over the spun plane's axes
    q = start - centre
    assert np.abs(rows[d:] @ (spun - start).ravel()).max() > 0.5 * angle * np.sum(q[:, :2] ** 2)


@pytest.mark.parametrize("d", [2, 3])
def test_exact_recovery_with_fewer_ranges_than_coordinates(rng, d):
    """Fewer ranges than coordinates, more than the coordinates beyond the rigid motion (the
    gauge rows' case, which MINPACK's LM takes): 5 x 5 = 25 ranges for 30 coordinates in 3-D,
    3 x 5 = 15 for 16 in 2-D. Noise-free ranges are fitted exactly from a perturbed truth, up to
    a rigid motion."""
    shape = (5, 5) if d == 3 else (3, 5)
    receivers = rng.uniform(0, 3, (shape[0], d))
    sources = rng.uniform(0, 3, (shape[1], d))
    ranges = range_matrix(receivers, sources)
    mask = np.ones(ranges.shape, dtype=bool)
    fit = refine_unfolding(
        receivers + 0.02 * rng.standard_normal(receivers.shape),
        sources + 0.02 * rng.standard_normal(sources.shape),
        ranges,
        mask,
    )
    assert ranges.size < (sum(shape)) * d
    assert fit.converged
    assert fit.rms < 1e-9
    assert align(fit.receivers, receivers, reflection=True).errors.max() < 1e-7


def test_the_gauge_moves_no_minimum(rng):
    """With noise, the fit reaches the cost that scipy's trust-region method reaches from the same
    start without gauge rows (the oracle of the same objective), and its gauge rows are zero:
    the result is in the start's frame."""
    scene = fig3_scene(rng)
    ranges = range_matrix(scene.mics, scene.sources) + 1e-3 * rng.standard_normal((6, 6))
    mask = np.ones(ranges.shape, dtype=bool)
    start = np.vstack([scene.mics, scene.sources]) + 0.01 * rng.standard_normal((12, 3))
    fit = refine_unfolding(start[:6], start[6:], ranges, mask)
    pairs = np.argwhere(mask)
    oracle = least_squares(
        lambda t: unfolding_residuals(t.reshape(-1, 3), 6, ranges[mask], pairs),
        start.ravel(),
        jac=lambda t: unfolding_jacobian(t.reshape(-1, 3), 6, pairs),
        method="trf",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    ssr = float(np.nansum(fit.residuals**2))
    assert ssr <= 2 * oracle.cost * (1 + 1e-6) + 1e-18
    points = np.vstack([fit.receivers, fit.sources])
    assert np.abs(gauge_rows(start) @ (points - start).ravel()).max() < 1e-9


def test_a_rigid_motion_of_the_start_moves_the_fit_with_it(rng):
    """Invariance: the ranges do not see a rigid motion, so the fit from a moved start is the
    fit from the start, moved the same way."""
    receivers, sources = rng.uniform(0, 3, (8, 3)), rng.uniform(0, 3, (5, 3))
    ranges = range_matrix(receivers, sources) + 1e-3 * rng.standard_normal((8, 5))
    mask = np.ones(ranges.shape, dtype=bool)
    r0 = receivers + 0.05 * rng.standard_normal(receivers.shape)
    s0 = sources + 0.05 * rng.standard_normal(sources.shape)
    turn, shift = Rotation.random(random_state=rng).as_matrix(), rng.uniform(-2, 2, 3)
    fit = refine_unfolding(r0, s0, ranges, mask)
    moved = refine_unfolding(r0 @ turn.T + shift, s0 @ turn.T + shift, ranges, mask)
    assert np.allclose(fit.receivers @ turn.T + shift, moved.receivers, atol=1e-7)
    assert np.allclose(fit.sources @ turn.T + shift, moved.sources, atol=1e-7)


def test_bad_input_is_named(rng):
    """Each refused argument is named in the error."""
    r, s = rng.uniform(0, 3, (4, 3)), rng.uniform(0, 3, (3, 3))
    ranges, mask = range_matrix(r, s), np.ones((4, 3), dtype=bool)
    with pytest.raises(InvalidInputError, match="loss"):
        refine_unfolding(r, s, ranges, mask, loss="tukey")
    with pytest.raises(InvalidInputError, match="loss_scale"):
        refine_unfolding(r, s, ranges, mask, loss="cauchy", loss_scale=0.0)
    with pytest.raises(InvalidInputError, match="mask"):
        refine_unfolding(r, s, ranges, np.zeros((4, 3), dtype=bool))
    with pytest.raises(InvalidInputError, match="sources"):
        refine_unfolding(r, s[:, :2], ranges, mask)
