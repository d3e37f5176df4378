"""EDM completion SDP and Dattorro's convex iteration (eqs. 8-11)."""

import cvxpy as cp
import numpy as np
import pytest

from rangeslam import InvalidInputError, SolverError
from rangeslam.geometry.edm import edm, range_matrix
from rangeslam.mdu.core import mdu_edm, mdu_mask
from rangeslam.solvers import sdp_pool
from rangeslam.solvers.sdp import (
    EDMCompletionSDP,
    complete_edm,
    eigen_gap,
    low_rank_direction,
    random_direction,
)
from rangeslam.solvers.sdp_pool import clear_sdp_pool, pooled_sdp


def _random_mask(rng, n, fraction):
    upper = np.triu(rng.random((n, n)) < fraction, 1)
    return upper | upper.T


def test_full_edm_trace_minimisation_bias_shrinks_as_one_over_lambda(rng):
    """All distances observed. The penalty form of eq. (10) trades the fit against <G, Z>, so the
    completion is biased by O(1/lambda) (exactness comes from the refinement that follows)."""
    x = rng.uniform(-1, 1, (9, 3))
    d = edm(x)
    mask = ~np.eye(9, dtype=bool)
    errors = []
    for lam in (10.0, 1e3):
        out = complete_edm(d, mask, 3, method="trace_min", fit_weight=lam)
        errors.append(np.abs(out.edm - d).max() / d.max())
        assert out.iterations == 1 and out.status in ("optimal", "optimal_inaccurate")
    assert errors[1] < 1e-4  # measured about 3e-5
    assert errors[1] < errors[0] / 30  # measured 100x for 100x lambda


def test_convex_iteration_reaches_rank_d_on_a_partial_edm(rng):
    """70% of the pairs of 12 points in 3-D: the convex iteration drives the N - d smallest
    eigenvalues to zero and, with a large fit weight, matches the truth on the missing pairs."""
    x = rng.uniform(-1, 1, (12, 3))
    d = edm(x)
    mask = _random_mask(rng, 12, 0.7)
    out = complete_edm(d, mask, 3, fit_weight=1e4)
    assert out.converged and out.eigen_gap <= 1e-6
    assert out.gaps[0] >= out.gaps[-1]
    np.testing.assert_allclose(out.edm, d, atol=1e-3 * d.max())  # measured about 1e-5


def test_trace_maximisation_is_available_and_differs(rng):
    x, s = rng.uniform(0, 1, (6, 3)), rng.uniform(-2, 3, (6, 3))
    w = mdu_mask(np.ones((6, 6), dtype=bool))
    d = mdu_edm(range_matrix(x, s))
    tmin = complete_edm(d, w, 3, method="trace_min")
    tmax = complete_edm(d, w, 3, method="trace_max")
    assert np.trace(tmax.gram) > np.trace(tmin.gram)
    assert tmax.method == "trace_max"


def test_units_do_not_change_the_answer(rng):
    """Data in metres or millimetres: the same configuration (squared distances scale by 1e6)."""
    x = rng.uniform(-1, 1, (10, 3))
    mask = _random_mask(rng, 10, 0.8)
    a = complete_edm(edm(x), mask, 3, max_iterations=10)
    b = complete_edm(edm(x) * 1e6, mask, 3, max_iterations=10)
    np.testing.assert_allclose(b.edm, a.edm * 1e6, rtol=1e-5, atol=1e-6 * b.edm.max())
    assert b.iterations == a.iterations


