"""Unknown emission times: one range offset per acoustic event (rangeslam.localization.emission)."""

import numpy as np
import pytest
from scipy.stats import chi2

from rangeslam import DegenerateGeometryError, InvalidInputError, Room, reconstruct_room
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.localization.emission import (
    multilaterate_with_offset,
    reconstruct_room_unknown_emission,
)
from rangeslam.mdu.emission import _OffsetUnfolding, calibrate_unknown_emission, offsets_from_rank
from rangeslam.sim.scenes import echo_ranges, random_convex_room, random_points_in_room
from rangeslam.status import Status

C = 343.0  # m/s
FS = 16_000.0  # Hz
TENTH_MS = 1e-4 * C  # 0.1 ms of emission time error, in metres (3.43 cm)


def _rooms(rng, dim):
    return [
        Room.shoebox([5.1, 3.7, 2.6][:dim]),
        random_convex_room(dim, dim + 3, rng=rng),
        random_convex_room(dim, 2 * dim + 2, rng=rng),
    ]


def _scene(rng, room, n_mics=8):
    mics = random_points_in_room(room, n_mics, margin=0.3, rng=rng)
    source = random_points_in_room(room, 1, margin=0.3, rng=rng)[0]
    points = np.vstack([source, room.image_sources(source, order=1).positions])
    return mics, source, points, echo_ranges(room, mics, source)


def _free_point_jacobian(mics, points):
    """(M (1+K), (1+K) d) Jacobian of all ranges in the points (column-major over points)."""
    c_n, d = points.shape
    m_n = len(mics)
    jac = np.zeros((m_n * c_n, c_n * d))
    for c in range(c_n):
        u = points[c] - mics
        jac[c * m_n : (c + 1) * m_n, c * d : (c + 1) * d] = u / np.linalg.norm(
            u, axis=1, keepdims=True
        )
    return jac


def _bounds(mics, points, centroids):
    """Cramer-Rao covariances per unit range noise, unknown emission time (one offset b).

    Returns (source (d, d), wall offsets at the true centroids (K, K), var b). With one image
    per wall, points and walls are two parametrisations of the same model; wall k's offset error
    at its centroid p_k is g = n.(p_k - (s + s_k) / 2), n = (s_k - s) / |s_k - s|.
    """
    c_n, d = points.shape
    jac = _free_point_jacobian(mics, points)
    jac = np.column_stack([jac, np.ones(len(jac))])
    cov = np.linalg.inv(jac.T @ jac)
    grad = np.zeros((c_n - 1, c_n * d))
    for k in range(c_n - 1):
        s, p = points[0], points[k + 1]
        n = (p - s) / np.linalg.norm(p - s)
        dn = (np.eye(d) - np.outer(n, n)) / np.linalg.norm(p - s)
        q = centroids[k] - (p + s) / 2
        grad[k, (k + 1) * d : (k + 2) * d] = dn @ q - n / 2
        grad[k, :d] = -dn @ q - n / 2
    return cov[:d, :d], grad @ cov[:-1, :-1] @ grad.T, cov[-1, -1]


def _signed_wall_errors(room, normals, offsets):
    """n_est . p_k - o_est at the true wall centroids p_k (K,), metres."""
    return np.einsum("kd,kd->k", normals, room.wall_centroids) - offsets


# --- multilaterate_with_offset -------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_multilaterate_with_offset_exact(rng, dim):
    """Exact pseudoranges give the point and the offset to round-off, from the minimal d + 2
    anchors up, for offsets of either sign (also ones that make ranges negative)."""
    for n in (dim + 2, dim + 3, 12):
        for b in (-3.0, -0.2, 0.0, 0.4, 7.0):
            anchors = rng.uniform(0, 5, (n, dim))
            x = rng.uniform(-2, 7, dim)
            r = np.linalg.norm(anchors - x, axis=1) + b
            res = multilaterate_with_offset(anchors, r)
            assert res.converged, res.message
            np.testing.assert_allclose(res.position, x, atol=1e-9)
            assert abs(res.offset - b) < 1e-9
            assert np.all(np.abs(res.residuals) < 1e-9)
            assert res.dop.shape == (dim + 1,)


