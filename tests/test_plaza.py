"""Real data: the CMU Plaza range-only SLAM data sets shipped with GTSAM.

J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground
truth", Journal of Field Robotics 26(9), 2009. Every threshold below was measured on Plaza1
against its ground truth; Plaza2 is kept as unseen data and only checked to load.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from rangeslam import DataFormatError, InvalidInputError
from rangeslam.datasets import PLAZA_CITATION, PlazaDataset, plaza

gtsam = pytest.importorskip("gtsam")

FILES = ("Plaza1_DR.txt", "Plaza1_TD.txt", "Plaza1_.mat")


@pytest.fixture(scope="module")
def p1() -> PlazaDataset:
    return plaza("Plaza1")


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _path_length(xy: np.ndarray) -> np.ndarray:
    """Cumulative length along a path of points (rows), starting at 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


# --- what the files hold -------------------------------------------------------------------------


def test_plaza1_counts(p1):
    """9,657 odometry steps at 5 Hz over 1,933 s; 3,529 ranges from sender 2 to beacons 0, 1, 5, 6;
    ground truth has one row more than the odometry (the start pose) and shares its times."""
    assert p1.name == "Plaza1" and p1.citation == PLAZA_CITATION
    assert len(p1.odometry_time) == 9657
    span = p1.odometry_time[-1] - p1.odometry_time[0]
    assert span == pytest.approx(1933.25, abs=0.01)
    assert (len(p1.odometry_time) - 1) / span == pytest.approx(5.0, abs=0.01)
    assert np.median(np.diff(p1.odometry_time)) == pytest.approx(0.2, abs=0.001)
    assert len(p1.ranges) == 3529  # every row kept: a bad row raises, none is skipped
    assert sorted(p1.beacon_ids.tolist()) == [0, 1, 5, 6]
    assert sorted(np.unique(p1.range_beacon).tolist()) == [0, 1, 5, 6]
    assert np.bincount(p1.range_beacon).tolist() == [902, 893, 0, 0, 0, 848, 886]
    assert set(p1.range_sender.tolist()) == {2}
    assert len(p1.truth_time) == len(p1.odometry_time) + 1
    np.testing.assert_array_equal(p1.truth_time[1:], p1.odometry_time)
    assert p1.odometry_time[0] - p1.truth_time[0] == pytest.approx(0.196, abs=0.001)
    # every range and odometry time lies in the ground-truth span
    assert p1.truth_time[0] <= p1.range_time.min() and p1.range_time.max() <= p1.truth_time[-1]


def test_plaza1_ranges_sorted_none_dropped(p1):
    """The TD file goes back in time at rows 1989 and 2867 (three overlapping sorted blocks);
    ranges come out sorted by time, each with its file row, all 3,529 of them."""
    assert p1.range_time_jumps == (1989, 2867)
    assert np.all(np.diff(p1.range_time) >= 0)
    assert sorted(p1.range_row.tolist()) == list(range(1, 3530))
    raw = np.loadtxt(gtsam.findExampleDataFile("Plaza1_TD.txt"))
    row = raw[p1.range_row - 1]
    np.testing.assert_array_equal(row[:, 0], p1.range_time)
    np.testing.assert_array_equal(row[:, 2], p1.range_beacon)
    np.testing.assert_array_equal(row[:, 3], p1.ranges)


