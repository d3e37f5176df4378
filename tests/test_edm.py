"""Tests of rangeslam.geometry.edm: EDMs, Gram matrices, Gower's test and classical MDS (eqs. 5-7)."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.errors import InvalidInputError
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import (
    centring_matrix,
    classical_mds,
    edm,
    edm_to_gram,
    gram_to_edm,
    is_edm,
)

SIGMA = 0.01  # metres, range noise of the noisy-EDM tests


def _noisy_edm(points: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Squared distances with symmetric i.i.d. N(0, sigma^2) noise on the distances, zero diagonal."""
    n = points.shape[0]
    dist = np.linalg.norm(points[:, None] - points[None, :], axis=2)
    noise = np.triu(rng.normal(0.0, sigma, size=(n, n)), 1)
    return (dist + noise + noise.T) ** 2


def test_edm_of_known_points():
    """edm() gives the squared distances of a 3-4-5 triangle and four corners of a unit cube."""
    d = edm([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])
    np.testing.assert_array_equal(d, [[0, 9, 25], [9, 0, 16], [25, 16, 0]])
    d3 = edm([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1]])
    np.testing.assert_allclose(
        d3, [[0, 1, 1, 3], [1, 0, 2, 2], [1, 2, 0, 2], [3, 2, 2, 0]], rtol=0, atol=1e-12
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_edm_matches_pairwise_loop(rng, dim):
    """edm() equals a double loop over ||x_i - x_j||^2, symmetric with an exact zero diagonal."""
    x = rng.uniform(-5.0, 5.0, size=(9, dim))
    want = np.array([[np.sum((a - b) ** 2) for b in x] for a in x])
    got = edm(x)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(np.diag(got), 0.0)
    np.testing.assert_array_equal(got, got.T)


@pytest.mark.parametrize("dim", [2, 3])
def test_gram_edm_round_trip(rng, dim):
    """edm_to_gram(D) is the Gram matrix of the centred points and gram_to_edm inverts it."""
    x = rng.normal(size=(8, dim)) * 3.0 + 10.0
    xc = x - x.mean(axis=0)
    d = edm(x)
    g = edm_to_gram(d)
    np.testing.assert_allclose(g, xc @ xc.T, rtol=0, atol=1e-10)
    np.testing.assert_allclose(g @ np.ones(8), 0.0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(gram_to_edm(g), d, rtol=0, atol=1e-10)
    np.testing.assert_allclose(gram_to_edm(xc @ xc.T), d, rtol=0, atol=1e-10)


def test_centring_matrix_is_a_projector():
    """J = I - 11^T/n is symmetric, idempotent and annihilates the ones vector."""
    j = centring_matrix(6)
    np.testing.assert_allclose(j @ j, j, rtol=0, atol=1e-15)
    np.testing.assert_allclose(j, j.T, rtol=0, atol=0)
    np.testing.assert_allclose(j @ np.ones(6), 0.0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("dim", [2, 3])
def test_is_edm_accepts_real_edms_with_embedding_dimension(rng, dim):
    """An EDM of points in d-D passes Gower's test, with dim >= d but not with dim = d - 1."""
    x = rng.uniform(0.0, 5.0, size=(10, dim))
    d = edm(x)
    assert is_edm(d)
    assert is_edm(d, dim=dim)
    assert is_edm(d, dim=3)
    assert not is_edm(d, dim=dim - 1)
    assert is_edm(1e4 * d, dim=dim) and is_edm(1e-4 * d, dim=dim)  # tolerances are relative


@pytest.mark.parametrize("dim", [2, 3])
def test_is_edm_rejects_non_edms(rng, dim):
    """Gower's test fails for a perturbed entry, asymmetry, negative entries and a non-zero diagonal."""
    x = rng.uniform(0.0, 5.0, size=(10, dim))
    d = edm(x)
    bump = 0.1 * d.mean()
    perturbed = d.copy()
    perturbed[2, 5] += bump  # symmetric, hollow, non-negative, but not Euclidean
    perturbed[5, 2] += bump
    assert not is_edm(perturbed)
    asym = d.copy()
    asym[0, 1] += bump
    assert not is_edm(asym)
    assert not is_edm(-d)
    nonhollow = d + bump * np.eye(10)
    assert not is_edm(nonhollow)
    # three points on a line violating the triangle inequality: |02| = 3 > |01| + |12| = 2
    assert not is_edm([[0.0, 1.0, 9.0], [1.0, 0.0, 1.0], [9.0, 1.0, 0.0]])


@pytest.mark.parametrize("dim", [2, 3])
def test_classical_mds_recovers_points_up_to_rigid_motion(rng, dim):
    """classical_mds of an exact EDM gives centred points that align to the truth exactly."""
    x = rng.uniform(0.0, 5.0, size=(12, dim))
    y = classical_mds(edm(x), dim)
    assert y.shape == (12, dim)
    np.testing.assert_allclose(y.mean(axis=0), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(edm(y), edm(x), rtol=0, atol=1e-10)
    fit = align(y, x, reflection=True)
    assert fit.rmse < 1e-10
    np.testing.assert_allclose(fit.aligned, x, rtol=0, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_classical_mds_clips_negative_eigenvalues_of_noisy_edm(rng, dim):
    """A noisy EDM has negative Gram eigenvalues; MDS clips them to zero and stays accurate.

    Bound: with range noise sigma = 1 cm on 12 points in a 5 m cube, the aligned rmse is about
    sigma; we assert < 3 sigma.
    """
    x = rng.uniform(0.0, 5.0, size=(12, dim))
    d = _noisy_edm(x, SIGMA, rng)
    eig = np.linalg.eigvalsh(edm_to_gram(d))
    assert eig[0] < 0  # the noise makes D non-Euclidean: clipping is exercised
    full = classical_mds(d, 12)
    assert np.all(np.isfinite(full))
    # column j has squared norm max(lambda_j, 0), eigenvalues in decreasing order
    np.testing.assert_allclose(np.sum(full**2, axis=0), np.maximum(eig[::-1], 0.0), atol=1e-9)
    # columns of clearly negative eigenvalues are exactly zero (the ones vector's ~0 is left out)
    n_negative = int(np.sum(eig < -1e-9 * np.abs(eig).max()))
    assert n_negative > 0
    np.testing.assert_array_equal(full[:, 12 - n_negative :], 0.0)
    y = classical_mds(d, dim)
    np.testing.assert_array_equal(y, full[:, :dim])
    assert align(y, x, reflection=True).rmse < 3 * SIGMA


@pytest.mark.parametrize(
    ("matrix", "match"),
    [
        (np.zeros((3, 4)), r"must be a square \(N, N\) matrix; got \(3, 4\)"),
        (np.zeros(3), r"must be a square \(N, N\) matrix; got \(3,?\)"),
        (np.zeros((0, 0)), r"must be a square \(N, N\) matrix; got \(0, 0\)"),
        (np.array([[0.0, np.nan], [np.nan, 0.0]]), "must be finite"),
        (np.array([[0.0, np.inf], [np.inf, 0.0]]), "must be finite"),
    ],
)
def test_edm_functions_reject_bad_matrices(matrix, match):
    """edm_to_gram, gram_to_edm, is_edm and classical_mds refuse non-square or non-finite input."""
    for fn in (edm_to_gram, gram_to_edm, is_edm, lambda m: classical_mds(m, 1)):
        with pytest.raises(InvalidInputError, match=match):
            fn(matrix)


@pytest.mark.parametrize(
    ("dim", "match"),
    [
        (0, "dim must be a positive integer; got 0"),
        (-2, "dim must be a positive integer"),
        (1.5, "dim must be a positive integer; got 1.5"),
        (5, r"dim must be <= the number of points 4; got 5"),
    ],
)
def test_classical_mds_rejects_bad_dim(dim, match):
    """classical_mds refuses a non-integer, non-positive or too large target dimension."""
    d = edm([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    with pytest.raises(InvalidInputError, match=match):
        classical_mds(d, dim)


@pytest.mark.parametrize(
    ("points", "match"),
    [
        ([1.0, 2.0, 3.0], r"points must have shape \(N, d\)"),
        (np.zeros((3, 4)), r"with d in \(2, 3\).*got \(3, 4\)"),
        ([[0.0, 0.0], [np.nan, 1.0]], r"points must be finite; entry \(1, 0\) is nan"),
    ],
)
def test_edm_rejects_bad_points(points, match):
    """edm() refuses points that are not (N, 2) or (N, 3) finite rows."""
    with pytest.raises(InvalidInputError, match=match):
        edm(points)