def test_multilaterate_with_offset_dop_is_the_noise_scale(rng):
    """With weights 1/sigma^2, dop is the standard deviation of the estimate: the normalised
    offset and position errors over 300 draws have mean square 1 (chi-square test at 1e-4)."""
    z2_b, z2_x, n = 0.0, 0.0, 300
    for _ in range(n):
        anchors = rng.uniform(0, 5, (8, 3))
        x, b, sigma = rng.uniform(0, 5, 3), rng.uniform(-1, 1), 1e-3
        r = np.linalg.norm(anchors - x, axis=1) + b + sigma * rng.standard_normal(8)
        res = multilaterate_with_offset(anchors, r, weights=np.full(8, sigma**-2))
        z2_b += ((res.offset - b) / res.dop[-1]) ** 2
        z2_x += np.sum(((res.position - x) / res.dop[:3]) ** 2) / 3
    for z2 in (z2_b, z2_x):
        assert chi2.ppf(1e-4, n) < z2 < chi2.ppf(1 - 1e-4, n)


def test_multilaterate_with_offset_shift_and_mask(rng):
    """A constant added to every range moves only the offset; masked entries are ignored."""
    anchors = rng.uniform(0, 5, (9, 3))
    x = rng.uniform(0, 5, 3)
    r = np.linalg.norm(anchors - x, axis=1) + 0.3 + 1e-3 * rng.standard_normal(9)
    a = multilaterate_with_offset(anchors, r)
    b = multilaterate_with_offset(anchors, r + 12.5)
    # To 1e-7 m: round-off of the shifted ranges amplified by the fit's conditioning (dop up to
    # a few; measured up to 1.5e-9 m over 60 seeds).
    np.testing.assert_allclose(b.position, a.position, atol=1e-7)
    assert abs(b.offset - a.offset - 12.5) < 1e-7
    mask = np.ones(9, dtype=bool)
    mask[[1, 4]] = False
    r_nan = r.copy()
    r_nan[[1, 4]] = np.nan
    masked = multilaterate_with_offset(anchors, r_nan, mask=mask)
    plain = multilaterate_with_offset(anchors[mask], r[mask])
    np.testing.assert_allclose(masked.position, plain.position, atol=1e-12)
    assert np.isnan(masked.residuals[[1, 4]]).all()


def test_multilaterate_with_offset_robust(rng):
    """Two wrong ranges of 10 (40-50 cm off) are rejected; the rest fit at the noise level."""
    anchors = rng.uniform(0, 5, (10, 3))
    x, b = rng.uniform(0, 5, 3), 0.8
    r = np.linalg.norm(anchors - x, axis=1) + b + 1e-3 * rng.standard_normal(10)
    r[[2, 7]] += [0.5, -0.4]
    res = multilaterate_with_offset(anchors, r, robust=True, rng=rng)
    assert res.converged, res.message
    assert res.n_outliers == 2 and not res.inliers[[2, 7]].any()
    assert np.linalg.norm(res.position - x) < 0.02 and abs(res.offset - b) < 0.02
    fixed = multilaterate_with_offset(anchors, r, robust=True, inlier_threshold=0.01, rng=rng)
    assert fixed.n_outliers == 2
    plain = multilaterate_with_offset(anchors, r)
    assert np.max(np.abs(plain.residuals)) > 0.05  # the plain fit is pulled by the wrong ranges


