"""Tests of rangeslam.geometry.alignment: Umeyama rigid / similarity alignment with and without reflection."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.alignment import Alignment, align


def _random_rotation(rng: np.random.Generator, dim: int) -> np.ndarray:
    """A random proper rotation (det +1) from the QR decomposition of a Gaussian matrix."""
    q, r = np.linalg.qr(rng.normal(size=(dim, dim)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _mirror(dim: int) -> np.ndarray:
    """The reflection x_d -> -x_d."""
    m = np.eye(dim)
    m[-1, -1] = -1.0
    return m


@pytest.mark.parametrize("dim", [2, 3])
def test_recovers_known_rigid_motion(rng, dim):
    """align recovers a random rotation and translation exactly, without reflection or scale."""
    x = rng.uniform(-3.0, 3.0, size=(10, dim))
    rot = _random_rotation(rng, dim)
    t = rng.uniform(-5.0, 5.0, size=dim)
    y = x @ rot.T + t
    fit = align(x, y)
    assert isinstance(fit, Alignment)
    np.testing.assert_allclose(fit.rotation, rot, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fit.translation, t, rtol=0, atol=1e-10)
    assert fit.scale == 1.0
    assert not fit.reflected
    np.testing.assert_allclose(fit.aligned, y, rtol=0, atol=1e-10)
    assert fit.rmse < 1e-10


@pytest.mark.parametrize("dim", [2, 3])
def test_mirrored_set_needs_reflection(rng, dim):
    """On a mirrored set: proper rotation with rmse > 0 unless reflection=True, which is exact."""
    x = rng.uniform(-3.0, 3.0, size=(10, dim))
    improper = _random_rotation(rng, dim) @ _mirror(dim)
    t = rng.uniform(-5.0, 5.0, size=dim)
    y = x @ improper.T + t
    proper = align(x, y, reflection=False)
    assert np.linalg.det(proper.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(proper.rotation @ proper.rotation.T, np.eye(dim), atol=1e-12)
    assert not proper.reflected
    assert proper.rmse > 0.1  # a random 10-point set in a 6 m cube is far from mirror-symmetric
    mirrored = align(x, y, reflection=True)
    assert mirrored.reflected
    np.testing.assert_allclose(mirrored.rotation, improper, rtol=0, atol=1e-10)
    np.testing.assert_allclose(mirrored.translation, t, rtol=0, atol=1e-10)
    assert mirrored.rmse < 1e-10


@pytest.mark.parametrize("dim", [2, 3])
def test_reflection_allowed_but_not_needed_gives_rotation(rng, dim):
    """With reflection=True on a proper motion the result is still a rotation (det +1)."""
    x = rng.uniform(-3.0, 3.0, size=(10, dim))
    rot = _random_rotation(rng, dim)
    fit = align(x, x @ rot.T, reflection=True)
    assert not fit.reflected
    np.testing.assert_allclose(fit.rotation, rot, rtol=0, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_proper_fit_is_a_local_minimum(rng, dim):
    """For noisy data no small rotation of the rigid fit (re-centred) lowers its rmse."""
    x = rng.uniform(-3.0, 3.0, size=(15, dim))
    y = x @ _random_rotation(rng, dim).T + rng.normal(0.0, 0.1, size=x.shape)
    fit = align(x, y)
    n_gen = dim * (dim - 1) // 2
    for _ in range(20):
        skew = np.zeros((dim, dim))
        skew[np.triu_indices(dim, 1)] = rng.normal(0.0, 1e-3, size=n_gen)
        rot = fit.rotation @ expm(skew - skew.T)
        t = y.mean(axis=0) - rot @ x.mean(axis=0)
        rmse = np.sqrt(np.mean(np.sum((x @ rot.T + t - y) ** 2, axis=1)))
        assert rmse >= fit.rmse - 1e-12


@pytest.mark.parametrize("dim", [2, 3])
def test_estimates_scale(rng, dim):
    """With scale=True a similarity transform c R x + t is recovered exactly; without, scale is 1."""
    x = rng.uniform(-3.0, 3.0, size=(10, dim))
    rot = _random_rotation(rng, dim)
    c = rng.uniform(1.5, 3.0)  # far enough from 1 that the rigid fit has a visible error
    t = rng.uniform(-5.0, 5.0, size=dim)
    y = c * x @ rot.T + t
    fit = align(x, y, scale=True)
    assert fit.scale == pytest.approx(c, rel=1e-12)
    np.testing.assert_allclose(fit.rotation, rot, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fit.translation, t, rtol=0, atol=1e-10)
    assert fit.rmse < 1e-10
    rigid = align(x, y)
    assert rigid.scale == 1.0
    assert rigid.rmse > 1e-3


@pytest.mark.parametrize("dim", [2, 3])
def test_apply_maps_other_points_consistently(rng, dim):
    """apply() maps the estimate to `aligned` and further points by the same recovered transform."""
    x = rng.uniform(-3.0, 3.0, size=(8, dim))
    others = rng.uniform(-3.0, 3.0, size=(5, dim))
    rot = _random_rotation(rng, dim) @ _mirror(dim)
    c = rng.uniform(0.5, 2.0)
    t = rng.uniform(-5.0, 5.0, size=dim)
    fit = align(x, c * x @ rot.T + t, reflection=True, scale=True)
    np.testing.assert_array_equal(fit.apply(x), fit.aligned)
    np.testing.assert_allclose(fit.apply(others), c * others @ rot.T + t, rtol=0, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_errors_and_rmse_agree_with_output(rng, dim):
    """errors are the distances aligned-to-reference and rmse their root mean square."""
    x = rng.uniform(-3.0, 3.0, size=(12, dim))
    y = x @ _random_rotation(rng, dim).T + rng.normal(0.0, 0.05, size=x.shape)
    fit = align(x, y, scale=True)
    errors = np.linalg.norm(fit.aligned - y, axis=1)
    np.testing.assert_allclose(fit.errors, errors, rtol=1e-12, atol=0)
    assert fit.rmse == pytest.approx(np.sqrt(np.mean(errors**2)), rel=1e-12)
    assert fit.rmse > 0


def test_does_not_mutate_inputs_and_returns_read_only_arrays(rng):
    """align leaves its inputs unchanged and hands out read-only arrays."""
    x = rng.normal(size=(6, 3))
    y = rng.normal(size=(6, 3))
    x0, y0 = x.copy(), y.copy()
    fit = align(x, y, reflection=True, scale=True)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(y, y0)
    with pytest.raises(ValueError, match="read-only"):
        fit.aligned[0, 0] = 1.0


@pytest.mark.parametrize(
    ("estimate", "reference", "match"),
    [
        (np.zeros((5, 3)), np.zeros((4, 3)), r"same shape; got \(5, 3\) and \(4, 3\)"),
        (np.zeros((5, 3)), np.zeros((5, 2)), r"reference must have shape \(N, d\) with d = 3"),
        (np.zeros(3), np.zeros(3), r"estimate must have shape \(N, d\)"),
        (
            np.zeros((4, 4)),
            np.zeros((4, 4)),
            r"estimate must have shape \(N, d\) with d in \(2, 3\)",
        ),
        ([[0.0, np.nan]], [[0.0, 0.0]], "estimate must be finite"),
    ],
)
def test_rejects_bad_shapes(estimate, reference, match):
    """align refuses mismatched shapes, wrong dimensions and non-finite points."""
    with pytest.raises(InvalidInputError, match=match):
        align(estimate, reference)


def test_scale_of_coincident_points_raises():
    """scale estimation refuses an estimate whose points all coincide."""
    with pytest.raises(DegenerateGeometryError, match="all coincide"):
        align(np.ones((4, 2)), np.arange(8.0).reshape(4, 2), scale=True)


def test_apply_rejects_wrong_dimension(rng):
    """apply() refuses points of another dimension than the fitted transform."""
    fit = align(rng.normal(size=(4, 2)), rng.normal(size=(4, 2)))
    with pytest.raises(InvalidInputError, match=r"points must have shape \(N, d\) with d = 2"):
        fit.apply(np.zeros((3, 3)))
