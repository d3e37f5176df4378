"""The factor graph of range-only SLAM with odometry: symbol keys, factors, values.

Keys: ``x`` poses (Pose2), ``l`` beacons (Point2), ``c`` range calibration groups (vectors (s,),
(b,) or (s, b): measured range = (1 + s) |t - beta| + b). Each factor's error is a small
top-level function with its measurement bound (as GTSAM's Python examples).
"""

from __future__ import annotations

import math

import numpy as np

from rangeslam._validation import frozen
from rangeslam.beacons.data import RangeOdometry
from rangeslam.beacons.options import BeaconSlamOptions
from rangeslam.solvers.robust_kernels import robust_noise_model

__all__: list[str] = []


def placed_error(p: np.ndarray):
    """CustomFactor error T(p) - beta for a point p seen in the frame of pose T."""
    p = np.array(p, dtype=float)
    lever = np.array([-p[1], p[0]])

    def error(this, values, jacobians):
        pose = values.atPose2(this.keys()[0])
        beta = values.atPoint2(this.keys()[1])
        c, s = np.cos(pose.theta()), np.sin(pose.theta())
        rot = np.array([[c, -s], [s, c]])
        if jacobians is not None:
            jacobians[0] = np.column_stack([rot, rot @ lever])
            jacobians[1] = -np.eye(2)
        return rot @ p + pose.translation() - beta

    return error


def range_error(r: float, model: str | None):
    """CustomFactor error (1 + s) |t - beta| + b - r for a range r from a Pose2 to a beacon.

    Keys: the pose, the beacon and, unless ``model`` is None, the calibration vector: (s,) for
    "scale", (b,) for "offset", (s, b) for "affine". Scalar arithmetic (math, not numpy): GTSAM
    calls this once per factor and linearisation, and in the joint polish of the incremental run
    these calls were a third of its time.
    """
    r = float(r)

    def error(this, values, jacobians):
        keys = this.keys()
        pose = values.atPose2(keys[0])
        bx, by = values.atPoint2(keys[1])
        s = b = 0.0
        if model is not None:
            cal = values.atVector(keys[2])
            if model == "scale":
                s = cal[0]
            elif model == "offset":
                b = cal[0]
            else:
                s, b = cal
        dx, dy = pose.x() - bx, pose.y() - by
        dist = max(math.hypot(dx, dy), 1e-9)
        ux, uy = dx / dist, dy / dist  # unit vector beacon -> pose
        k = 1.0 + s
        if jacobians is not None:
            c, sn = math.cos(pose.theta()), math.sin(pose.theta())
            # d dist / d (pose's body-frame translation, heading): R^T u, 0
            jacobians[0] = np.array([[k * (c * ux + sn * uy), k * (c * uy - sn * ux), 0.0]])
            jacobians[1] = np.array([[-k * ux, -k * uy]])
            if model == "scale":
                jacobians[2] = np.array([[dist]])
            elif model == "offset":
                jacobians[2] = np.ones((1, 1))
            elif model == "affine":
                jacobians[2] = np.array([[dist, 1.0]])
        return np.array([k * dist + b - r])

    return error


def range_factor(gtsam, model, pose: int, beacon: int, r: float, group: int, calibration):
    """The range factor of range ``r`` from pose ``pose`` to ``beacon`` (calibration ``group``)."""
    keys = [key_x(pose), key_l(beacon)] + ([] if calibration is None else [key_c(group)])
    return gtsam.CustomFactor(model, keys, range_error(float(r), calibration))


def range_noise(gtsam, cfg: BeaconSlamOptions):
    """Isotropic range noise (``range_sigma``) under the ``robust`` kernel of the table."""
    return robust_noise_model(
        gtsam, gtsam.noiseModel.Isotropic.Sigma(1, cfg.range_sigma), cfg.robust
    )


def calibration_prior(gtsam, group: int, cfg: BeaconSlamOptions):
    """Weak zero-mean prior on one group's calibration vector (s,), (b,) or (s, b)."""
    sig = {"scale": [cfg.calibration_sigma[0]], "offset": [cfg.calibration_sigma[1]]}.get(
        cfg.range_calibration, list(cfg.calibration_sigma)
    )
    model = gtsam.noiseModel.Diagonal.Sigmas(np.array(sig))
    return gtsam.PriorFactorVector(key_c(group), np.zeros(len(sig)), model)


def gauge_prior(gtsam, pose: np.ndarray):
    """Pose 0 pinned (1 mm, 1 mrad): the gauge of range-only SLAM with odometry."""
    return gtsam.PriorFactorPose2(
        key_x(0), gtsam.Pose2(*pose), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)
    )


def odometry_factor(gtsam, i: int, step: np.ndarray, model):
    """Between factor x_i -> x_{i+1}: Pose2(d, 0, dtheta), move then turn."""
    return gtsam.BetweenFactorPose2(
        key_x(i), key_x(i + 1), gtsam.Pose2(float(step[0]), 0.0, float(step[1])), model
    )