def test_multilaterate_with_offset_bad_input(rng):
    anchors = rng.uniform(0, 5, (6, 3))
    x = rng.uniform(0, 5, 3)
    r = np.linalg.norm(anchors - x, axis=1) + 0.5
    with pytest.raises(InvalidInputError, match="at least 5 observed"):
        multilaterate_with_offset(anchors[:4], r[:4])
    mask = np.array([True, True, True, True, False, False])
    with pytest.raises(InvalidInputError, match="at least 5 observed"):
        multilaterate_with_offset(anchors, r, mask=mask)
    with pytest.raises(InvalidInputError, match="positive weight"):
        multilaterate_with_offset(anchors, r, weights=[1, 1, 1, 1, 0, 0])
    flat = anchors.copy()
    flat[:, 2] = 1.0  # coplanar in 3-D: a mirror image
    with pytest.raises(DegenerateGeometryError, match="coplanar"):
        multilaterate_with_offset(flat, np.linalg.norm(flat - x, axis=1))
    line = np.column_stack([np.arange(5.0), np.zeros(5)])
    with pytest.raises(DegenerateGeometryError, match="collinear"):
        multilaterate_with_offset(line, np.arange(5.0) + 1)
    # Anchors on a cone around the point (at different distances, so not coplanar): u . n is the
    # same for every anchor, and moving the point along n trades off against the offset.
    ang = np.linspace(0, 2 * np.pi, 7)[:-1]
    dirs = np.column_stack([np.cos(ang) * 0.6, np.sin(ang) * 0.6, np.full(6, 0.8)])
    cone = x + dirs * np.array([1.0, 2.0, 1.5, 3.0, 2.5, 1.2])[:, None]
    on_cone = multilaterate_with_offset(cone, np.linalg.norm(cone - x, axis=1) + 0.3)
    assert on_cone.status is Status.NOT_IDENTIFIABLE and "cone" in on_cone.message
    assert np.all(np.isinf(on_cone.dop))
    with pytest.raises(InvalidInputError, match=r"ranges must have shape \(6,\)"):
        multilaterate_with_offset(anchors, r[:5])
    with pytest.raises(InvalidInputError, match="anchors must have shape"):
        multilaterate_with_offset(anchors[:, 0], r)
    bad = r.copy()
    bad[3] = np.nan
    with pytest.raises(InvalidInputError, match="finite where observed"):
        multilaterate_with_offset(anchors, bad)
    with pytest.raises(InvalidInputError, match="weights must have shape"):
        multilaterate_with_offset(anchors, r, weights=np.ones(5))
    with pytest.raises(InvalidInputError, match="non-negative"):
        multilaterate_with_offset(anchors, r, weights=-np.ones(6))
    with pytest.raises(InvalidInputError, match="inlier_threshold"):
        multilaterate_with_offset(anchors, r, robust=True, inlier_threshold=0.0)
    with pytest.raises(InvalidInputError, match="max_hypotheses"):
        multilaterate_with_offset(anchors, r, robust=True, max_hypotheses=0)
    # Robust with only d + 2 ranges: a wrong range cannot be found, so the point is not
    # determined under the model robust=True declares; without robust the exact fit converges.
    res = multilaterate_with_offset(anchors[:5], r[:5], robust=True)
    assert res.status is Status.NOT_IDENTIFIABLE and "no outlier rejection" in res.message
    assert multilaterate_with_offset(anchors[:5], r[:5]).converged


# --- reconstruct_room_unknown_emission -----------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("robust", [True, False])
def test_room_exact_at_zero_noise(rng, dim, robust):
    """Exact echoes with an unknown emission time give the offset, the source and every wall to
    1e-8, in shoeboxes and non-box rooms."""
    for room in _rooms(rng, dim):
        mics, source, points, d_true = _scene(rng, room)
        b = rng.uniform(-0.5, 0.5)
        out = reconstruct_room_unknown_emission(mics, d_true + b, c=C, robust=robust, rng=rng)
        assert out.converged, out.message
        assert abs(out.offset - b) < 1e-8
        assert abs(out.offset_time - b / C) < 1e-8 / C
        assert out.offset_std < 1e-8
        res = out.reconstruction
        np.testing.assert_allclose(res.sources[0], source, atol=1e-8)
        np.testing.assert_allclose(res.wall_normals, room.normals, atol=1e-8)
        np.testing.assert_allclose(res.wall_offsets, room.offsets, atol=1e-8)
        np.testing.assert_allclose(out.points, points, atol=1e-8)
        np.testing.assert_allclose(out.corrected_ranges, d_true, atol=1e-8)
        assert out.room is not None and abs(out.room.volume - room.volume) < 1e-6


@pytest.mark.parametrize("robust", [True, False])
def test_room_shift_changes_only_the_offset(rng, robust):
    """Ranges shifted by a constant (another assumed emission time) give the same room and
    source, and an offset shifted by that constant."""
    room = random_convex_room(3, 6, rng=rng)
    mics, _, _, d_true = _scene(rng, room)
    r = d_true + 1e-2 * rng.standard_normal(d_true.shape)
    a = reconstruct_room_unknown_emission(mics, r, robust=robust, rng=1)
    b = reconstruct_room_unknown_emission(mics, r + 2.75, robust=robust, rng=1)
    assert a.converged and b.converged
    # To 1e-7 m: the round-off of the shifted ranges (1e-16 relative), amplified by the
    # conditioning of the joint fit (offset and distances are strongly correlated; measured up to
    # 6e-9 m over 30 seeds).
    assert abs(b.offset - a.offset - 2.75) < 1e-7
    for x, y in [
        (a.reconstruction.sources, b.reconstruction.sources),
        (a.reconstruction.wall_normals, b.reconstruction.wall_normals),
        (a.reconstruction.wall_offsets, b.reconstruction.wall_offsets),
    ]:
        np.testing.assert_allclose(x, y, atol=1e-7)


