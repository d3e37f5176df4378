"""The CMU Plaza rangeslam.baselines: odometry alone, GTSAM's RangeISAMExample_plaza2 port and a range-only
EKF (rangeslam.baselines.odometry_only, rangeslam.baselines.gtsam_range_example, rangeslam.baselines.ekf_range_odometry).

Data: J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with
ground truth", Journal of Field Robotics 26(9), 2009. Every Plaza1 bound below was measured (the
figure is in the comment) and is asserted with a margin; errors are position errors after the
rigid alignment (rangeslam.align) of the estimated x, y onto the ground truth at the pose times.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rangeslam import InvalidInputError, align
from rangeslam.baselines.ekf_range_odometry import ekf_range_odometry
from rangeslam.baselines.gtsam_range_example import gtsam_range_example
from rangeslam.baselines.odometry_only import odometry_only
from rangeslam.beacons import BeaconSlamResult
from rangeslam.datasets import PlazaDataset, plaza
from rangeslam.status import Status

pytest.importorskip("gtsam")  # the Plaza files ship with GTSAM's wheel

# The GTSAM example's beacon starts are random and its answer falls in one of two basins: of
# default_rng(s), s = 0..13, ten seeds gave 1.08 m mean error and four (0, 2, 3, 13) a wrong
# local minimum at 19.7 m. The accuracy test pins a seed of the good basin.
GTSAM_SEED = 1


@pytest.fixture(scope="module")
def p1() -> PlazaDataset:
    return plaza("Plaza1")


@pytest.fixture(scope="module")
def gtsam_p1(p1) -> BeaconSlamResult:
    return gtsam_range_example(p1, rng=np.random.default_rng(GTSAM_SEED))


@pytest.fixture(scope="module")
def ekf_p1(p1) -> BeaconSlamResult:
    return ekf_range_odometry(p1, rng=np.random.default_rng(0))


def _errors(res: BeaconSlamResult, data: PlazaDataset):
    """Position errors (N + 1,) and beacon errors (B,) after aligning the poses to the truth."""
    a = align(res.poses[:, :2], data.truth_at(data.pose_time))
    return a.errors, np.linalg.norm(a.apply(res.beacons) - data.beacons, axis=1)


def _check_shapes(res: BeaconSlamResult, data: PlazaDataset, method: str) -> None:
    n, b, r = len(data.pose_time), len(data.beacon_ids), len(data.ranges)
    assert isinstance(res, BeaconSlamResult)
    assert res.method == method
    np.testing.assert_array_equal(res.pose_time, data.pose_time)
    assert res.poses.shape == (n, 3) and res.beacons.shape == (b, 2)
    for cal in (res.range_bias, res.range_scale):
        if isinstance(cal, np.ndarray):  # one per beacon; a shared calibration is a float
            assert cal.shape == (b,) and not cal.flags.writeable
        else:
            assert cal is None or isinstance(cal, float)
    if res.range_inlier is not None:
        assert res.range_inlier.shape == (r,) and res.range_inlier.dtype == bool
    assert not res.poses.flags.writeable and not res.beacons.flags.writeable


def _head(data: PlazaDataset, n_steps: int) -> PlazaDataset:
    """The first n_steps odometry steps of data and the ranges up to the last one's time."""
    keep = data.range_time <= data.odometry_time[n_steps - 1]
    return replace(
        data,
        odometry_time=data.odometry_time[:n_steps],
        odometry=data.odometry[:n_steps],
        range_time=data.range_time[keep],
        range_sender=data.range_sender[keep],
        range_beacon=data.range_beacon[keep],
        ranges=data.ranges[keep],
        range_row=data.range_row[keep],
        truth_time=data.truth_time[: n_steps + 1],
        truth=data.truth[: n_steps + 1],
    )


# --- a simulated data set where the EKF's model holds -------------------------------------------

SIM_BEACONS = np.array([[4.0, 6.0], [16.0, 15.0], [12.0, -4.0], [-3.0, 18.0]])
SIM_SCALE = 1.05  # measured range = SIM_SCALE * distance + offset (shared by the beacons) ...
SIM_OFFSET = 1.0
SIM_BIAS = np.array([0.5, 1.0, 2.0, 3.0])  # ... or distance + SIM_BIAS[beacon] (scale 1)
SIM_RANGE_SD = 0.2
SIM_ODO_SD = (0.005, 0.002)


