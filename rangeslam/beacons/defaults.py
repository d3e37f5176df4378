"""Settings derived from the data: range noise, odometry noise, window length, spread.

A setting left at None in :class:`~rangeslam.beacons.options.BeaconSlamOptions` is derived here
from the data's own scales, so the same defaults serve a 3 m room and a 300 m field:

- ``range_sigma``: the ranges' own noise, from their second differences along the path
  (:func:`range_noise`).
- ``min_spread``: :data:`MIN_SPREAD_SIGMAS` range sigmas. A beacon and its mirror image across
  the line of a window's poses differ in range by about twice the poses' offset across that line,
  so a spread of a couple of sigmas tells them apart.
- ``window_length``: :data:`WINDOW_RANGES` median ranges of travel: the path then curves round
  the beacons it hears by a wide angle.
- ``odometry_sigma``: :data:`ODOMETRY_STEP_FRACTION` of the median step along and across the
  track, and :data:`ODOMETRY_HEADING_SIGMA` per step.

The constants were chosen on CMU Plaza1 (the development set) so that its settings stay what
they were: range noise 0.55 m, window 150 m, spread 1.1 m (was 1 m), odometry (0.01 m, 0.01 m,
0.002 rad); the figures in benchmarks/README.md, "Beacon defaults from the data".
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rangeslam._robust import MAD_TO_STD
from rangeslam.beacons.data import RangeOdometry, path_length
from rangeslam.beacons.options import BeaconSlamOptions, min_window_length

__all__ = [
    "MIN_SPREAD_SIGMAS",
    "ODOMETRY_HEADING_SIGMA",
    "ODOMETRY_STEP_FRACTION",
    "WINDOW_RANGES",
    "odometry_noise",
    "range_noise",
    "resolve_options",
]

#: min_spread in range sigmas (Plaza1: 2 x 0.55 m = 1.1 m, the former fixed 1 m).
MIN_SPREAD_SIGMAS = 2.0
#: window_length in median ranges (Plaza1: 3.4 x 43.9 m = 150 m, the former fixed 150 m).
WINDOW_RANGES = 3.4
#: odometry sigma along and across the track as a fraction of the median step (Plaza1: 0.05 x
#: 0.197 m = 0.01 m, the former fixed value: the size of its drift against the ground truth).
ODOMETRY_STEP_FRACTION = 0.05
#: odometry heading sigma per step [rad] (Plaza1's former fixed value).
ODOMETRY_HEADING_SIGMA = 0.002
# The smallest range noise a derivation returns, as a fraction of the median range: exact
# (simulated) ranges would otherwise give a sigma of zero.
NOISE_FLOOR = 1e-6


def range_noise(data: RangeOdometry) -> float:
    """The ranges' noise standard deviation [m], from the data alone (``data``: a RangeOdometry
    or anything with its odometry, range_pose, range_beacon and ranges).

    For three consecutive ranges to one beacon at distances s0 < s1 < s2 travelled, the middle
    one minus its linear interpolation from the outer two, r1 - ((1 - w) r0 + w r2) with
    w = (s1 - s0) / (s2 - s0), has variance sigma^2 (1 + w^2 + (1 - w)^2) plus the range's
    curvature along the path (about gap^2 / (8 distance): 1.4 cm on Plaza1 against 0.55 m of
    noise). Normalised, their robust scale (1.4826 MAD) is sigma; wrong ranges are in the MAD's
    tail. A constant or proportional range error (the calibration) is smooth and drops out.
    Fewer than three ranges to every beacon: the floor.
    """
    travelled = path_length(np.asarray(data.odometry, dtype=float))
    parts = []
    for b in np.unique(data.range_beacon):
        idx = np.flatnonzero(data.range_beacon == b)
        if len(idx) < 3:
            continue
        s, r = travelled[data.range_pose[idx]], data.ranges[idx]
        gap = s[2:] - s[:-2]
        w = np.divide(s[1:-1] - s[:-2], gap, out=np.full(len(gap), 0.5), where=gap > 0)
        e = r[1:-1] - ((1.0 - w) * r[:-2] + w * r[2:])
        parts.append(e / np.sqrt(1.0 + w**2 + (1.0 - w) ** 2))
    floor = NOISE_FLOOR * float(np.median(data.ranges))
    if not parts:
        return floor
    e = np.concatenate(parts)
    return max(floor, float(MAD_TO_STD * np.median(np.abs(e - np.median(e)))))


def odometry_noise(data: RangeOdometry) -> np.ndarray:
    """(3,) odometry sigmas per step (along [m], across [m], heading [rad]) from the median
    length of the steps that moved (:data:`ODOMETRY_STEP_FRACTION`)."""
    moved = np.abs(data.odometry[:, 0])
    moved = moved[moved > 0]
    step = float(np.median(moved)) if moved.size else NOISE_FLOOR * float(np.median(data.ranges))
    xy = ODOMETRY_STEP_FRACTION * step
    return np.array([xy, xy, ODOMETRY_HEADING_SIGMA])


def resolve_options(cfg: BeaconSlamOptions, data: RangeOdometry) -> BeaconSlamOptions:
    """``cfg`` with every setting left at None derived from ``data`` (module notes); the others
    kept. The window is at least 2 sqrt(2) min_spread and three mean steps long."""
    changes: dict = {}
    sigma = cfg.range_sigma if cfg.range_sigma is not None else range_noise(data)
    changes["range_sigma"] = sigma
    if cfg.odometry_sigma is None:
        changes["odometry_sigma"] = odometry_noise(data)
    spread = cfg.min_spread if cfg.min_spread is not None else MIN_SPREAD_SIGMAS * sigma
    changes["min_spread"] = spread
    if cfg.window_length is None:
        steps = np.abs(data.odometry[:, 0])
        shortest = max(min_window_length(spread), 3.0 * float(np.mean(steps)))
        changes["window_length"] = max(WINDOW_RANGES * float(np.median(data.ranges)), shortest)
    return replace(cfg, **changes)