def test_direction_matrices():
    """Step (ii) of eq. (10) in closed form: the projector on the N - d smallest eigenvectors;
    <G, Z> is then the sum of the N - d smallest eigenvalues."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((8, 8))
    g = a @ a.T
    z = low_rank_direction(g, 3)
    np.testing.assert_allclose(z @ z, z, atol=1e-12)
    assert np.trace(z) == pytest.approx(5)
    eig = np.linalg.eigvalsh(g)
    assert np.sum(z * g) == pytest.approx(eig[:5].sum())
    assert eigen_gap(g, 3) == pytest.approx(eig[:5].sum() / eig.sum())
    zr = random_direction(8, 3, rng)
    np.testing.assert_allclose(zr @ zr, zr, atol=1e-12)
    np.testing.assert_allclose(zr @ np.ones(8), np.ones(8), atol=1e-12)  # keeps the null space


def test_distance_bounds_are_enforced(rng):
    """Eq. (11): bounds on chosen pairs hold in the completed EDM, even against the data."""
    x = rng.uniform(-1, 1, (8, 3))
    d = edm(x)
    mask = _random_mask(rng, 8, 0.6)
    pairs = np.array([[0, 1], [2, 3]])
    true = np.sqrt(d[pairs[:, 0], pairs[:, 1]])
    lower, upper = 1.1 * true, 1.2 * true  # deliberately excluding the truth
    out = complete_edm(d, mask, 3, bounded_pairs=pairs, bounds=(lower, upper), max_iterations=5)
    got = np.sqrt(out.edm[pairs[:, 0], pairs[:, 1]])
    assert np.all(got >= lower * (1 - 1e-5)) and np.all(got <= upper * (1 + 1e-5))


def test_problem_is_built_once_and_reused(rng):
    x = rng.uniform(-1, 1, (8, 3))
    mask = _random_mask(rng, 8, 0.8)
    problem = EDMCompletionSDP(mask)
    built = problem._problem
    a = complete_edm(edm(x), mask, 3, problem=problem, max_iterations=5)
    b = complete_edm(edm(2 * x), mask, 3, problem=problem, max_iterations=5)
    assert problem._problem is built
    np.testing.assert_allclose(b.edm, 4 * a.edm, rtol=1e-4, atol=1e-6)


@pytest.fixture
def empty_pool():
    clear_sdp_pool()
    yield
    clear_sdp_pool()


def _bounded_walk(rng, n=10):
    """Points of a walk (n, 3), the full mask, its consecutive pairs and +-20% bounds on them."""
    x = np.cumsum(rng.normal(0, 0.5, (n, 3)), axis=0)
    pairs = np.column_stack([np.arange(n - 1), np.arange(1, n)])
    steps = np.linalg.norm(np.diff(x, axis=0), axis=1)
    return x, ~np.eye(n, dtype=bool), pairs, (0.8 * steps, 1.2 * steps)


def test_a_pooled_problem_gives_the_bits_of_a_new_one(rng, empty_pool):
    """A problem handed out again by the pool keeps its compiled form but builds its solver anew
    for the next data: each completion is bitwise that of a problem built for its data, whatever
    the pooled one solved before (its solver updated instead, walks differed by up to 2e-3)."""
    _, mask, pairs, _ = _bounded_walk(rng)
    run = {"max_iterations": 4, "bounded_pairs": pairs}
    with pooled_sdp(mask, bounded_pairs=pairs) as first:
        pass
    for _ in range(4):
        y, _, _, bounds = _bounded_walk(rng)
        noisy = edm(y) + rng.normal(0, 1e-3, mask.shape) * mask
        noisy = 0.5 * (noisy + noisy.T)
        with pooled_sdp(mask, bounded_pairs=pairs) as again:
            assert again is first
            reused = complete_edm(noisy, mask, 3, problem=again, bounds=bounds, **run)
        fresh = complete_edm(noisy, mask, 3, bounds=bounds, **run)
        assert reused.iterations == fresh.iterations
        np.testing.assert_array_equal(reused.gram, fresh.gram)


def test_the_pool_hands_a_problem_to_one_user_at_a_time(empty_pool):
    mask = ~np.eye(7, dtype=bool)
    with pooled_sdp(mask) as outer, pooled_sdp(mask) as inner:
        assert inner is not outer
    with pooled_sdp(mask) as later, pooled_sdp(mask, loss="l1") as other:
        assert later in (outer, inner)
        assert other not in (outer, inner) and other.loss == "l1"
    with pooled_sdp(mask, bounded_pairs=[[0, 1]]) as bounded:
        assert bounded not in (outer, inner, other) and len(bounded.bounded_pairs) == 1


def test_a_problem_that_raised_is_dropped_and_a_closed_generator_returns_its_own(empty_pool):
    mask = ~np.eye(6, dtype=bool)
    with pytest.raises(SolverError), pooled_sdp(mask) as broken:
        raise SolverError("simulated failure")
    with pooled_sdp(mask) as built:
        assert built is not broken

    def runs():
        with pooled_sdp(mask) as sdp:
            yield sdp
            yield sdp

    gen = runs()
    held = next(gen)
    with pooled_sdp(mask) as meanwhile:  # in use by the generator: not handed out
        assert meanwhile is not held
    gen.close()  # returned: the last one back is the first one out
    with pooled_sdp(mask) as after:
        assert after is held


def test_the_pool_keeps_at_most_pool_size_problems(monkeypatch, empty_pool):
    monkeypatch.setattr(sdp_pool, "POOL_SIZE", 2)
    made = {}
    for n in (5, 6, 7):
        with pooled_sdp(~np.eye(n, dtype=bool)) as sdp:
            made[n] = sdp
    with pooled_sdp(~np.eye(5, dtype=bool)) as again:  # the least recently used was dropped
        assert again is not made[5]
    with pooled_sdp(~np.eye(7, dtype=bool)) as kept:
        assert kept is made[7]


def test_the_pool_trims_past_structures_taken_and_dropped(monkeypatch, empty_pool):
    """A structure whose problem was taken and then dropped (an exception) or is still held (a
    nested block) leaves nothing behind that trimming trips on."""
    monkeypatch.setattr(sdp_pool, "POOL_SIZE", 2)
    with pooled_sdp(~np.eye(5, dtype=bool)):
        pass
    with pytest.raises(KeyboardInterrupt), pooled_sdp(~np.eye(5, dtype=bool)):
        raise KeyboardInterrupt
    with pooled_sdp(~np.eye(4, dtype=bool)) as held:
        for n in range(6, 10):
            with pooled_sdp(~np.eye(n, dtype=bool)):
                pass
    with pooled_sdp(~np.eye(4, dtype=bool)) as again:
        assert again is held
    with pooled_sdp(~np.eye(8, dtype=bool)) as recent, pooled_sdp(~np.eye(6, dtype=bool)) as old:
        assert recent.n == 8 and old.n == 6


def test_a_pooled_problem_retried_after_a_raise_gives_a_new_problems_bits(
    rng, monkeypatch, empty_pool
):
    """Clarabel raising while it has no solver to update (a data set's first solve) sends the
    solve down the retries to the fallback solver: a pooled problem holds no solver from its
    last data (restart), so it takes the same path as a new problem, to the same bits."""
    from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import CLARABEL

    original = CLARABEL.solve_via_data

    def cold_fails(self, data, warm_start, verbose, solver_opts, solver_cache=None):
        if not solver_cache:  # a data set's first solve: no solver to update yet
            raise cp.error.SolverError("simulated failure")
        return original(self, data, warm_start, verbose, solver_opts, solver_cache)

    x, mask, _, _ = _bounded_walk(rng, 9)
    y = x + rng.normal(0, 0.3, x.shape)
    noisy = edm(y) + rng.normal(0, 1e-3, mask.shape) * mask
    noisy = 0.5 * (noisy + noisy.T)
    with pooled_sdp(mask) as sdp:
        complete_edm(edm(x), mask, 3, problem=sdp, max_iterations=3)
    monkeypatch.setattr(CLARABEL, "solve_via_data", cold_fails)
    with pooled_sdp(mask) as sdp:
        reused = complete_edm(noisy, mask, 3, problem=sdp, max_iterations=3)
    fresh = complete_edm(noisy, mask, 3, max_iterations=3)
    np.testing.assert_array_equal(reused.gram, fresh.gram)


def _breaks(monkeypatch, *names):
    """The named solvers' cvxpy interfaces raise SolverError (both solve paths go through them)."""
    from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import CLARABEL
    from cvxpy.reductions.solvers.conic_solvers.scs_conif import SCS

    def fails(self, *args, **kwargs):
        raise cp.error.SolverError("simulated failure")

    for cls in (CLARABEL, SCS):
        if cls.__name__ in names:
            monkeypatch.setattr(cls, "solve_via_data", fails)


def test_fallback_solver_is_used_and_recorded(rng, monkeypatch):
    x = rng.uniform(-1, 1, (6, 2))
    mask = ~np.eye(6, dtype=bool)
    _breaks(monkeypatch, "CLARABEL")
    out = complete_edm(edm(x), mask, 2, method="trace_min", fit_weight=100.0)
    assert out.solver == "SCS"
    np.testing.assert_allclose(out.edm, edm(x), atol=1e-3 * edm(x).max())


def test_solver_failure_raises_with_the_statuses(rng, monkeypatch):
    _breaks(monkeypatch, "CLARABEL", "SCS")
    x = rng.uniform(-1, 1, (6, 2))
    with pytest.raises(SolverError, match=r"CLARABEL: error.*SCS: error") as info:
        complete_edm(edm(x), ~np.eye(6, dtype=bool), 2)
    assert "simulated failure" in info.value.status


@pytest.mark.filterwarnings("ignore:Solution may be inaccurate")
@pytest.mark.parametrize("variant", ["l2", "l1", "affine ranges", "bounds"])
def test_conic_data_path_is_cvxpys_own_solve(rng, variant):
    """Each solve hands Clarabel conic data compiled once per set_data, q moved with Z: the Gram
    matrix is cvxpy's own solve of the same Parameters (Problem.solve), for every form of the
    problem, across directions Z and after new data."""
    x, mask, groups = _unfolding_with_ranges(rng)
    n = len(x)
    build = {"loss": "l1"} if variant == "l1" else {}
    if variant == "affine ranges":
        build = {"range_groups": groups, "range_model": "affine"}
    data = {}
    if variant == "bounds":
        build = {"bounded_pairs": np.array([[0, 1], [1, 2]])}
        true = np.linalg.norm(x[[0, 1]] - x[[1, 2]], axis=1)
        data = {"bounds": (0.9 * true, 1.1 * true)}
    problem = EDMCompletionSDP(mask, **build)
    options = {"tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7}  # the package's, for Clarabel
    if variant == "affine ranges":
        options["static_regularization_constant"] = 1e-7
    compared = 0
    for scale in (1.0, 1.7):
        problem.set_data(edm(scale * x) + rng.normal(0, 1e-3, (n, n)) * mask, **data)
        z = np.eye(n)
        for _ in range(3):  # trace minimisation, then the convex iteration's directions
            g, status, solver = problem.solve(z)
            assert solver == "CLARABEL" and status in ("optimal", "optimal_inaccurate")
            value = problem._problem.objective.value
            z = low_rank_direction(g, 2)
            try:  # these SDPs are rank-deficient: Clarabel's own path fails now and then
                problem._problem.solve(solver="CLARABEL", **options)
            except cp.error.SolverError:
                continue
            own = 0.5 * (problem._gram.value + problem._gram.value.T) * problem.scale**2
            # the same optimum to the solver's accuracy (a wrong q would move the value by the
            # size of <Z, G> itself); an l1 fit's G need not be unique, its value is
            assert value == pytest.approx(problem._problem.value, rel=1e-4, abs=1e-9)
            np.testing.assert_allclose(g, own, atol=1e-2 * np.abs(own).max())
            compared += 1
    assert compared >= 3


def test_zero_weight_is_the_same_as_a_missing_pair(rng):
    x = rng.uniform(-1, 1, (8, 3))
    full = ~np.eye(8, dtype=bool)
    holed = full.copy()
    holed[0, 1:4] = holed[1:4, 0] = False
    weights = holed.astype(float)
    a = complete_edm(edm(x), holed, 3, method="trace_min")
    b = complete_edm(edm(x), full, 3, method="trace_min", weights=weights)
    np.testing.assert_allclose(a.gram, b.gram, atol=1e-3 * np.abs(a.gram).max())


def test_l1_fit_completes_clean_data(rng):
    """The L1 fit (used by robust calibration) has the same O(1/lambda) bias on clean data."""
    x = rng.uniform(-1, 1, (10, 3))
    d = edm(x)
    problem = EDMCompletionSDP(~np.eye(10, dtype=bool), loss="l1")
    out = complete_edm(
        d, ~np.eye(10, dtype=bool), 3, method="trace_min", fit_weight=1e3, problem=problem
    )
    assert problem.loss == "l1"
    assert np.abs(out.edm - d).max() < 1e-3 * d.max()


def test_bad_bounds_weights_and_reuse(rng):
    x = rng.uniform(-1, 1, (6, 2))
    full = ~np.eye(6, dtype=bool)
    pairs = [[0, 1]]
    with pytest.raises(InvalidInputError, match="0 <= lower <= upper"):
        complete_edm(edm(x), full, 2, bounded_pairs=pairs, bounds=([-1.0], [2.0]))
    with pytest.raises(InvalidInputError, match="0 <= lower <= upper"):
        complete_edm(edm(x), full, 2, bounded_pairs=pairs, bounds=([2.0], [1.0]))
    with pytest.raises(InvalidInputError, match=r"shape \(1,\)"):
        complete_edm(edm(x), full, 2, bounded_pairs=pairs, bounds=([1.0, 2.0], [2.0, 3.0]))
    with pytest.raises(InvalidInputError, match="finite"):
        complete_edm(edm(x), full, 2, bounded_pairs=pairs, bounds=([1.0], [np.inf]))
    with pytest.raises(InvalidInputError, match="no bounded_pairs"):
        complete_edm(edm(x), full, 2, bounds=([1.0], [2.0]))
    with pytest.raises(InvalidInputError, match="bounds are required"):
        complete_edm(edm(x), full, 2, bounded_pairs=pairs)
    with pytest.raises(InvalidInputError, match=r"weights must have shape \(6, 6\)"):
        complete_edm(edm(x), full, 2, weights=np.ones((5, 5)))
    with pytest.raises(InvalidInputError, match="weights must be finite and non-negative"):
        complete_edm(edm(x), full, 2, weights=-np.ones((6, 6)))
    other = full.copy()
    other[0, 1] = other[1, 0] = False
    with pytest.raises(InvalidInputError, match="mask differs"):
        complete_edm(edm(x), other, 2, problem=EDMCompletionSDP(full))
    with pytest.raises(InvalidInputError, match="z0 must be a finite symmetric"):
        complete_edm(edm(x), full, 2, z0=np.triu(np.ones((6, 6))))
    with pytest.raises(InvalidInputError, match="z0 is only used by the convex iteration"):
        complete_edm(edm(x), full, 2, method="trace_min", z0=np.eye(6))
    with pytest.raises(InvalidInputError, match="loss must be"):
        EDMCompletionSDP(full, loss="huber")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"method": "nuclear"}, "method must be one of"),
        ({"fit_weight": 0.0}, "fit_weight must be positive"),
        ({"max_iterations": 0}, "max_iterations must be a positive integer"),
        ({"z0": np.eye(3)}, r"z0 must have shape \(6, 6\)"),
    ],
)
def test_bad_arguments(kwargs, match):
    x = np.random.default_rng(1).uniform(-1, 1, (6, 2))
    with pytest.raises(InvalidInputError, match=match):
        complete_edm(edm(x), ~np.eye(6, dtype=bool), 2, **kwargs)


