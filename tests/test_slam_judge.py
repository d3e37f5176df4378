"""slam judged by the one judge (issue 42): every alternative (the other convex-iteration runs,
GTSAM from random starts, refits without one landmark or one window of steps, mirrors) compared
with the answer on one graph over every range (rangeslam.mdu.slam_judge)."""

import dataclasses

import numpy as np
import pytest

from rangeslam import align
from rangeslam.evaluation.verdict_cases import make_case
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu import slam
from rangeslam.mdu.core import ConvexIterationOptions
from rangeslam.mdu.planar_walk import PLANAR_CHECK
from rangeslam.mdu.slam import parse_slam
from rangeslam.mdu.slam_graph import graph_deviance, graph_fit, stacked
from rangeslam.mdu.slam_judge import (
    answer_region,
    subgraph_fit,
    trajectory_distance,
    trajectory_information,
)
from rangeslam.sim.scenes import add_range_noise, walk_in_random_room
from rangeslam.sim.trajectories import step_lengths
from rangeslam.verdict.judge import Alternative

RIGHT = 0.01  # metres: benchmarks/bench_robust_slam.py's right answer


def _walk(rng, m: int, n_wrong: int, noise_std: float = 1e-3):
    """As benchmarks/bench_robust_slam.py: a non-planar walk of M steps of 0.3 m in a random
    room, the loudspeaker and its 6 nearest images, ``noise_std`` noise, ``n_wrong`` wrong picks
    of 0.3-1 m, +-20% step bounds. Returns (trajectory, landmarks, ranges, bounds)."""
    traj, landmarks = walk_in_random_room(m, rng=rng)
    ranges = add_range_noise(range_matrix(traj, landmarks), noise_std, rng=rng)
    cells = rng.choice(ranges.size, size=n_wrong, replace=False)
    ranges.flat[cells] += rng.choice([-1, 1], size=n_wrong) * rng.uniform(0.3, 1.0, n_wrong)
    steps = step_lengths(traj)
    return traj, landmarks, ranges, (0.8 * steps, 1.2 * steps)


def _problem(ranges, bounds, noise_std, robust):
    return parse_slam(
        ranges, bounds, None, 3, True, noise_std, robust, None, "uniform", 0,
        ConvexIterationOptions(start="cheap"),
    )  # fmt: skip


def test_the_issue_walk_is_right():
    """Frozen (bench_robust_slam_judge.py seed 44340, M = 10, one wrong pick, 1 mm): before the
    judge the Cauchy kernel dropped 11 ranges (the wrong one among them) and the answer was
    CONVERGED 5.7 cm off (30 CRLBs), a minimum 339 deviance units above the right one. The refit
    without landmark 5 reaches the right basin and replaces it: converged, within 1 cm, the
    wrong pick the one range left out, and the result lists the judge's checks."""
    rng = np.random.default_rng(44340)
    traj, landmarks = walk_in_random_room(10, rng=rng)
    ranges = add_range_noise(range_matrix(traj, landmarks), 1e-3, rng=rng)
    cells = rng.choice(ranges.size, size=1, replace=False)
    ranges.flat[cells] += rng.choice([-1, 1], size=1) * rng.uniform(0.3, 1.0, 1)
    steps = step_lengths(traj)
    bounds = (0.8 * steps, 1.2 * steps)
    out = slam(ranges, step_bounds=bounds, noise_std=1e-3, robust="cauchy", rng=44340)
    assert out.converged, out.message
    assert align(out.receivers, traj, reflection=True).rmse < RIGHT
    assert out.n_outliers == 1 and out.outliers.flat[cells[0]]
    assert [c.name for c in out.checks] == [
        "rival minima",
        "search complete",
        PLANAR_CHECK,
        "verdict",
    ]
    assert out.checks[0].passed and out.judged > 10
    assert out.start != "edm"  # an alternative of the judge replaced the search's answer


def _right_or_not_converged(rng, n_walks: int, n_wrong: int) -> None:
    for _ in range(n_walks):
        traj, _, ranges, bounds = _walk(rng, 8, n_wrong)
        out = slam(ranges, step_bounds=bounds, noise_std=1e-3, robust="cauchy", rng=rng)
        error = align(out.receivers, traj, reflection=True).rmse
        assert not out.converged or error < RIGHT, (error, out.message)
        assert out.judged > 0
        plane = [PLANAR_CHECK] if out.converged else []  # a converged answer's plane is tested
        assert [c.name for c in out.checks] == [
            "rival minima",
            "search complete",
            *plane,
            "verdict",
        ]