def _simulated(
    rng: np.random.Generator,
    *,
    scale: float = SIM_SCALE,
    bias: np.ndarray | float = SIM_OFFSET,
    outlier_every: int = 40,
) -> PlazaDataset:
    """Two laps of a 20 m rounded square at 0.5 m/s (5 Hz: 0.1 m steps, 90 degree turns over 10
    steps; 1,680 steps), odometry with N(0, 5 mm) and N(0, 2 mrad) noise per step, a range every
    second step to the beacons in turn (210 each) equal to scale * distance + bias (bias: one
    value or one per beacon) plus N(0, 0.2 m) noise, and every ``outlier_every``-th range from
    the 8th on 10 m too long. The ranges span 2.4-29.5 m of distance."""
    lap = [(0.1, 0.0)] * 200 + [(0.1, np.pi / 20)] * 10
    u = np.array(lap * 8)
    n = len(u)
    pose = np.zeros((n + 1, 3))
    for k in range(n):  # move, then turn
        x, y, th = pose[k]
        pose[k + 1] = x + u[k, 0] * np.cos(th), y + u[k, 0] * np.sin(th), th + u[k, 1]
    t = 100.0 + 0.2 * np.arange(n + 1)
    odo = u + rng.standard_normal((n, 2)) * SIM_ODO_SD
    odo[:, 0] = np.abs(odo[:, 0])
    k = np.arange(1, n + 1, 2)  # ranges at pose times: each joins that pose
    b = np.arange(len(k)) % len(SIM_BEACONS)
    dist = np.linalg.norm(pose[k, :2] - SIM_BEACONS[b], axis=1)
    ranges = scale * dist + np.broadcast_to(bias, len(SIM_BEACONS))[b]
    ranges += SIM_RANGE_SD * rng.standard_normal(len(k))
    ranges[7::outlier_every] += 10.0
    ids = np.array([3, 7, 8, 9])
    return PlazaDataset(
        name="simulated",
        odometry_time=t[1:],
        odometry=odo,
        range_time=t[k],
        range_sender=np.full(len(k), 2),
        range_beacon=ids[b],
        ranges=ranges,
        range_row=np.arange(1, len(k) + 1),
        range_time_jumps=(),
        beacon_ids=ids,
        beacons=SIM_BEACONS.copy(),
        truth_time=t,
        truth=pose,
    )


# --- odometry alone -------------------------------------------------------------------------------


def test_odometry_only_is_dead_reckoning(p1):
    """Dead reckoning from truth[0] (or a given start); no beacons, no ranges used. Plaza1:
    1.34 m mean, 1.30 m median, 4.33 m max after alignment (the odometry is good)."""
    res = odometry_only(p1)
    _check_shapes(res, p1, "odometry")
    np.testing.assert_array_equal(res.poses, p1.dead_reckoning(p1.truth[0]))
    assert np.all(np.isnan(res.beacons))
    assert res.range_bias is None and res.range_inlier is None and res.converged
    err = align(res.poses[:, :2], p1.truth_at(p1.pose_time)).errors
    assert 1.2 < err.mean() < 1.5 and err.max() < 5.0
    start = [1.0, -2.0, 0.5]
    np.testing.assert_array_equal(
        odometry_only(p1, start_pose=start).poses, p1.dead_reckoning(start)
    )


# --- GTSAM's example ------------------------------------------------------------------------------


def test_gtsam_example_plaza1(p1, gtsam_p1):
    """GTSAM_SEED's basin: 1.08 m mean, 1.00 m median, 3.05 m max; beacons 2.7-3.1 m off (the
    ranges' +2.8 m mean bias is not modelled); every range keeps a Tukey weight > 0 (sigma
    100 m, c = 15: a residual would need 1.5 km to lose it)."""
    res = gtsam_p1
    _check_shapes(res, p1, "gtsam example")
    assert res.converged, res.message
    assert res.range_bias is None
    assert res.range_inlier.all()
    assert np.all(np.isfinite(res.poses)) and np.all(np.isfinite(res.beacons))
    err, beacon_err = _errors(res, p1)
    assert err.mean() < 1.5 and np.median(err) < 1.5 and err.max() < 4.5
    assert np.all(beacon_err < 4.0)
    np.testing.assert_allclose(res.poses[0], p1.truth[0], atol=1e-9)  # only the prior holds it
    assert np.all(np.abs(np.diff(res.poses[:, 2])) < np.pi)  # headings unwrapped


