"""Range-aided SLAM without the reference: each robot's first pose placed from the data
(rangeslam.rangeaided.placement), the one judge of alternative answers on the GTSAM graph
(rangeslam.rangeaided.rivals), and the checks the verdict lists. Problems built here, noise from
the seeded ``rng`` fixture (``--seed``)."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from rangeslam.geometry.alignment import align
from rangeslam.rangeaided import RangeAidedProblem, RangeMeasurements, RelativePoses
from rangeslam.rangeaided.gtsam_solve import solve_gtsam
from rangeslam.rangeaided.placement import place_robots
from rangeslam.rangeaided.poses import positions, relative
from rangeslam.status import Status

pytest.importorskip("gtsam")

ODO_SIGMA, HEADING_SIGMA, RANGE_SIGMA = 0.03, 0.01, 0.1
CHECKS = ["solver", "robots placed", "identifiable", "rival minima", "range outliers",
          "range chi-square", "odometry chi-square", "search complete"]  # fmt: skip


def _walk(rng, n: int, start: np.ndarray) -> np.ndarray:
    """(n, 3) poses of a wandering 2-D walk from ``start`` (steps 0.3-0.5 m, turns of 0.25 rad)."""
    steps = np.column_stack([rng.uniform(0.3, 0.5, n - 1), np.zeros(n - 1),
                             rng.normal(0.0, 0.25, n - 1)])  # fmt: skip
    out = [start]
    for s in steps:
        x, y, t = out[-1]
        out.append(np.array([x + s[0] * np.cos(t), y + s[0] * np.sin(t), t + s[2]]))
    return np.array(out)


def two_robots(rng, *, n: int = 50, shared: bool = True, n_ranges: int = 90) -> RangeAidedProblem:
    """Robots A and B wandering 4 m apart, 3 landmarks; ranges pose-landmark (both robots) and
    between them (``shared``: else B ranges to nothing A sees), odometry and ranges with noise
    at the stated sigmas; the reference is the truth."""
    b0 = np.array([rng.uniform(2, 5), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)])
    truth = np.vstack([_walk(rng, n, np.zeros(3)), _walk(rng, n, b0)])
    marks = rng.uniform(-3, 8, (3, 2))
    a = np.r_[np.arange(n - 1), n + np.arange(n - 1)]
    sd = np.array([ODO_SIGMA, ODO_SIGMA, HEADING_SIGMA])
    steps = relative(truth[a], truth[a + 1]) + rng.normal(size=(len(a), 3)) * sd
    pose = rng.integers(0, 2 * n, n_ranges)
    to_mark = np.arange(n_ranges) % 3 != 0
    other = np.where(to_mark, rng.integers(0, 3, n_ranges), (pose + n) % (2 * n))
    if not shared:  # B's ranges dropped: nothing ties it to A
        keep = pose < n
        keep &= to_mark | (other < n)
        pose, other, to_mark = pose[keep], other[keep], to_mark[keep]
    pos = positions(truth)
    ends = np.where(to_mark[:, None], marks[np.where(to_mark, other, 0)],
                    pos[np.where(to_mark, 0, other)])  # fmt: skip
    dist = np.linalg.norm(pos[pose] - ends, axis=1) + rng.normal(0, RANGE_SIGMA, len(pose))
    m = len(pose)
    return RangeAidedProblem(
        dim=2, robots=("A", "B"), pose_robot=np.repeat([0, 1], n),
        pose_index=np.tile(np.arange(n), 2), pose_time=np.tile(np.arange(n, dtype=float), 2),
        landmark_ids=np.arange(3),
        odometry=RelativePoses(a, a + 1, steps, np.broadcast_to(np.diag(sd**2), (len(a), 3, 3)),
                               np.zeros(len(a))),
        ranges=RangeMeasurements(pose, other, to_mark, np.abs(dist), np.full(m, RANGE_SIGMA**2),
                                 np.zeros(m)),
        truth_poses=truth, truth_landmarks=marks,
    )  # fmt: skip


def _without_truth(p: RangeAidedProblem, **changes) -> RangeAidedProblem:
    kw = {f.name: getattr(p, f.name) for f in fields(p)}
    kw.update({"truth_poses": None, "truth_landmarks": None, **changes})
    return RangeAidedProblem(**kw)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_first_poses_recovered_from_the_ranges(rng, seed):
    """Two robots, no reference given to the solver: B's first pose relative to A's is found
    from the ranges, the answer CONVERGED and the same as GTSAM started at the truth (0.1 mm),
    B's first pose within 0.4 m and 0.2 rad of the truth (sigmas: ranges 0.1 m, a step 3 cm and
    0.01 rad; about 30 ranges on B: measured errors 0.03-0.31 m, 0.015-0.15 rad), every pose
    within 0.6 m of the truth after one rigid alignment (as the APE)."""
    p = two_robots(np.random.default_rng([seed, int(rng.integers(1 << 30))]))
    res = solve_gtsam(_without_truth(p))
    assert res.status is Status.CONVERGED, res.message
    from_truth = solve_gtsam(p, start=(p.truth_poses, p.truth_landmarks))
    np.testing.assert_allclose(res.poses, from_truth.poses, atol=1e-4)  # LM stops at 1e-6 rel.
    rows = [0, p.robot_rows(1)[0]]
    est = relative(res.poses[rows[0]], res.poses[rows[1]])[0]
    true = relative(p.truth_poses[rows[0]], p.truth_poses[rows[1]])[0]
    assert np.linalg.norm(est[:2] - true[:2]) < 0.4, (est, true)
    assert abs(np.angle(np.exp(1j * (est[2] - true[2])))) < 0.2
    np.testing.assert_allclose(res.poses[0], np.zeros(3), atol=1e-5)  # the gauge: A at origin
    fit = align(positions(res.poses), positions(p.truth_poses))
    assert np.max(fit.errors) < 0.6
    assert "B: placed from" in res.placement and "A: first pose at the origin" in res.placement


def test_robot_sharing_no_range_is_not_identifiable(rng):
    """Robot B with no range to A or to a landmark A locates: not placed (left at the origin),
    NOT_IDENTIFIABLE with the reason, the "robots placed" check failed; never the truth."""
    p = two_robots(rng, shared=False)
    placement = place_robots(p)
    assert list(placement.placed) == [True, False]
    res = solve_gtsam(p)
    assert res.status is Status.NOT_IDENTIFIABLE
    assert "robots B share no range or landmark" in res.message
    failed = [c.name for c in res.checks if not c.passed]
    assert "robots placed" in failed
    np.testing.assert_array_equal(res.first_poses[1], np.zeros(3))


def test_solver_never_reads_the_reference(rng):
    """The same problem with the reference removed, or replaced by random poses, gives the same
    estimate bit for bit (the placement, the solve and the judge do not read it)."""
    p = two_robots(rng, n=30, n_ranges=60)
    scrambled = replace(p, truth_poses=rng.normal(size=p.truth_poses.shape) * 50,
                        truth_landmarks=rng.normal(size=(3, 2)) * 50)  # fmt: skip
    runs = [solve_gtsam(q) for q in (p, _without_truth(p), scrambled)]
    for other in runs[1:]:
        np.testing.assert_array_equal(other.poses, runs[0].poses)
        np.testing.assert_array_equal(other.landmarks, runs[0].landmarks)
        assert other.status is runs[0].status and other.checks == runs[0].checks


def test_judge_checks_listed_and_given_first_poses(rng):
    """The result lists every check in order with its statistic and level; the rival check
    holds the cost gap of the nearest worse minimum against the chi-square(1) level. First
    poses a user gives are the start (robot A's the gauge), named in the placement."""
    p = two_robots(rng)
    res = solve_gtsam(p)
    assert [c.name for c in res.checks] == CHECKS
    rival = res.checks[3]
    assert rival.level == pytest.approx(10.83, abs=0.01)
    assert all(c.reason == "" for c in res.checks if c.passed and c.name != "search complete")
    assert res.alternatives >= 1 and res.judge_seconds > 0
    first = p.truth_poses[[0, p.robot_rows(1)[0]]]
    given = solve_gtsam(_without_truth(p), first_poses=first)
    assert given.placement == "A: given; B: given" and given.method.endswith("given")
    np.testing.assert_allclose(given.poses[0], first[0], atol=1e-5)


def test_heading_not_in_the_data_is_a_rival(rng):
    """Robot B ranging only from its first pose (exact ranges): its heading is not in the data.
    The placement still places it, but the judge's random starts reach other headings at the
    same cost far from the answer: the "rival minima" check fails, NOT_IDENTIFIABLE."""
    p = two_robots(rng)
    r, n = p.ranges, p.n_poses // 2
    pose = np.where(r.pose >= n, n, r.pose)
    other = np.where(~r.to_landmark & (r.other >= n), n, r.other)
    pos = positions(p.truth_poses)
    ends = np.where(r.to_landmark[:, None], p.truth_landmarks[np.where(r.to_landmark, r.other, 0)],
                    pos[np.where(r.to_landmark, 0, other)])  # fmt: skip
    dist = np.linalg.norm(pos[pose] - ends, axis=1)
    q = replace(p, ranges=RangeMeasurements(pose, other, r.to_landmark, dist, r.variance, r.time))
    res = solve_gtsam(q)
    assert res.status is Status.NOT_IDENTIFIABLE, res.message
    rival = next(c for c in res.checks if c.name == "rival minima")
    assert not rival.passed and rival.statistic <= rival.level
    assert "fits the data as well" in res.message


def test_file_priors_fix_the_gauge(rng):
    """A prior on a pose of each robot (data, as a PyFG VERTEX_SE2:PRIOR): each robot's first
    pose is its prior run back along its odometry (no search, no gauge prior), and the answer
    lies in the priors' frame, within 0.6 m of the truth without any alignment (as the
    recovery test after alignment)."""
    from rangeslam.rangeaided import PosePriors

    p = two_robots(rng)
    rows = np.array([7, p.robot_rows(1)[12]])
    cov = np.broadcast_to(np.diag([1e-4, 1e-4, 1e-6]), (2, 3, 3))
    q = _without_truth(p, pose_priors=PosePriors(rows, p.truth_poses[rows], cov, np.zeros(2)))
    placement = place_robots(q)
    assert placement.how == ("from the file's prior on A7", "from the file's prior on B12")
    res = solve_gtsam(q)
    assert res.status is Status.CONVERGED, res.message
    np.testing.assert_allclose(res.poses[rows], p.truth_poses[rows], atol=0.05)
    assert np.max(np.linalg.norm(positions(res.poses) - positions(p.truth_poses), axis=1)) < 0.6


def _answer_and_graph(p: RangeAidedProblem):
    """(graph, the answer as an Alternative) as solve_gtsam makes them, from the truth's first
    poses."""
    from rangeslam.rangeaided.gtsam_solve import build_graph
    from rangeslam.rangeaided.rivals import candidate
    from rangeslam.rangeaided.start import landmark_start, odometry_start

    poses, _ = odometry_start(p, p.truth_poses[[0, p.robot_rows(1)[0]]])
    graph, _ = build_graph(p, poses)
    return graph, candidate(p, graph, (poses, landmark_start(p, poses)), "answer", True, 200)


def test_judge_work_budget_cuts_far_runs_and_finishes_near_ones(rng):
    """The judge's Levenberg-Marquardt work is SEARCH_BUDGET times the answer's iterations. A run
    capped by what is left while still far above the answer's cost is dropped, in words; one
    capped within the cost level (here the answer's minimum, moved 1 cm) is run on to its
    minimum, its iterations counted in full."""
    from rangeslam.rangeaided.rivals import WorkBudget
    from rangeslam.verdict.thresholds import SEARCH_BUDGET

    p = two_robots(rng)
    graph, answer = _answer_and_graph(p)
    budget = WorkBudget(answer, 200)
    assert budget.total == SEARCH_BUDGET * answer.payload.iterations
    assert str(budget.total) in budget.words()
    budget.left = 1
    far = (p.truth_poses + np.array([5.0, -3.0, 2.0]), p.truth_landmarks + 4.0)
    assert budget.run(p, graph, far, "far start", True) is None
    assert budget.left <= 0 and budget.cut[0].startswith("far start: cut by the budget after 1")
    budget.left = 1
    fit = answer.payload
    near = (fit.poses + rng.normal(0, 0.01, fit.poses.shape), fit.marks)
    alt = budget.run(p, graph, near, "near start", True)
    assert alt is not None and alt.payload.iterations > 1
    assert alt.deviance == pytest.approx(answer.deviance, abs=1e-3)
    assert budget.left == 1 - alt.payload.iterations


def test_judge_search_ends_within_its_budget(rng, monkeypatch):
    """Every first run of a candidate is capped by what is left of the budget, so together they
    stay within it (a run on of a candidate within the level comes on top)."""
    import rangeslam.rangeaided.gtsam_solve as gtsam_solve
    import rangeslam.rangeaided.rivals as rivals

    runs = []
    original = rivals.candidate

    def counted(problem, graph, start, origin, counted, max_iterations):
        alt = original(problem, graph, start, origin, counted, max_iterations)
        runs.append((origin, alt.payload.iterations))
        return alt

    monkeypatch.setattr(rivals, "candidate", counted)
    monkeypatch.setattr(gtsam_solve, "candidate", counted)
    res = solve_gtsam(two_robots(rng, n=80))
    assert runs[0][0] == "the answer"
    seen, first_runs = set(), []
    for origin, iterations in runs[1:]:
        if origin not in seen:
            first_runs.append(iterations)
        seen.add(origin)
    assert len(first_runs) >= 2
    assert sum(first_runs) <= rivals.SEARCH_BUDGET * max(runs[0][1], 1)
    assert res.checks[-1].name == "search complete"
