"""GTSAM on range-aided SLAM problems (rangeslam.rangeaided.gtsam_solve) and `rangeslam run
FILE.pyfg`: exact recovery without noise (2-D and 3-D, one and several robots), the verdict's
branches, the TUM files evo reads and evo's APE equal to ours."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rangeslam.app.cli import main
from rangeslam.app.pyfg_run import score, tum_name
from rangeslam.datasets.paths import data_path
from rangeslam.datasets.pyfg import load_pyfg, write_pyfg
from rangeslam.errors import DataNotFoundError, InvalidInputError
from rangeslam.rangeaided import RangeAidedProblem, RangeMeasurements, RelativePoses
from rangeslam.rangeaided.gtsam_solve import gtsam_covariance, solve_gtsam
from rangeslam.rangeaided.poses import positions, relative
from rangeslam.status import Status

pytest.importorskip("gtsam")

ODO_SIGMA = 0.05
RANGE_SIGMA = 0.1


def _circle(n: int, centre, radius: float, phase: float, dim: int) -> np.ndarray:
    """(n, 3) or (n, 7) poses driving round a circle (3-D: climbing +-1 m, yawing; with +-0.3 m
    a landmark's mirror image through the nearly flat path fitted within the judge's cost level,
    a rival: NOT_IDENTIFIABLE, rightly)."""
    a = phase + np.linspace(0, 1.5 * np.pi, n)
    xy = np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])
    yaw = a + np.pi / 2
    if dim == 2:
        return np.column_stack([xy, yaw])
    z = 1.0 + 1.0 * np.sin(2 * a)
    q = np.column_stack([np.zeros((n, 2)), np.sin(yaw / 2), np.cos(yaw / 2)])
    return np.column_stack([xy, z, q])


def synthetic(rng, *, dim=2, robots=2, n=40, noise=0.0, landmarks=3) -> RangeAidedProblem:
    """Robots on circles, ranges to landmarks and between robots, odometry from the truth plus
    ``noise`` times the stated sigmas (0: exact)."""
    truth = np.vstack([_circle(n, (4.0 * r, 0.0), 3.0, r, dim) for r in range(robots)])
    marks = rng.uniform(-2, 8, (landmarks, dim))
    rows = np.arange(robots * n).reshape(robots, n)
    a = rows[:, :-1].ravel()
    steps = relative(truth[a], truth[a + 1])
    steps[:, :dim] += noise * ODO_SIGMA * rng.normal(size=(len(a), dim))
    k = 3 if dim == 2 else 6
    pose = rng.integers(0, robots * n, 60)
    to_mark = np.arange(60) % 3 != 0
    other = np.where(to_mark, rng.integers(0, landmarks, 60), (pose + n + n // 3) % (robots * n))
    pos = positions(truth)
    ends = np.where(
        to_mark[:, None], marks[np.where(to_mark, other, 0)], pos[np.where(to_mark, 0, other)]
    )
    dist = np.linalg.norm(pos[pose] - ends, axis=1) + noise * RANGE_SIGMA * rng.normal(size=60)
    return RangeAidedProblem(
        dim=dim, robots=("A", "B", "C")[:robots], pose_robot=np.repeat(np.arange(robots), n),
        pose_index=np.tile(np.arange(n), robots), pose_time=np.tile(np.arange(n, dtype=float), robots),
        landmark_ids=np.arange(landmarks),
        odometry=RelativePoses(a, a + 1, steps, np.broadcast_to(np.eye(k) * ODO_SIGMA**2, (len(a), k, k)),
                               np.zeros(len(a))),
        ranges=RangeMeasurements(pose, other, to_mark, dist, np.full(60, RANGE_SIGMA**2), np.zeros(60)),
        truth_poses=truth, truth_landmarks=marks,
    )  # fmt: skip


@pytest.mark.parametrize("dim", [2, 3])
def test_exact_recovery_from_a_perturbed_start(rng, dim):
    """Without noise, GTSAM started 0.2 m and 0.05 rad off the truth (first pose exact: the
    gauge) returns the reference poses and landmarks to 1e-6 m, CONVERGED."""
    p = synthetic(rng, dim=dim)
    poses = p.truth_poses.copy()
    poses[1:, :dim] += 0.2 * rng.standard_normal((len(poses) - 1, dim))
    if dim == 2:
        poses[1:, 2] += 0.05 * rng.standard_normal(len(poses) - 1)
    marks = p.truth_landmarks + 0.2 * rng.standard_normal(p.truth_landmarks.shape)
    res = solve_gtsam(p, start=(poses, marks))
    assert res.status is Status.CONVERGED, res.message
    np.testing.assert_allclose(positions(res.poses), positions(p.truth_poses), atol=1e-6, rtol=0)
    np.testing.assert_allclose(res.landmarks, p.truth_landmarks, atol=1e-6, rtol=0)
    assert score(p, res)["ape_max_m"] < 1e-6


def test_noisy_problem_beats_odometry_and_is_consistent(rng):
    """With noise at the stated sigmas, the odometry start converges (the chi-square tests pass)
    and its APE is below odometry alone's."""
    from rangeslam.rangeaided.gtsam_solve import dead_reckoning_result

    p = synthetic(rng, noise=1.0, n=60)
    res = solve_gtsam(p)
    assert res.converged, res.message
    assert score(p, res)["ape_rmse_m"] < score(p, dead_reckoning_result(p))["ape_rmse_m"]
    assert 0.5 < np.sqrt(res.range_chi2 / res.range_dof) < 1.5


