"""Range-only SLAM with odometry and radio beacons (paper, section 4, on real radio data).

A robot at unknown poses measures its odometry and ranges to beacons at unknown positions. The
geometry is the acoustic SLAM's: the poses are the receivers, the beacons the landmarks, and the
ranges fill the off-diagonal block of an EDM (eq. 9). What changes at this scale:

- **Windows of the MDU problem.** One SDP cannot take thousands of poses, so the trajectory is cut
  into windows of ``window_length`` metres of travel. Within a window dead reckoning is nearly
  rigid (on Plaza1, after aligning each window onto the truth, the largest error is 0.2-0.35 m
  in a typical 60-120 s window; in the 150 m windows of the default, 1.4-1.7 m in the worst
  two), so the pose-pose block of the EDM is taken from it and the pose-beacon block holds the
  ranges: the EDM completion (eq. 10, convex iteration, l1 fit) places the beacons heard from
  non-collinear poses in the window's dead-reckoning frame. The ranges enter uncalibrated (7 %
  long on Plaza): the start only needs to be within the refinement's reach.
- **Stitching.** One rigid correction per window and one position per beacon are fitted to the
  windows' beacons (GTSAM, Huber), with consecutive corrections tied by the odometry's drift; the
  corrections, interpolated along the path, carry the dead-reckoned poses into the map.
- **Refinement.** GTSAM: Pose2 odometry between factors, robust range factors, and the range
  calibration as an unknown (:data:`RANGE_CALIBRATIONS`). The radio ranges of the Plaza data are
  about 7 % long (range minus true distance grows as 0.07 times the distance, intercept within
  0.1 m), which a constant bias cannot model, hence a scale and an offset.
- **Incremental mode** (:func:`beacon_slam_incremental`): iSAM2 consumes odometry and ranges in time
  order; each beacon is initialised from the first window whose EDM places it, and its earlier
  ranges join the graph then.

Data: :class:`RangeOdometry` (``RangeOdometry.from_plaza`` for the CMU Plaza sets: J. Djugash,
B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground truth",
Journal of Field Robotics 26(9), 2009).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_point, as_points, frozen, shape_str
from rangeslam.errors import InvalidInputError, SolverError

__all__ = [
    "RANGE_CALIBRATIONS",
    "BeaconSlamResult",
    "RangeOdometry",
    "beacon_slam",
    "beacon_slam_incremental",
    "dead_reckoning",
    "simulate_beacon_run",
]

#: Range models: measured range = (1 + s) * distance + b with s and b unknown ("affine"), s alone
#: ("scale"), b alone ("offset", a constant bias), or neither (None: ranges taken as distances).
RANGE_CALIBRATIONS = ("affine", "scale", "offset", None)

_ROBUST_K = {"huber": 1.345, "cauchy": 2.3849, "tukey": 4.6851}


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class RangeOdometry:
    """Odometry and ranges to beacons, validated. N odometry steps, R ranges, B beacons.

    Attributes:
        pose_time: (N + 1,) time of each pose [s], strictly increasing (pose 0 is the start).
        odometry: (N, 2) per step: distance travelled [m] (>= 0) and heading change [rad]; step k
            takes pose k to pose k + 1, moving then turning (Pose2(d, 0, dtheta)).
        range_pose: (R,) index of the pose each range was measured from, non-decreasing (time
            order, which the incremental mode needs).
        range_beacon: (R,) beacon of each range, 0..B-1.
        ranges: (R,) measured ranges [m], > 0 (uncalibrated: see ``range_calibration``).
        n_beacons: B.
    """

    pose_time: np.ndarray
    odometry: np.ndarray
    range_pose: np.ndarray
    range_beacon: np.ndarray
    ranges: np.ndarray
    n_beacons: int | None = None

    def __post_init__(self) -> None:
        """Validate and freeze (copies); InvalidInputError names what is wrong. Runs for direct
        construction too, so a RangeOdometry is always valid."""
        odo = as_float_array(self.odometry, "odometry")
        if odo.ndim != 2 or odo.shape[1] != 2 or len(odo) < 1:
            raise InvalidInputError(
                f"odometry must have shape (N, 2) (distance, heading change) with N >= 1; got "
                f"{shape_str(odo.shape)}"
            )
        _finite(odo, "odometry")
        if np.any(odo[:, 0] < 0):
            i = int(np.argmax(odo[:, 0] < 0))
            raise InvalidInputError(f"odometry distances must be >= 0; row {i} has {odo[i, 0]}")
        t = as_float_array(self.pose_time, "pose_time")
        if t.shape != (len(odo) + 1,):
            raise InvalidInputError(
                f"pose_time must have shape ({len(odo) + 1},) (one more than odometry rows); got "
                f"{shape_str(t.shape)}"
            )
        _finite(t, "pose_time")
        if np.any(np.diff(t) <= 0):
            i = int(np.argmax(np.diff(t) <= 0)) + 1
            raise InvalidInputError(f"pose_time must increase strictly; entry {i} does not")
        r = as_float_array(self.ranges, "ranges")
        if r.ndim != 1 or len(r) < 1:
            raise InvalidInputError(f"ranges must be 1-D and non-empty; got {shape_str(r.shape)}")
        _finite(r, "ranges")
        if np.any(r <= 0):
            i = int(np.argmax(r <= 0))
            raise InvalidInputError(f"ranges must be > 0; entry {i} is {r[i]}")
        pose = _as_index(self.range_pose, "range_pose", len(r), len(t))
        if np.any(np.diff(pose) < 0):
            i = int(np.argmax(np.diff(pose) < 0)) + 1
            raise InvalidInputError(
                f"range_pose must be non-decreasing (ranges in time order); entry {i} goes back"
            )
        b = self.n_beacons
        if b is None:
            b = int(np.max(_as_index(self.range_beacon, "range_beacon", len(r), 2**62))) + 1
        if isinstance(b, bool) or not isinstance(b, int | np.integer) or b < 1:
            raise InvalidInputError(f"n_beacons must be a positive integer; got {self.n_beacons!r}")
        beacon = _as_index(self.range_beacon, "range_beacon", len(r), int(b))
        for name, value in (
            ("pose_time", t),
            ("odometry", odo),
            ("range_pose", pose),
            ("range_beacon", beacon),
            ("ranges", r),
        ):
            object.__setattr__(self, name, frozen(value))
        object.__setattr__(self, "n_beacons", int(b))

    @classmethod
    def create(
        cls,
        pose_time: ArrayLike,
        odometry: ArrayLike,
        range_pose: ArrayLike,
        range_beacon: ArrayLike,
        ranges: ArrayLike,
        n_beacons: int | None = None,
    ) -> RangeOdometry:
        """The same as the constructor, with ``n_beacons`` optional (max beacon index + 1)."""
        return cls(pose_time, odometry, range_pose, range_beacon, ranges, n_beacons)

    @classmethod
    def from_plaza(cls, data) -> RangeOdometry:
        """The odometry and ranges of a :class:`~rangeslam.datasets.PlazaDataset` (beacons as its
        rows; each range at the first pose at or after its time, as GTSAM's Plaza examples do)."""
        return cls.create(
            data.pose_time,
            data.odometry,
            data.range_pose,
            data.range_beacon_index,
            data.ranges,
            len(data.beacon_ids),
        )

    def first(self, n_poses: int) -> RangeOdometry:
        """The first ``n_poses`` poses (n_poses - 1 odometry steps) and the ranges among them."""
        if not (isinstance(n_poses, int | np.integer) and 2 <= n_poses <= len(self.pose_time)):
            raise InvalidInputError(
                f"n_poses must be an integer in [2, {len(self.pose_time)}]; got {n_poses!r}"
            )
        keep = self.range_pose < n_poses
        return RangeOdometry.create(
            self.pose_time[:n_poses],
            self.odometry[: n_poses - 1],
            self.range_pose[keep],
            self.range_beacon[keep],
            self.ranges[keep],
            self.n_beacons,
        )


def _finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise InvalidInputError(f"{name} must be finite; entry {bad} is {arr[bad]}")


def _as_index(value: ArrayLike, name: str, length: int, upper: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        raise InvalidInputError(f"{name} must hold integers; got dtype {arr.dtype}")
    if arr.shape != (length,):
        raise InvalidInputError(f"{name} must have shape ({length},); got {shape_str(arr.shape)}")
    integral = arr.dtype.kind in "iu" or (
        arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))
    )
    if not integral:
        raise InvalidInputError(f"{name} must hold integers; got dtype {arr.dtype}")
    idx = arr.astype(np.int64)
    if np.any((idx < 0) | (idx >= upper)):
        i = int(np.argmax((idx < 0) | (idx >= upper)))
        raise InvalidInputError(f"{name} must lie in [0, {upper - 1}]; entry {i} is {idx[i]}")
    return idx


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class BeaconSlamResult:
    """A trajectory and beacon map estimated from odometry and ranges. N steps, B beacons, R ranges.

    Attributes:
        method: what produced it (e.g. "edm+gtsam", "edm+isam2", "gtsam example", "odometry",
            "ekf").
        pose_time: (N + 1,) time of each pose, seconds.
        poses: (N + 1, 3) x, y [m] and heading [rad] of each pose (headings not wrapped).
        beacons: (B, 2) beacon positions [m], same frame; NaN rows for beacons the method did not
            place (e.g. odometry alone, or a beacon never initialised).
        range_bias: (B,) the estimated constant range offset per beacon [m] (one value repeated
            when it is shared); None when the method does not estimate one.
        range_inlier: (R,) True for ranges the estimate accepts (beacon_slam: calibrated
            residual within 3 range_sigma; rangeslam.baselines: their kernel weight or gate); None when
            the method does not use the ranges.
        converged: the estimator ended normally: the optimiser converged (batch: Levenberg-
            Marquardt; incremental: the final iSAM2 updates settled; rangeslam.baselines: their own test,
            e.g. the filter did not diverge), and every beacon ranged to was placed.
        message: why not, or a short description of the stop.
        range_scale: (B,) estimated range scale 1 + s per beacon (measured = scale * distance +
            bias); None when not estimated, NaN for beacons not placed (likewise ``range_bias``).
        initial_poses: (N + 1, 3) the initialisation the optimiser started from (None if none).
        initial_beacons: (B, 2) likewise (NaN for beacons not placed).
        seconds: wall time of the whole estimate [s].
    """

    method: str
    pose_time: np.ndarray
    poses: np.ndarray
    beacons: np.ndarray
    range_bias: np.ndarray | None
    range_inlier: np.ndarray | None
    converged: bool
    message: str = ""
    range_scale: np.ndarray | None = None
    initial_poses: np.ndarray | None = None
    initial_beacons: np.ndarray | None = None
    seconds: float = float("nan")