def test_bad_masks_and_data():
    x = np.random.default_rng(1).uniform(-1, 1, (6, 2))
    full = ~np.eye(6, dtype=bool)
    with pytest.raises(InvalidInputError, match="square boolean"):
        EDMCompletionSDP(full.astype(int))
    lopsided = full.copy()
    lopsided[0, 1] = False
    with pytest.raises(InvalidInputError, match="symmetric"):
        EDMCompletionSDP(lopsided)
    with pytest.raises(InvalidInputError, match="observes no pair"):
        EDMCompletionSDP(np.zeros((6, 6), dtype=bool))
    with pytest.raises(InvalidInputError, match="bounded_pairs"):
        EDMCompletionSDP(full, bounded_pairs=[[0, 9]])
    with pytest.raises(InvalidInputError, match="dim must be smaller"):
        complete_edm(edm(x), full, 6)
    bad = edm(x)
    bad[0, 1] = bad[1, 0] = np.nan
    with pytest.raises(InvalidInputError, match="finite and non-negative"):
        complete_edm(bad, full, 2)
    with pytest.raises(InvalidInputError, match=r"edm_matrix must have shape \(6, 6\)"):
        complete_edm(edm(x)[:5, :5], full, 2)


# --- uncalibrated range groups (scale / offset / affine unknown per group) ----------------------


