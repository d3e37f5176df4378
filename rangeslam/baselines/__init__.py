"""Baselines the rangeslam methods are measured against (not used by the library itself)."""

from rangeslam.baselines.ekf_range_odometry import ekf_range_odometry
from rangeslam.baselines.gtsam_range_example import gtsam_range_example
from rangeslam.baselines.linear_multilateration import linear_multilaterate
from rangeslam.baselines.odometry_only import odometry_only

__all__ = ["ekf_range_odometry", "gtsam_range_example", "linear_multilaterate", "odometry_only"]