# ----------------------------------------------------------------------------------------------
# Pure geometry: dead reckoning, windows, Pose2 algebra on arrays
# ----------------------------------------------------------------------------------------------


def dead_reckoning(odometry: np.ndarray, start_pose: np.ndarray) -> np.ndarray:
    """(N + 1, 3) poses from integrating (N, 2) odometry (distance [m], heading change [rad]).

    Each step moves, then turns: the pose composed with Pose2(d, 0, dtheta).
    """
    d, dtheta = odometry[:, 0], odometry[:, 1]
    theta = start_pose[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    x = start_pose[0] + np.concatenate([[0.0], np.cumsum(d * np.cos(theta[:-1]))])
    y = start_pose[1] + np.concatenate([[0.0], np.cumsum(d * np.sin(theta[:-1]))])
    return np.column_stack([x, y, theta])


def _compose(frame: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Poses (n, 3) expressed in ``frame`` (3,) or per-pose frames (n, 3), moved to the world."""
    frame = np.broadcast_to(frame, poses.shape)
    c, s = np.cos(frame[:, 2]), np.sin(frame[:, 2])
    x = frame[:, 0] + c * poses[:, 0] - s * poses[:, 1]
    y = frame[:, 1] + s * poses[:, 0] + c * poses[:, 1]
    return np.column_stack([x, y, frame[:, 2] + poses[:, 2]])


@dataclass(frozen=True, eq=False)
class Submap:
    """Beacons placed by one window's EDM completion, in the dead-reckoning frame.

    Attributes:
        window: index of the window.
        beacons: (b,) rows of the beacons placed.
        positions: (b, 2) their positions in the dead-reckoning frame [m].
        counts: (b,) ranges to each in the window.
        spread: (b,) robust spread (1.4826 MAD) of the window's range residuals per beacon [m].
        eigen_gap: eigen-gap of the SDP answer (0: exactly 2-D).
        keyframes: (k,) poses that entered the EDM.
    """

    window: int
    beacons: np.ndarray
    positions: np.ndarray
    counts: np.ndarray
    spread: np.ndarray
    eigen_gap: float
    keyframes: np.ndarray


# Clarabel's KKT solves failed (NumericalError) on some noise-free simulated windows at its default
# static regularisation 1e-8 (1 of 11 seeds); at 1e-7 none of them did, and Plaza is unchanged.
_WINDOW_SOLVER_OPTIONS = {"static_regularization_constant": 1e-7}
# Convex iterations per window. With range noise of a metre the eigen-gap never reaches the
# tolerance, so the iteration ran to its limit (20: up to 3.8 s a window on Plaza1); the start it
# gives GTSAM needs metres, not the last decimals of the rank.
_WINDOW_ITERATIONS = 5
# A window whose EDM answer keeps more than this share of its trace beyond two dimensions
# (eigen-gap) is left out of the stitching. Plaza1's windows reach 0.05 after 5 iterations.
_MAX_WINDOW_GAP = 0.1


def _window_submap(
    window: int,
    dr_xy: np.ndarray,
    rows: np.ndarray,
    range_pose: np.ndarray,
    range_beacon: np.ndarray,
    ranges: np.ndarray,
    *,
    keyframes: int,
    min_ranges: int,
    min_spread: float,
    pose_weight: float,
) -> Submap | None:
    """EDM completion of one window (eq. 9 with the receiver block known from dead reckoning).

    The points are the window's keyframe poses and the beacons heard at least ``min_ranges``
    times from poses whose RMS spread across their principal direction is at least
    ``min_spread`` metres (collinear poses leave a beacon's mirror image equally good). Up to
    ``keyframes`` ranges are taken, evenly in time and shared among the beacons. Pose-pose
    distances come from dead reckoning (weight ``pose_weight``), pose-beacon distances are the
    ranges (weight 1, l1 fit: robust to wrong ranges); beacon-beacon distances are unknown. The
    completed points are aligned onto the dead-reckoned keyframes (reflection allowed: an EDM has
    no handedness, the odometry has), which carries the beacons into the dead-reckoning frame.
    None when no beacon qualifies. SolverError from the SDP propagates.
    """
    from rangeslam.geometry.alignment import align
    from rangeslam.solvers.sdp import complete_edm

    beacon_ids, counts = np.unique(range_beacon[rows], return_counts=True)
    n_heard = int(np.sum(counts >= min_ranges))
    if n_heard == 0:
        return None
    picks_per_beacon = max(min_ranges, keyframes // n_heard)
    chosen: list[np.ndarray] = []
    placed: list[int] = []
    for b, c in zip(beacon_ids, counts, strict=True):
        if c < min_ranges:
            continue
        mine = rows[range_beacon[rows] == b]
        spaced = np.linspace(0, len(mine) - 1, min(picks_per_beacon, len(mine)))
        pick = mine[np.unique(spaced.round().astype(int))]
        xy = dr_xy[range_pose[pick]]
        sv = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
        if sv[-1] / np.sqrt(len(pick)) < min_spread:
            continue
        chosen.append(pick)
        placed.append(int(b))
    if not placed:
        return None
    picks = np.concatenate(chosen)
    poses, pose_of = np.unique(range_pose[picks], return_inverse=True)
    p, nb = len(poses), len(placed)
    n = p + nb
    col = {b: p + i for i, b in enumerate(placed)}
    sq = np.zeros((n, n))
    weights = np.zeros((n, n))
    diff = dr_xy[poses][:, None, :] - dr_xy[poses][None, :, :]
    sq[:p, :p] = np.sum(diff**2, axis=-1)
    weights[:p, :p] = pose_weight
    total = np.zeros((n, n))
    hits = np.zeros((n, n))
    for r_idx, i in zip(picks, pose_of, strict=True):
        j = col[int(range_beacon[r_idx])]
        total[i, j] += ranges[r_idx]
        hits[i, j] += 1
    seen = hits > 0  # a pose with two ranges to one beacon: their mean
    sq[seen] = (total[seen] / hits[seen]) ** 2
    weights[seen] = 1.0
    sq = np.maximum(sq, sq.T)
    weights = np.maximum(weights, weights.T)
    mask = weights > 0
    np.fill_diagonal(mask, False)
    completion = complete_edm(
        sq,
        mask,
        2,
        loss="l1",
        weights=weights,
        max_iterations=_WINDOW_ITERATIONS,
        solver_options=_WINDOW_SOLVER_OPTIONS,
    )
    fit = align(completion.points[:p], dr_xy[poses], reflection=True)
    positions = fit.apply(completion.points[p:])
    spread = np.empty(nb)
    count = np.empty(nb, dtype=int)
    for i, b in enumerate(placed):
        mine = rows[range_beacon[rows] == b]
        res = np.linalg.norm(dr_xy[range_pose[mine]] - positions[i], axis=1) - ranges[mine]
        spread[i] = 1.4826 * np.median(np.abs(res - np.median(res)))
        count[i] = len(mine)
    return Submap(
        window=window,
        beacons=np.array(placed),
        positions=positions,
        counts=count,
        spread=spread,
        eigen_gap=completion.eigen_gap,
        keyframes=poses,
    )


def _stitch(
    submaps: list[Submap],
    n_windows: int,
    n_beacons: int,
    *,
    drift_xy: float,
    drift_theta: float,
    beacon_sigma: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fuse the windows' beacons: one rigid correction per window and one position per beacon.

    Unknowns: T_w (Pose2) taking window w's dead-reckoning frame to the map, beta_j (Point2).
    Factors: beta_j = T_w(p_jw) for each beacon placed in window w (Huber), consecutive
    corrections equal up to the drift of the dead reckoning (between factors), T_0 = identity
    (gauge). Returns corrections (n_windows, 3), beacons (n_beacons, 2) (NaN if never placed) and
    which beacons were placed.
    """
    import gtsam

    def key_t(w: int) -> int:
        return gtsam.symbol("t", w)

    def key_b(j: int) -> int:
        return gtsam.symbol("b", j)

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(
        gtsam.PriorFactorPose2(key_t(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6))
    )
    drift = gtsam.noiseModel.Diagonal.Sigmas(np.array([drift_xy, drift_xy, drift_theta]))
    for w in range(n_windows):
        values.insert(key_t(w), gtsam.Pose2())
        if w > 0:
            graph.add(gtsam.BetweenFactorPose2(key_t(w - 1), key_t(w), gtsam.Pose2(), drift))
    placed = np.zeros(n_beacons, dtype=bool)
    sums = np.zeros((n_beacons, 2))
    for s in submaps:
        for j, p, spread, count in zip(s.beacons, s.positions, s.spread, s.counts, strict=True):
            sigma = beacon_sigma * max(spread, 0.1) / np.sqrt(max(count, 1) / 10.0)
            model = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                gtsam.noiseModel.Isotropic.Sigma(2, sigma),
            )
            graph.add(gtsam.CustomFactor(model, [key_t(s.window), key_b(int(j))], _placed_error(p)))
            placed[j] = True
            sums[j] += p
    counts = np.zeros(n_beacons)
    for s in submaps:
        counts[s.beacons] += 1
    for j in np.flatnonzero(placed):
        values.insert(key_b(int(j)), sums[j] / counts[j])
    params = gtsam.LevenbergMarquardtParams()
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    corrections = np.array(
        [
            [*result.atPose2(key_t(w)).translation(), result.atPose2(key_t(w)).theta()]
            for w in range(n_windows)
        ]
    )
    beacons = np.full((n_beacons, 2), np.nan)
    for j in np.flatnonzero(placed):
        beacons[j] = result.atPoint2(key_b(int(j)))
    return corrections, beacons, placed


def _placed_error(p: np.ndarray):
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


def _range_error(r: float, model: str | None):
    """CustomFactor error (1 + s) |t - beta| + b - r for a range r from a Pose2 to a beacon.

    Keys: the pose, the beacon and, unless ``model`` is None, the calibration vector: (s,) for
    "scale", (b,) for "offset", (s, b) for "affine".
    """

    def error(this, values, jacobians):
        keys = this.keys()
        pose = values.atPose2(keys[0])
        beta = values.atPoint2(keys[1])
        s = b = 0.0
        if model is not None:
            cal = values.atVector(keys[2])
            if model == "scale":
                s = cal[0]
            elif model == "offset":
                b = cal[0]
            else:
                s, b = cal
        delta = pose.translation() - beta
        dist = max(float(np.hypot(*delta)), 1e-9)
        u = delta / dist
        if jacobians is not None:
            c, sn = np.cos(pose.theta()), np.sin(pose.theta())
            k = 1.0 + s
            jacobians[0] = k * np.array([[c * u[0] + sn * u[1], -sn * u[0] + c * u[1], 0.0]])
            jacobians[1] = -k * u[None, :]
            if model == "scale":
                jacobians[2] = np.array([[dist]])
            elif model == "offset":
                jacobians[2] = np.ones((1, 1))
            elif model == "affine":
                jacobians[2] = np.array([[dist, 1.0]])
        return np.array([(1.0 + s) * dist + b - r])

    return error


def _kernel(gtsam, robust: str | None, k: float):
    kernels = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        "tukey": gtsam.noiseModel.mEstimator.Tukey,
    }
    return None if robust is None else kernels[robust].Create(k)


def _range_factor(gtsam, model, pose: int, beacon: int, r: float, group: int, calibration):
    keys = [_key_x(pose), _key_l(beacon)] + ([] if calibration is None else [_key_c(group)])
    return gtsam.CustomFactor(model, keys, _range_error(float(r), calibration))


def _range_noise(gtsam, cfg: _Settings):
    base = gtsam.noiseModel.Isotropic.Sigma(1, cfg.range_sigma)
    kernel = _kernel(gtsam, cfg.robust, _ROBUST_K.get(cfg.robust, 1.0))
    return base if kernel is None else gtsam.noiseModel.Robust.Create(kernel, base)


def _calibration_prior(gtsam, group: int, cfg: _Settings):
    """Weak zero-mean prior on one group's calibration vector (s,), (b,) or (s, b)."""
    sig = {"scale": [cfg.calibration_sigma[0]], "offset": [cfg.calibration_sigma[1]]}.get(
        cfg.range_calibration, list(cfg.calibration_sigma)
    )
    model = gtsam.noiseModel.Diagonal.Sigmas(np.array(sig))
    return gtsam.PriorFactorVector(_key_c(group), np.zeros(len(sig)), model)


def _gauge_prior(gtsam, pose: np.ndarray):
    """Pose 0 pinned (1 mm, 1 mrad): the gauge of range-only SLAM with odometry."""
    return gtsam.PriorFactorPose2(
        _key_x(0), gtsam.Pose2(*pose), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)
    )


