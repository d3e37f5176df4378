"""MINPACK on the Gaussian range graph: GTSAM's cost, GTSAM's minima, its own limits."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rangeslam import InvalidInputError, align
from rangeslam.geometry.edm import range_matrix
from rangeslam.solvers.graph_minpack import graph_terms, minpack_fit, minpack_refine, start_frame
from rangeslam.solvers.gtsam_graph import parse_graph_problem, refine_graph
from rangeslam.status import Status


def _walk(rng, m=8, k=6, dim=3):
    """A random walk of ``m`` steps of 0.3-0.6 m among ``k`` landmarks in a 4 m box, its step
    lengths."""
    steps = rng.uniform(0.3, 0.6, m - 1)[:, None] * rng.standard_normal((m - 1, dim))
    steps /= np.linalg.norm(steps, axis=1, keepdims=True) / rng.uniform(0.3, 0.6, (m - 1, 1))
    x = np.vstack([np.zeros(dim), np.cumsum(steps, axis=0)]) + 1.0
    s = rng.uniform(-1, 4, (k, dim))
    return x, s, np.linalg.norm(np.diff(x, axis=0), axis=1)


def _both(x0, s0, ranges, **kw):
    """GTSAM's and MINPACK's fits of the same graph from the same start."""
    return (
        refine_graph(x0, s0, ranges, covariances=False, **kw),
        minpack_refine(x0, s0, ranges, **kw),
    )


@pytest.mark.parametrize("prior", ["uniform", "dead_zone", None])
def test_the_cost_is_gtsams_wherever_the_points_are(rng, prior):
    x, s, steps = _walk(rng)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    mask = rng.random(ranges.shape) > 0.2
    mask[:, 0] = True
    bounds = None if prior is None else (0.9 * steps, 1.1 * steps)
    kw = dict(noise_std=0.01, mask=mask, step_bounds=bounds, step_prior=prior or "uniform")
    for spread in (0.0, 0.05, 0.5):  # the truth, near it, far (steps outside their bounds)
        x0, s0 = (
            x + spread * rng.standard_normal(x.shape),
            s + spread * rng.standard_normal(s.shape),
        )
        gtsam_fit, minpack = _both(x0, s0, ranges, max_iterations=0, **kw)
        assert minpack.error == pytest.approx(gtsam_fit.error, rel=1e-10)
        assert minpack.iterations == 0 and minpack.converged


def test_a_receivers_plane_costs_and_holds_as_in_gtsams_graph(rng):
    """With ``receiver_plane`` the same cost as GTSAM's graph (the plane's priors included) at
    any points, and the fit keeps the receivers in the plane through their start's centroid, at
    GTSAM's minimum or below it (GTSAM's LM stops early in the landmarks' flat valleys)."""
    x, s, steps = _walk(rng)
    x[:, 2] = 1.0 + 0.01 * rng.standard_normal(len(x))  # a walk almost on a floor
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    kw = dict(noise_std=0.01, step_bounds=(0.8 * steps, 1.2 * steps), receiver_plane=[0, 0, 1])
    x0, s0 = x + 0.05 * rng.standard_normal(x.shape), s + 0.05 * rng.standard_normal(s.shape)
    gtsam_fit, minpack = _both(x0, s0, ranges, max_iterations=0, **kw)
    assert minpack.error == pytest.approx(gtsam_fit.error, rel=1e-10)
    tilted = dict(kw, receiver_plane=[0.3, -0.2, 1.0])
    gtsam_tilted, minpack_tilted = _both(x0, s0, ranges, max_iterations=0, **tilted)
    assert minpack_tilted.error == pytest.approx(gtsam_tilted.error, rel=1e-10)
    gtsam_fit, minpack = _both(x0, s0, ranges, max_iterations=5000, **kw)
    assert minpack.converged, minpack.message
    # held by priors of sigma GAUGE_TIGHT noise_std (0.1 mm), as in GTSAM's graph
    np.testing.assert_allclose(minpack.receivers[:, 2], x0[:, 2].mean(), atol=1e-5)
    assert minpack.error <= gtsam_fit.error * (1 + 1e-6)


def test_the_start_frame_moves_only_within_a_plane(rng):
    points = rng.standard_normal((9, 3))
    normal = np.array([1.0, 2.0, 2.0]) / 3.0
    turn = Rotation.from_rotvec(0.4 * normal).as_matrix()
    moved = points @ turn.T + 2.0 * np.cross(normal, [1.0, 0.0, 0.0])  # a motion in the plane
    back = start_frame(moved, points, normal)
    np.testing.assert_allclose(back, points, atol=1e-12)
    tilted = start_frame(points @ Rotation.from_rotvec([0.3, 0, 0]).as_matrix().T, points, normal)
    np.testing.assert_allclose(tilted @ normal, (points @ Rotation.from_rotvec([0.3, 0, 0])
                               .as_matrix().T) @ normal, atol=1e-12)  # fmt: skip


