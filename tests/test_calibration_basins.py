"""A calibration does not accept a minimum when a lower one is within reach (the fuzz's S2):
the judge's alternatives (rangeslam.mdu.calibration_judge) reach it from the search's answer."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import align, calibrate, mdu_crlb
from rangeslam.app.experiments import fig3_scene
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.calibration import parse_calibration
from rangeslam.mdu.calibration_judge import judge_calibration
from rangeslam.mdu.core import ConvexIterationOptions
from rangeslam.solvers.least_squares import refine_unfolding

SIGMA = 1e-3  # m


def _s2_scene():
    """The fuzz's scene: Fig. 3 at default_rng(1), 1 mm of noise from default_rng(1001)."""
    scene = fig3_scene(np.random.default_rng(1))
    noise = SIGMA * np.random.default_rng(1001).standard_normal(scene.ranges.shape)
    return scene, scene.ranges + noise


def _ssr(receivers, sources, ranges):
    return float(np.sum((range_matrix(receivers, sources) - ranges) ** 2))


@pytest.mark.parametrize("declared", [SIGMA, 3 * SIGMA])
def test_the_lower_minimum_of_the_fig3_scene_is_taken(declared):
    """Before: CONVERGED 7.3 cm off (bound 1.9 cm) at 1.86 times the cost least squares reaches
    from the truth, with noise_std right and 3 times too large."""
    scene, ranges = _s2_scene()
    res = calibrate(ranges, noise_std=declared, rng=0)
    oracle = refine_unfolding(scene.mics, scene.sources, ranges, np.ones(ranges.shape, bool))
    oracle_ssr = float(np.sum(oracle.residuals**2))
    assert _ssr(res.receivers, res.sources, ranges) <= oracle_ssr * (1 + 1e-6)
    bound = mdu_crlb(scene.mics, scene.sources, SIGMA).receiver_rmse
    error = align(res.receivers, scene.mics, reflection=True).rmse
    assert not res.converged or error <= 3 * bound, res.message


def test_the_judge_leaves_the_wrong_minimum_for_the_lower_one(monkeypatch):
    """Without the judge the search stops in the wrong minimum (1.86 times the oracle's cost);
    the judge's alternatives from there reach the oracle's minimum, which is its answer."""
    scene, ranges = _s2_scene()
    observed = np.ones(ranges.shape, bool)
    oracle = refine_unfolding(scene.mics, scene.sources, ranges, observed)
    oracle_ssr = float(np.sum(oracle.residuals**2))
    monkeypatch.setattr(
        "rangeslam.mdu.calibration.judged_outcome", lambda outcome, problem, rng: (outcome, None)
    )
    wrong = calibrate(ranges, noise_std=SIGMA, rng=0)
    assert _ssr(wrong.receivers, wrong.sources, ranges) > 1.5 * oracle_ssr
    monkeypatch.undo()
    problem = parse_calibration(
        ranges, None, 3, SIGMA, True, False, 100, ConvexIterationOptions(8, 10.0, 50, 1e-6, "cheap")
    )
    answer = np.vstack([wrong.receivers, wrong.sources])
    judged = judge_calibration(problem, answer, SIGMA, np.random.default_rng(0))
    assert judged.judgement.answer.deviance * SIGMA**2 == pytest.approx(oracle_ssr, rel=1e-6)


def test_a_lower_minimum_far_away_that_fits_as_well_is_not_converged():
    """Fig. 3 at 1 mm (bench fig3, seed 0, trial 43): a random start of the agreement check
    ends 0.45 noise variances below the search's answer with the microphones 1.39 m away; it
    replaced the answer and the result said CONVERGED 1.39 m off (bound 2.4 cm). Replaced or
    not, the answer is now either right or not converged."""
    from rangeslam.app.benchmarking import plan
    from rangeslam.app.experiments import calibration_experiment

    trial = plan("fig3", 50, 0, sigmas=(1e-3,))[43]
    e = calibration_experiment(1e-3, trial.rng())
    assert not e.result.converged or e.mic_error <= 3 * e.mic_crlb, e.result.message