def _odometry_factor(gtsam, i: int, step: np.ndarray, model):
    return gtsam.BetweenFactorPose2(
        _key_x(i), _key_x(i + 1), gtsam.Pose2(float(step[0]), 0.0, float(step[1])), model
    )


def _build_graph(
    start_pose: np.ndarray,
    odometry: np.ndarray,
    range_pose: np.ndarray,
    range_beacon: np.ndarray,
    ranges: np.ndarray,
    group_of_range: np.ndarray,
    n_groups: int,
    cfg: _Settings,
):
    """The factor graph: gauge prior, Pose2 odometry (between factors), calibrated robust range
    factors, weak priors on the calibration."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(_gauge_prior(gtsam, start_pose))
    odo = gtsam.noiseModel.Diagonal.Sigmas(cfg.odometry_sigma)
    for i, step in enumerate(odometry):
        graph.add(_odometry_factor(gtsam, i, step, odo))
    noise = _range_noise(gtsam, cfg)
    for i, j, r, g in zip(range_pose, range_beacon, ranges, group_of_range, strict=True):
        graph.add(_range_factor(gtsam, noise, int(i), int(j), r, int(g), cfg.range_calibration))
    if cfg.range_calibration is not None:
        for g in range(n_groups):
            graph.add(_calibration_prior(gtsam, g, cfg))
    return graph


def _key_x(i: int) -> int:
    import gtsam

    return gtsam.symbol("x", i)


def _key_l(j: int) -> int:
    import gtsam

    return gtsam.symbol("l", j)


def _key_c(g: int) -> int:
    import gtsam

    return gtsam.symbol("c", g)


# The relative-decrease test counts as convergence only at damping up to this (a unit-free
# lambda on whitened residuals: at 1e-2 the step is within about 1% of Gauss-Newton's).
_LM_CONVERGED_LAMBDA = 1e-2


@dataclass(frozen=True)
class _LMReport:
    iterations: int
    initial_cost: float
    cost: float
    converged: bool
    message: str


def _levenberg_marquardt(
    graph,
    values,
    dims: dict[int, int],
    *,
    max_iterations: int = 100,
    rel_tol: float = 1e-6,
    lambda_initial: float = 1e-5,
    lambda_max: float = 1e10,
):
    """Levenberg-Marquardt on a GTSAM graph, the outer loop in Python (GTSAM's algorithm: damping
    lambda I added as prior factors on every variable, Cholesky on the damped system).

    Why not gtsam.LevenbergMarquardtOptimizer: it linearises in TBB worker threads, and every
    CustomFactor callback from a worker thread takes the GIL afresh. With 3,500 range factors that
    cost 2.7 s per iteration where ``graph.linearize`` called from Python takes 0.05 s.

    Converged: an accepted step decreased the cost by at most ``rel_tol`` of it, with the damping
    low enough that the step was close to Gauss-Newton's. Not converged: the iteration limit, a
    non-finite initial cost, or no decrease up to ``lambda_max`` (a stall: a wrong Jacobian, or a
    point that is not a minimum of the model). Failed linear solves count as rejected steps.

    Returns the optimised values and an :class:`_LMReport`.
    """
    import gtsam

    damping_models = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    cost = initial = graph.error(values)
    if not np.isfinite(cost):
        return values, _LMReport(0, initial, cost, False, "the initial cost is not finite")
    lam = lambda_initial
    for iteration in range(1, max_iterations + 1):
        linear = graph.linearize(values)
        while True:
            damped = linear.clone()
            root = np.sqrt(lam)
            for key, d in dims.items():
                damped.add(
                    gtsam.JacobianFactor(key, root * np.eye(d), np.zeros(d), damping_models[d])
                )
            try:
                delta = damped.optimize()
                trial = values.retract(delta)
                trial_cost = graph.error(trial)
            except RuntimeError:  # e.g. an indeterminant system: as GTSAM, a failed step
                trial_cost = np.inf
            if np.isfinite(trial_cost) and trial_cost <= cost:
                break
            lam *= 10.0
            if lam > lambda_max:
                return values, _LMReport(
                    iteration, initial, cost, False, "stalled: no decrease at the largest damping"
                )
        decrease = cost - trial_cost
        values, cost = trial, trial_cost
        # A tiny decrease under heavy damping is a short step, not a minimum: keep going.
        if decrease <= rel_tol * max(cost, 1e-300) and lam <= _LM_CONVERGED_LAMBDA:
            return values, _LMReport(iteration, initial, cost, True, "relative decrease below tol")
        lam = max(lam / 10.0, 1e-12)
    return values, _LMReport(
        max_iterations, initial, cost, False, f"not converged in {max_iterations} iterations"
    )


# ----------------------------------------------------------------------------------------------
# Public estimators
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Settings:
    range_calibration: str | None
    per_beacon: bool
    range_sigma: float
    odometry_sigma: np.ndarray
    robust: str | None
    calibration_sigma: tuple[float, float]
    window_length: float
    keyframes: int
    min_ranges: int
    min_spread: float
    pose_weight: float


def _positive_number(value, name: str) -> float:
    """A finite number > 0 (bools refused); InvalidInputError naming ``name`` otherwise."""
    ok = not isinstance(value, bool | np.bool_) and isinstance(value, int | float | np.number)
    if not (ok and np.isfinite(value) and value > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return float(value)


def _settings(
    range_calibration,
    per_beacon,
    range_sigma,
    odometry_sigma,
    robust,
    calibration_sigma,
    window_length,
    keyframes,
    min_ranges,
    min_spread,
    pose_weight,
) -> _Settings:
    if range_calibration not in RANGE_CALIBRATIONS:
        raise InvalidInputError(
            f"range_calibration must be one of {RANGE_CALIBRATIONS}; got {range_calibration!r}"
        )
    if robust is not None and robust not in _ROBUST_K:
        raise InvalidInputError(f"robust must be None or one of {tuple(_ROBUST_K)}; got {robust!r}")
    osig = as_float_array(odometry_sigma, "odometry_sigma")
    if osig.shape != (3,) or not np.all(np.isfinite(osig)) or np.any(osig <= 0):
        raise InvalidInputError(
            "odometry_sigma must be three positive numbers (along [m], across [m], heading "
            f"[rad] per step); got {odometry_sigma!r}"
        )
    csig = as_float_array(calibration_sigma, "calibration_sigma")
    if csig.shape != (2,) or not np.all(np.isfinite(csig)) or np.any(csig <= 0):
        raise InvalidInputError(
            "calibration_sigma must be two positive numbers (prior sd of the scale error s and "
            f"of the offset b [m]); got {calibration_sigma!r}"
        )
    for value, name in (
        (range_sigma, "range_sigma"),
        (window_length, "window_length"),
        (min_spread, "min_spread"),
        (pose_weight, "pose_weight"),
    ):
        _positive_number(value, name)
    for value, name, low in ((keyframes, "keyframes", 3), (min_ranges, "min_ranges", 3)):
        if isinstance(value, bool) or not (isinstance(value, int | np.integer) and value >= low):
            raise InvalidInputError(f"{name} must be an integer >= {low}; got {value!r}")
    if not isinstance(per_beacon, bool | np.bool_):
        raise InvalidInputError(f"per_beacon must be True or False; got {per_beacon!r}")
    return _Settings(
        range_calibration,
        bool(per_beacon),
        float(range_sigma),
        osig,
        robust,
        (float(csig[0]), float(csig[1])),
        float(window_length),
        int(keyframes),
        int(min_ranges),
        float(min_spread),
        float(pose_weight),
    )


_DEFAULTS = dict(
    range_calibration="affine",
    per_beacon=False,
    range_sigma=1.0,
    odometry_sigma=(0.01, 0.01, 0.002),
    robust="huber",
    calibration_sigma=(0.2, 10.0),
    window_length=150.0,
    keyframes=24,
    min_ranges=6,
    min_spread=1.0,
    pose_weight=10.0,
)

_SETTINGS_DOC = """
        range_calibration: the range model (:data:`RANGE_CALIBRATIONS`): "affine" (default),
            "scale", "offset" or None.
        per_beacon: one calibration per beacon instead of one shared by all.
        range_sigma: standard deviation of a range [m]. The default, 1 m, is about twice the
            spread of Plaza1's ranges after the affine calibration (0.54 m); the 3-sigma inlier
            gate of ``range_inlier`` then flags none of them.
        odometry_sigma: per-step standard deviations along and across the track [m] and of the
            heading [rad]. The defaults, 0.01 m, 0.01 m and 0.002 rad per 0.2 s step, are of the
            size of the drift of Plaza1's odometry against its ground truth over 100-300 steps.
        robust: kernel on the range factors: "huber" (default), "cauchy", "tukey" or None.
        calibration_sigma: zero-mean prior standard deviations of the scale error s and the
            offset b [m] (weak: they only keep the graph determinate).
        window_length: metres of travel per EDM window.
        keyframes: about how many ranges per window enter its EDM, shared among the beacons
            heard (each gets at least ``min_ranges``); the SDP has one point per keyframe pose
            plus one per beacon.
        min_ranges, min_spread: a beacon is placed in a window only when heard at least
            ``min_ranges`` times from poses spread ``min_spread`` metres across their line.
        pose_weight: weight of the dead-reckoned pose-pose distances in a window's EDM fit
            (ranges weigh 1).