def test_exact_recovery_without_noise(rng):
    x, s, steps = _walk(rng)
    start = (x + 0.05 * rng.standard_normal(x.shape), s + 0.05 * rng.standard_normal(s.shape))
    fit = minpack_refine(*start, range_matrix(x, s), noise_std=0.01, step_bounds=(steps, steps))
    assert fit.converged, fit.message
    assert align(fit.receivers, x, reflection=True).rmse < 1e-7
    assert align(np.vstack([fit.receivers, fit.sources]), np.vstack([x, s])).rmse < 1e-7
    assert fit.error < 1e-10 * fit.initial_error


@pytest.mark.parametrize("prior", ["uniform", "dead_zone"])
def test_it_reaches_the_minimum_gtsam_reaches(rng, prior):
    """From a start near the truth, at 1 cm: both end at one minimum (the oracle's own: least
    squares from the truth), the same cost, the same points up to a rigid motion."""
    x, s, steps = _walk(rng)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    kw = dict(noise_std=0.01, step_bounds=(0.8 * steps, 1.2 * steps), step_prior=prior)
    x0, s0 = x + 0.1 * rng.standard_normal(x.shape), s + 0.1 * rng.standard_normal(s.shape)
    gtsam_fit, minpack = _both(x0, s0, ranges, max_iterations=5000, **kw)
    oracle = minpack_refine(x, s, ranges, max_iterations=5000, **kw)
    assert minpack.converged and gtsam_fit.converged
    assert minpack.error == pytest.approx(gtsam_fit.error, rel=1e-6)
    assert minpack.error == pytest.approx(oracle.error, rel=1e-6)
    both = [np.vstack([f.receivers, f.sources]) for f in (minpack, gtsam_fit)]
    assert align(both[0], both[1]).rmse < 1e-5  # metres: 1e-3 of the noise


def test_the_fit_is_invariant_to_a_rigid_motion_of_the_data(rng):
    x, s, steps = _walk(rng)
    ranges = range_matrix(x, s) + 0.005 * rng.standard_normal((len(x), len(s)))
    kw = dict(noise_std=0.005, step_bounds=(0.8 * steps, 1.2 * steps), max_iterations=5000)
    x0, s0 = x + 0.05 * rng.standard_normal(x.shape), s + 0.05 * rng.standard_normal(s.shape)
    rot, shift = Rotation.random(random_state=rng).as_matrix(), np.array([3.0, -2.0, 0.5])
    first = minpack_refine(x0, s0, ranges, **kw)
    moved = minpack_refine(x0 @ rot.T + shift, s0 @ rot.T + shift, ranges, **kw)
    assert moved.error == pytest.approx(first.error, rel=1e-8)
    np.testing.assert_allclose(moved.receivers, first.receivers @ rot.T + shift, atol=1e-7)


@pytest.mark.parametrize("dim", [2, 3])
def test_the_jacobian_is_the_derivative_of_the_residuals(rng, dim):
    """Range rows, the dead zone inside and outside its bounds, the uniform prior's rows and (in
    3-D) a tilted receivers' plane, against central differences."""
    x, s, _ = _walk(rng, dim=dim)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    start = np.vstack([x, s]) + 0.02 * rng.standard_normal((len(x) + len(s), dim))
    normal = np.array([0.2, -0.3, 0.9]) / np.linalg.norm([0.2, -0.3, 0.9]) if dim == 3 else None
    on_plane = start[: len(x)]
    if normal is not None:  # where the door puts the start's receivers
        on_plane = on_plane - np.outer((on_plane - on_plane.mean(axis=0)) @ normal, normal)
    steps = np.linalg.norm(np.diff(on_plane, axis=0), axis=1)
    outside = np.arange(len(steps)) % 2 == 1  # every other step beyond its bounds
    problem = parse_graph_problem(
        start[: len(x)], start[len(x) :], ranges, noise_std=0.01, mask=None,
        step_bounds=(np.where(outside, 1.2, 0.9) * steps, np.where(outside, 1.3, 1.1) * steps),
        step_sigma=None, step_prior="uniform", step_lengths=None, step_vectors=None,
        odometry_sigma=None, robust=None, robust_scale=None, max_iterations=10,
        lambda_upper_bound=1e12, receiver_plane=normal,
    )  # fmt: skip
    terms, z = graph_terms(problem), np.vstack([problem.receivers, problem.sources]).ravel()
    step = 1e-7
    numeric = np.column_stack([
        (terms.residuals(z + step * e) - terms.residuals(z - step * e)) / (2 * step)
        for e in np.eye(z.size)
    ])  # fmt: skip
    np.testing.assert_allclose(terms.jacobian(z), numeric, atol=1e-5 * np.abs(numeric).max())
    dead = terms.zone > 0
    inside = np.abs(terms.residuals(z)[: len(terms.target)][dead]) == 0
    assert inside.any() and (~inside).any()  # both sides of the dead zone were differentiated