def _noisy_trials(rng, dim, n, noise, *, with_known=False):
    """n draws (cycling the three room kinds) of 8 microphones and one source, reconstructed with
    an unknown emission time (non-robust: pure least squares). Yields per draw a dict."""
    for t in range(n):
        room = _rooms(rng, dim)[t % 3]
        mics, source, points, d_true = _scene(rng, room)
        b = rng.uniform(-0.5, 0.5)
        if noise == "16kHz":
            # Arrival times on a 16 kHz sample grid whose phase is unrelated to the emission.
            phase = rng.uniform(0, 1 / FS)
            known = (np.round((d_true / C + phase) * FS) / FS - phase) * C
            sigma = C / FS / np.sqrt(12.0)  # standard deviation of the rounding
        else:
            sigma = noise
            known = d_true + sigma * rng.standard_normal(d_true.shape)
        out = reconstruct_room_unknown_emission(mics, known + b, c=C, robust=False)
        assert out.converged, out.message
        cov_s, cov_w, var_b = _bounds(mics, points, room.wall_centroids)
        trial = {
            "room": room,
            "mics": mics,
            "source": source,
            "points": points,
            "b": b,
            "out": out,
            "sigma": sigma,
            "cov_s": cov_s * sigma**2,
            "cov_w": cov_w * sigma**2,
            "std_b": np.sqrt(var_b) * sigma,
        }
        if with_known:
            trial["known"] = reconstruct_room(mics, known, robust=False)
            assert trial["known"].converged
        yield trial


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
@pytest.mark.parametrize(
    "noise",
    [
        1e-3,
        pytest.param(1e-2, marks=pytest.mark.slow),
        pytest.param("16kHz", marks=pytest.mark.slow),
    ],
)
def test_room_offset_within_a_tenth_of_a_millisecond(rng, dim, noise):
    """Range noise of 1 mm, 1 cm, or arrival times on a 16 kHz grid (6.2 mm RMS): the emission
    time error is found within 0.1 ms (3.43 cm) in every draw at 1 mm, and in at least 75% of
    24 draws otherwise; within 0.1 ms wherever the Cramer-Rao bound allows it (4 sigma_b <=
    0.1 ms), and within 5 sigma_b in every draw.

    Measured (150 draws per case, 8 microphones in shoeboxes and non-box rooms): at 1 mm all
    within 0.1 ms (worst 15 mm); at 1 cm 95% (2-D) and 92% (3-D) within 0.1 ms, worst 158 mm in
    2-D and 109 mm in 3-D; on the 16 kHz grid 98% within, worst 65 mm (2-D) and 51 mm (3-D). So a
    75% threshold fails with probability about 0.3% at 92%. The bound sigma_b per unit range noise
    has median 0.8 (2-D) and 1.2 (3-D), 95th percentile 3.8-3.9, worst 8.7: a source near a wall
    or far from the array makes b trade off against the distances.
    """
    within = 0
    n = 12 if noise == 1e-3 else 24
    for trial in _noisy_trials(rng, dim, n, noise):
        err = abs(trial["out"].offset - trial["b"])
        std = trial["std_b"]
        assert err <= 5 * std + 1e-12
        assert abs(trial["out"].offset_time - trial["out"].offset / C) < 1e-15
        if 4 * std <= TENTH_MS:
            assert err <= TENTH_MS
        within += err <= TENTH_MS
    assert within == n if noise == 1e-3 else within >= 0.75 * n


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_room_attains_the_bound_at_one_cm(rng, dim):
    """At 1 cm range noise the unknown-time estimates of the offset, the source and the wall
    offsets attain the Cramer-Rao bound of the model with an unknown offset: the Mahalanobis
    errors over 24 draws are within chi-square limits (false-alarm rate 1e-4 per check).

    The bound with an unknown emission time is larger than with a known one (one more unknown
    per event); measured ratios of RMS errors unknown/known over 150 draws per case, with the
    bound's own ratio in brackets: source 2.7 [2.65] in 2-D and 1.7 [1.8] in 3-D; wall offsets
    1.9 [1.77] in 2-D and 1.2 [1.19] in 3-D; wall normals 1.05-1.1. So "within 10% of the known-time
    error" does not hold for the source and wall offsets, by the information the offset takes.
    """
    z2 = {"b": 0.0, "source": 0.0, "walls": 0.0}
    dof = {"b": 0, "source": 0, "walls": 0}
    for trial in _noisy_trials(rng, dim, 24, 1e-2):
        out = trial["out"]
        e_b = out.offset - trial["b"]
        e_s = out.reconstruction.sources[0] - trial["source"]
        e_w = _signed_wall_errors(
            trial["room"], out.reconstruction.wall_normals, out.reconstruction.wall_offsets
        )
        z2["b"] += e_b**2 / trial["std_b"] ** 2
        z2["source"] += e_s @ np.linalg.solve(trial["cov_s"], e_s)
        z2["walls"] += e_w @ np.linalg.solve(trial["cov_w"], e_w)
        dof["b"] += 1
        dof["source"] += dim
        dof["walls"] += len(e_w)
        # The offset's own standard deviation (from the fit's residuals) is of the bound's size.
        assert 0.3 < out.offset_std / trial["std_b"] < 3.0
    for key in z2:
        assert z2[key] <= chi2.ppf(1 - 1e-4, dof[key]), (key, z2[key], dof[key])
        assert z2[key] >= chi2.ppf(1e-4, dof[key]), (key, z2[key], dof[key])


