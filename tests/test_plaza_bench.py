"""``rangeslam bench plaza`` and its evaluation (rangeslam.app.plaza_bench) on CMU Plaza1.

Data: J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with
ground truth", Journal of Field Robotics 26(9), 2009.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from rangeslam import RangeSlamError
from rangeslam.app.cli import main

pytest.importorskip("gtsam")

from rangeslam.app import plaza_bench as pb
from rangeslam.datasets import plaza


@pytest.fixture(scope="module")
def p1():
    return plaza("Plaza1")


@pytest.mark.slow
def test_bench_plaza_end_to_end(tmp_path, capsys):
    code = main(
        [
            *("bench", "plaza", "--methods", "odometry", "ekf", "--lengths", "--trials", "1"),
            *("--out", str(tmp_path), "--tum"),
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "| odometry | 1 (1) | 1.34 |" in printed  # dead reckoning, measured
    for name in ("methods.csv", "summary.json", "summary.md", ".png"):
        assert (tmp_path / f"plaza_Plaza1_{name}".replace("_.png", ".png")).exists()
    summary = json.loads((tmp_path / "plaza_Plaza1_summary.json").read_text())
    assert summary["dataset"] == "Plaza1" and "Djugash" in summary["citation"]
    assert [r["method"] for r in summary["methods"]] == ["odometry", "ekf"]
    assert summary["lengths"] == []
    tum = np.loadtxt(tmp_path / "tum" / "plaza_Plaza1_ekf.tum")
    assert tum.shape == (9658, 8)


def test_bad_method_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "plaza", "--methods", "magic"])
    assert "invalid choice" in capsys.readouterr().err


def test_evaluate_is_rigid_alignment(p1):
    """A result that is the truth moved rigidly has zero error; NaN poses are left out."""
    from rangeslam.beacons import BeaconSlamResult
    from rangeslam.status import Status

    truth = p1.truth_at(p1.pose_time)
    c, s = np.cos(0.4), np.sin(0.4)
    moved = truth @ np.array([[c, -s], [s, c]]).T + [5.0, -3.0]
    beacons = p1.beacons @ np.array([[c, -s], [s, c]]).T + [5.0, -3.0]
    poses = np.column_stack([moved, np.zeros(len(moved))])
    res = BeaconSlamResult("x", p1.pose_time, poses, beacons, None, None, Status.CONVERGED)
    ev = pb.evaluate(res, p1)
    assert np.max(ev.errors) < 1e-9 and np.max(ev.beacon_errors) < 1e-9
    poses[-10:] = np.nan
    ev = pb.evaluate(replace(res, poses=poses), p1)
    assert np.isnan(ev.errors[-10:]).all() and np.nanmax(ev.errors) < 1e-9
    # a result over other times than the data set's first poses is scored at its own times
    part = replace(
        res, pose_time=p1.pose_time[500:900], poses=np.column_stack([moved[500:900], np.zeros(400)])
    )
    assert np.max(pb.evaluate(part, p1).errors) < 1e-9


def test_lengths_rows_report_cost_and_failures(p1):
    """The first 250 poses (50 s) are the robot standing still: no window can place a beacon,
    which is reported as a failed row, not an answer."""
    rows = pb.length_rows(p1, [250, 1500], methods=("edm+gtsam",))
    assert rows[0]["poses"] == 250 and rows[0]["status"].startswith("failed: no window placed")
    ok = rows[1]
    assert ok["status"] == "ok" and ok["poses"] == 1500
    assert ok["seconds"] > 0 and ok["per_pose_ms"] > 0 and ok["mean"] < 1.5
    _, table = pb.lengths_table(rows)
    assert len(table) == 2 and table[0][-1].startswith("failed")


def test_unknown_method_and_lengths_for_baselines(p1):
    with pytest.raises(RangeSlamError, match="unknown method"):
        pb.run_method("magic", p1, np.random.default_rng(0))
    with pytest.raises(RangeSlamError, match="EDM pipelines only"):
        pb.run_method("ekf", p1, np.random.default_rng(0), n_poses=500)
