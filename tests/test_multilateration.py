"""SR-LS multilateration (paper eq. 3; Beck, Stoica and Li 2008) and the single-point CRLB."""

import numpy as np
import pytest
from scipy.optimize import minimize

from rangeslam import (
    DegenerateGeometryError,
    InvalidInputError,
    multilaterate,
    multilateration_crlb,
)
from rangeslam.baselines import linear_multilaterate
from rangeslam.geometry.edm import range_matrix
from rangeslam.sim.scenes import add_outliers
from rangeslam.status import Status


def _scene(rng, dim, kind, m=8):
    """Anchors (M, d) and a point (d,) for a named configuration."""
    if kind == "room":  # anchors and point spread over a room-sized box
        return rng.uniform(0, 4, (m, dim)), rng.uniform(0, 4, dim)
    if kind == "far":  # a 1 m array and a point 30 m away
        direction = rng.normal(size=dim)
        return rng.uniform(0, 1, (m, dim)), 30.0 * direction / np.linalg.norm(direction)
    if kind == "thin":  # anchors in a slab 10 cm thick (nearly coplanar / collinear)
        a = rng.uniform(0, 3, (m, dim))
        a[:, -1] = rng.uniform(0, 0.1, m)
        p = rng.uniform(0, 3, dim)
        p[-1] = 1.5
        return a, p
    if kind == "mixed":  # half the anchors near the point, half 5-8 m away
        return np.vstack(
            [rng.uniform(0, 0.5, (m // 2, dim)), rng.uniform(5, 8, (m - m // 2, dim))]
        ), rng.uniform(0, 0.5, dim)
    if kind == "minimal":  # exactly d + 1 anchors
        return rng.uniform(0, 4, (dim + 1, dim)), rng.uniform(0, 4, dim)
    raise AssertionError(kind)


def _ranges(anchors, point):
    return range_matrix(anchors, point[None, :])[:, 0]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", ["room", "far", "thin", "mixed", "minimal"])
@pytest.mark.parametrize("weights", ["inverse_range", "uniform"])
def test_exact_at_zero_noise(rng, dim, kind, weights):
    """Without noise SR-LS returns the true point to 1e-8 m, in easy and in awkward geometries."""
    for _ in range(10):
        anchors, point = _scene(rng, dim, kind)
        res = multilaterate(anchors, _ranges(anchors, point), weights=weights)
        assert res.converged
        np.testing.assert_allclose(res.position, point, atol=1e-8, rtol=0)
        np.testing.assert_allclose(res.residuals, 0.0, atol=1e-8)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("weights", ["uniform", "inverse_range"])
def test_global_minimiser_of_squared_range_cost(rng, dim, weights):
    """With noise, no local search from 30 random starts finds a lower (weighted) eq.-(3) cost than
    SR-LS, and the reported cost is the cost at the returned point."""
    anchors, point = _scene(rng, dim, "room", m=6)
    ranges = _ranges(anchors, point) + 0.05 * rng.standard_normal(6)
    res = multilaterate(anchors, ranges, weights=weights)
    w = np.ones(6) if weights == "uniform" else 1.0 / ranges**2

    def cost(x):
        return np.sum(w * (np.sum((anchors - x) ** 2, axis=1) - ranges**2) ** 2)

    assert res.cost == pytest.approx(cost(res.position), rel=1e-10)
    for _ in range(30):
        local = minimize(cost, rng.uniform(-2, 6, dim), method="BFGS", options={"gtol": 1e-12})
        assert cost(res.position) <= local.fun * (1 + 1e-9) + 1e-12


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
@pytest.mark.parametrize("sigma", [1e-3, pytest.param(1e-2, marks=pytest.mark.slow)])
def test_rmse_within_ten_percent_of_crlb(rng, dim, sigma):
    """Over 1000 noisy trials the RMSE of SR-LS is within 10% of the Cramer-Rao bound (both sides).

    The issue asks for 200 trials; their Monte-Carlo standard error on the RMSE (3-4%) puts 10% at
    under 3 standard errors, so 200-trial runs fail by chance on some seeds. With 1000 trials the
    standard error is about 1.5% and 10% is a real test of the estimator.
    """
    anchors, point = _scene(rng, dim, "room")
    true = _ranges(anchors, point)
    errors = np.array(
        [
            multilaterate(anchors, true + sigma * rng.standard_normal(len(true))).position - point
            for _ in range(1000)
        ]
    )
    rmse = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
    crlb = np.sqrt(np.trace(multilateration_crlb(anchors, point, sigma)))
    assert abs(rmse / crlb - 1.0) <= 0.10, (rmse, crlb)


@pytest.mark.parametrize("kind", ["thin", "mixed"])
def test_linear_least_squares_does_badly_where_srls_does_not(rng, kind):
    """With a thin (10 cm) array or anchors at very different distances, linear LS has over 3 times
    the RMSE of SR-LS (measured over 30 seeds: 8.6-50x and 6-17x), while SR-LS stays within 25% of
    the CRLB (measured: at most 1.08x)."""
    anchors, point = _scene(rng, 3, kind, m=8)
    true = _ranges(anchors, point)
    sigma = 1e-3
    e_srls, e_lls = [], []
    for _ in range(200):
        noisy = true + sigma * rng.standard_normal(len(true))
        e_srls.append(multilaterate(anchors, noisy).position - point)
        e_lls.append(linear_multilaterate(anchors, noisy) - point)
    rmse_srls = np.sqrt(np.mean(np.sum(np.square(e_srls), axis=1)))
    rmse_lls = np.sqrt(np.mean(np.sum(np.square(e_lls), axis=1)))
    crlb = np.sqrt(np.trace(multilateration_crlb(anchors, point, sigma)))
    assert rmse_lls > 3.0 * rmse_srls
    assert rmse_srls <= 1.25 * crlb


@pytest.mark.parametrize("dim", [2, 3])
def test_equivariant_under_rigid_motion_and_units(rng, dim):
    """Rotating/translating the anchors moves the estimate the same way; metres -> mm scales it."""
    anchors, point = _scene(rng, dim, "room")
    ranges = _ranges(anchors, point) + 0.01 * rng.standard_normal(len(anchors))
    base = multilaterate(anchors, ranges).position
    q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    t = rng.normal(size=dim) * 10
    moved = multilaterate(anchors @ q.T + t, ranges).position
    np.testing.assert_allclose(moved, base @ q.T + t, atol=1e-9)
    scaled = multilaterate(anchors * 1000.0, ranges * 1000.0).position
    np.testing.assert_allclose(scaled, base * 1000.0, rtol=1e-9, atol=1e-9)


def test_does_not_mutate_inputs(rng):
    """Inputs are left as they were and outputs are read-only."""
    anchors, point = _scene(rng, 3, "room")
    ranges = _ranges(anchors, point)
    a0, r0 = anchors.copy(), ranges.copy()
    res = multilaterate(anchors, ranges, robust=True, rng=rng)
    np.testing.assert_array_equal(anchors, a0)
    np.testing.assert_array_equal(ranges, r0)
    with pytest.raises(ValueError, match="read-only"):
        res.position[0] = 1.0


def test_mask_ignores_placeholder_values(rng):
    """Unobserved entries are ignored whatever they hold (even NaN); zero weights do the same."""
    anchors, point = _scene(rng, 3, "room", m=8)
    ranges = _ranges(anchors, point) + 0.01 * rng.standard_normal(8)
    mask = np.ones(8, dtype=bool)
    mask[[1, 5]] = False
    ref = multilaterate(anchors[mask], ranges[mask]).position
    junk = ranges.copy()
    junk[[1, 5]] = [np.nan, -3.0]
    res = multilaterate(anchors, junk, mask=mask)
    np.testing.assert_allclose(res.position, ref, atol=1e-12)
    assert np.isnan(res.residuals[[1, 5]]).all() and not res.inliers[[1, 5]].any()
    w = np.where(mask, 1.0 / np.maximum(ranges, 1e-9) ** 2, 0.0)
    np.testing.assert_allclose(multilaterate(anchors, ranges, weights=w).position, ref, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_robust_rejects_wrong_picks(rng, dim):
    """With 20% gross outliers (0.2-2 m) among 30 ranges and 1 mm noise, the robust variant rejects
    every outlier and at most 3 good ranges (a 2.5 sigma threshold rejects 1.2% of good ranges), and
    stays within 5 CRLBs; plain SR-LS is pulled far off."""
    anchors, point = _scene(rng, dim, "room", m=30)
    sigma = 1e-3
    clean = _ranges(anchors, point) + sigma * rng.standard_normal(30)
    corrupted, is_out = add_outliers(clean, 0.2, rng=rng)
    res = multilaterate(anchors, corrupted, robust=True, rng=rng)
    crlb = np.sqrt(np.trace(multilateration_crlb(anchors[~is_out], point, sigma)))
    assert res.converged
    assert not np.any(res.inliers & is_out)
    assert np.sum(~res.inliers & ~is_out) <= 3
    assert np.linalg.norm(res.position - point) <= 5 * crlb
    plain = multilaterate(anchors, corrupted)
    if is_out.any():
        assert np.linalg.norm(plain.position - point) > 10 * np.linalg.norm(res.position - point)


def test_robust_exact_at_zero_noise_with_outliers(rng):
    """Exact ranges with 3 wrong picks of 12: the robust estimate is exact to 1e-8 m."""
    anchors, point = _scene(rng, 3, "room", m=12)
    corrupted = _ranges(anchors, point)
    is_out = np.zeros(12, dtype=bool)
    is_out[rng.choice(12, 3, replace=False)] = True
    corrupted[is_out] += rng.uniform(0.2, 2.0, 3)
    res = multilaterate(anchors, corrupted, robust=True, rng=rng)
    np.testing.assert_allclose(res.position, point, atol=1e-8)
    np.testing.assert_array_equal(res.inliers, ~is_out)


def test_robust_with_fixed_threshold(rng):
    """A fixed inlier threshold in metres keeps every range within it of the final fit."""
    anchors, point = _scene(rng, 3, "room", m=15)
    ranges = _ranges(anchors, point) + 0.005 * rng.standard_normal(15)
    ranges[0] += 0.5
    res = multilaterate(anchors, ranges, robust=True, inlier_threshold=0.03, rng=rng)
    assert not res.inliers[0]
    assert np.all(np.abs(res.residuals[res.inliers]) <= 0.03)


def test_msac_keeps_half_right_picks_of_a_distant_cluster(rng):
    """MSAC with a known threshold (4 mm at 1 mm noise) on 12 anchors clustered 1.5 m wide, 2-4 m
    from the point, half their ranges wrong by 0.2-1 m either way: the minimal subsets of right
    ranges give points off by several thresholds there, so only the local optimisation of the
    best hypotheses (LO-RANSAC) keeps exactly the right picks (without it, 9 of 60 draws kept
    others; with it, 0 of 300). The judge of the truncated cost (issue 42) finds, in a few draws
    (2 of 40 seeds), a point just outside the answer's confidence region that keeps another set
    of ranges within the cost level (the noise only estimated from 3 redundant ranges): those
    are NOT_IDENTIFIABLE by its rival check, with the right picks still kept."""
    rivals = 0
    for _ in range(20):
        anchors = rng.uniform([3, 2, 0.4], [4.5, 3.5, 2.0], (12, 3))
        x = rng.uniform([0.3, 0.3, 0.3], [1.5, 1.5, 2.3])
        r = np.linalg.norm(anchors - x, axis=1) + 1e-3 * rng.standard_normal(12)
        wrong = rng.permutation(12)[:6]
        r[wrong] += rng.choice([-1, 1], 6) * rng.uniform(0.2, 1.0, 6)
        out = multilaterate(anchors, r, robust=True, inlier_threshold=4e-3, rng=rng)
        assert np.array_equal(np.flatnonzero(~out.inliers), np.sort(wrong)), out.message
        if not out.converged:
            rival = next(c for c in out.checks if c.name == "rival minima")
            assert out.status is Status.NOT_IDENTIFIABLE and not rival.passed, out.message
            rivals += 1
    assert rivals <= 2


def test_robust_needs_redundancy(rng):
    """With d + 1 ranges no outlier can be detected; the result says so and is the plain SR-LS."""
    anchors, point = _scene(rng, 3, "minimal")
    res = multilaterate(anchors, _ranges(anchors, point), robust=True)
    assert res.converged and "no outlier rejection" in res.message
    np.testing.assert_allclose(res.position, point, atol=1e-8)


@pytest.mark.parametrize(
    ("anchors", "ranges", "kwargs", "error", "match"),
    [
        (np.zeros(3), np.ones(3), {}, InvalidInputError, r"anchors must have shape \(N, d\)"),
        (np.zeros((5, 4)), np.ones(5), {}, InvalidInputError, r"anchors must have shape"),
        (
            [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.inf]],
            np.ones(4),
            {},
            InvalidInputError,
            "finite",
        ),
        (np.eye(3), np.ones(3), {}, InvalidInputError, "at least 4 observed ranges"),
        (np.eye(4)[:, :3], np.ones(5), {}, InvalidInputError, r"ranges must have shape \(4,\)"),
        (np.eye(4)[:, :3], [1, 1, np.nan, 1], {}, InvalidInputError, "finite where observed"),
        (np.eye(4)[:, :3], [1, 1, -1, 1], {}, InvalidInputError, "non-negative"),
        (np.eye(4)[:, :3], np.ones(4), {"mask": [1, 1, 1, 1]}, InvalidInputError, "boolean"),
        (
            np.eye(4)[:, :3],
            np.ones(4),
            {"mask": np.ones(3, bool)},
            InvalidInputError,
            r"mask must have shape",
        ),
        (np.eye(4)[:, :3], np.ones(4), {"weights": "cubic"}, InvalidInputError, "weights must be"),
        (
            np.eye(4)[:, :3],
            np.ones(4),
            {"weights": [1, 1, 1]},
            InvalidInputError,
            r"weights must have shape",
        ),
        (
            np.eye(4)[:, :3],
            np.ones(4),
            {"weights": [1, -1, 1, 1]},
            InvalidInputError,
            "non-negative",
        ),
        (
            np.eye(4)[:, :3],
            np.ones(4),
            {"inlier_threshold": 0.0},
            InvalidInputError,
            "inlier_threshold",
        ),
        (np.eye(4)[:, :3], np.ones(4), {"max_hypotheses": 0}, InvalidInputError, "max_hypotheses"),
    ],
)
def test_bad_input(anchors, ranges, kwargs, error, match):
    """Each bad argument raises the package's error naming it."""
    with pytest.raises(error, match=match):
        multilaterate(anchors, ranges, **kwargs)


@pytest.mark.parametrize(
    ("anchors", "kind"),
    [
        (np.column_stack([np.arange(5.0), 2 * np.arange(5.0), np.zeros(5)]), "collinear"),
        (np.column_stack([np.arange(5.0), [0, 1, 0, 1, 2.0], np.ones(5)]), "coplanar"),
        (np.column_stack([np.arange(4.0), np.arange(4.0)]), "collinear"),
    ],
)
def test_ambiguous_anchors_refused(anchors, kind):
    """Anchors that leave a mirror or circle of solutions raise DegenerateGeometryError."""
    with pytest.raises(DegenerateGeometryError, match=kind):
        multilaterate(anchors, np.ones(len(anchors)))


def test_zero_weight_leaves_too_few_anchors():
    """Positive weights on coplanar anchors only is as ambiguous as coplanar anchors."""
    anchors = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0.0]])
    with pytest.raises(DegenerateGeometryError, match="positive weight"):
        multilaterate(anchors, np.ones(5), weights=[1, 1, 1, 0, 1])