@pytest.mark.parametrize("dim", [2, 3])
def test_room_unknown_time_error_is_the_offset_error_propagated(rng, dim):
    """Against the known-time result from the same noisy echoes: the unknown-time source differs
    from it by the offset error propagated through the geometry, -h (b_est - b), h the least-
    squares shift of the points for a unit change of every range (first order), to 10% plus
    0.5 mm (the second-order terms are ~ sigma (b_est - b) / distance; measured worst 3%, 1 mm,
    over 120 draws at 1 cm). So the cost of an unknown emission time is exactly the offset error,
    which attains its bound (previous test)."""
    for trial in _noisy_trials(rng, dim, 9, 1e-2, with_known=True):
        known, out = trial["known"], trial["out"]
        est_points = np.vstack([known.sources, known.image_sources[0]])
        jac = _free_point_jacobian(trial["mics"], est_points)
        h = np.linalg.lstsq(jac, np.ones(len(jac)), rcond=None)[0][:dim]
        predicted = -h * (out.offset - trial["b"])
        diff = out.reconstruction.sources[0] - known.sources[0]
        assert np.linalg.norm(diff - predicted) <= 0.1 * np.linalg.norm(predicted) + 5e-4


def test_room_robust_to_wrong_echo_picks(rng):
    """Two wrong picks (30-60 cm off) among 56 echoes: rejected, offset and walls as without."""
    room = Room.shoebox([5.1, 3.7, 2.6])
    mics, _, _, d_true = _scene(rng, room)
    r = d_true + 1e-3 * rng.standard_normal(d_true.shape) + 0.4
    r[2, 3] += 0.6
    r[5, 1] -= 0.3
    out = reconstruct_room_unknown_emission(mics, r, rng=rng)
    assert out.converged, out.message
    assert not out.reconstruction.inliers[0, 2, 3] and not out.reconstruction.inliers[0, 5, 1]
    assert abs(out.offset - 0.4) < 0.01
    np.testing.assert_allclose(out.reconstruction.wall_offsets, room.offsets, atol=0.02)
    plain = reconstruct_room_unknown_emission(mics, r, robust=False)
    assert plain.residual_rms > 5 * out.residual_rms  # pulled by the wrong picks


