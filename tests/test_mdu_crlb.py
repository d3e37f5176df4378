"""Anchor-free Cramer-Rao bound of multidimensional unfolding (paper eq. 9; issue 3's yardstick)."""

import numpy as np
import pytest

from rangeslam import DegenerateGeometryError, InvalidInputError, align
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import rigid_motion_basis
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.verdict.crlb import mdu_crlb


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
    with pytest.raises(InvalidInputError, match="sigma must be in"):
        mdu_crlb(x, s, 0.0)
    with pytest.raises(DegenerateGeometryError, match="coincides"):
        mdu_crlb(x, np.vstack([s[:-1], x[:1]]), 0.01)
    with pytest.raises(InvalidInputError, match="boolean"):
        mdu_crlb(x, s, 0.01, mask=np.ones((8, 8), dtype=int))


def test_ill_conditioned_bound_is_finite(rng):
    """Nearly coplanar points in 3-D (z spread 1e-4 m): the information is regular but its
    smallest gauge-free eigenvalue is under 1e-9 of the largest (the old fixed cut called the
    bound infinite). The bound is finite and equals sigma^2 pinv(J) pinv(J)^T computed directly
    (rigid motions cut by pinv's rcond), within 1e-6 relative."""
    x, s = _scene(rng, 3)
    x[:, 2] = 1e-4 * rng.standard_normal(len(x))
    s[:, 2] = 1e-4 * rng.standard_normal(len(s))
    sigma = 1e-6
    bound = mdu_crlb(x, s, sigma, gauge="all")
    assert np.isfinite(bound.receiver_rmse) and bound.null_dimension == 6
    pts = np.vstack([x, s])
    m, k = len(x), len(s)
    jac = np.zeros((m * k, (m + k) * 3))
    for row, (i, j) in enumerate(np.ndindex(m, k)):
        u = (pts[i] - pts[m + j]) / np.linalg.norm(pts[i] - pts[m + j])
        jac[row, 3 * i : 3 * i + 3] = u
        jac[row, 3 * (m + j) : 3 * (m + j) + 3] = -u
    fisher = jac.T @ jac
    eig = np.linalg.eigvalsh(fisher)
    assert eig[6] < 1e-9 * eig[-1]  # the case the fixed cut refused
    pinv = np.linalg.pinv(jac, rcond=1e-12)
    cov = sigma**2 * pinv @ pinv.T
    rmse = np.sqrt(np.trace(cov[: 3 * m, : 3 * m]) / m)
    np.testing.assert_allclose(bound.receiver_rmse, rmse, rtol=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_flexible_configuration_still_singular(rng, dim):
    """A receiver heard by d - 1 sources can swing about them: one direction beyond the rigid
    motions is unobservable, and the bound is refused (not a huge finite number)."""
    x, s = _scene(rng, dim)
    mask = np.ones((len(x), len(s)), dtype=bool)
    mask[0, dim - 1 :] = False
    with pytest.raises(DegenerateGeometryError, match="unobservable directions"):
        mdu_crlb(x, s, 0.01, mask=mask)


@pytest.mark.parametrize("bad", ["x", np.array([0.1, 0.2]), np.nan, True, 1j, None])
def test_sigma_refused_at_the_door(rng, bad):
    """A string, an array, NaN, a bool, a complex or None as sigma: InvalidInputError naming it."""
    x, s = _scene(rng, 3)
    with pytest.raises(InvalidInputError, match="sigma"):
        mdu_crlb(x, s, bad)