@pytest.mark.slow
def test_gtsam_example_wrong_basin_is_inconsistent(p1, gtsam_p1):
    """Seed 0's start falls in the wrong basin (19.7 m mean error): the studentised tail of its
    range residuals (7.7 robust standard deviations against a limit of 5.3) says INCONSISTENT,
    without the truth; GTSAM_SEED's basin (1.08 m) stays converged (largest about 3.5). On
    default_rng(s), s = 0..29: 23 right (all CONVERGED), 7 wrong (all INCONSISTENT)."""
    wrong = gtsam_range_example(p1, rng=np.random.default_rng(0))
    assert wrong.status is Status.INCONSISTENT, wrong.message
    assert "heavy tail" in wrong.message
    assert _errors(wrong, p1)[0].mean() > 10.0  # the basin this test is about
    assert gtsam_p1.status is Status.CONVERGED, gtsam_p1.message


@pytest.mark.slow
def test_gtsam_example_is_deterministic(p1, gtsam_p1):
    """The same rng seed gives the same answer, bit for bit."""
    again = gtsam_range_example(p1, rng=np.random.default_rng(GTSAM_SEED))
    np.testing.assert_array_equal(again.poses, gtsam_p1.poses)
    np.testing.assert_array_equal(again.beacons, gtsam_p1.beacons)
    np.testing.assert_array_equal(again.range_inlier, gtsam_p1.range_inlier)


def test_gtsam_example_cholesky_failure_is_reported(p1):
    """The example's own Cholesky iSAM2 hits an indeterminate system on Plaza1: not converged,
    GTSAM's message kept, poses after the last estimate NaN, no range counted as an inlier."""
    res = gtsam_range_example(p1, rng=np.random.default_rng(GTSAM_SEED), factorization="CHOLESKY")
    _check_shapes(res, p1, "gtsam example")
    assert not res.converged and res.status is Status.SOLVER_FAILED
    assert "Indeterminate" in res.message
    assert np.isnan(res.poses[-1]).all()
    assert not res.range_inlier.any()


def test_gtsam_example_gaussian_and_short(p1, rng):
    """robust=False (Gaussian ranges) on the first 1,500 steps: converges, every range an
    inlier, and the flush after the loop puts every pose into the estimate."""
    short = _head(p1, 1500)
    res = gtsam_range_example(short, rng=rng, robust=False)
    _check_shapes(res, short, "gtsam example")
    assert res.converged, res.message
    assert res.range_inlier.all() and np.all(np.isfinite(res.poses))


# --- the EKF --------------------------------------------------------------------------------------


def _truth_scale(data: PlazaDataset) -> float:
    """The range scale against the ground truth: slope of the least-squares line (with intercept,
    as the EKF's default "affine" model) of range on true distance, all beacons together.
    Plaza1: 1.0694 (intercept 0.03 m; through the origin 1.0701)."""
    robot = data.truth_at(data.range_time)
    dist = np.linalg.norm(robot - data.beacons[data.range_beacon_index], axis=1)
    design = np.column_stack([dist, np.ones_like(dist)])
    (slope, _), *_ = np.linalg.lstsq(design, data.ranges, rcond=None)
    return float(slope)


def test_ekf_plaza1(p1, ekf_p1):
    """Defaults (one affine calibration shared by the beacons): 0.29 m mean, 0.21 m median,
    1.59 m max; all four beacons initialised, 0.21-0.39 m off; scale 1.0641 against 1.0694 fitted
    to the truth, offset -0.06 m; all 3,529 ranges used. Under a second."""
    res = ekf_p1
    _check_shapes(res, p1, "ekf")
    assert res.converged, res.message
    assert np.all(np.isfinite(res.poses)) and np.all(np.isfinite(res.beacons))
    np.testing.assert_array_equal(res.poses[0], p1.truth[0])
    err, beacon_err = _errors(res, p1)
    assert err.mean() < 0.45 and np.median(err) < 0.4 and err.max() < 2.5
    assert np.all(beacon_err < 0.7)
    assert res.range_inlier.mean() > 0.98
    # one shared (s, b): scalars, not one value repeated per beacon (issue 43)
    assert isinstance(res.range_scale, float) and isinstance(res.range_bias, float)
    assert _truth_scale(p1) == pytest.approx(1.069, abs=0.002)
    assert res.range_scale == pytest.approx(_truth_scale(p1), abs=0.02)
    assert abs(res.range_bias) < 0.5