def test_crlb_bad_input():
    """The CRLB refuses zero noise, a point on an anchor and a singular geometry."""
    a = np.array([[0.0, 0], [1, 0], [0, 1]])
    with pytest.raises(InvalidInputError, match="sigma must be positive"):
        multilateration_crlb(a, [0.5, 0.5], 0.0)
    with pytest.raises(InvalidInputError, match=r"sigma must be a scalar or have shape \(3,\)"):
        multilateration_crlb(a, [0.5, 0.5], [0.1, 0.1])
    with pytest.raises(DegenerateGeometryError, match="coincides with an anchor"):
        multilateration_crlb(a, [1.0, 0.0], 0.01)
    with pytest.raises(DegenerateGeometryError, match="singular"):
        multilateration_crlb(np.array([[0.0, 0], [1, 0], [2, 0]]), [3.0, 0.0], 0.01)


def test_crlb_matches_closed_form():
    """Two orthogonal anchors at unit distance: the CRLB is sigma^2 I."""
    cov = multilateration_crlb(np.array([[1.0, 0], [0, 1]]), [0.0, 0.0], 0.1)
    np.testing.assert_allclose(cov, 0.01 * np.eye(2), atol=1e-15)


@pytest.mark.parametrize(
    ("anchors", "radius2"),
    [
        ([[1, 0], [-1, 0], [0, 1], [0, -1]], 7.0),
        ([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], 22.0 / 3.0),
    ],
)
def test_hard_case_reports_non_unique_minimiser(anchors, radius2):
    """Symmetric anchors with equal, inconsistent ranges (3 m from unit-distance anchors): every
    point at squared radius radius2 minimises eq. (3) (the cost is n(r^2 - 8)^2 + 8 r^2 for n anchors:
    r^2 = 7 in 2-D, 22/3 in 3-D; Beck et al.'s hard case). The
    result is one of them, finite, and says it is not unique (converged False)."""
    res = multilaterate(anchors, [3.0] * len(anchors), weights="uniform")
    assert res.status is Status.NOT_IDENTIFIABLE and "not unique" in res.message
    assert np.all(np.isfinite(res.position))
    assert res.position @ res.position == pytest.approx(radius2, rel=1e-9)