"""


def _windows(data: RangeOdometry, length: float) -> tuple[np.ndarray, np.ndarray]:
    """(N + 1,) distance travelled at each pose [m] and (N + 1,) its window (``length`` m each)."""
    travelled = np.concatenate([[0.0], np.cumsum(data.odometry[:, 0])])
    return travelled, np.floor(travelled / length).astype(int)


def _check_data(data) -> None:
    if not isinstance(data, RangeOdometry):
        raise InvalidInputError(
            f"data must be a RangeOdometry (see RangeOdometry.create); got {type(data).__name__}"
        )


def _group_of_range(data: RangeOdometry, per_beacon: bool) -> tuple[np.ndarray, int]:
    if per_beacon:
        return data.range_beacon.copy(), data.n_beacons
    return np.zeros(len(data.ranges), dtype=int), 1


def _calibration_dim(model: str | None) -> int:
    return {"scale": 1, "offset": 1, "affine": 2}.get(model, 0)


def _calibration_arrays(values, cfg: _Settings, n_beacons: int, placed: np.ndarray):
    """Per-beacon (scale, offset) from the calibration variables (None where not estimated)."""
    model = cfg.range_calibration
    if model is None:
        return None, None
    scale = np.full(n_beacons, np.nan)
    offset = np.full(n_beacons, np.nan)
    for j in np.flatnonzero(placed):
        g = int(j) if cfg.per_beacon else 0
        if not values.exists(_key_c(g)):
            continue
        cal = values.atVector(_key_c(g))
        s = cal[0] if model in ("scale", "affine") else 0.0
        b = cal[-1] if model in ("offset", "affine") else 0.0
        scale[j], offset[j] = 1.0 + s, b
    return (
        frozen(scale) if model in ("scale", "affine") else None,
        frozen(offset) if model in ("offset", "affine") else None,
    )


def _inliers(data, poses, beacons, scale, offset, cfg: _Settings) -> np.ndarray:
    """Ranges whose calibrated residual is within 3 range_sigma (False for unplaced beacons)."""
    k = np.ones(data.n_beacons) if scale is None else np.nan_to_num(scale, nan=1.0)
    b = np.zeros(data.n_beacons) if offset is None else np.nan_to_num(offset, nan=0.0)
    beacon = beacons[data.range_beacon]
    dist = np.linalg.norm(poses[data.range_pose, :2] - beacon, axis=1)
    res = k[data.range_beacon] * dist + b[data.range_beacon] - data.ranges
    with np.errstate(invalid="ignore"):
        return frozen(np.abs(res) <= 3.0 * cfg.range_sigma)


def _pose_array(values, n: int) -> np.ndarray:
    out = np.empty((n, 3))
    for i in range(n):
        p = values.atPose2(_key_x(i))
        out[i] = (p.x(), p.y(), p.theta())
    return out


@dataclass
class _WindowLog:
    """Windows whose SDP failed and windows left out for not being 2-D, for the result's message."""

    failed: list[str] = field(default_factory=list)
    far_from_2d: list[int] = field(default_factory=list)

    def notes(self) -> list[str]:
        out = []
        if self.far_from_2d:
            out.append(
                f"windows {self.far_from_2d} left out: their EDM was not 2-D (eigen-gap > 0.1)"
            )
        if self.failed:
            out.append(f"{len(self.failed)} window SDPs failed ({self.failed[0]})")
        return out


