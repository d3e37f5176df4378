"""GTSAM back end: range-factor graph, dead-zone step priors, gauge, robust kernels, marginals."""

import numpy as np
import pytest

from rangeslam import InvalidInputError, align, mdu_crlb
from rangeslam.geometry.edm import range_matrix
from rangeslam.sim.scenes import add_outliers
from rangeslam.sim.trajectories import lemniscate, step_lengths
from rangeslam.solvers.gtsam_graph import STATIONARY_CHI2, STEP_PRIORS, refine_graph
from rangeslam.status import Status


def _scene(rng, dim=3, m=8, k=8):
    return rng.uniform(0, 2, (m, dim)), rng.uniform(-2, 4, (k, dim))


@pytest.mark.parametrize("dim", [2, 3])
def test_exact_recovery_from_a_perturbed_start(rng, dim):
    x, s = _scene(rng, dim)
    start_x = x + 0.05 * rng.standard_normal(x.shape)
    start_s = s + 0.05 * rng.standard_normal(s.shape)
    fit = refine_graph(start_x, start_s, range_matrix(x, s), noise_std=0.01)
    assert fit.converged, fit.message
    assert align(fit.receivers, x).rmse < 1e-6
    assert align(fit.sources, s).rmse < 1e-6
    np.testing.assert_allclose(fit.residuals, 0, atol=1e-6)
    assert fit.error < fit.initial_error