def _unfolding_with_ranges(rng, m=10, k=4):
    """Receivers with known pairwise distances, sources seen only through ranges (one group)."""
    x = np.vstack([rng.uniform(0, 10, (m, 2)), rng.uniform(-5, 15, (k, 2))])
    n = m + k
    mask = np.zeros((n, n), dtype=bool)
    mask[:m, :] = True
    mask[:, :m] = True
    np.fill_diagonal(mask, False)
    groups = -np.ones((n, n), dtype=int)
    groups[:m, m:] = 0
    groups[m:, :m] = 0
    return x, mask, groups


def _with_calibration(x, groups, scale, offset):
    d = edm(x)
    ranged = groups >= 0
    d[ranged] = (scale * np.sqrt(d[ranged]) + offset) ** 2
    return d


@pytest.mark.parametrize(
    ("model", "tol_points", "tol_scale", "tol_offset"),
    # scale: exact (the SDP stays exact); offset and affine: the relaxation e >= c^2 / a leaves the
    # convex iteration a few centimetres off on 5-20 m ranges (worst of 20 seeds: 4 cm, 0.005 in
    # scale, 0.1 m in offset): a start for a refinement, not an estimate to stop at. (offset: a is
    # constrained to 1, so its scale is 1 to solver precision.)
    [("scale", 1e-3, 1e-4, 0.0), ("offset", 0.1, 1e-6, 0.05), ("affine", 0.15, 0.02, 0.25)],
)
def test_range_groups_recover_calibration(rng, model, tol_points, tol_scale, tol_offset):
    from rangeslam.geometry.alignment import align

    x, mask, groups = _unfolding_with_ranges(rng)
    scale = 1.0 if model == "offset" else rng.uniform(0.9, 1.1)
    offset = 0.0 if model == "scale" else rng.uniform(-1.0, 1.0)
    d = _with_calibration(x, groups, scale, offset)
    out = complete_edm(d, mask, 2, range_groups=groups, range_model=model, fit_weight=1e3)
    assert align(out.points, x, reflection=True).errors.max() < tol_points
    assert abs(out.range_scale[0] - scale) <= tol_scale + 1e-12
    assert abs(out.range_offset[0] - offset) <= tol_offset + 1e-12