def _place_window(
    w: int,
    dr_xy: np.ndarray,
    rows: np.ndarray,
    data: RangeOdometry,
    cfg: _Settings,
    log: _WindowLog,
) -> Submap | None:
    """The submap of window ``w`` (its ranges ``rows``), or None when it places no beacon, its
    SDP fails or its EDM is not 2-D (the last two recorded in ``log``)."""
    try:
        sub = _window_submap(
            w,
            dr_xy,
            rows,
            data.range_pose,
            data.range_beacon,
            data.ranges,
            keyframes=cfg.keyframes,
            min_ranges=cfg.min_ranges,
            min_spread=cfg.min_spread,
            pose_weight=cfg.pose_weight,
        )
    except SolverError as exc:
        log.failed.append(f"window {w}: {exc}")
        return None
    if sub is not None and sub.eigen_gap > _MAX_WINDOW_GAP:
        log.far_from_2d.append(w)
        return None
    return sub


def _all_heard_placed(data: RangeOdometry, placed: np.ndarray) -> bool:
    """Every beacon that was ranged to got a position (beacons never heard do not count)."""
    heard = np.isin(np.arange(data.n_beacons), data.range_beacon)
    return bool(np.all(placed[heard]))


def _check_initialisation(initialisation: str, rng) -> None:
    if initialisation not in ("edm", "random"):
        raise InvalidInputError(f"initialisation must be 'edm' or 'random'; got {initialisation!r}")
    if initialisation == "random" and not isinstance(rng, np.random.Generator):
        raise InvalidInputError(
            f"rng must be a numpy Generator for initialisation='random'; got {rng!r}"
        )