def test_verdict_branches(rng):
    """A range 50 sigmas off is OUTLIERS; a robot tied to nothing is NOT_IDENTIFIABLE; an
    iteration limit of 1 from a bad start is SOLVER_FAILED."""
    p = synthetic(rng, noise=1.0, n=60)
    r = p.ranges
    wrong = r.ranges.copy()
    wrong[5] += 50 * RANGE_SIGMA
    bad = RangeAidedProblem(**{**_fields(p), "ranges": RangeMeasurements(
        r.pose, r.other, r.to_landmark, wrong, r.variance, r.time)})  # fmt: skip
    assert solve_gtsam(bad).status is Status.OUTLIERS
    keep = p.pose_robot[r.pose] == 0
    keep &= ~(~r.to_landmark & (p.pose_robot[np.where(r.to_landmark, 0, r.other)] == 1))
    alone = RangeAidedProblem(**{**_fields(p), "ranges": RangeMeasurements(
        r.pose[keep], r.other[keep], r.to_landmark[keep], r.ranges[keep], r.variance[keep],
        r.time[keep])})  # fmt: skip
    res = solve_gtsam(alone)
    assert res.status is Status.NOT_IDENTIFIABLE and "robots B" in res.message
    start = (p.truth_poses + 0.5, p.truth_landmarks + 3.0)
    assert solve_gtsam(p, start=start, max_iterations=1).status is Status.SOLVER_FAILED


def _fields(p):
    from dataclasses import fields

    return {f.name: getattr(p, f.name) for f in fields(p)}