@pytest.mark.parametrize("name", ["Plaza1", "Plaza2"])
def test_shapes_and_read_only(name):
    """Every array has the documented shape and is read-only; beacons index consistently."""
    d = plaza(name)
    n, r, b, t = len(d.odometry_time), len(d.range_time), len(d.beacon_ids), len(d.truth_time)
    assert d.odometry.shape == (n, 2) and d.truth.shape == (t, 3) and d.beacons.shape == (b, 2)
    for arr in (d.range_sender, d.range_beacon, d.ranges, d.range_row):
        assert arr.shape == (r,)
    for arr in (
        d.odometry_time,
        d.odometry,
        d.range_time,
        d.range_sender,
        d.range_beacon,
        d.ranges,
        d.range_row,
        d.beacon_ids,
        d.beacons,
        d.truth_time,
        d.truth,
    ):
        assert not arr.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0
    assert d.range_beacon.dtype.kind == "i" and d.beacon_ids.dtype.kind == "i"
    np.testing.assert_array_equal(d.beacon_ids[d.range_beacon_index], d.range_beacon)
    assert {k: d.beacon_ids[v] for k, v in d.beacon_index.items()} == {
        int(k): k for k in d.beacon_ids
    }
    with pytest.raises(TypeError):
        d.beacon_index[0] = 1  # type: ignore[index]
    assert d.dead_reckoning(d.truth[0]).shape == (n + 1, 3) and d.range_bias().shape == (b,)


def test_plaza2_loads():
    """Plaza2 (unseen data: nothing is tuned on it): 4,090 steps at 10 Hz, 1,816 ranges to the
    same four beacon ids, ground truth one row longer than the odometry, time-sorted ranges."""
    d = plaza("Plaza2")
    assert len(d.odometry_time) == 4090 and len(d.ranges) == 1816 and len(d.truth_time) == 4091
    assert sorted(d.beacon_ids.tolist()) == [0, 1, 5, 6] and d.range_time_jumps == ()


def test_frame_is_plausible(p1):
    """Plaza1's ground truth starts at the origin and stays in a 46 x 64 m box; the surveyed
    beacons lie around it (within 50 m of its centre) and the ranges are 3 to 75 m."""
    np.testing.assert_array_equal(p1.truth[0, :2], [0.0, 0.0])
    lo, hi = p1.truth[:, :2].min(axis=0), p1.truth[:, :2].max(axis=0)
    assert np.all(hi - lo < [50, 70]) and np.all(hi - lo > [40, 60])
    centre = (lo + hi) / 2
    assert np.all(np.linalg.norm(p1.beacons - centre, axis=1) < 50)
    assert p1.ranges.min() > 3 and p1.ranges.max() < 75
    # the total ground-truth path agrees with the odometry's distance to 0.2 %
    assert _path_length(p1.truth[:, :2])[-1] == pytest.approx(p1.odometry[:, 0].sum(), rel=2e-3)


def test_truth_at(p1):
    """Interpolation reproduces the samples, returns (n, 2), and refuses times outside the span."""
    np.testing.assert_array_equal(p1.truth_at(p1.truth_time[:5]), p1.truth[:5, :2])
    mid = (p1.truth_time[100] + p1.truth_time[101]) / 2
    np.testing.assert_allclose(p1.truth_at(mid), [(p1.truth[100, :2] + p1.truth[101, :2]) / 2])
    assert p1.truth_at(mid).shape == (1, 2)
    with pytest.raises(InvalidInputError, match=r"ground-truth span .*times\[1\]"):
        p1.truth_at([mid, p1.truth_time[-1] + 1.0])
    with pytest.raises(InvalidInputError, match="times"):
        p1.truth_at([np.nan])
    with pytest.raises(InvalidInputError, match="1-D"):
        p1.truth_at(np.ones((2, 2)) * mid)


# --- measured facts ------------------------------------------------------------------------------


def test_range_bias_per_beacon(p1):
    """Range minus true distance, per beacon, has mean 2.600, 2.904, 2.792, 2.880 m (beacons 0, 1,
    5, 6) and all together 2.79 m: the issue's 'about +2.8 m, 2.6 to 2.9 per beacon'. The data are
    fixed, so the means are asserted to 5 mm (enough for any interpolation detail: nearest-sample
    truth moves them by under 3 mm); the band is the issue's widened by 0.1 m, about two standard
    errors of a per-beacon mean (1.3 m / sqrt(848) = 0.044 m)."""
    bias = dict(zip(p1.beacon_ids.tolist(), p1.range_bias(), strict=True))
    measured = {0: 2.600, 1: 2.904, 5: 2.792, 6: 2.880}
    for b, value in measured.items():
        assert bias[b] == pytest.approx(value, abs=0.005)
        assert 2.5 <= bias[b] <= 3.0
    assert p1.range_errors().mean() == pytest.approx(2.79, abs=0.01)