def test_range_groups_one_scale_per_group(rng):
    x, mask, _ = _unfolding_with_ranges(rng, m=10, k=3)
    groups = -np.ones(mask.shape, dtype=int)
    scales = np.array([0.95, 1.05, 1.1])
    d = edm(x)
    for j, s in enumerate(scales):
        groups[:10, 10 + j] = groups[10 + j, :10] = j
        d[:10, 10 + j] *= s**2
        d[10 + j, :10] *= s**2
    out = complete_edm(d, mask, 2, range_groups=groups, fit_weight=1e3)
    np.testing.assert_allclose(out.range_scale, scales, atol=1e-3)
    assert complete_edm(edm(x), mask, 2).range_scale is None


def test_range_groups_without_calibration_are_unchanged(rng):
    """Calibrated data at scale 1 and offset 0: the same answer as plain distances."""
    x, mask, groups = _unfolding_with_ranges(rng)
    plain = complete_edm(edm(x), mask, 2, fit_weight=1e3)
    grouped = complete_edm(edm(x), mask, 2, range_groups=groups, fit_weight=1e3)
    assert abs(grouped.range_scale[0] - 1.0) < 1e-4
    np.testing.assert_allclose(grouped.edm, plain.edm, atol=1e-2 * np.median(edm(x)))


