"""Simulated range-odometry runs: a robot looping around a plaza with radio beacons."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, as_scalar, frozen
from rangeslam.beacons.data import RangeOdometry, dead_reckoning
from rangeslam.beacons.options import positive_number
from rangeslam.errors import InvalidInputError

__all__ = ["SimulatedBeaconRun", "simulate_beacon_run"]


@dataclass(frozen=True, eq=False)
class SimulatedBeaconRun:
    """Output of :func:`simulate_beacon_run`: the data, the truth behind them (poses (N + 1, 3),
    beacons (B, 2)), which ranges are outliers (R,), and how many simulated ranges were dropped
    for being <= 0."""

    data: RangeOdometry
    poses: np.ndarray
    beacons: np.ndarray
    outliers: np.ndarray
    dropped: int


def simulate_beacon_run(
    rng: np.random.Generator,
    *,
    n_steps: int = 2000,
    step_length: float = 0.12,
    dt: float = 0.2,
    radius: float = 15.0,
    beacons: ArrayLike | None = None,
    range_scale: float = 1.0,
    range_offset: float = 0.0,
    range_std: float = 0.3,
    odometry_std: tuple[float, float] = (0.005, 0.002),
    range_rate: float = 0.4,
    outlier_fraction: float = 0.0,
    outlier_size: float = 10.0,
) -> SimulatedBeaconRun:
    """A robot looping around a plaza with radio beacons, in the Plaza data's conventions.

    The true path integrates controls (``step_length`` per step, heading change (step /
    ``radius``) plus a slow wobble) with the move-then-turn model, so odometry is exact up to the
    added noise ``odometry_std`` (distance [m], heading [rad] per step). Each pose ranges, with
    probability ``range_rate``, to one beacon drawn at random: (scale * distance + offset) plus
    N(0, range_std^2), and a fraction ``outlier_fraction`` of the ranges get + U(0.5, 1) *
    ``outlier_size`` (late arrivals, as multipath gives). Beacons default to four around the
    loop. Pose 0 is at the origin facing +x.
    """
    odo_std = _check_simulation(
        rng,
        n_steps,
        odometry_std,
        positive={"step_length": step_length, "dt": dt, "radius": radius},
        fractions={"range_rate": range_rate, "outlier_fraction": outlier_fraction},
        non_negative={"range_std": range_std, "outlier_size": outlier_size},
        real={"range_scale": range_scale, "range_offset": range_offset},
    )
    # Checked numbers as floats: a huge Python int would overflow numpy's C long below.
    step_length, dt, radius = float(step_length), float(dt), float(radius)
    range_std = float(range_std) + 0.0  # -0.0 would be a negative scale to numpy
    k = np.arange(n_steps)
    turn = step_length / radius * (1.0 + 0.8 * np.sin(2 * np.pi * k / 700.0))
    controls = np.column_stack([np.full(n_steps, step_length), turn])
    poses = dead_reckoning(controls, np.zeros(3))
    if beacons is None:
        centre = poses[:, :2].mean(axis=0)
        angles = np.array([0.3, 1.9, 3.4, 5.0])
        b = centre + 1.3 * radius * np.column_stack([np.cos(angles), np.sin(angles)])
    else:
        b = as_points(beacons, "beacons", dim=2)
    odo_noise = rng.normal(0.0, 1.0, (n_steps, 2)) * odo_std
    odometry = controls + odo_noise
    odometry[:, 0] = np.abs(odometry[:, 0])
    heard = np.flatnonzero(rng.random(n_steps + 1) < range_rate)
    which = rng.integers(0, len(b), len(heard))
    dist = np.linalg.norm(poses[heard, :2] - b[which], axis=1)
    ranges = range_scale * dist + range_offset + rng.normal(0.0, range_std, len(heard))
    outliers = rng.random(len(heard)) < outlier_fraction
    ranges[outliers] += outlier_size * rng.uniform(0.5, 1.0, int(outliers.sum()))
    keep = ranges > 0  # a negative offset can push a short range below 0: counted in dropped
    data = RangeOdometry.create(
        np.arange(n_steps + 1) * dt, odometry, heard[keep], which[keep], ranges[keep], len(b)
    )
    return SimulatedBeaconRun(
        data=data,
        poses=frozen(poses),
        beacons=frozen(b),
        outliers=frozen(outliers[keep]),
        dropped=int(np.sum(~keep)),
    )


# The largest simulated run: a few arrays of n_steps rows each (10^7 steps: about 1 GB).
MAX_SIM_STEPS = 10_000_000


def _check_simulation(
    rng, n_steps, odometry_std, *, positive: dict, fractions: dict, non_negative: dict, real: dict
) -> np.ndarray:
    """Validate :func:`simulate_beacon_run`'s arguments (the dicts map names to values, checked
    in order); returns ``odometry_std`` as (2,)."""
    if not isinstance(rng, np.random.Generator):
        raise InvalidInputError(f"rng must be a numpy Generator; got {rng!r:.80}")
    as_scalar(
        n_steps, "n_steps", low=10, high=MAX_SIM_STEPS, integer=True,
        expected=f"an integer >= 10 (at most {MAX_SIM_STEPS})",
    )  # fmt: skip
    for name, value in positive.items():
        positive_number(value, name)
    for name, value in fractions.items():
        as_scalar(value, name, low=0.0, high=1.0, expected="a fraction in [0, 1]")
    if fractions["range_rate"] == 0:
        raise InvalidInputError("range_rate must be > 0: without ranges there is nothing to map")
    odo_std = as_float_array(odometry_std, "odometry_std")
    if odo_std.shape != (2,) or not np.all(np.isfinite(odo_std)) or np.any(odo_std < 0):
        raise InvalidInputError(
            f"odometry_std must be two numbers >= 0 (distance [m], heading [rad]); got "
            f"{odometry_std!r:.80}"
        )
    for name, value in non_negative.items():
        as_scalar(value, name, low=0.0, expected="a number >= 0")
    for name, value in real.items():
        as_scalar(value, name)
    return odo_std