def test_range_spread_per_beacon(p1):
    """The spread (standard deviation) of range minus true distance is 1.00, 1.29, 1.27, 0.98 m for
    beacons 0, 1, 5, 6: between 0.9 and 1.35 m, narrower than the issue's '1.2 to 1.8 m'."""
    err, idx = p1.range_errors(), p1.range_beacon_index
    spread = {int(b): err[idx == i].std(ddof=1) for i, b in enumerate(p1.beacon_ids)}
    for b, value in {0: 0.998, 1: 1.286, 5: 1.267, 6: 0.984}.items():
        assert spread[b] == pytest.approx(value, abs=0.005)
        assert 0.9 < spread[b] < 1.35


def test_still_at_start(p1):
    """Ground truth stays within 1 cm of the start for the first 44 s, is at 0.24 m by 48 s and
    1.35 m by 50 s (the issue's '49 s' is when the robot is fully under way); the odometry creeps
    6 cm meanwhile (under 2 mm per second)."""
    t = p1.truth_time - p1.truth_time[0]
    moved = np.linalg.norm(p1.truth[:, :2] - p1.truth[0, :2], axis=1)
    assert moved[t <= 44].max() < 0.01
    assert np.interp(48, t, moved) == pytest.approx(0.24, abs=0.02)
    assert np.interp(50, t, moved) > 1.0
    creep = p1.odometry[p1.odometry_time - p1.truth_time[0] <= 44, 0].sum()
    assert 0.03 < creep < 0.08


def test_dead_reckoning_close_to_truth(p1):
    """From the first ground-truth pose, integrated odometry stays within 0.81 m of the truth over
    the first 10 m of path, 1.17 m over 50 m and 4.39 m over the whole 1,861 m (asserted: 1.0, 1.5
    and 6 m). Its headings equal the ground truth's modulo 2 pi: the file's heading is the
    integrated odometry heading."""
    poses = p1.dead_reckoning(p1.truth[0])
    err = np.linalg.norm(poses[:, :2] - p1.truth[:, :2], axis=1)
    along = _path_length(p1.truth[:, :2])
    assert err[along <= 10].max() < 1.0
    assert err[along <= 50].max() < 1.5
    assert err.max() < 6.0 and along[-1] == pytest.approx(1859.0, abs=1.0)
    np.testing.assert_allclose(_wrap(poses[:, 2] - p1.truth[:, 2]), 0.0, atol=1e-9)


