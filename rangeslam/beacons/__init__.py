"""Range-only SLAM with odometry and radio beacons (the CMU Plaza sets)."""

from __future__ import annotations

from rangeslam.beacons.slam import (
    RANGE_CALIBRATIONS,
    BeaconSlamResult,
    RangeOdometry,
    beacon_slam,
    beacon_slam_incremental,
    dead_reckoning,
    simulate_beacon_run,
)

__all__ = [
    "RANGE_CALIBRATIONS",
    "BeaconSlamResult",
    "RangeOdometry",
    "beacon_slam",
    "beacon_slam_incremental",
    "dead_reckoning",
    "simulate_beacon_run",
]