def test_room_bad_input(rng):
    room = Room.shoebox([5.1, 3.7, 2.6])
    mics, _, _, d_true = _scene(rng, room)
    r = d_true + 0.2
    with pytest.raises(InvalidInputError, match="at least d \\+ 2 = 5 microphones"):
        reconstruct_room_unknown_emission(mics[:4], r[:4])
    flat = mics.copy()
    flat[:, 2] = 1.0
    with pytest.raises(DegenerateGeometryError, match="coplanar"):
        reconstruct_room_unknown_emission(flat, r)
    with pytest.raises(InvalidInputError, match=r"ranges must have shape \(8, 1\+K\)"):
        reconstruct_room_unknown_emission(mics, r[:, :1])
    with pytest.raises(InvalidInputError, match=r"ranges must have shape \(8, 1\+K\)"):
        reconstruct_room_unknown_emission(mics, r[:7])
    bad = r.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InvalidInputError, match="finite where observed"):
        reconstruct_room_unknown_emission(mics, bad)
    mask = np.ones(r.shape, dtype=bool)
    mask[1, 2] = False
    assert reconstruct_room_unknown_emission(mics, bad, mask=mask, robust=False).converged
    with pytest.raises(InvalidInputError, match="mask must be a boolean"):
        reconstruct_room_unknown_emission(mics, r, mask=mask.astype(int))
    with pytest.raises(InvalidInputError, match="c must be a positive speed"):
        reconstruct_room_unknown_emission(mics, r, c=0.0)
    # Every column seen by only d + 1 = 4 microphones: no column can start the offset.
    sparse = np.zeros(r.shape, dtype=bool)
    sparse[:4] = True
    with pytest.raises(InvalidInputError, match="no column of ranges has 5 observed"):
        reconstruct_room_unknown_emission(mics, r, mask=sparse)


# --- calibrate_unknown_emission (Problem 2) ------------------------------------------------------


def _event_scene(rng, dim, n_events, n_mics=8):
    """Microphones in a shoebox, and per event a loudspeaker with its first-order images."""
    room = Room.shoebox([5.1, 3.7, 2.6][:dim])
    mics = random_points_in_room(room, n_mics, margin=0.3, rng=rng)
    points, groups = [], []
    for j in range(n_events):
        s = random_points_in_room(room, 1, margin=0.3, rng=rng)[0]
        points.append(np.vstack([s, room.image_sources(s, order=1).positions]))
        groups += [j] * (2 * dim + 1)
    return mics, np.vstack(points), np.array(groups)


