"""The library's APE against evo's (Grupp, "evo: Python package for the evaluation of odometry
and SLAM", github.com/MichaelGrupp/evo) on the TUM files the benches export.

evo is GPL-licensed: a test dependency only (``pip install -e .[test]``); the library never
imports it. Skipped when it is not installed.
"""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam.app.reports import write_tum
from rangeslam.beacons import RangeOdometry, beacon_slam, simulate_beacon_run
from rangeslam.datasets import plaza
from rangeslam.evaluation.metrics import ape, ape_statistics

pytest.importorskip("gtsam")
file_interface = pytest.importorskip("evo.tools.file_interface")
from evo.core import metrics, sync  # noqa: E402


def _evo_ape(truth_path, estimate_path) -> dict:
    """evo_ape tum truth estimate -a (rigid alignment, no scale), translation part."""
    reference = file_interface.read_tum_trajectory_file(str(truth_path))
    estimate = file_interface.read_tum_trajectory_file(str(estimate_path))
    reference, estimate = sync.associate_trajectories(reference, estimate)
    estimate.align(reference, correct_scale=False)
    metric = metrics.APE(metrics.PoseRelation.translation_part)
    metric.process_data((reference, estimate))
    return metric.get_all_statistics()


def _compare(tmp_path, times, estimate_xy, truth_xy, beacons, true_beacons):
    ours = ape_statistics(ape(estimate_xy, truth_xy, beacons, true_beacons).errors)
    write_tum(tmp_path / "truth.tum", truth_xy, times=times)
    write_tum(tmp_path / "estimate.tum", estimate_xy, times=times)
    theirs = _evo_ape(tmp_path / "truth.tum", tmp_path / "estimate.tum")
    for name in ("mean", "median", "max", "rmse"):
        assert getattr(ours, name) == pytest.approx(theirs[name], rel=1e-6, abs=1e-8), (
            name
        )  # 1e-9 m in TUM text


def test_simulated_run_ape_equals_evo(tmp_path, rng):
    run = simulate_beacon_run(rng, n_steps=1500, range_scale=1.05, range_offset=0.3)
    res = beacon_slam(run.data, start_pose=run.poses[0])
    _compare(
        tmp_path,
        run.data.pose_time,
        res.poses[:, :2],
        run.poses[:, :2],
        res.beacons,
        run.beacons,
    )


def test_plaza1_ape_equals_evo(tmp_path):
    """Plaza1's first 1500 poses, at the data set's own time stamps (ground truth interpolated to
    the pose times as the bench does)."""
    dataset = plaza("Plaza1")
    data = RangeOdometry.from_plaza(dataset).first(1500)
    res = beacon_slam(data, start_pose=dataset.truth[0])
    truth = dataset.truth_at(res.pose_time)
    _compare(tmp_path, res.pose_time, res.poses[:, :2], truth, res.beacons, dataset.beacons)


def test_a_rotated_and_shifted_copy_has_zero_ape_in_both(tmp_path, rng):
    truth = np.cumsum(rng.normal(0, 0.2, (300, 2)), axis=0)
    angle = 0.7
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    estimate = truth @ rot.T + [3.0, -2.0]
    _compare(tmp_path, np.arange(300) * 0.2, estimate, truth, np.zeros((1, 2)), np.zeros((1, 2)))