def test_plaza1_range_error_is_a_scale_not_an_offset(p1):
    """Why a constant bias per beacon is the wrong model on Plaza1 (with it the EKF's biases are
    1.4, -4.9, -2.0, 1.7 m, far from data.range_bias()'s 2.6-2.9 m): range minus true distance is
    0.07 x distance (intercepts -0.02 to 0.10 m, residual SD 0.53-0.56 m against 1.0-1.3 m about the
    mean), so a constant per beacon trades off against the beacon's distance."""
    robot = p1.truth_at(p1.range_time)
    idx = p1.range_beacon_index
    dist = np.linalg.norm(robot - p1.beacons[idx], axis=1)
    err = p1.range_errors()
    for j in range(len(p1.beacon_ids)):
        m = idx == j
        design = np.column_stack([np.ones(m.sum()), dist[m]])
        (offset, slope), *_ = np.linalg.lstsq(design, err[m], rcond=None)
        assert abs(offset) < 0.3 and 0.06 < slope < 0.08
        assert np.std(err[m] - design @ [offset, slope]) < 0.7


def test_ekf_plaza1_per_beacon_offsets(p1):
    """range_calibration="offset", per_beacon=True (a constant bias per beacon, the model this
    baseline had before): 1.31 m mean, 4.41 m max, no better than odometry alone (1.34 m);
    beacons 1.2-7.9 m off; no scale estimated."""
    res = ekf_range_odometry(
        p1, range_calibration="offset", per_beacon=True, rng=np.random.default_rng(0)
    )
    _check_shapes(res, p1, "ekf")
    assert res.converged and res.range_scale is None
    assert np.all(np.isfinite(res.range_bias)) and np.ptp(res.range_bias) > 3.0
    err, beacon_err = _errors(res, p1)
    assert err.mean() < 1.8 and err.max() < 6.0 and np.all(beacon_err < 12.0)


def test_ekf_plaza1_uncalibrated(p1):
    """range_calibration=None: no calibration states, range_scale and range_bias None; 1.12 m
    mean, 2.47 m max; beacons 2.4-2.9 m off (pushed out by the unmodelled 7 % scale)."""
    res = ekf_range_odometry(p1, range_calibration=None, rng=np.random.default_rng(0))
    _check_shapes(res, p1, "ekf")
    assert res.converged and res.range_bias is None and res.range_scale is None
    err, beacon_err = _errors(res, p1)
    assert err.mean() < 1.5 and err.max() < 4.0 and np.all(beacon_err < 4.0)


def _outliers(data: PlazaDataset) -> np.ndarray:
    outlier = np.zeros(len(data.ranges), dtype=bool)
    outlier[7::40] = True
    return outlier


def test_ekf_simulated_recovers_scale_and_offset(rng):
    """Defaults on simulated ranges 1.05 x distance + 1.0 m (module helper). Over 200 seeds the
    worst figures were: scale 0.0074 and offset 0.056 m off, 0.13 m mean trajectory error,
    beacons 0.19 m off, at most 27 of 819 good ranges unused and every +10 m outlier rejected.
    With perfect poses the standard deviations would be 0.0014 (scale) and 0.017 m (offset); the
    rest comes from the pose errors and the filter's linearisation. Tolerances: about 2x those
    worsts, far below the 0.05 scale error and 1 m offset an unestimated calibration leaves."""
    data = _simulated(rng)
    res = ekf_range_odometry(data, range_sigma=SIM_RANGE_SD, odometry_sigma=SIM_ODO_SD, rng=rng)
    _check_shapes(res, data, "ekf")
    assert res.converged, res.message
    np.testing.assert_allclose(res.range_scale, SIM_SCALE, atol=0.015)
    np.testing.assert_allclose(res.range_bias, SIM_OFFSET, atol=0.12)
    a = align(res.poses[:, :2], data.truth[:, :2])
    assert a.errors.mean() < 0.25
    np.testing.assert_allclose(a.apply(res.beacons), SIM_BEACONS, atol=0.4)
    outlier = _outliers(data)
    assert not res.range_inlier[outlier].any()
    assert res.range_inlier[~outlier].mean() > 0.95


