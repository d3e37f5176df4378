"""Unsynchronised receivers and unknown emission times (rangeslam.mdu.clock_offsets):
T[m, k] = ||x_m - s_k|| + a_m + b_{g(k)}, through calibrate_unknown_emission(receiver_offsets=True)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rangeslam import InvalidInputError
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.clock_offsets import (
    ProfiledUnfolding,
    clock_offsets_crlb,
    joint_jacobian,
    unknowns_with_clock_offsets,
)
from rangeslam.mdu.emission import calibrate_unknown_emission
from rangeslam.verdict.crlb import mdu_crlb

ROOM = np.array([10.0, 10.0, 3.0])  # metres: the simulated room


def _scene(rng, dim=3, m=12, k=12, spread=3.0):
    """Receivers and sources uniform in the room (its first ``dim`` sides), offsets of metres."""
    x = rng.uniform(0, 1, (m, dim)) * ROOM[:dim]
    s = rng.uniform(0, 1, (k, dim)) * ROOM[:dim]
    a, b = rng.uniform(-spread, spread, m), rng.uniform(-spread, spread, k)
    return x, s, a, b, range_matrix(x, s) + a[:, None] + b[None, :]


def _receiver_error(out, x):
    """Largest receiver error (metres) after the best rigid motion (reflection allowed)."""
    return align(out.receivers, x, reflection=True).errors.max()


@pytest.mark.parametrize("dim", [2, 3])
def test_exact_with_both_offsets(rng, dim):
    """Exact arrivals, M = K = 12: receivers and sources to 1e-6 m up to a rigid motion, the
    offsets in the gauge mean(a) = 0 (a - mean(a), b + mean(a)), status converged."""
    x, s, a, b, t = _scene(rng, dim)
    out = calibrate_unknown_emission(
        t, np.arange(12), dim=dim, receiver_offsets=True, noise_std=0.0, rng=rng
    )
    assert out.converged, out.message
    assert _receiver_error(out, x) < 1e-6
    pts = align(np.vstack([out.receivers, out.sources]), np.vstack([x, s]), reflection=True)
    assert pts.errors.max() < 1e-6
    np.testing.assert_allclose(out.receiver_offsets, a - a.mean(), atol=1e-6)
    np.testing.assert_allclose(out.offsets, b + a.mean(), atol=1e-6)
    assert out.redundancy == t.size - unknowns_with_clock_offsets(12, 12, 12, dim)


def test_exact_with_a_mask_and_shared_events(rng):
    """Missing arrivals and two columns per event (G = 6): still exact, residuals NaN where
    unobserved and fitted minus measured elsewhere (recomputed from the output)."""
    x, s, a, _, _ = _scene(rng, 3)
    groups = np.repeat(np.arange(6), 2)
    b = rng.uniform(-3, 3, 6)
    t = range_matrix(x, s) + a[:, None] + b[groups][None, :]
    mask = np.ones(t.shape, dtype=bool)
    mask[rng.choice(12, 10), rng.choice(12, 10)] = False
    out = calibrate_unknown_emission(
        t, groups, receiver_offsets=True, mask=mask, noise_std=0.0, rng=rng
    )
    assert out.converged, out.message
    assert _receiver_error(out, x) < 1e-6
    assert np.all(np.isnan(out.residuals[~mask]))
    fitted = range_matrix(out.receivers, out.sources) + out.receiver_offsets[:, None]
    fitted = fitted + out.offsets[groups][None, :]
    np.testing.assert_allclose(out.residuals[mask], (fitted - t)[mask], atol=1e-9)


def test_noise_against_the_bound(rng):
    """1 mm arrival noise, M = K = 12, 6 draws: the receivers' RMS error after a rigid alignment
    within 1.5x the RMS of the per-draw Cramer-Rao bounds with both offset kinds unknown (the
    issue's 1.2x is measured over 40 draws in benchmarks/bench_xtdoa.py; 1.5 leaves room for the
    spread of an RMS over 6 draws of 36 coordinates)."""
    sigma, err2, bound2 = 1e-3, [], []
    for _ in range(6):
        x, s, _, _, t = _scene(rng, 3)
        noisy = t + sigma * rng.standard_normal(t.shape)
        out = calibrate_unknown_emission(
            noisy, np.arange(12), receiver_offsets=True, noise_std=sigma, rng=rng
        )
        assert out.converged, out.message
        err2.append(np.mean(align(out.receivers, x, reflection=True).errors ** 2))
        bound2.append(clock_offsets_crlb(x, s, sigma) ** 2)
    assert np.sqrt(np.mean(err2)) <= 1.5 * np.sqrt(np.mean(bound2))


def test_bound_exceeds_the_synchronised_bound(rng):
    """Unknown offsets cost information: the bound with them is above mdu_crlb's (known
    offsets, receiver gauge), and scales with sigma."""
    x, s, *_ = _scene(rng, 3)
    with_offsets = clock_offsets_crlb(x, s, 1e-3)
    assert with_offsets > mdu_crlb(x, s, 1e-3).receiver_rmse
    assert clock_offsets_crlb(x, s, 2e-3) == pytest.approx(2 * with_offsets, rel=1e-9)


def test_offsets_do_not_change_the_points(rng):
    """Adding t to every receiver offset and subtracting it from every event offset (the
    unobservable shift), or any other offsets, gives the same points (same seed), and the
    offsets move by exactly what was added."""
    *_, t = _scene(rng, 3)
    groups, seed = np.arange(12), int(rng.integers(1 << 30))
    kw = dict(receiver_offsets=True, noise_std=0.0, rng=seed)
    out = calibrate_unknown_emission(t, groups, **kw)
    shifted = calibrate_unknown_emission(t + 2.5 - 2.5, groups, **kw)
    da, db = rng.uniform(-1, 1, 12), rng.uniform(-1, 1, 12)
    moved = calibrate_unknown_emission(t + da[:, None] + db[None, :], groups, **kw)
    for other in (shifted, moved):
        np.testing.assert_allclose(other.receivers, out.receivers, atol=1e-6)
    np.testing.assert_allclose(
        moved.receiver_offsets, out.receiver_offsets + da - da.mean(), atol=1e-6
    )
    np.testing.assert_allclose(moved.offsets, out.offsets + db + da.mean(), atol=1e-6)


def test_permuting_receivers_permutes_the_answer(rng):
    """Receivers given in another order: the same configuration (pairwise distances permuted)
    and the receiver offsets permuted."""
    *_, t = _scene(rng, 3)
    perm = rng.permutation(12)
    kw = dict(receiver_offsets=True, noise_std=0.0, rng=rng)
    out = calibrate_unknown_emission(t, np.arange(12), **kw)
    per = calibrate_unknown_emission(t[perm], np.arange(12), **kw)
    np.testing.assert_allclose(
        range_matrix(per.receivers, per.receivers),
        range_matrix(out.receivers, out.receivers)[np.ix_(perm, perm)],
        atol=1e-6,
    )
    np.testing.assert_allclose(per.receiver_offsets, out.receiver_offsets[perm], atol=1e-6)


def test_bad_input(rng):
    *_, t = _scene(rng, 3, m=7, k=6)
    g = np.arange(6)
    # 7 receivers and 6 events in 3-D: 13 * 3 - 6 + 6 + 7 - 1 = 45 unknowns for 42 arrivals.
    with pytest.raises(InvalidInputError, match="42 observed ranges for 45 unknowns"):
        calibrate_unknown_emission(t, g, receiver_offsets=True)
    *_, t = _scene(rng, 3, m=12, k=6)
    mask = np.ones(t.shape, dtype=bool)
    mask[:4, 0] = False  # 12 receivers and 6 events: 65 unknowns, 72 - 8 = 64 arrivals
    mask[4:8, 1] = False
    with pytest.raises(InvalidInputError, match="64 observed ranges for 65 unknowns"):
        calibrate_unknown_emission(t, g, receiver_offsets=True, mask=mask)
    with pytest.raises(InvalidInputError, match="offsets0 must be None"):
        calibrate_unknown_emission(t, g, receiver_offsets=True, offsets0=np.zeros(6))
    with pytest.raises(InvalidInputError, match="receiver_offsets must be True or False"):
        calibrate_unknown_emission(t, g, receiver_offsets="yes")
    with pytest.raises(InvalidInputError, match="random_starts"):
        calibrate_unknown_emission(t, g, receiver_offsets=True, random_starts=0)
    with pytest.raises(InvalidInputError, match="groups must be an integer array"):
        calibrate_unknown_emission(t, g[:-1], receiver_offsets=True)
    with pytest.raises(InvalidInputError, match=r"ranges must be an \(M, K\) array"):
        calibrate_unknown_emission(t[0], g, receiver_offsets=True)
    with pytest.raises(InvalidInputError, match="noise_std"):
        calibrate_unknown_emission(t, g, receiver_offsets=True, noise_std=-1.0)
    with pytest.raises(InvalidInputError, match="dim must be 2 or 3"):
        calibrate_unknown_emission(t, g, receiver_offsets=True, dim=4)


def test_joint_jacobian_matches_central_differences(rng):
    """The joint Jacobian (points, a_1..a_{M-1}, b) against central differences of (C1)."""
    x, s, _, _, t = _scene(rng, 3, m=6, k=7)
    obs = np.ones(t.shape, dtype=bool)
    model = ProfiledUnfolding(t, obs, np.arange(7), 3, 1.0)
    theta = np.vstack([x, s]).ravel()

    def resid(v):
        pts, off = v[: theta.size].reshape(-1, 3), v[theta.size :]
        aa = np.r_[0.0, off[:5]]
        return (range_matrix(pts[:6], pts[6:]) + aa[:, None] + off[5:][None, :] - t).ravel()

    v0 = np.r_[theta, np.zeros(5 + 7)]
    num = np.array([(resid(v0 + 1e-6 * e) - resid(v0 - 1e-6 * e)) / 2e-6 for e in np.eye(v0.size)])
    np.testing.assert_allclose(joint_jacobian(model, theta), num.T, atol=1e-7)


@settings(max_examples=6, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    dim=st.sampled_from([2, 3]),
    m=st.integers(8, 10),
    k=st.integers(8, 10),
)
def test_property_exact_and_offsets_consistent(seed, dim, m, k):
    """Any exact configuration (receivers and sources in the room, offsets of metres): the
    arrivals are reproduced (residual RMS <= 1e-6 m) by the reported points and offsets, the
    receiver offsets have mean 0, and the redundancy is arrivals minus the unknowns."""
    rng = np.random.default_rng(seed)
    *_, t = _scene(rng, dim, m=m, k=k)
    out = calibrate_unknown_emission(
        t, np.arange(k), dim=dim, receiver_offsets=True, noise_std=0.0, rng=rng
    )
    fitted = range_matrix(out.receivers, out.sources)
    fitted = fitted + out.receiver_offsets[:, None] + out.offsets[None, :]
    assert np.sqrt(np.mean((fitted - t) ** 2)) <= 1e-6, out.message
    assert abs(out.receiver_offsets.mean()) < 1e-9
    assert out.redundancy == m * k - unknowns_with_clock_offsets(m, k, k, dim)