@pytest.mark.parametrize("n_wrong", [1, 2])
def test_a_robust_walk_with_wrong_picks_is_right_or_not_converged(rng, n_wrong):
    """A fresh walk of M = 8, 1 mm, noise_std given, Cauchy, 1 or 2 wrong picks: right
    (trajectory within 1 cm, the benchmark's test) or not converged, and judged."""
    _right_or_not_converged(rng, 1, n_wrong)


@pytest.mark.slow
@pytest.mark.parametrize("n_wrong", [1, 2])
def test_robust_walks_with_wrong_picks_are_right_or_not_converged(rng, n_wrong):
    """Five more such walks per count of wrong picks (about 6 s each)."""
    _right_or_not_converged(np.random.default_rng(rng.integers(2**31)), 5, n_wrong)


def test_exact_data_recovered_exactly_and_judged(rng):
    """Exact ranges of a non-planar walk, noise_std 0, with and without a kernel: the judge
    finds no rival, the answer is converged and exact to round-off (1e-6 m)."""
    traj, landmarks = walk_in_random_room(8, rng=rng)
    steps = step_lengths(traj)
    exact = range_matrix(traj, landmarks)
    for robust in (None, "cauchy"):
        out = slam(exact, step_bounds=(0.8 * steps, 1.2 * steps), noise_std=0.0, robust=robust,
                   rng=rng)  # fmt: skip
        assert out.converged, out.message
        assert align(out.receivers, traj, reflection=True).rmse < 1e-6
        assert out.checks[0].name == "rival minima" and out.checks[0].passed


def test_a_refit_without_a_block_of_exact_data_returns_the_answer(rng):
    """subgraph_fit on exact ranges from the truth, one landmark's ranges or two steps' left
    out, on the graph of 1 mm: the points stay at the truth within a tenth of that sigma (LM's
    tolerance), the left-out ones moving with their neighbours."""
    traj, landmarks = walk_in_random_room(8, rng=rng)
    steps = step_lengths(traj)
    problem = _problem(range_matrix(traj, landmarks), (0.8 * steps, 1.2 * steps), 1e-3, None)
    truth = np.vstack([traj, landmarks])
    for block in ((slice(None), 2), (slice(3, 5), slice(None))):
        without = np.zeros_like(problem.observed)
        without[block] = True
        got = subgraph_fit(problem, truth, 1e-3, problem.observed & ~without)
        np.testing.assert_allclose(got, truth, atol=1e-4)


def test_the_deviance_is_the_kernel_cost_over_every_range(rng):
    """graph_deviance is twice GTSAM's error on the problem's graph: at the truth of a walk
    with a wrong pick it counts the wrong range through the kernel (Cauchy: c^2 log(1 +
    (r / c)^2) in noise units, about 4 times its log for a 0.3-1 m pick at 1 mm), so a
    configuration that drops right ranges is not cheaper for dropping them."""
    traj, landmarks, ranges, bounds = _walk(rng, 8, 1)
    problem = _problem(ranges, bounds, 1e-3, "cauchy")
    gaussian = dataclasses.replace(problem, robust=None)
    truth = np.vstack([traj, landmarks])
    robust_dev = graph_deviance(problem, truth, 1e-3)
    assert robust_dev == pytest.approx(2 * graph_fit(problem, truth, 1e-3, max_iterations=0).error)
    assert 20 < robust_dev < graph_deviance(gaussian, truth, 1e-3) / 100
    fit = graph_fit(problem, truth, 1e-3)
    assert graph_deviance(problem, stacked(fit), 1e-3) <= robust_dev


def test_a_planar_walk_fitted_in_3d_no_longer_converges_wrong():
    """Frozen (verdict benchmark seed 71137679, "M=10, no bounds", seed 1560209429: a planar
    walk, 1 mm): fitted in 3-D, the answer (the 3-D graph's minimum nearest the truth as well)
    was CONVERGED 2.7 cm off against a 0.73 cm bound. Refitted in its plane
    (rangeslam.mdu.planar_walk): right (1.1 cm, within 3 bounds), or not converged."""
    case = make_case("slam", "M=10, no bounds", 1560209429)
    out = slam(case.run.args[0], **case.run.keywords)
    assert not out.converged or case.judge(out)[1], out.message


