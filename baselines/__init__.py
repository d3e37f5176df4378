"""Baselines the rangeslam methods are measured against (not used by the library itself)."""

from .ekf_range_odometry import ekf_range_odometry
from .gtsam_range_example import gtsam_range_example
from .linear_multilateration import linear_multilaterate
from .odometry_only import odometry_only

__all__ = ["ekf_range_odometry", "gtsam_range_example", "linear_multilaterate", "odometry_only"]