def test_solver_refusals_and_covariance_order(rng):
    """A non-problem is refused; the first poses must have one row per robot; a 3-D covariance
    (translation, rotation) reaches GTSAM as (rotation, translation)."""
    with pytest.raises(InvalidInputError, match="problem must be a RangeAidedProblem"):
        solve_gtsam("plaza")
    with pytest.raises(InvalidInputError, match=r"first_poses must be finite with shape \(2, 3\)"):
        solve_gtsam(synthetic(rng), first_poses=np.zeros((1, 3)))
    cov = np.diag([1.0, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(np.diag(gtsam_covariance(cov)), [4, 5, 6, 1, 2, 3])


# ------------------------------------------------------------------------------- the command
def _evo_ape(reference, estimate) -> dict:
    """evo_ape tum reference estimate -a (rigid alignment, no scale), translation part."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from evo.core import metrics, sync

    ref = file_interface.read_tum_trajectory_file(str(reference))
    est = file_interface.read_tum_trajectory_file(str(estimate))
    ref, est = sync.associate_trajectories(ref, est)
    est.align(ref, correct_scale=False)
    metric = metrics.APE(metrics.PoseRelation.translation_part)
    metric.process_data((ref, est))
    return metric.get_all_statistics()


def test_cli_run_writes_tum_files_evo_reads(rng, tmp_path, capsys):
    """`rangeslam run two_robots.pyfg`: exit 0, run_trajectory.tum and run_trajectory_B.tum
    that evo's TUM reader reads (one row per pose, orientations unit quaternions), the
    landmarks CSV, the summary with the APE, a plot."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    p = synthetic(rng, noise=1.0, n=60)
    path = write_pyfg(p, tmp_path / "two_robots.pyfg")
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 0
    assert "CONVERGED" in capsys.readouterr().out
    for r, name in enumerate(("run_trajectory.tum", "run_trajectory_B.tum")):
        assert tum_name("run_trajectory", r) == name
        traj = file_interface.read_tum_trajectory_file(str(out / name))
        assert traj.num_poses == 60
        np.testing.assert_allclose(
            np.linalg.norm(traj.orientations_quat_wxyz, axis=1), 1, atol=1e-8
        )
    summary = json.loads((out / "run_summary.json").read_text())
    assert (
        summary["status"] == "CONVERGED" and summary["ape_rmse_m"] < summary["odometry_ape_rmse_m"]
    )
    assert (
        (out / "run_landmarks.csv").read_text().startswith("landmark,x,y,reference_x,reference_y")
    )
    assert (out / "run_trajectory.png").read_bytes()[:4] == b"\x89PNG"
    assert not (out / "run_trajectory_C.tum").exists()


def test_one_robot_ape_equals_evo(rng, tmp_path):
    """For one robot, the summary's APE is evo's on run_reference.tum and run_trajectory.tum
    (to the 1e-9 m of the TUM text)."""
    p = synthetic(rng, robots=1, noise=1.0, n=80)
    out = tmp_path / "out"
    assert main(["run", str(write_pyfg(p, tmp_path / "one.pyfg")), "--out", str(out)]) in (0, 1)
    ours = json.loads((out / "run_summary.json").read_text())
    theirs = _evo_ape(out / "run_reference.tum", out / "run_trajectory.tum")
    for name in ("mean", "median", "max", "rmse"):
        assert ours[f"ape_{name}_m"] == pytest.approx(theirs[name], rel=1e-6, abs=1e-8)


def test_cli_run_bad_pyfg_exits_2(tmp_path, capsys):
    """A bad line is named (exit 2); RIR options with a PyFG file are refused (exit 2)."""
    bad = tmp_path / "bad.pyfg"
    bad.write_text("VERTEX_SE2 0 A0 0 0 0\nEDGE_FOO 1\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "bad.pyfg, line 2: unknown record 'EDGE_FOO'" in capsys.readouterr().err
    good = tmp_path / "good.pyfg"
    good.write_text("VERTEX_SE2 0 A0 0 0 0\n")
    assert main(["run", str(good), "--fs", "16000", "--out", str(tmp_path / "o")]) == 2
    assert "--fs: for RIRs" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", ["factor_graph_small", "plaza1", "mrclam5a", "tiers", "single_drone"]
)
def test_cli_run_on_the_cora_files(tmp_path, name):
    """`rangeslam run` on each of CORA's files writes one TUM file per robot that evo reads;
    GTSAM (from the EDM windows on Plaza1, else from the first poses from the data) ends below
    odometry alone's APE (dead reckoning from the same first poses) on every file but TIERS
    (measured: Plaza1 0.255 vs 1.335 m mean, MR.CLAM 5a 0.158 vs 0.220, drone 0.509 vs 0.854).
    On TIERS the dead reckoning from the first poses the data place is 0.030 m, GTSAM on the
    file's graph 0.036 m (0.076 m from the reference's first poses): its odometry drifts less
    than the file's ranges, at their stated noise, pull (benchmarks/README.md). TIERS's judge
    takes about 10 s within its budget of work (7 minutes with a budget of draws)."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    try:
        path = data_path(f"pyfg/{name}.pyfg")
    except DataNotFoundError as exc:
        pytest.skip(str(exc))
    out = tmp_path / name
    assert main(["run", str(path), "--out", str(out)]) in (0, 1)
    summary = json.loads((out / "run_summary.json").read_text())
    problem = load_pyfg(path)
    for r in range(len(problem.robots)):
        traj = file_interface.read_tum_trajectory_file(str(out / tum_name("run_trajectory", r)))
        assert traj.num_poses == len(problem.robot_rows(r))
    if name != "tiers":
        assert summary["ape_mean_m"] <= summary["odometry_ape_mean_m"] + 1e-9


BEACON_LOG_METHODS = ("edm+gtsam", "edm+isam2", "ekf", "gtsam-example")


def test_bench_pyfg_table(rng, tmp_path, capsys):
    """`rangeslam bench pyfg`: a row per file and method; gtsam's first poses come from the data,
    the odometry baseline's and gtsam-reference-start's from the reference (named in the
    table); the beacon-log methods (edm+gtsam, edm+isam2, ekf, gtsam-example) run on a one-robot
    2-D beacon log and each says why it does not on two robots; the table, CSV and JSON are
    written."""
    from rangeslam.beacons import simulate_beacon_run

    run = simulate_beacon_run(rng, n_steps=400)
    one = run.data.to_problem(truth_poses=run.poses, truth_beacons=run.beacons)
    two = synthetic(rng, noise=1.0, n=60)
    files = [write_pyfg(one, tmp_path / "one.pyfg"), write_pyfg(two, tmp_path / "two.pyfg")]
    out = tmp_path / "bench"
    assert main(["bench", "pyfg", *map(str, files), "--out", str(out)]) == 0
    rows = json.loads((out / "pyfg_bench.json").read_text())["rows"]
    assert [(r["file"], r["method"]) for r in rows] == [
        (f, m)
        for f in ("one", "two")
        for m in ("odometry", "gtsam", "gtsam-reference-start", *BEACON_LOG_METHODS)
    ]
    by = {(r["file"], r["method"]): r for r in rows}
    for m in BEACON_LOG_METHODS:
        assert by["two", m]["status"] == "not run"
        assert "2 robots" in by["two", m]["message"]
        assert by["one", m]["status"] != "not run"
        assert np.isfinite(by["one", m]["ape_mean_m"])
    for m in ("edm+gtsam", "edm+isam2"):  # the EDM start reads the ranges: below dead reckoning
        assert by["one", m]["ape_mean_m"] < by["one", "odometry"]["ape_mean_m"], m
    assert by["two", "gtsam"]["ape_rmse_m"] < by["two", "odometry"]["ape_rmse_m"]
    table = (out / "pyfg_bench.md").read_text()
    assert "| two | gtsam | data | CONVERGED |" in table
    assert "| two | gtsam-reference-start | reference |" in table
    assert by["two", "gtsam"]["judge_seconds"] > 0


def test_baselines_take_a_range_aided_problem(rng):
    """The EKF, GTSAM's example and dead reckoning take a RangeAidedProblem that is a beacon log
    as they take its RangeOdometry (the same answer), and refuse one that is not, naming why."""
    from rangeslam.baselines import ekf_range_odometry, gtsam_range_example, odometry_only
    from rangeslam.beacons import RangeOdometry, simulate_beacon_run
    from rangeslam.errors import InvalidInputError

    run = simulate_beacon_run(rng, n_steps=300)
    problem = run.data.to_problem(truth_poses=run.poses, truth_beacons=run.beacons)
    data = RangeOdometry.from_problem(problem)
    for method in (ekf_range_odometry, gtsam_range_example, odometry_only):
        kwargs = {} if method is odometry_only else {"rng": np.random.default_rng(7)}
        a = method(problem, **kwargs)
        kwargs = {} if method is odometry_only else {"rng": np.random.default_rng(7)}
        b = method(data, **kwargs)
        np.testing.assert_array_equal(a.poses, b.poses)
        assert a.status is b.status
        with pytest.raises(InvalidInputError, match="2 robots"):
            method(synthetic(rng, n=20), **kwargs)