@pytest.mark.parametrize(
    ("regime", "seed"), [("M=10, bounds", 1947307538), ("M=8, no bounds", 118574050)]
)
def test_minima_closer_than_the_stated_precision_are_one_answer(regime, seed):
    """Frozen false alarms (verdict benchmark seeds 84042158 and 49711082): the refits without
    one landmark reached a second minimum as cheap as the answer, outside its confidence region
    (delta^2 72-124 against 51 and 42) but 1.1-1.6 RMS standard deviations per point from it,
    both right. The judge's precision test makes them one answer: CONVERGED and right."""
    case = make_case("slam", regime, seed)
    out = slam(case.run.args[0], **case.run.keywords)
    assert out.converged, out.message
    assert case.judge(out)[1]


def test_a_minimum_within_the_precision_must_state_one():
    """Frozen (verdict benchmark seed 428255110, "M=8, no bounds", seed 506318005): the refit
    without landmark 4 is as likely as the answer (gap 1.4), outside its confidence region
    (delta^2 159 against 42) and within its precision, but the data fix the trajectory to 5.7%
    of the scene there (the truth's bound is 5.25%: not identifiable). The precision test holds
    where the truth may lie: not converged (it was CONVERGED, 8.7 cm off)."""
    case = make_case("slam", "M=8, no bounds", 506318005)
    assert not case.identifiable
    out = slam(case.run.args[0], **case.run.keywords)
    assert not out.converged, out.message


def _answer_and_region(rng):
    """A 1 mm walk's answer (GTSAM from the truth) and its :func:`answer_region`."""
    traj, landmarks, ranges, bounds = _walk(rng, 8, 0)
    problem = _problem(ranges, bounds, 1e-3, None)
    truth = np.vstack([traj, landmarks])
    points = stacked(graph_fit(problem, truth, 1e-3))
    answer = Alternative(points, graph_deviance(problem, points, 1e-3), "the answer")
    return problem, truth, answer, answer_region(problem, answer, 1e-3)


def test_points_on_the_way_in_the_answers_basin_return_to_it(rng):
    """GTSAM from the answer moved 1-3 cm at random, stopped after 1, 2, 4, ... iterations:
    every point on the way that is reached comes back to the answer when LM goes on (delta^2
    under 1e-3), and the way in is reached before its end. The answer itself is reached."""
    problem, _, answer, reached = _answer_and_region(rng)
    m = problem.ranges.shape[0]
    distance2 = trajectory_distance(trajectory_information(problem, answer.points, 1e-3), m)
    assert reached(answer.points)
    early = 0
    for spread in (0.01, 0.02, 0.03):
        pts = answer.points + spread * rng.standard_normal(answer.points.shape)
        for limit in (1, 2, 4, 8, 16, 32):
            pts = stacked(graph_fit(problem, pts, 1e-3, max_iterations=limit))
            if not reached(pts):
                continue
            early += distance2(answer, Alternative(pts, 0.0, "on the way")) > 1e-3
            back = Alternative(stacked(graph_fit(problem, pts, 1e-3)), 0.0, "back")
            assert distance2(answer, back) < 1e-3
    assert early > 0


def test_a_lower_minimum_or_a_distant_walk_is_not_reached(rng):
    """With the truth as the 'answer' (not the minimum of its noisy ranges), the minimum inside
    its region costs less than it by about the distance between them: the cost does not rise
    as the truth's information says, not its basin. A walk with one step moved 20 cm is outside
    the region; a walk turned as a whole with one landmark left behind is inside it (the
    trajectory's distance is up to a rigid motion) but costs far more than the model says."""
    problem, truth, answer, _ = _answer_and_region(rng)
    at_truth = Alternative(truth, graph_deviance(problem, truth, 1e-3), "the truth")
    assert not answer_region(problem, at_truth, 1e-3)(answer.points)
    region = answer_region(problem, answer, 1e-3)
    far = answer.points.copy()
    far[4] += [0.2, 0.0, 0.0]
    assert not region(far)
    # the walk turned as a whole by 2 degrees (no move of the trajectory to the judge), one
    # landmark left where it was: its ranges no longer fit
    turn = 2 * np.pi / 180
    c, s = np.cos(turn), np.sin(turn)
    turned = answer.points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    landmark = problem.ranges.shape[0] + 2
    turned[landmark] = answer.points[landmark]
    assert not region(turned)
