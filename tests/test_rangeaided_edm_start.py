"""The EDM-windows start of range-aided SLAM (rangeslam.rangeaided.edm_start) and how
solve_gtsam chooses its start: the EDM windows on a beacon log, the odometry elsewhere, each named
in the result; the refusals named. Simulated beacon logs from the seeded ``rng`` fixture."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.beacons import simulate_beacon_run
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.alignment import align
from rangeslam.rangeaided.edm_start import edm_start, edm_start_refusal
from rangeslam.rangeaided.gtsam_solve import solve_gtsam
from rangeslam.rangeaided.poses import positions
from rangeslam.status import Status

pytest.importorskip("gtsam")


def _log(rng, **noise):
    """A simulated 600-step beacon run as a RangeAidedProblem, the truth as its reference, the
    stated noise the simulation's."""
    run = simulate_beacon_run(rng, n_steps=600, **noise)
    odo = noise.get("odometry_std", (0.005, 0.002))
    problem = run.data.to_problem(truth_poses=run.poses, truth_beacons=run.beacons,
                                  odometry_sigma=(odo[0], odo[0], odo[1]),
                                  range_sigma=noise.get("range_std", 0.3))  # fmt: skip
    return problem, run


def _errors(poses, marks, problem) -> np.ndarray:
    """Position errors [m] of poses and landmarks after one rigid alignment on the truth."""
    est = np.vstack([positions(poses), marks])
    true = np.vstack([positions(problem.truth_poses), problem.truth_landmarks])
    return align(est, true, reflection=False).errors


def test_exact_log_starts_and_ends_at_the_truth(rng):
    """Noise-free odometry and ranges: the EDM windows place poses and landmarks at the truth
    (to the SDP's accuracy), and GTSAM from there reaches it exactly."""
    problem, _ = _log(rng, range_std=1e-9, odometry_std=(1e-9, 1e-9))
    start = edm_start(problem)
    assert start.poses.shape == (problem.n_poses, 3) and start.marks.shape == (4, 2)
    assert np.max(_errors(start.poses, start.marks, problem)) < 0.05
    res = solve_gtsam(problem)
    assert res.method.startswith("gtsam from the EDM windows") and res.start == "edm"
    assert np.max(_errors(res.poses, res.landmarks, problem)) < 1e-4


def test_noisy_log_edm_start_reaches_the_oracle(rng):
    """With noise, GTSAM from the EDM windows ends at the minimum GTSAM reaches from the truth
    (the oracle: the same graph started at the reference), and the judge says CONVERGED."""
    problem, _ = _log(rng)
    res = solve_gtsam(problem)
    oracle = solve_gtsam(problem, start=(problem.truth_poses, problem.truth_landmarks))
    assert res.status is Status.CONVERGED, res.message
    assert res.final_error == pytest.approx(oracle.final_error, rel=1e-6, abs=1e-6)
    gap = _errors(res.poses, res.landmarks, problem) - _errors(oracle.poses, oracle.landmarks,
                                                                problem)  # fmt: skip
    assert np.max(np.abs(gap)) < 1e-3


def _split(problem):
    """The log as two robots: the second half of the walk robot B (its odometry step from A's
    last pose dropped)."""
    from dataclasses import replace

    from rangeslam.rangeaided import RelativePoses

    n, o = problem.n_poses, problem.odometry
    half = n // 2
    keep = o.pose_a != half - 1
    robot = (np.arange(n) >= half).astype(np.int64)
    return replace(
        problem, robots=("A", "B"), pose_robot=robot,
        pose_index=np.arange(n) - half * robot,
        odometry=RelativePoses(o.pose_a[keep], o.pose_b[keep], o.values[keep],
                               o.covariance[keep], o.time[keep]),
    )  # fmt: skip


def test_start_is_chosen_and_named(rng):
    """The start "auto" takes the EDM windows on a beacon log and the odometry on what is not
    one (two robots); "odometry" is dead reckoning from the first poses; "edm" on a problem
    without that start is refused, naming why; an unknown name is refused."""
    problem, _ = _log(rng)
    by_odometry = solve_gtsam(problem, initialisation="odometry")
    assert by_odometry.method == "gtsam, first poses from the data"
    assert by_odometry.start == "odometry"
    two = _split(problem)
    assert "2 robots" in edm_start_refusal(two)
    assert solve_gtsam(two).method == "gtsam, first poses from the data"
    with pytest.raises(InvalidInputError, match=r"no EDM-windows start.*2 robots"):
        solve_gtsam(two, initialisation="edm")
    with pytest.raises(InvalidInputError, match="initialisation must be one of"):
        solve_gtsam(problem, initialisation="random")


def test_priors_refuse_the_edm_start(rng):
    """A prior fixes the frame the EDM start does not know: refused, and "auto" starts from the
    odometry placed by the prior."""
    from dataclasses import replace

    from rangeslam.rangeaided import PosePriors

    problem, _ = _log(rng)
    prior = PosePriors(np.array([0]), problem.truth_poses[:1],
                       np.diag([1e-4, 1e-4, 1e-6])[None], np.zeros(1))  # fmt: skip
    q = replace(problem, pose_priors=prior)
    assert "priors" in edm_start_refusal(q)
    with pytest.raises(InvalidInputError, match="priors"):
        edm_start(q)
    assert "EDM" not in solve_gtsam(q).method