def _edm_initialisation(data: RangeOdometry, dr: np.ndarray, cfg: _Settings):
    """Steps 2-3 of :func:`beacon_slam`: window EDMs, stitching, corrected poses.

    Returns initial poses (N + 1, 3), beacons (B, 2) (NaN where not placed), which beacons were
    placed (B,), and notes for the result's message.
    """
    travelled, window_of_pose = _windows(data, cfg.window_length)
    n_windows = int(window_of_pose[-1]) + 1
    window_of_range = window_of_pose[data.range_pose]
    submaps, log = [], _WindowLog()
    for w in range(n_windows):
        rows = np.flatnonzero(window_of_range == w)
        if len(rows) == 0:
            continue
        sub = _place_window(w, dr[:, :2], rows, data, cfg, log)
        if sub is not None:
            submaps.append(sub)
    if not submaps:
        raise SolverError(
            "no window placed any beacon (too few ranges, collinear paths, or every SDP failed"
            + (f": {log.failed[0]}" if log.failed else "")
            + ")"
        )
    corrections, beacons0, placed = _stitch(
        submaps,
        n_windows,
        data.n_beacons,
        drift_xy=1.0,
        drift_theta=0.05,
        beacon_sigma=1.0,
    )
    centres = (np.arange(n_windows) + 0.5) * cfg.window_length
    corrections[:, 2] = np.unwrap(corrections[:, 2])  # theta() is wrapped; interpolate unwrapped
    frames = np.column_stack([np.interp(travelled, centres, corrections[:, k]) for k in range(3)])
    # Window 0's correction is the identity (the stitching's gauge), so pose 0 stays at start.
    poses0 = _compose(frames, dr)

    notes = [f"{len(submaps)} of {n_windows} windows placed beacons", *log.notes()]
    return poses0, beacons0, placed, notes