def test_gauge_priors_do_not_move_the_solution(rng):
    """Started at the truth with exact ranges, nothing moves: the gauge priors pin only the
    unobservable rigid motion."""
    x, s = _scene(rng)
    fit = refine_graph(x, s, range_matrix(x, s), noise_std=0.01)
    np.testing.assert_allclose(fit.receivers, x, atol=1e-9)
    np.testing.assert_allclose(fit.sources, s, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_marginals_are_the_crlb_in_the_receiver_gauge(rng, dim):
    """At the truth, GTSAM's marginals (mapped to the receiver gauge) equal the anchor-free
    CRLB of mdu_crlb: the same Fisher information, the same gauge."""
    x, s = _scene(rng, dim)
    fit = refine_graph(x, s, range_matrix(x, s), noise_std=0.01)
    bound = mdu_crlb(x, s, 0.01)
    np.testing.assert_allclose(fit.receiver_cov, bound.receiver_cov, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(fit.source_cov, bound.source_cov, rtol=1e-5, atol=1e-12)


@pytest.mark.slow
def test_covariances_are_honest_over_trials(rng):
    """200 noisy trials from the truth: RMSE matches the marginals within 10% and the mean NEES of
    the receivers (M d - 6 degrees of freedom after the receiver gauge) is inside the 95% band."""
    x, s = _scene(rng)
    true = range_matrix(x, s)
    sigma = 0.01
    errs, nees = [], []
    for _ in range(200):
        z = true + sigma * rng.standard_normal(true.shape)
        fit = refine_graph(x, s, z, noise_std=sigma)
        a = align(fit.receivers, x)
        e = (a.aligned - x).ravel()
        cov = fit.joint_cov[: x.size, : x.size]
        nees.append(e @ np.linalg.pinv(cov, rcond=1e-9, hermitian=True) @ e)
        errs.append(a.rmse**2)
    rmse = np.sqrt(np.mean(errs))
    predicted = np.sqrt(np.mean(np.trace(fit.receiver_cov, axis1=1, axis2=2)))
    assert abs(rmse / predicted - 1) < 0.1
    dof = x.size - 6
    # mean of 200 chi-square(dof) draws: 95% band dof +- 1.96 sqrt(2 dof / 200)
    assert abs(np.mean(nees) - dof) < 1.96 * np.sqrt(2 * dof / 200) + 0.05 * dof


def test_dead_zone_step_prior(rng):
    """Bounds that hold cost nothing, even with the truth off their centre; bounds that the ranges
    violate pull the steps towards them, and the answer is then a compromise inside the range
    fit's noise."""
    traj = lemniscate(10, step=0.3, phase=0.4)
    s = rng.uniform([0, 0, 0], [5, 4, 2.6], (7, 3))
    ranges = range_matrix(traj, s)
    steps = step_lengths(traj)
    free = refine_graph(traj, s, ranges, noise_std=0.01)
    inside = refine_graph(
        traj,
        s,
        ranges,
        noise_std=0.01,
        step_bounds=(0.7 * steps, 1.1 * steps),
        step_prior="dead_zone",
    )
    np.testing.assert_allclose(inside.receivers, free.receivers, atol=1e-9)
    assert inside.error == pytest.approx(free.error, abs=1e-12)
    for prior in STEP_PRIORS:
        tight = refine_graph(
            traj,
            s,
            ranges,
            noise_std=0.01,
            step_bounds=(1.5 * steps, 1.6 * steps),
            step_sigma=1e-3,
            step_prior=prior,
        )
        assert np.all(step_lengths(tight.receivers) > steps)
        assert tight.error > 1.0


def test_uniform_step_prior(rng):
    """The default reads the bounds as a step length uniform on them: no cost when the steps sit
    at the bounds' centres; off centre, a pull towards the centres that the ranges resist, so it
    shrinks with the range noise (the prior's weight is fixed, the ranges' grows as 1/sigma^2)."""
    traj = lemniscate(10, step=0.3, phase=0.4)
    s = rng.uniform([0, 0, 0], [5, 4, 2.6], (7, 3))
    ranges = range_matrix(traj, s)
    steps = step_lengths(traj)
    centred = refine_graph(traj, s, ranges, noise_std=0.01, step_bounds=(0.8 * steps, 1.2 * steps))
    assert centred.initial_error == pytest.approx(0.0, abs=1e-20)
    np.testing.assert_allclose(centred.receivers, traj, atol=1e-9)
    # Every step 0.1 step below the centre (0.87 sigma of the uniform): each factor costs
    # 0.5 * 0.87^2 at the truth, and the fit trades some of it for range residuals. The pull is
    # the worst case, all steps off the same way; over 30 random landmark sets it moved the
    # trajectory 2.1 cm in median and 6.1 cm at most at 1 cm noise, and 4% (at most 13%) of that
    # at 1 mm.
    moved = []
    for sigma in (0.01, 0.001):
        off = refine_graph(traj, s, ranges, noise_std=sigma, step_bounds=(0.9 * steps, 1.3 * steps))
        assert off.initial_error == pytest.approx(9 * 0.5 * 0.1**2 / (0.4**2 / 12), rel=1e-9)
        assert 0 < off.error < off.initial_error
        moved.append(align(off.receivers, traj, reflection=True).rmse)
    assert moved[0] < 0.10 and moved[1] < 0.25 * moved[0]


def test_robust_kernel_resists_a_wrong_range(rng):
    x, s = _scene(rng, m=10, k=8)
    true = range_matrix(x, s)
    bad, _ = add_outliers(true, 0.05, min_error=0.3, max_error=1.0, rng=rng)
    plain = refine_graph(x, s, bad, noise_std=0.005)
    errors = {}
    for kernel in ("huber", "cauchy", "tukey"):
        fit = refine_graph(x, s, bad, noise_std=0.005, robust=kernel)
        errors[kernel] = align(fit.receivers, x).rmse
    plain_error = align(plain.receivers, x).rmse
    assert errors["cauchy"] < plain_error / 5 and errors["tukey"] < plain_error / 5
    assert errors["huber"] < plain_error


def test_odometry_priors(rng):
    """Step vectors fix the orientation (no gauge priors); step lengths add information."""
    traj = lemniscate(12, step=0.3, phase=1.0)
    s = rng.uniform([0, 0, 0], [5, 4, 2.6], (7, 3))
    ranges = range_matrix(traj, s)
    start = traj + 0.03 * rng.standard_normal(traj.shape)
    fit = refine_graph(
        start, s, ranges, noise_std=0.01, step_vectors=np.diff(traj, axis=0), odometry_sigma=0.01
    )
    assert fit.converged
    np.testing.assert_allclose(fit.receivers - fit.receivers[0], traj - traj[0], atol=1e-6)
    with_len = refine_graph(
        traj, s, ranges, noise_std=0.01, step_lengths=step_lengths(traj), odometry_sigma=0.001
    )
    without = refine_graph(traj, s, ranges, noise_std=0.01)
    assert np.trace(with_len.joint_cov) < np.trace(without.joint_cov)


def test_zero_iterations_evaluate_the_graph(rng):
    """max_iterations=0 leaves the points where they are and returns the graph's cost there (what
    slam uses to compare runs on one graph)."""
    x, s = _scene(rng)
    z = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    start = x + 0.02 * rng.standard_normal(x.shape)
    fit = refine_graph(start, s, z, noise_std=0.01, max_iterations=0, covariances=False)
    np.testing.assert_array_equal(fit.receivers, start)
    assert fit.iterations == 0 and fit.error == fit.initial_error > 0
    moved = refine_graph(start, s, z, noise_std=0.01, max_iterations=1, covariances=False)
    assert moved.initial_error == fit.error and moved.error < fit.error


@pytest.mark.parametrize("model", ["gaussian", "huber", "violated bounds"])
def test_iteration_limit_fails_only_short_of_the_minimum(rng, model):
    """LM stopped by its iteration limit: SOLVER_FAILED while a Gauss-Newton step would still
    lower the cost by more than STATIONARY_CHI2 noise variances (one iteration from 20 cm off);
    converged, with a note, when the start is already within it (one iteration from 0.1 mm off
    the answer of a full run: the predicted decrease is far below one variance). Also with a
    robust kernel and two wrong ranges, and with step bounds the answer breaks (dead-zone and
    uniform-prior factors), whose nonlinear error is not the linearised model's value."""
    x, s = _scene(rng)
    z = range_matrix(x, s) + 0.01 * rng.standard_normal((len(x), len(s)))
    options = {"noise_std": 0.01, "covariances": False}
    if model == "huber":
        z[0, 0] += 0.5
        z[3, 2] -= 0.4
        options["robust"] = "huber"
    if model == "violated bounds":
        steps = np.linalg.norm(np.diff(x, axis=0), axis=1)
        options["step_bounds"] = (0.5 * steps, 0.7 * steps)
    far = refine_graph(x + 0.2 * rng.standard_normal(x.shape), s, z, max_iterations=1, **options)
    assert far.status is Status.SOLVER_FAILED
    assert "hit the limit of 1 iterations short of the minimum" in far.message
    full = refine_graph(x, s, z, **options)
    assert full.converged and full.iterations > 1
    nudged = full.receivers + 1e-4 * rng.standard_normal(x.shape)  # so that LM takes a step
    near = refine_graph(nudged, full.sources, z, max_iterations=1, **options)
    assert near.iterations == 1 and near.converged, near.message
    assert near.message.startswith("noted: Levenberg-Marquardt hit the limit of 1 iterations (")
    predicted = float(near.message.split("decrease of ")[1].split(" noise")[0])
    assert 0 <= predicted < STATIONARY_CHI2


def test_bad_input(rng):
    x, s = _scene(rng)
    r = range_matrix(x, s)
    m = len(x)
    with pytest.raises(InvalidInputError, match="noise_std must be positive"):
        refine_graph(x, s, r, noise_std=0.0)
    with pytest.raises(InvalidInputError, match="robust must be one of None, False, True"):
        refine_graph(x, s, r, noise_std=0.01, robust="l1")
    with pytest.raises(InvalidInputError, match=r"lower must have shape \(7,\)"):
        refine_graph(x, s, r, noise_std=0.01, step_bounds=(np.ones(5), np.ones(7)))
    with pytest.raises(InvalidInputError, match="lower <= upper; step 2"):
        lo, hi = np.ones(m - 1), 2 * np.ones(m - 1)
        lo[2] = 3.0
        refine_graph(x, s, r, noise_std=0.01, step_bounds=(lo, hi))
    with pytest.raises(InvalidInputError, match="lower must be >= 0"):
        refine_graph(x, s, r, noise_std=0.01, step_bounds=(-np.ones(m - 1), np.ones(m - 1)))
    with pytest.raises(InvalidInputError, match="odometry_sigma"):
        refine_graph(x, s, r, noise_std=0.01, step_lengths=np.ones(m - 1))
    with pytest.raises(InvalidInputError, match="max_iterations must be an integer >= 0"):
        refine_graph(x, s, r, noise_std=0.01, max_iterations=-1)
    with pytest.raises(InvalidInputError, match="step_prior must be one of"):
        bounds = (np.ones(m - 1), 2 * np.ones(m - 1))
        refine_graph(x, s, r, noise_std=0.01, step_bounds=bounds, step_prior="gaussian")
    with pytest.raises(InvalidInputError, match="sources must have shape"):
        refine_graph(x, s[:, :2], r, noise_std=0.01)


@pytest.mark.parametrize("d", [2, 3])
def test_the_gauge_prior_pins_only_its_rows(d):
    """The gauge prior is GTSAM's own linear factor: its error is |rows (p - at)|^2 / 2 over the
    tight sigma and its linearisation the rows themselves wherever p is (a point is a vector
    space, so the linear factor is exact); directions outside the rows cost nothing."""
    import gtsam

    from rangeslam.solvers.gtsam_graph import GAUGE_TIGHT, partial_prior

    rng = np.random.default_rng(d)
    key, at = gtsam.symbol("x", 3), rng.standard_normal(d)
    rows = np.linalg.qr(rng.standard_normal((d, d)))[0][: d - 1]  # all but one direction
    noise_std = 0.01
    factor = partial_prior(gtsam, key, at, rows, noise_std)
    sigma = GAUGE_TIGHT * noise_std
    for p in (at + rng.standard_normal(d), at + 5.0 * rng.standard_normal(d)):
        values = gtsam.Values()
        values.insert(key, p)
        expected = rows @ (p - at) / sigma
        assert factor.error(values) == pytest.approx(0.5 * expected @ expected, rel=1e-12)
        jac, rhs = factor.linearize(values).jacobian()
        np.testing.assert_allclose(jac, rows / sigma, rtol=1e-12)
        np.testing.assert_allclose(rhs, -expected, rtol=1e-12, atol=1e-9)
    normal = np.linalg.svd(rows)[2][-1]  # the direction the rows leave free
    values = gtsam.Values()
    values.insert(key, at + 3.0 * normal)
    assert factor.error(values) == pytest.approx(0.0, abs=1e-12)