@pytest.mark.parametrize(("dim", "n_events"), [(2, 1), (2, 2), (3, 1)])
def test_calibrate_unknown_emission_exact(rng, dim, n_events):
    """Exact ranges: microphones, sources and every event's offset to 1e-8 (up to a rigid motion
    and a reflection), including one offset shared by all ranges (identifiable: the rank of the
    Jacobian is full up to the rigid motions)."""
    mics, sources, groups = _event_scene(rng, dim, n_events)
    b = rng.uniform(-1, 1, n_events)
    r = range_matrix(mics, sources) + b[groups]
    start = offsets_from_rank(r, groups, dim=dim)
    np.testing.assert_allclose(start, b, atol=1e-7)
    out = calibrate_unknown_emission(r, groups, dim=dim, noise_std=0.0, c=C, rng=rng)
    assert out.converged, out.message
    np.testing.assert_allclose(out.offsets, b, atol=1e-8)
    np.testing.assert_allclose(out.offset_times, b / C, atol=1e-8 / C)
    fit = align(
        np.vstack([out.receivers, out.sources]), np.vstack([mics, sources]), reflection=True
    )
    assert fit.errors.max() < 1e-8
    assert out.redundancy == r.size - ((8 + len(sources)) * dim - dim * (dim + 1) // 2 + n_events)


def test_calibrate_unknown_emission_one_offset_for_all_random_points(rng):
    """Random receivers and sources (not images), one offset for every range (groups=None)."""
    x, s = rng.uniform(0, 4, (8, 2)), rng.uniform(0, 4, (8, 2))
    r = range_matrix(x, s) - 0.7  # ranges shorter than distances: a late assumed emission
    out = calibrate_unknown_emission(r, dim=2, noise_std=0.0, rng=rng)
    assert out.converged, out.message
    assert abs(out.offsets[0] + 0.7) < 1e-8
    shifted = calibrate_unknown_emission(r + 3.0, dim=2, noise_std=0.0, rng=rng)
    assert abs(shifted.offsets[0] - 2.3) < 1e-8


def test_calibrate_unknown_emission_noise(rng):
    """1 mm range noise, one event in 2-D: offset within 0.1 ms and 5 sigma of its bound."""
    mics, sources, groups = _event_scene(rng, 2, 1)
    b = rng.uniform(-1, 1, 1)
    d = range_matrix(mics, sources)
    r = d + b[groups] + 1e-3 * rng.standard_normal(d.shape)
    out = calibrate_unknown_emission(r, groups, dim=2, noise_std=1e-3, rng=rng)
    assert out.converged, out.message
    # Bound from the Jacobian of (points, offset), gauge removed by the pseudo-inverse.
    m, k = d.shape
    model = _OffsetUnfolding(d + b[groups], np.ones(d.shape, dtype=bool), groups, 2)
    jac = model.jacobian(np.r_[np.vstack([mics, sources]).ravel(), b])
    std_b = 1e-3 * np.sqrt(np.linalg.pinv(jac.T @ jac)[-1, -1])
    assert abs(out.offsets[0] - b[0]) <= min(5 * std_b, TENTH_MS)
    assert 0.5e-3 < out.noise_estimate < 2e-3
    assert m * k - out.redundancy == (m + k) * 2 - 3 + 1


def test_calibrate_unknown_emission_bad_input(rng):
    mics, sources, groups = _event_scene(rng, 2, 1)
    r = range_matrix(mics, sources) + 0.3
    with pytest.raises(InvalidInputError, match="groups must be an integer array"):
        calibrate_unknown_emission(r, groups[:-1], dim=2)
    with pytest.raises(InvalidInputError, match="groups must be an integer array"):
        calibrate_unknown_emission(r, groups.astype(float), dim=2)
    with pytest.raises(InvalidInputError, match=r"numbered 0\.\.G-1"):
        calibrate_unknown_emission(r, groups + 1, dim=2)
    with pytest.raises(InvalidInputError, match="dim must be 2 or 3"):
        calibrate_unknown_emission(r, groups, dim=4)
    with pytest.raises(InvalidInputError, match=r"ranges must be an \(M, K\) array"):
        calibrate_unknown_emission(r[0], groups, dim=2)
    bad = r.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="finite where observed"):
        calibrate_unknown_emission(bad, groups, dim=2)
    # Enough ranges for the points up to a rigid motion (3 receivers and 5 sources in 2-D: 13),
    # one short of them and the offset.
    mask = np.ones((3, 5), dtype=bool)
    mask[0, :2] = False
    with pytest.raises(InvalidInputError, match="13 observed ranges for 14 unknowns"):
        calibrate_unknown_emission(r[:3], groups, dim=2, mask=mask)
    # One column per event (TDOA self-calibration): the rank start cannot do it.
    with pytest.raises(InvalidInputError, match="pass offsets0"):
        calibrate_unknown_emission(r, np.arange(r.shape[1]), dim=2)
    with pytest.raises(InvalidInputError, match="offsets0 must be finite"):
        calibrate_unknown_emission(r, groups, dim=2, offsets0=[0.1, 0.2])
    with pytest.raises(InvalidInputError, match="noise_std"):
        calibrate_unknown_emission(r, groups, dim=2, noise_std=-1.0)
    with pytest.raises(InvalidInputError, match="max_attempts"):
        calibrate_unknown_emission(r, groups, dim=2, max_attempts=0)
    with pytest.raises(InvalidInputError, match="c must be a positive"):
        calibrate_unknown_emission(r, groups, dim=2, c=-1.0)


def test_calibrate_unknown_emission_reports_a_mirror_ambiguity(rng):
    """In a shoebox the source and its images lie on three lines through the source, so a
    receiver that misses both floor and ceiling echoes hears only points in one horizontal plane:
    its mirror image in that plane fits as well. Reported as not converged, naming it."""
    mics, sources, groups = _event_scene(rng, 3, 1, n_mics=10)
    r = range_matrix(mics, sources) + 0.25
    mask = np.ones(r.shape, dtype=bool)
    mask[4, 5:] = False  # columns 5, 6: the images in the floor and the ceiling (walls -z, +z)
    out = calibrate_unknown_emission(r, groups, dim=3, mask=mask, noise_std=0.0, rng=rng)
    assert not out.converged
    assert "receiver 4" in out.message and "ambiguous" in out.message
    assert abs(out.offsets[0] - 0.25) < 1e-8  # the rest is determined