def test_known_step_lengths_and_a_step_sigma_cost_as_in_gtsams_graph(rng):
    x, s, steps = _walk(rng)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    x0, s0 = x + 0.05 * rng.standard_normal(x.shape), s + 0.05 * rng.standard_normal(s.shape)
    for bounds, step_sigma in (((steps, steps), None), ((0.9 * steps, 1.1 * steps), 0.003)):
        kw = dict(noise_std=0.01, step_bounds=bounds, step_sigma=step_sigma)
        gtsam_fit, minpack = _both(x0, s0, ranges, max_iterations=0, **kw)
        assert minpack.error == pytest.approx(gtsam_fit.error, rel=1e-10)


def test_the_iteration_limit_fails_only_short_of_the_minimum(rng):
    x, s, _ = _walk(rng)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    x0, s0 = x + 0.3 * rng.standard_normal(x.shape), s + 0.3 * rng.standard_normal(s.shape)
    short = minpack_refine(x0, s0, ranges, noise_std=0.01, max_iterations=2)
    assert short.status is Status.SOLVER_FAILED
    assert "short of the minimum" in short.message
    done = minpack_refine(x0, s0, ranges, noise_std=0.01, max_iterations=5000)
    again = minpack_refine(done.receivers, done.sources, ranges, noise_std=0.01, max_iterations=1)
    assert again.converged, again.message  # at the minimum a limit of 1 predicts nothing more


def test_fewer_ranges_than_unknowns_fit_and_stop_at_the_limit(rng):
    """Three steps and two landmarks (6 ranges and 2 step priors, 15 unknowns): MINPACK is
    handed rows of zeros to make up its square system; the limit's report is on the graph's own
    residuals."""
    x, s, steps = _walk(rng, m=3, k=2)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((3, 2))
    x0, s0 = x + 0.3 * rng.standard_normal(x.shape), s + 0.3 * rng.standard_normal(s.shape)
    kw = dict(noise_std=0.01, step_bounds=(0.8 * steps, 1.2 * steps), step_prior="dead_zone")
    short = minpack_refine(x0, s0, ranges, max_iterations=1, **kw)
    assert short.iterations == 1 and np.isfinite(short.error)
    fit = minpack_refine(x0, s0, ranges, max_iterations=5000, **kw)
    assert fit.converged, fit.message
    assert fit.error < 1e-8  # an underdetermined graph fits its ranges exactly


def test_what_only_gtsam_has_is_refused(rng):
    x, s, steps = _walk(rng)
    common = dict(noise_std=0.01, mask=None, step_bounds=None, step_sigma=None,
                  step_prior="uniform", robust_scale=None, max_iterations=10,
                  lambda_upper_bound=1e12)  # fmt: skip
    for extra in (
        dict(robust="cauchy", step_lengths=None, step_vectors=None, odometry_sigma=None),
        dict(robust=None, step_lengths=steps, step_vectors=None, odometry_sigma=0.01),
        dict(robust=None, step_lengths=None, step_vectors=np.diff(x, axis=0), odometry_sigma=0.01),
    ):
        problem = parse_graph_problem(x, s, range_matrix(x, s), **common, **extra)
        with pytest.raises(ValueError, match="GTSAM's alone"):
            minpack_fit(problem)


def test_bad_input_is_refused_by_refine_graphs_door(rng):
    x, s, _ = _walk(rng)
    with pytest.raises(InvalidInputError, match="ranges"):
        minpack_refine(x, s, range_matrix(x, s)[:, :-1], noise_std=0.01)
    with pytest.raises(InvalidInputError, match="noise_std"):
        minpack_refine(x, s, range_matrix(x, s), noise_std=-1.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(3, 9), k=st.integers(2, 6),
       dim=st.sampled_from([2, 3]))  # fmt: skip
def test_property_never_above_the_start_and_gtsams_cost(seed, m, k, dim):
    rng = np.random.default_rng(seed)
    x, s, steps = _walk(rng, m, k, dim)
    ranges = range_matrix(x, s) + 0.01 * rng.standard_normal((m, k))
    x0, s0 = x + 0.2 * rng.standard_normal(x.shape), s + 0.2 * rng.standard_normal(s.shape)
    kw = dict(noise_std=0.01, step_bounds=(0.8 * steps, 1.2 * steps))
    fit = minpack_refine(x0, s0, ranges, max_iterations=2000, **kw)
    assert np.isfinite(fit.error) and fit.error <= fit.initial_error
    at = refine_graph(fit.receivers, fit.sources, ranges, covariances=False, max_iterations=0, **kw)
    assert fit.error == pytest.approx(at.error, rel=1e-9, abs=1e-12)