def test_bad_range_groups(rng):
    x, mask, groups = _unfolding_with_ranges(rng)
    with pytest.raises(InvalidInputError, match="range_model must be one of"):
        EDMCompletionSDP(mask, range_groups=groups, range_model="linear")
    with pytest.raises(InvalidInputError, match="range_groups must be an integer"):
        EDMCompletionSDP(mask, range_groups=groups.astype(float))
    with pytest.raises(InvalidInputError, match="range_groups must be an integer"):
        EDMCompletionSDP(mask, range_groups=groups[:-1])
    skew = groups.copy()
    skew[0, 10] = -1
    with pytest.raises(InvalidInputError, match="symmetric"):
        EDMCompletionSDP(mask, range_groups=skew)
    with pytest.raises(InvalidInputError, match="marks no observed pair"):
        EDMCompletionSDP(mask, range_groups=-np.ones_like(groups))
    gap = np.where(groups == 0, 1, groups)
    with pytest.raises(InvalidInputError, match=r"numbered 0\.\.G-1"):
        EDMCompletionSDP(mask, range_groups=gap)
    all_ranges = np.where(mask, 0, -1)
    with pytest.raises(InvalidInputError, match="needs observed pairs with distances"):
        EDMCompletionSDP(mask, range_groups=all_ranges, range_model="scale")
    EDMCompletionSDP(mask, range_groups=all_ranges, range_model="offset")  # units kept by a = 1
    problem = EDMCompletionSDP(mask)
    with pytest.raises(InvalidInputError, match="fixed when the problem is built"):
        complete_edm(edm(x), mask, 2, problem=problem, range_groups=groups)