def test_ekf_simulated_recovers_per_beacon_biases(rng):
    """range_calibration="offset", per_beacon=True on ranges distance + SIM_BIAS[beacon]. Over
    200 seeds the worst figures were: 0.19 m mean trajectory error, beacons 0.34 m and biases
    0.28 m off, at most 21 of 819 good ranges unused and every +10 m outlier rejected. With
    perfect poses the bias's standard deviation would be 0.016-0.067 m; the rest comes from the
    pose errors. Tolerances: about 1.5x those worsts, and well below the 0.5 m gap between the
    biases (a swapped or unestimated bias fails)."""
    data = _simulated(rng, scale=1.0, bias=SIM_BIAS)
    res = ekf_range_odometry(
        data,
        range_sigma=SIM_RANGE_SD,
        odometry_sigma=SIM_ODO_SD,
        range_calibration="offset",
        per_beacon=True,
        rng=rng,
    )
    _check_shapes(res, data, "ekf")
    assert res.converged, res.message
    assert res.range_scale is None
    a = align(res.poses[:, :2], data.truth[:, :2])
    assert a.errors.mean() < 0.3
    np.testing.assert_allclose(a.apply(res.beacons), SIM_BEACONS, atol=0.5)
    np.testing.assert_allclose(res.range_bias, SIM_BIAS, atol=0.4)
    outlier = _outliers(data)
    assert not res.range_inlier[outlier].any()
    assert res.range_inlier[~outlier].mean() > 0.95


def test_ekf_divergence_is_reported(rng):
    """A NaN in the odometry makes the state non-finite: not converged, poses from then on NaN."""
    data = _simulated(rng)
    odo = np.array(data.odometry)
    odo[1000, 0] = np.nan
    res = ekf_range_odometry(
        replace(data, odometry=odo), range_sigma=SIM_RANGE_SD, odometry_sigma=SIM_ODO_SD, rng=rng
    )
    assert not res.converged and "diverged at pose 1001" in res.message
    assert res.status is Status.SOLVER_FAILED
    assert np.all(np.isfinite(res.poses[:1001])) and np.all(np.isnan(res.poses[1001:]))


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"start_pose": [0.0, 0.0]}, "start_pose"),
        ({"start_pose": [0.0, np.nan, 0.0]}, "start_pose"),
        ({"range_sigma": 0.0}, "range_sigma"),
        ({"range_sigma": -1.0}, "range_sigma"),
        ({"odometry_sigma": (0.05, 0.0)}, "odometry_sigma"),
        ({"odometry_sigma": (0.05,)}, "odometry_sigma"),
        ({"gate_probability": 1.0}, "gate_probability"),
        ({"init_ranges": 2}, "init_ranges"),
        ({"init_spread": np.inf}, "init_spread"),
        ({"calibration_sigma": (0.2, 0.0)}, "calibration_sigma"),
        ({"calibration_sigma": (0.2,)}, "calibration_sigma"),
        ({"range_calibration": "linear"}, "range_calibration"),
        ({"range_calibration": "Affine"}, "range_calibration"),
        ({"per_beacon": "yes"}, "per_beacon"),
        ({"n_starts": 0}, "n_starts"),
    ],
)
def test_ekf_bad_input(p1, kwargs, name):
    with pytest.raises(InvalidInputError, match=name):
        ekf_range_odometry(p1, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"start_pose": np.zeros((1, 3))}, "start_pose"),
        ({"rng": 3}, "rng"),
        ({"min_ranges": -1}, "min_ranges"),
        ({"batch_ranges": 2.5}, "batch_ranges"),
        ({"factorization": "LU"}, "factorization"),
    ],
)
def test_gtsam_example_bad_input(p1, kwargs, name):
    kwargs = {"rng": np.random.default_rng(0), **kwargs}
    with pytest.raises(InvalidInputError, match=name):
        gtsam_range_example(p1, **kwargs)


@pytest.mark.parametrize(
    "call",
    [
        lambda d: odometry_only(d.odometry),
        lambda d: gtsam_range_example(d.ranges, rng=np.random.default_rng(0)),
        lambda d: ekf_range_odometry(d.truth),
    ],
)
def test_data_must_be_a_plaza_dataset(p1, call):
    with pytest.raises(
        InvalidInputError, match=r"data must be a RangeOdometry .* or a PlazaDataset"
    ):
        call(p1)


def test_odometry_only_bad_start(p1):
    with pytest.raises(InvalidInputError, match="start_pose"):
        odometry_only(p1, start_pose=[0.0, 0.0, 0.0, 0.0])