def test_dead_reckoning_moves_then_turns(p1):
    """One step from any start pose moves d along the current heading, then turns by dtheta; on
    Plaza1's turning steps (|dtheta| > 0.03 rad, d > 0.1 m) that predicts the next ground-truth
    position with median error 4.9 mm, against 10.0 mm for turning first."""
    start = np.array([1.0, -2.0, 0.3])
    poses = p1.dead_reckoning(start)
    np.testing.assert_array_equal(poses[0], start)
    (d0, dth0), (d1, _) = p1.odometry[0], p1.odometry[1]
    np.testing.assert_allclose(poses[1], [1 + d0 * np.cos(0.3), -2 + d0 * np.sin(0.3), 0.3 + dth0])
    np.testing.assert_allclose(
        poses[2, :2], poses[1, :2] + d1 * np.array([np.cos(0.3 + dth0), np.sin(0.3 + dth0)])
    )
    # the convention against the truth, one step at a time from each ground-truth pose
    d, dth = p1.odometry[:, 0], p1.odometry[:, 1]
    turning = (np.abs(dth) > 0.03) & (d > 0.1)
    assert turning.sum() == 3498
    median = {}
    for label, heading in (("move_then_turn", p1.truth[:-1, 2]), ("turn_then_move", None)):
        heading = p1.truth[:-1, 2] + dth if heading is None else heading
        pred = p1.truth[:-1, :2] + d[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        median[label] = np.median(np.linalg.norm(pred - p1.truth[1:, :2], axis=1)[turning])
    assert median["move_then_turn"] == pytest.approx(0.0049, abs=0.0005)
    assert median["turn_then_move"] > 1.8 * median["move_then_turn"]


def test_dead_reckoning_start_pose_checked(p1):
    with pytest.raises(InvalidInputError, match="start_pose"):
        p1.dead_reckoning([0.0, 0.0])


# --- bad input -----------------------------------------------------------------------------------


def test_unknown_name():
    with pytest.raises(InvalidInputError, match="'Plaza1', 'Plaza2'; got 'Plaza3'"):
        plaza("Plaza3")


@pytest.fixture
def copy_dir(tmp_path: Path) -> Path:
    """A copy of the three Plaza1 files, to be corrupted by the test."""
    for f in FILES:
        shutil.copy(gtsam.findExampleDataFile(f), tmp_path / f)
    return tmp_path


def _edit_row(path: Path, row: int, new: str) -> None:
    """Replace the 1-based row ``row`` of a text file (CRLF line ends kept)."""
    lines = path.read_bytes().split(b"\r\n")
    lines[row - 1] = new.encode()
    path.write_bytes(b"\r\n".join(lines))


def test_copy_loads_like_the_original(copy_dir, p1):
    """The unmodified copy in data_dir loads to the same arrays (so the failures below are the
    corruption's)."""
    d = plaza("Plaza1", data_dir=copy_dir)
    np.testing.assert_array_equal(d.ranges, p1.ranges)
    np.testing.assert_array_equal(d.truth, p1.truth)


@pytest.mark.parametrize("missing", FILES)
def test_missing_file(copy_dir, missing):
    (copy_dir / missing).unlink()
    with pytest.raises(FileNotFoundError, match=missing):
        plaza("Plaza1", data_dir=str(copy_dir))


@pytest.mark.parametrize(
    ("file", "row", "new", "match"),
    [
        ("Plaza1_DR.txt", 17, "3860.3 0.2", r"Plaza1_DR.txt, row 17: expected 3 numbers"),
        ("Plaza1_DR.txt", 17, "3860.3 0.2 x0.01", r"Plaza1_DR.txt, row 17: could not convert"),
        ("Plaza1_DR.txt", 17, "3860.3 nan 0.01", r"Plaza1_DR.txt, row 17: distance must be finite"),
        ("Plaza1_DR.txt", 17, "3860.3 0.2 inf", r"Plaza1_DR.txt, row 17: heading change must be"),
        ("Plaza1_DR.txt", 17, "3850.0 0.2 0.01", r"Plaza1_DR.txt, row 17: time must increase"),
        ("Plaza1_DR.txt", 17, "3860.3 -0.2 0.01", r"Plaza1_DR.txt, row 17: distance travelled"),
        ("Plaza1_TD.txt", 5, "3859.0 2 7 50.0", r"Plaza1_TD.txt, row 5: beacon id 7 is not among"),
        ("Plaza1_TD.txt", 5, "3859.0 2 1.5 50.0", r"Plaza1_TD.txt, row 5: beacon id must be an"),
        ("Plaza1_TD.txt", 5, "3859.0 2 1 -50.0", r"Plaza1_TD.txt, row 5: range must be > 0"),
        ("Plaza1_TD.txt", 5, "3859.0 2 1 nan", r"Plaza1_TD.txt, row 5: range must be finite"),
        ("Plaza1_TD.txt", 5, "3859.0 2 1", r"Plaza1_TD.txt, row 5: expected 4 numbers"),
        ("Plaza1_TD.txt", 5, "", r"Plaza1_TD.txt, row 5: expected 4 numbers .*got 0"),
    ],
)
def test_bad_row(copy_dir, file, row, new, match):
    """A malformed, truncated, non-finite, out-of-order or unknown-beacon row is refused with the
    file and its 1-based row in the message (DataFormatError is an InvalidInputError)."""
    _edit_row(copy_dir / file, row, new)
    with pytest.raises(InvalidInputError, match=match) as info:
        plaza("Plaza1", data_dir=copy_dir)
    assert isinstance(info.value, DataFormatError)


def test_truncated_text_file(copy_dir):
    """A file cut in the middle of its last row: that row is reported as short."""
    path = copy_dir / "Plaza1_DR.txt"
    data = path.read_bytes()
    last = data.rstrip(b"\r\n").rsplit(b"\r\n", 1)[1]
    start = len(data) - len(b"\r\n") - len(last)
    path.write_bytes(data[: start + 30] + b"\r\n")  # first number, a tab, start of the second
    with pytest.raises(DataFormatError, match=r"Plaza1_DR.txt, row 9657: expected 3 numbers"):
        plaza("Plaza1", data_dir=copy_dir)


@pytest.mark.parametrize("name", ["Plaza1_DR.txt", "Plaza1_TD.txt"])
def test_file_cut_inside_its_last_number(copy_dir, name):
    """Cut inside the last number's exponent (4.6e-005 -> 4.6e-00 still parses): refused
    because the last row has no line end."""
    path = copy_dir / name
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(DataFormatError, match=name + r", row \d+: the last row has no line end"):
        plaza("Plaza1", data_dir=copy_dir)


def test_out_of_order_ranges_are_sorted_not_refused(copy_dir):
    """Time going back in the TD file is what Plaza1 itself does: the rows are kept and sorted,
    and the jump is reported."""
    _edit_row(copy_dir / "Plaza1_TD.txt", 5, "3858.0 2 1 50.0")
    d = plaza("Plaza1", data_dir=copy_dir)
    assert d.range_time_jumps == (5, 1989, 2867) and len(d.ranges) == 3529
    assert d.range_row[0] == 5 and d.range_time[0] == 3858.0


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ("drop_gt", r"Plaza1_.mat: variable 'GT' .* is missing"),
        ("gt_back", r"Plaza1_.mat, row 11: GT time must increase"),
        ("gt_nan", r"Plaza1_.mat: GT row 4, column 3 must be finite"),
        ("tl_shape", r"Plaza1_.mat: TL must have shape \(\*, 3\)"),
        ("tl_dup", r"Plaza1_.mat: TL ids must be distinct integers"),
        ("truncate", r"Plaza1_.mat"),
    ],
)
def test_bad_mat(copy_dir, change, match):
    """Missing or malformed ground truth and beacons, and a truncated file, are refused."""
    path = copy_dir / "Plaza1_.mat"
    if change == "truncate":
        path.write_bytes(path.read_bytes()[:100])
    else:
        mat = scipy.io.loadmat(path, variable_names=["GT", "TL"])
        gt, tl = mat["GT"].copy(), mat["TL"].copy()
        if change == "gt_back":
            gt[10, 0] = gt[9, 0] - 1.0
        elif change == "gt_nan":
            gt[3, 2] = np.nan
        elif change == "tl_shape":
            tl = tl[:, :2]
        elif change == "tl_dup":
            tl[1, 0] = tl[0, 0]
        variables = {"TL": tl} if change == "drop_gt" else {"GT": gt, "TL": tl}
        scipy.io.savemat(path, variables)
    with pytest.raises(DataFormatError, match=match):
        plaza("Plaza1", data_dir=copy_dir)
