"""Fig. 5 of the paper as acceptance tests (issue 4): SLAM on the lemniscate of eq. (12), the
loudspeaker and its 6 first-order images as landmarks, +-20% step bounds. Trajectory errors are
RMS over the steps after the best rigid motion (with reflection); see
benchmarks/bench_slam.py for the 50-trial tables these thresholds come from."""

import numpy as np
import pytest

from rangeslam.app.experiments import mean_nees, slam_experiment

STEPS = (5, 6, 8, 10, 15, 20)
TRIALS = 8


@pytest.fixture(scope="module")
def bounded_1cm(request):
    """TRIALS runs per M at sigma = 1 cm with bounds, shared by the tests below."""
    rng = np.random.default_rng(request.config.getoption("--seed"))
    return {m: [slam_experiment(m, 0.01, True, rng) for _ in range(TRIALS)] for m in STEPS}


def test_mean_error_within_4cm_and_gtsam_no_worse_than_edm(bounded_1cm):
    for m, runs in bounded_1cm.items():
        error = np.mean([r.error for r in runs])
        edm = np.mean([r.edm_error for r in runs])
        assert error <= 0.04, f"M = {m}: mean trajectory error {error:.4f} m"
        assert error <= edm, f"M = {m}: EDM + GTSAM {error:.4f} m, EDM alone {edm:.4f} m"


def test_success_and_convergence_from_six_steps(bounded_1cm):
    """From M = 6: at least 95% of the trials within 10 cm, and those that are not say so."""
    runs = [r for m, rs in bounded_1cm.items() if m >= 6 for r in rs]
    assert np.mean([r.error < 0.10 for r in runs]) >= 0.95
    assert not any(r.converged for r in runs if r.error >= 0.10)


def test_covariances_are_honest_from_ten_steps(bounded_1cm):
    """NEES of the whole trajectory against its covariance, M >= 10: the mean over the trials
    (divided by its dof) inside the two-sided 99% chi-square band (the 95% band is the
    benchmark's, over 50 trials)."""
    runs = [r for m, rs in bounded_1cm.items() if m >= 10 for r in rs]
    assert all(np.isfinite(r.nees) for r in runs)
    mean, lo, hi = mean_nees([r.nees for r in runs], [r.nees_dof for r in runs], level=0.99)
    assert lo <= mean <= hi, f"mean NEES / dof {mean:.3f} outside [{lo:.3f}, {hi:.3f}]"


def test_1mm_twenty_steps_within_1_3_crlb(rng):
    """sigma = 1 mm, M = 20, bounds: median trajectory error within 1.3x the median CRLB of the
    ranges alone (the step prior can only add information)."""
    # 30 walks: over 30 the ratio was 0.98-1.07 on the seeds tried (0.77 over the benchmark's
    # 50); over 10 the median moves by a factor of 2 between seeds.
    runs = [slam_experiment(20, 0.001, True, rng, baseline=False) for _ in range(30)]
    error = np.median([r.error for r in runs])
    bound = np.median([r.crlb for r in runs])
    assert np.isfinite(bound)
    assert error <= 1.3 * bound, f"median error {error:.5f} m, CRLB {bound:.5f} m"