def beacon_slam(
    data: RangeOdometry,
    *,
    start_pose: ArrayLike = (0.0, 0.0, 0.0),
    max_iterations: int = 100,
    initialisation: str = "edm",
    rng: np.random.Generator | None = None,
    **settings,
) -> BeaconSlamResult:
    """Batch range-only SLAM with odometry: windowed EDM initialisation, then GTSAM.

    1. Dead reckoning from ``start_pose`` (the gauge: the map is expressed in its frame).
    2. EDM completion per window of ``window_length`` metres: beacons in each window's frame.
    3. Stitching: a rigid correction per window and one position per beacon; the corrections,
       interpolated along the path (by distance travelled), move the dead-reckoned poses.
    4. GTSAM: Pose2 odometry, robust range factors with the range calibration unknown,
       Levenberg-Marquardt (the loop in Python, see :func:`_levenberg_marquardt`).

    Raises SolverError when no window can place any beacon (e.g. a robot that never moved): there
    is nothing to refine. Beacons that no window places are NaN, their ranges unused (counted in
    ``message``), and ``converged`` is False.

    Args:
        data: the odometry and ranges (:class:`RangeOdometry`).
        start_pose: pose 0, (x, y, heading); it fixes the gauge.
        max_iterations: Levenberg-Marquardt iterations at most.
        initialisation: "edm" (steps 2-3) or "random": dead-reckoned poses and beacons drawn
            from N(0, I) m as GTSAM's RangeISAMExample_plaza2 starts them (needs ``rng``): the
            same graph without the EDM, for comparison.
        rng: random generator for ``initialisation="random"``.
    """
    t0 = time.perf_counter()
    _check_data(data)
    if not (isinstance(max_iterations, int | np.integer) and max_iterations >= 1):
        raise InvalidInputError(
            f"max_iterations must be a positive integer; got {max_iterations!r}"
        )
    _check_initialisation(initialisation, rng)
    cfg = _settings(**{**_DEFAULTS, **_known(settings)})
    start = as_point(start_pose, "start_pose", dim=3)
    dr = dead_reckoning(data.odometry, start)
    if initialisation == "edm":
        poses0, beacons0, placed, notes = _edm_initialisation(data, dr, cfg)
    else:
        poses0, beacons0 = dr, rng.standard_normal((data.n_beacons, 2))
        placed = np.isin(np.arange(data.n_beacons), data.range_beacon)
        beacons0[~placed] = np.nan
        notes = ["random beacons, dead-reckoned poses"]
    used = placed[data.range_beacon]
    values, dims = _initial_values(poses0, beacons0, placed, cfg, data.n_beacons)
    group, n_groups = _group_of_range(data, cfg.per_beacon)
    graph = _build_graph(
        poses0[0],
        data.odometry,
        data.range_pose[used],
        data.range_beacon[used],
        data.ranges[used],
        group[used],
        n_groups,
        cfg,
    )
    values, report = _levenberg_marquardt(graph, values, dims, max_iterations=max_iterations)
    poses = _pose_array(values, len(data.pose_time))
    beacons = np.full((data.n_beacons, 2), np.nan)
    for j in np.flatnonzero(placed):
        beacons[j] = values.atPoint2(_key_l(int(j)))
    scale, offset = _calibration_arrays(values, cfg, data.n_beacons, placed)
    notes.append(
        f"LM: {report.message} after {report.iterations} iterations "
        f"(cost {report.initial_cost:.4g} -> {report.cost:.4g})"
    )
    if not np.all(placed):
        notes.append(
            f"beacons never placed: {np.flatnonzero(~placed).tolist()} "
            f"({int(np.sum(~used))} of their ranges unused)"
        )
    return BeaconSlamResult(
        method="edm+gtsam" if initialisation == "edm" else "gtsam random beacons",
        pose_time=data.pose_time,
        poses=frozen(poses),
        beacons=frozen(beacons),
        range_bias=offset,
        range_inlier=_inliers(data, poses, beacons, scale, offset, cfg),
        converged=report.converged and _all_heard_placed(data, placed),
        message="; ".join(notes),
        range_scale=scale,
        initial_poses=frozen(poses0),
        initial_beacons=frozen(beacons0),
        seconds=time.perf_counter() - t0,
    )


beacon_slam.__doc__ += _SETTINGS_DOC


def _known(settings: dict) -> dict:
    unknown = sorted(set(settings) - set(_DEFAULTS))
    if unknown:
        raise InvalidInputError(f"unknown setting(s) {unknown}; known: {sorted(_DEFAULTS)}")
    return settings


def _initial_values(poses, beacons, placed, cfg: _Settings, n_beacons: int):
    import gtsam

    values = gtsam.Values()
    dims: dict[int, int] = {}
    for i, p in enumerate(poses):
        values.insert(_key_x(i), gtsam.Pose2(*p))
        dims[_key_x(i)] = 3
    for j in np.flatnonzero(placed):
        values.insert(_key_l(int(j)), np.asarray(beacons[j], dtype=float))
        dims[_key_l(int(j))] = 2
    nc = _calibration_dim(cfg.range_calibration)
    if nc:
        for g in range(n_beacons if cfg.per_beacon else 1):
            values.insert(_key_c(g), np.zeros(nc))
            dims[_key_c(g)] = nc
    return values, dims


# End of data: at most this many extra iSAM2 updates, until no position moves by _SETTLED [m].
_FINAL_UPDATES = 10
_SETTLED = 1e-6


