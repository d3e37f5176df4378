"""PyFG files (CORA's benchmark problems) in and out, and the RangeAidedProblem they load into.

The five files are in ../shared/data/pyfg (or $RANGESLAM_DATA/pyfg); the tests that read them
skip, naming the paths tried, when they are absent. Cite A. Papalia et al., "Certifiably Correct
Range-Aided SLAM", IEEE T-RO 2024, wherever they are used.
"""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.beacons import RangeOdometry
from rangeslam.datasets.paths import data_path
from rangeslam.datasets.pyfg import RECORDS, load_pyfg, write_pyfg
from rangeslam.errors import DataFormatError, DataNotFoundError, InvalidInputError
from rangeslam.rangeaided.poses import dead_reckoning, positions, relative

FILES = ("factor_graph_small", "plaza1", "mrclam5a", "tiers", "single_drone")


@pytest.fixture(scope="module")
def pyfg_dir():
    """The folder of the PyFG files, as the loaders find it; skip when it is absent."""
    try:
        return data_path("pyfg").resolve()
    except DataNotFoundError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def plaza1(pyfg_dir):
    return load_pyfg(pyfg_dir / "plaza1.pyfg")


def test_small_file_as_written(pyfg_dir):
    """factor_graph_small: 6 poses, 1 landmark, 5 odometry steps, 5 ranges, unit covariances;
    its odometry is exactly the relative poses of its reference (zero noise) and its ranges the
    reference distances to the file's 9 decimals."""
    p = load_pyfg(pyfg_dir / "factor_graph_small.pyfg")
    assert (p.dim, p.robots, p.n_poses, p.n_landmarks) == (2, ("A",), 6, 1)
    assert p.pose_names == ("A0", "A1", "A2", "A3", "A4", "A5")
    np.testing.assert_array_equal(p.odometry.covariance, np.broadcast_to(np.eye(3), (5, 3, 3)))
    rel = relative(p.truth_poses[p.odometry.pose_a], p.truth_poses[p.odometry.pose_b])
    np.testing.assert_allclose(rel, p.odometry.values, atol=1e-7, rtol=0)
    start = p.truth_poses[:1]
    np.testing.assert_allclose(dead_reckoning(start, p.odometry.values), p.truth_poses, atol=1e-6)
    dist = np.linalg.norm(positions(p.truth_poses)[p.ranges.pose] - p.truth_landmarks[0], axis=1)
    np.testing.assert_allclose(p.ranges.ranges, dist, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", FILES)
def test_files_load_and_round_trip_bit_for_bit(pyfg_dir, tmp_path, name):
    """Each file loads; writing it and reading it back gives the same problem, every array bit
    for bit, and writing that again gives the same text."""
    p = load_pyfg(pyfg_dir / f"{name}.pyfg")
    first = write_pyfg(p, tmp_path / "a.pyfg")
    q = load_pyfg(first)
    assert p.same_as(q)
    assert write_pyfg(q, tmp_path / "b.pyfg").read_text() == first.read_text()


def test_file_contents(pyfg_dir):
    """Counts as the README states them: robots, poses, landmarks, ranges (pose-pose between
    robots in tiers and mrclam5a), EDGE_SE2_XY observations in mrclam5a, SE(3) in the drone."""
    counts = {}
    for name in FILES[1:]:
        p = load_pyfg(pyfg_dir / f"{name}.pyfg")
        counts[name] = (p.dim, len(p.robots), p.n_poses, p.n_landmarks, len(p.ranges.ranges),
                        int(np.sum(~p.ranges.to_landmark)), len(p.landmark_observations.time))  # fmt: skip
    assert counts == {
        "plaza1": (2, 1, 9658, 4, 3326, 0, 0),
        "mrclam5a": (2, 5, 1080, 15, 316, 316, 1127),
        "tiers": (2, 4, 9768, 1, 7789, 4713, 0),
        "single_drone": (3, 1, 1754, 1, 1754, 0, 0),
    }


def test_plaza1_agrees_with_the_gtsam_wheel(plaza1):
    """The PyFG Plaza1 and the gtsam wheel's Plaza1 (rangeslam.datasets.plaza) are the same run:
    pose times, odometry (dx = distance, dy = 0, dtheta) and reference poses agree to the file's
    ~16 digits, landmark k is the wheel's surveyed beacon row k. The ranges are the wheel's
    through one affine map per beacon (CORA's calibration, scale 0.933-0.936): 3,309 of the
    3,326 are one wheel range at the same time to the same beacon, reproduced to 1e-12 m."""
    from rangeslam.datasets import plaza

    gtsam_plaza = pytest.importorskip("gtsam") and plaza("Plaza1")
    p = plaza1
    np.testing.assert_allclose(p.pose_time, gtsam_plaza.pose_time, atol=1e-10, rtol=0)
    odo = p.odometry.values
    np.testing.assert_allclose(odo[:, [0, 2]], gtsam_plaza.odometry, atol=1e-15, rtol=0)
    assert np.all(odo[:, 1] == 0)
    np.testing.assert_allclose(p.truth_poses, gtsam_plaza.truth, atol=1e-12, rtol=0)
    np.testing.assert_allclose(p.truth_landmarks, gtsam_plaza.beacons, atol=1e-12, rtol=0)
    r = p.ranges
    beacon = gtsam_plaza.beacon_ids[r.other]
    wheel = np.full(len(r.ranges), np.nan)
    for k in range(len(wheel)):
        same = (gtsam_plaza.range_beacon == beacon[k]) & (
            np.abs(gtsam_plaza.range_time - r.time[k]) < 1e-6
        )
        if np.sum(same) == 1:
            wheel[k] = gtsam_plaza.ranges[same][0]
    matched = np.isfinite(wheel)
    assert matched.sum() == 3309
    for b in range(4):
        s = matched & (r.other == b)
        design = np.column_stack([wheel[s], np.ones(s.sum())])
        coef = np.linalg.lstsq(design, r.ranges[s], rcond=None)[0]
        assert 0.93 < coef[0] < 0.94
        np.testing.assert_allclose(design @ coef, r.ranges[s], atol=1e-12, rtol=0)


@pytest.mark.parametrize(("name", "low", "high"), [("plaza1", 0.9, 1.1), ("mrclam5a", 0.9, 1.1),
                                                   ("tiers", 0.85, 1.1)])  # fmt: skip
def test_the_triangles_are_covariances(pyfg_dir, name, low, high):
    """Covariance, not information: the ranges' errors against the reference have the standard
    deviation the file's variances give (ratio measured 1.01, 1.00, 0.95), where the information
    reading would make the noise 4 to 600 times larger; the odometry's errors are smaller than
    its stated sigma, never 1/sigma."""
    p = load_pyfg(pyfg_dir / f"{name}.pyfg")
    r, pos = p.ranges, positions(p.truth_poses)
    other = np.where(
        r.to_landmark[:, None],
        p.truth_landmarks[np.where(r.to_landmark, r.other, 0)],
        pos[np.where(r.to_landmark, 0, r.other)],
    )
    err = r.ranges - np.linalg.norm(pos[r.pose] - other, axis=1)
    sigma = np.sqrt(np.median(r.variance))
    assert low < np.std(err) / sigma < high
    assert np.std(err) / (1 / sigma) < 0.3  # the information reading: 4 to 600 times too big
    o = p.odometry
    step = relative(p.truth_poses[o.pose_a], p.truth_poses[o.pose_b])[:, :2] - o.values[:, :2]
    assert np.sqrt(np.mean(step**2)) < np.sqrt(np.median(o.covariance[:, 0, 0]))


# ---------------------------------------------------------------------------------- bad input
GOOD = [
    "VERTEX_SE2 0.0 A0 0.0 0.0 0.0",
    "VERTEX_SE2 1.0 A1 1.0 0.0 0.0",
    "VERTEX_XY L0 3.0 4.0",
    "EDGE_SE2 1.0 A0 A1 1.0 0.0 0.0 0.01 0.0 0.0 0.01 0.0 0.001",
    "EDGE_RANGE 1.0 A1 L0 4.4 0.25",
]


def _file(tmp_path, lines, name="bad.pyfg"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("VERTEX_FOO 0 A2 1 2 3", r"line 6: unknown record 'VERTEX_FOO'"),
        ("EDGE_RANGE 1.0 A0 L0 4.4", "line 6: EDGE_RANGE takes 5 fields after its name; got 4"),
        ("EDGE_RANGE 1.0 A0 L0 four 0.25", "line 6: 'four' is not a number"),
        ("EDGE_RANGE 1.0 A0 L0 nan 0.25", "line 6: 'nan' is not a finite number"),
        ("EDGE_RANGE 1.0 A0 l0 4.4 0.25", "line 6: variable name 'l0' is not a capital letter"),
        ("EDGE_RANGE 1.0 A0 L01 4.4 0.25", "line 6: variable name 'L01'"),
        ("VERTEX_SE2 2.0 A1 0 0 0", "line 6: A1 is defined again .first on line 2"),
        ("VERTEX_SE2 2.0 L3 0 0 0", "line 6: L3 must name a pose"),
        ("VERTEX_XY B3 0 0", "line 6: B3 must name a landmark"),
        ("EDGE_SE2 1 A0 A7 1 0 0 1 0 0 1 0 1", "line 6: A7 must be a pose defined by a VERTEX"),
        ("EDGE_SE2 1 A0 L0 1 0 0 1 0 0 1 0 1", "line 6: L0 must be a pose defined by a VERTEX"),
        ("EDGE_SE2_XY 1 A0 A1 1 0 1 0 1", "line 6: A1 must be a landmark defined by a VERTEX"),
        ("EDGE_RANGE 1.0 A0 A9 4.4 0.25", "line 6: A9 is not defined by a VERTEX"),
        ("EDGE_RANGE 1.0 L0 L0 4.4 0.25", "line 6: a range between two landmarks"),
        ("EDGE_RANGE 1.0 A0 L0 -4.4 0.25", "line 6: a range must be >= 0"),
        ("EDGE_RANGE 1.0 A0 L0 4.4 0", "line 6: a range's variance must be > 0"),
        ("EDGE_SE2 1 A0 A1 1 0 0 1 2 0 1 0 1", "line 6: the covariance must be positive definite"),
        ("VERTEX_XYZ L5 0 0 0", "line 6: VERTEX_XYZ is a 3-D record; line 1 made the file 2-D"),
    ],
)
def test_bad_lines_are_named(tmp_path, line, match):
    """Every bad line is refused naming the file and its line number, and what is wrong."""
    with pytest.raises(DataFormatError, match=match) as info:
        load_pyfg(_file(tmp_path, [*GOOD, line]))
    assert "bad.pyfg, line 6" in str(info.value)