def build_graph(
    start_pose: np.ndarray,
    odometry: np.ndarray,
    range_pose: np.ndarray,
    range_beacon: np.ndarray,
    ranges: np.ndarray,
    group_of_range: np.ndarray,
    n_groups: int,
    cfg: BeaconSlamOptions,
    known=None,
):
    """The factor graph: gauge prior (or, with ``known`` beacons
    (:class:`~rangeslam.beacons.known.KnownBeacons`), their priors instead: they fix the frame),
    Pose2 odometry (between factors), calibrated robust range factors, weak priors on the
    calibration."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    if known is None:
        graph.add(gauge_prior(gtsam, start_pose))
    else:
        from rangeslam.beacons.known import known_priors

        for factor in known_priors(gtsam, known, cfg.range_sigma, key_l):
            graph.add(factor)
    odo = gtsam.noiseModel.Diagonal.Sigmas(cfg.odometry_sigma)
    for i, step in enumerate(odometry):
        graph.add(odometry_factor(gtsam, i, step, odo))
    noise = range_noise(gtsam, cfg)
    for i, j, r, g in zip(range_pose, range_beacon, ranges, group_of_range, strict=True):
        graph.add(range_factor(gtsam, noise, int(i), int(j), r, int(g), cfg.range_calibration))
    if cfg.range_calibration is not None:
        for g in range(n_groups):
            graph.add(calibration_prior(gtsam, g, cfg))
    return graph


def key_x(i: int) -> int:
    """Key of pose i."""
    import gtsam

    return gtsam.symbol("x", i)


def key_l(j: int) -> int:
    """Key of beacon j."""
    import gtsam

    return gtsam.symbol("l", j)


def key_c(g: int) -> int:
    """Key of calibration group g."""
    import gtsam

    return gtsam.symbol("c", g)


def group_of_range(data: RangeOdometry, per_beacon: bool) -> tuple[np.ndarray, int]:
    """(R,) calibration group of each range and the number of groups."""
    if per_beacon:
        return data.range_beacon.copy(), data.n_beacons
    return np.zeros(len(data.ranges), dtype=int), 1


def calibration_dim(model: str | None) -> int:
    """Length of one calibration vector: 2 ("affine"), 1 ("scale", "offset") or 0 (None)."""
    return {"scale": 1, "offset": 1, "affine": 2}.get(model, 0)


def calibration_arrays(values, cfg: BeaconSlamOptions, n_beacons: int, placed: np.ndarray):
    """Per-beacon (scale, offset) from the calibration variables (None where not estimated)."""
    model = cfg.range_calibration
    if model is None:
        return None, None
    scale = np.full(n_beacons, np.nan)
    offset = np.full(n_beacons, np.nan)
    for j in np.flatnonzero(placed):
        g = int(j) if cfg.per_beacon else 0
        if not values.exists(key_c(g)):
            continue
        cal = values.atVector(key_c(g))
        s = cal[0] if model in ("scale", "affine") else 0.0
        b = cal[-1] if model in ("offset", "affine") else 0.0
        scale[j], offset[j] = 1.0 + s, b
    return (
        frozen(scale) if model in ("scale", "affine") else None,
        frozen(offset) if model in ("offset", "affine") else None,
    )


def range_inliers(data, poses, beacons, scale, offset, cfg: BeaconSlamOptions) -> np.ndarray:
    """Ranges whose calibrated residual is within 3 range_sigma (False for unplaced beacons)."""
    k = np.ones(data.n_beacons) if scale is None else np.nan_to_num(scale, nan=1.0)
    b = np.zeros(data.n_beacons) if offset is None else np.nan_to_num(offset, nan=0.0)
    beacon = beacons[data.range_beacon]
    dist = np.linalg.norm(poses[data.range_pose, :2] - beacon, axis=1)
    res = k[data.range_beacon] * dist + b[data.range_beacon] - data.ranges
    with np.errstate(invalid="ignore"):
        return frozen(np.abs(res) <= 3.0 * cfg.range_sigma)


def pose_array(values, n: int) -> np.ndarray:
    """(n, 3) x, y, heading of poses 0..n-1 in ``values``."""
    import gtsam

    pose_values = gtsam.utilities.allPose2s(values)
    keys = np.asarray(pose_values.keys(), dtype=np.uint64)
    if np.array_equal(keys, np.uint64(key_x(0)) + np.arange(n, dtype=np.uint64)):
        return np.asarray(gtsam.utilities.extractPose2(pose_values), dtype=float).reshape(n, 3)
    out = np.empty((n, 3))
    for i in range(n):
        p = values.atPose2(key_x(i))
        out[i] = (p.x(), p.y(), p.theta())
    return out


def initial_values(
    poses, beacons, placed, cfg: BeaconSlamOptions, n_beacons: int, calibration0=None
):
    """GTSAM Values for poses, placed beacons and the calibrations (zero, or ``calibration0``
    (G, nc): each group's (s,), (b,) or (s, b)), and each key's dimension."""
    import gtsam

    values = gtsam.Values()
    dims: dict[int, int] = {}
    for i, p in enumerate(poses):
        values.insert(key_x(i), gtsam.Pose2(*p))
        dims[key_x(i)] = 3
    for j in np.flatnonzero(placed):
        values.insert(key_l(int(j)), np.asarray(beacons[j], dtype=float))
        dims[key_l(int(j))] = 2
    nc = calibration_dim(cfg.range_calibration)
    if nc:
        for g in range(n_beacons if cfg.per_beacon else 1):
            start = np.zeros(nc) if calibration0 is None else np.asarray(calibration0[g], float)
            values.insert(key_c(g), start)
            dims[key_c(g)] = nc
    return values, dims


def beacon_array(values, placed: np.ndarray) -> np.ndarray:
    """(B, 2) positions of the ``placed`` beacons in ``values`` (NaN rows for the others)."""
    beacons = np.full((len(placed), 2), np.nan)
    for j in np.flatnonzero(placed):
        beacons[j] = values.atPoint2(key_l(int(j)))
    return beacons
