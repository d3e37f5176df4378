"""Anchor-free Cramer-Rao bound of multidimensional unfolding (paper eq. 9; issue 3's yardstick)."""

import numpy as np
import pytest

from rangeslam import DegenerateGeometryError, InvalidInputError, align
from rangeslam.evaluation.crlb import mdu_crlb
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import rigid_motion_basis
from rangeslam.solvers.least_squares import refine_unfolding


def _scene(rng, dim, m=8, k=8):
    return rng.uniform(0, 2, (m, dim)), rng.uniform(-2, 4, (k, dim))


@pytest.mark.parametrize("dim", [2, 3])
def test_null_space_is_the_rigid_motions(rng, dim):
    """The Fisher information is singular exactly along the rigid motions: 3 in 2-D, 6 in 3-D."""
    x, s = _scene(rng, dim)
    bound = mdu_crlb(x, s, 0.01)
    assert bound.null_dimension == dim * (dim + 1) // 2
    # the range Jacobian annihilates every rigid motion of all the points
    pts = np.vstack([x, s])
    basis = rigid_motion_basis(pts)
    h = 1e-6
    base = range_matrix(x, s)
    for col in basis.T:
        moved = (pts.ravel() + h * col).reshape(pts.shape)
        np.testing.assert_allclose(range_matrix(moved[: len(x)], moved[len(x) :]), base, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_receiver_gauge_matches_monte_carlo(rng, dim):
    """Maximum likelihood started at the truth, 200 noisy trials, receivers aligned rigidly to the
    truth: the RMSE matches the receiver-gauge bound within 10% (measured 1%); the all-points
    gauge is a different, larger number for the receivers."""
    x, s = _scene(rng, dim)
    m, k = len(x), len(s)
    sigma = 0.01
    bound = mdu_crlb(x, s, sigma)
    true = range_matrix(x, s)
    errs = []
    observed = np.ones((m, k), dtype=bool)
    for _ in range(200):
        z = true + sigma * rng.standard_normal(true.shape)
        est = refine_unfolding(x, s, z, observed).receivers  # the estimator calibrate refines with
        errs.append(align(est, x).rmse ** 2)
    mc = np.sqrt(np.mean(errs))
    assert abs(mc / bound.receiver_rmse - 1) <= 0.10, (mc, bound.receiver_rmse)
    all_points = mdu_crlb(x, s, sigma, gauge="all")
    assert all_points.receiver_rmse > 1.05 * bound.receiver_rmse


def test_bound_scales_with_sigma(rng):
    """Covariances scale with sigma^2."""
    x, s = _scene(rng, 3)
    a, b = mdu_crlb(x, s, 0.001), mdu_crlb(x, s, 0.01)
    np.testing.assert_allclose(b.receiver_cov, 100 * a.receiver_cov, rtol=1e-6, atol=1e-14)


def test_bad_input(rng):
    """Too few ranges, a bad gauge, non-positive sigma, a receiver on a source, a bad mask."""
    x, s = _scene(rng, 3, m=4, k=4)
    with pytest.raises(DegenerateGeometryError, match="more than the 6 rigid motions"):
        mdu_crlb(x, s, 0.01)  # 16 ranges for 24 coordinates
    x, s = _scene(rng, 3)
    with pytest.raises(InvalidInputError, match="gauge must be"):
        mdu_crlb(x, s, 0.01, gauge="sources")
    with pytest.raises(InvalidInputError, match="sigma must be positive"):
        mdu_crlb(x, s, 0.0)
    with pytest.raises(DegenerateGeometryError, match="coincides"):
        mdu_crlb(x, np.vstack([s[:-1], x[:1]]), 0.01)
    with pytest.raises(InvalidInputError, match="boolean"):
        mdu_crlb(x, s, 0.01, mask=np.ones((8, 8), dtype=int))