def test_bad_files(tmp_path):
    """No poses, not text, a directory, a missing file; a 3-D quaternion off unit norm."""
    with pytest.raises(DataFormatError, match="no pose"):
        load_pyfg(_file(tmp_path, ["VERTEX_XY L0 1 2"]))
    with pytest.raises(DataFormatError, match="no pose"):
        load_pyfg(_file(tmp_path, [""]))
    (tmp_path / "bin.pyfg").write_bytes(b"\xff\xfe\x00VERTEX")
    with pytest.raises(DataFormatError, match="not a text file"):
        load_pyfg(tmp_path / "bin.pyfg")
    with pytest.raises(DataFormatError, match="is a directory"):
        load_pyfg(tmp_path)
    with pytest.raises(DataNotFoundError, match="PyFG file"):
        load_pyfg(tmp_path / "nowhere.pyfg")
    with pytest.raises(DataFormatError, match="line 1: the quaternion must have norm 1"):
        load_pyfg(_file(tmp_path, ["VERTEX_SE3:QUAT 0 A0 0 0 0 0 0 0 0.9"]))


def test_every_record_kind_reads(tmp_path):
    """Each of the 13 record kinds (the priors and EDGE_SE3_XYZ too, which none of the five
    files has) is read and written back; a range written landmark first is turned round."""
    two = [*GOOD, "VERTEX_SE2:PRIOR 0 A0 0 0 0 1 0 0 1 0 1", "VERTEX_XY:PRIOR 0 L0 3 4 1 0 1",
           "EDGE_SE2_XY 1 A1 L0 2 4 0.5 0 0.5", "EDGE_RANGE 2 L0 A0 5 0.25"]  # fmt: skip
    cov6 = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
    three = ["VERTEX_SE3:QUAT 0 A0 0 0 0 0 0 0 1", "VERTEX_SE3:QUAT 1 A1 1 0 0 0 0 0 1",
             "VERTEX_XYZ L0 1 2 3", f"VERTEX_SE3:QUAT:PRIOR 0 A0 0 0 0 0 0 0 1 {cov6}",
             "VERTEX_XYZ:PRIOR 0 L0 1 2 3 1 0 0 1 0 1", f"EDGE_SE3:QUAT 1 A0 A1 1 0 0 0 0 0 1 {cov6}",
             "EDGE_SE3_XYZ 1 A1 L0 0 2 3 1 0 0 1 0 1", "EDGE_RANGE 1 A0 L0 3.7 0.1"]  # fmt: skip
    seen = set()
    for lines in (two, three):
        path = _file(tmp_path, lines, "all.pyfg")
        p = load_pyfg(path)
        text = write_pyfg(p, tmp_path / "out.pyfg").read_text()
        seen |= {row.split()[0] for row in text.splitlines()}
        assert load_pyfg(tmp_path / "out.pyfg").same_as(p)
    assert seen == set(RECORDS)
    p = load_pyfg(_file(tmp_path, two, "two.pyfg"))
    assert p.ranges.pose[-1] == 0 and p.ranges.to_landmark[-1] and p.ranges.other[-1] == 0


def test_write_values_and_refusals(tmp_path):
    """write_pyfg writes an estimate as the vertices' values when given one; a problem without
    reference values needs one; a non-problem is refused."""
    p = load_pyfg(_file(tmp_path, GOOD))
    est = p.truth_poses + 0.5
    q = load_pyfg(write_pyfg(p, tmp_path / "est.pyfg", poses=est))
    np.testing.assert_array_equal(q.truth_poses, est)
    bare = RangeOdometry.create([0.0, 1.0], [[1.0, 0.0]], [1], [0], [3.0]).to_problem()
    with pytest.raises(InvalidInputError, match="poses: the problem has no reference values"):
        write_pyfg(bare, tmp_path / "x.pyfg")
    with pytest.raises(InvalidInputError, match=r"poses must be finite with shape \(2, 3\)"):
        write_pyfg(bare, tmp_path / "x.pyfg", poses=np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="problem must be a RangeAidedProblem"):
        write_pyfg("A0", tmp_path / "x.pyfg")