def beacon_slam_incremental(
    data: RangeOdometry,
    *,
    start_pose: ArrayLike = (0.0, 0.0, 0.0),
    update_every: int = 25,
    relinearize_threshold: float = 0.1,
    factorization: str = "QR",
    initialisation: str = "edm",
    rng: np.random.Generator | None = None,
    **settings,
) -> BeaconSlamResult:
    """Incremental range-only SLAM with odometry: iSAM2 over the data in time order.

    Each odometry step adds a pose (predicted from the latest estimate) and its between factor.
    A range to a placed beacon adds its factor; a range to a beacon not yet placed waits. When a
    window of ``window_length`` metres ends while beacons are missing, its EDM completion places
    the beacons it can (in the window's dead-reckoning frame, carried into the map by aligning
    the window's keyframes onto their current estimates) and their waiting ranges join. iSAM2
    updates after every ``update_every`` new ranges (as GTSAM's RangeISAMExample_plaza2) and at
    each window that placed beacons. Once every beacon is placed no SDP runs any more. Unlike the
    batch, a run in which no beacon is ever placed is not an error (the data may simply not have
    reached a usable window yet): it returns the odometry-only estimate with ``converged``
    False and the unplaced beacons and unused ranges counted in ``message``.

    Args:
        data, start_pose: as :func:`beacon_slam`.
        update_every: new range factors between iSAM2 updates.
        relinearize_threshold: iSAM2's relinearisation threshold.
        factorization: "QR" (default) or "CHOLESKY" (iSAM2's; on Plaza1 GTSAM's example needs QR).
        initialisation: "edm", or "random": each beacon enters at its first range, drawn from
            N(0, I) m as in GTSAM's RangeISAMExample_plaza2 (needs ``rng``), for comparison.
        rng: random generator for ``initialisation="random"``.
    """
    import gtsam

    from rangeslam.geometry.alignment import align

    t0 = time.perf_counter()
    _check_data(data)
    if isinstance(update_every, bool) or not (
        isinstance(update_every, int | np.integer) and update_every >= 1
    ):
        raise InvalidInputError(f"update_every must be a positive integer; got {update_every!r}")
    _positive_number(relinearize_threshold, "relinearize_threshold")
    if factorization not in ("QR", "CHOLESKY"):
        raise InvalidInputError(f"factorization must be 'QR' or 'CHOLESKY'; got {factorization!r}")
    _check_initialisation(initialisation, rng)
    cfg = _settings(**{**_DEFAULTS, **_known(settings)})
    start = as_point(start_pose, "start_pose", dim=3)
    dr = dead_reckoning(data.odometry, start)  # causal: pose i uses steps before i only
    _, window_of_pose = _windows(data, cfg.window_length)
    group, _ = _group_of_range(data, cfg.per_beacon)
    n_cal = _calibration_dim(cfg.range_calibration)

    params = gtsam.ISAM2Params()
    params.setFactorization(factorization)
    params.setRelinearizeThreshold(relinearize_threshold)
    isam = gtsam.ISAM2(params)
    odo = gtsam.noiseModel.Diagonal.Sigmas(cfg.odometry_sigma)
    noise = _range_noise(gtsam, cfg)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(_gauge_prior(gtsam, start))
    values.insert(_key_x(0), gtsam.Pose2(*start))
    placed = np.zeros(data.n_beacons, dtype=bool)
    beacons0 = np.full((data.n_beacons, 2), np.nan)
    waiting: list[list[int]] = [[] for _ in range(data.n_beacons)]
    calibrated: set[int] = set()
    window_rows: list[int] = []
    log = _WindowLog()
    fresh = 0
    updates = 0
    last_pose = gtsam.Pose2(*start)
    n_steps = len(data.odometry)
    k = 0

    def add_range(idx: int) -> None:
        graph.add(
            _range_factor(
                gtsam,
                noise,
                int(data.range_pose[idx]),
                int(data.range_beacon[idx]),
                data.ranges[idx],
                int(group[idx]),
                cfg.range_calibration,
            )
        )

    def place(j: int, at: np.ndarray) -> None:
        beacons0[j] = at
        values.insert(_key_l(j), at)
        g = j if cfg.per_beacon else 0
        if n_cal and g not in calibrated:
            values.insert(_key_c(g), np.zeros(n_cal))
            graph.add(_calibration_prior(gtsam, g, cfg))
            calibrated.add(g)
        placed[j] = True
        for idx in waiting[j]:
            add_range(idx)
        waiting[j] = []

    def take_ranges(pose: int) -> None:
        nonlocal k, fresh
        while k < len(data.ranges) and data.range_pose[k] == pose:
            j = int(data.range_beacon[k])
            window_rows.append(k)
            if initialisation == "random" and not placed[j]:
                place(j, rng.standard_normal(2))
            if placed[j]:
                add_range(k)
                fresh += 1
            else:
                waiting[j].append(k)
            k += 1

    def update(force: bool = False) -> gtsam.Values:
        """One iSAM2 step; ``force`` relinearises past the threshold regardless of iSAM2's
        relinearizeSkip (10 by default: relinearisation is checked every 10th update)."""
        nonlocal graph, values, fresh, updates
        isam.update(graph, values, force_relinearize=force)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        fresh = 0
        updates += 1
        return isam.calculateEstimate()

    take_ranges(0)
    for i in range(n_steps):
        graph.add(_odometry_factor(gtsam, i, data.odometry[i], odo))
        last_pose = last_pose.compose(gtsam.Pose2(data.odometry[i, 0], 0.0, data.odometry[i, 1]))
        values.insert(_key_x(i + 1), last_pose)
        take_ranges(i + 1)
        window_ends = i + 1 == n_steps or window_of_pose[i + 2] != window_of_pose[i + 1]
        if window_ends and not np.all(placed) and window_rows:
            estimate = update()
            sub = _place_window(
                int(window_of_pose[i + 1]), dr[:, :2], np.array(window_rows), data, cfg, log
            )
            new = [] if sub is None else [int(j) for j in sub.beacons if not placed[j]]
            if new:
                current = np.array(
                    [
                        [estimate.atPose2(_key_x(int(p))).x(), estimate.atPose2(_key_x(int(p))).y()]
                        for p in sub.keyframes
                    ]
                )
                to_map = align(dr[sub.keyframes, :2], current)  # rigid, handed like the odometry
                for j in new:
                    place(j, to_map.apply(sub.positions[list(sub.beacons).index(j)][None, :])[0])
                estimate = update(force=True)
                last_pose = estimate.atPose2(_key_x(i + 1))
        if window_ends:
            window_rows = []
        if fresh >= update_every:
            last_pose = update().atPose2(_key_x(i + 1))
    estimate = update()
    poses = _pose_array(estimate, len(data.pose_time))
    # At the end of the data, a few more updates (each one more Gauss-Newton step on the variables
    # past the relinearisation threshold) until the poses settle: beacons placed late, e.g. by
    # the last window of a short run, have had only one update otherwise.
    settled = False
    for _ in range(_FINAL_UPDATES):
        before = poses
        estimate = update(force=True)
        poses = _pose_array(estimate, len(data.pose_time))
        if np.max(np.abs(poses[:, :2] - before[:, :2])) < _SETTLED:
            settled = True
            break
    beacons = np.full((data.n_beacons, 2), np.nan)
    for j in np.flatnonzero(placed):
        beacons[j] = estimate.atPoint2(_key_l(int(j)))
    scale, offset = _calibration_arrays(estimate, cfg, data.n_beacons, placed)
    unused = sum(len(w) for w in waiting)
    notes = [f"{updates} iSAM2 updates"]
    if not settled:
        notes.append(f"not settled: positions still moved by >= {_SETTLED} m after the last update")
    notes += log.notes()
    if not np.all(placed):
        notes.append(
            f"beacons never placed: {np.flatnonzero(~placed).tolist()} ({unused} ranges unused)"
        )
    return BeaconSlamResult(
        method="edm+isam2" if initialisation == "edm" else "isam2 random beacons",
        pose_time=data.pose_time,
        poses=frozen(poses),
        beacons=frozen(beacons),
        range_bias=offset,
        range_inlier=_inliers(data, poses, beacons, scale, offset, cfg),
        converged=settled and _all_heard_placed(data, placed),
        message="; ".join(notes),
        range_scale=scale,
        initial_poses=None,
        initial_beacons=frozen(beacons0),
        seconds=time.perf_counter() - t0,
    )


beacon_slam_incremental.__doc__ += _SETTINGS_DOC


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
    if not isinstance(rng, np.random.Generator):
        raise InvalidInputError(f"rng must be a numpy Generator; got {rng!r}")
    if isinstance(n_steps, bool) or not (isinstance(n_steps, int | np.integer) and n_steps >= 10):
        raise InvalidInputError(f"n_steps must be an integer >= 10; got {n_steps!r}")
    for value, name in ((step_length, "step_length"), (dt, "dt"), (radius, "radius")):
        _positive_number(value, name)
    for value, name in ((range_rate, "range_rate"), (outlier_fraction, "outlier_fraction")):
        if not (isinstance(value, int | float | np.number) and 0 <= value <= 1):
            raise InvalidInputError(f"{name} must be a fraction in [0, 1]; got {value!r}")
    if range_rate == 0:
        raise InvalidInputError("range_rate must be > 0: without ranges there is nothing to map")
    odo_std = as_float_array(odometry_std, "odometry_std")
    if odo_std.shape != (2,) or not np.all(np.isfinite(odo_std)) or np.any(odo_std < 0):
        raise InvalidInputError(
            f"odometry_std must be two numbers >= 0 (distance [m], heading [rad]); got "
            f"{odometry_std!r}"
        )
    for value, name in ((range_std, "range_std"), (outlier_size, "outlier_size")):
        if not (isinstance(value, int | float | np.number) and np.isfinite(value) and value >= 0):
            raise InvalidInputError(f"{name} must be a number >= 0; got {value!r}")
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
