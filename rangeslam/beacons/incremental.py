"""Incremental range-only SLAM with odometry: iSAM2 over the data in time order.

Each beacon is initialised from the first window whose EDM places it
(:mod:`rangeslam.beacons.windows`), and its earlier ranges join the graph then.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_point, frozen
from rangeslam.beacons.data import RangeOdometry, all_heard_placed, check_data, dead_reckoning
from rangeslam.beacons.graph import (
    beacon_array,
    calibration_arrays,
    calibration_dim,
    calibration_prior,
    gauge_prior,
    group_of_range,
    key_c,
    key_l,
    key_x,
    odometry_factor,
    pose_array,
    range_factor,
    range_inliers,
    range_noise,
)
from rangeslam.beacons.options import BeaconSlamOptions, check_initialisation, positive_number
from rangeslam.beacons.result import BeaconSlamResult, calibration_check
from rangeslam.beacons.windows import WindowLog, place_window, windows
from rangeslam.errors import InvalidInputError
from rangeslam.status import Status

__all__ = ["beacon_slam_incremental"]

# End of data: at most this many extra iSAM2 updates, until no position moves by SETTLED [m].
FINAL_UPDATES = 10
SETTLED = 1e-6


@dataclass(frozen=True)
class IsamSettings:
    """The iSAM2 run's own settings, validated: new range factors between updates, iSAM2's
    relinearisation threshold and factorisation ("QR" or "CHOLESKY"), the initialisation."""

    update_every: int
    relinearize_threshold: float
    factorization: str
    initialisation: str


class IsamRun:
    """The state of one incremental run: iSAM2, the factors and values not yet given to it, and
    the beacons placed so far with the ranges waiting for them."""

    def __init__(self, data: RangeOdometry, cfg: BeaconSlamOptions, isam_cfg: IsamSettings, start):
        """An iSAM2 instance and a graph holding the gauge prior on pose 0 at ``start`` (3,)."""
        import gtsam

        self.gtsam, self.data, self.cfg, self.isam_cfg = gtsam, data, cfg, isam_cfg
        params = gtsam.ISAM2Params()
        params.setFactorization(isam_cfg.factorization)
        params.setRelinearizeThreshold(isam_cfg.relinearize_threshold)
        self.isam = gtsam.ISAM2(params)
        self.odo = gtsam.noiseModel.Diagonal.Sigmas(cfg.odometry_sigma)
        self.noise = range_noise(gtsam, cfg)
        self.group, _ = group_of_range(data, cfg.per_beacon)
        self.n_cal = calibration_dim(cfg.range_calibration)
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.graph.add(gauge_prior(gtsam, start))
        self.values.insert(key_x(0), gtsam.Pose2(*start))
        self.placed = np.zeros(data.n_beacons, dtype=bool)
        self.beacons0 = np.full((data.n_beacons, 2), np.nan)
        self.waiting: list[list[int]] = [[] for _ in range(data.n_beacons)]
        self.calibrated: set[int] = set()
        self.window_rows: list[int] = []
        self.log = WindowLog()
        self.fresh = self.updates = self.k = 0
        self.last_pose = gtsam.Pose2(*start)

    def add_range(self, idx: int) -> None:
        """Add the factor of range ``idx`` (its beacon is placed)."""
        d = self.data
        self.graph.add(
            range_factor(
                self.gtsam,
                self.noise,
                int(d.range_pose[idx]),
                int(d.range_beacon[idx]),
                d.ranges[idx],
                int(self.group[idx]),
                self.cfg.range_calibration,
            )
        )

    def place(self, j: int, at: np.ndarray) -> None:
        """Beacon ``j`` enters at ``at`` (2,) (with its calibration group if new); its waiting
        ranges join the graph."""
        self.beacons0[j] = at
        self.values.insert(key_l(j), at)
        g = j if self.cfg.per_beacon else 0
        if self.n_cal and g not in self.calibrated:
            self.values.insert(key_c(g), np.zeros(self.n_cal))
            self.graph.add(calibration_prior(self.gtsam, g, self.cfg))
            self.calibrated.add(g)
        self.placed[j] = True
        for idx in self.waiting[j]:
            self.add_range(idx)
        self.waiting[j] = []

    def take_ranges(self, pose: int, rng) -> None:
        """The ranges measured at ``pose``: a factor if the beacon is placed, else they wait."""
        d = self.data
        while self.k < len(d.ranges) and d.range_pose[self.k] == pose:
            j = int(d.range_beacon[self.k])
            self.window_rows.append(self.k)
            if self.isam_cfg.initialisation == "random" and not self.placed[j]:
                self.place(j, rng.standard_normal(2))
            if self.placed[j]:
                self.add_range(self.k)
                self.fresh += 1
            else:
                self.waiting[j].append(self.k)
            self.k += 1

    def add_step(self, i: int) -> None:
        """Odometry step i: its between factor and pose i + 1 predicted from the last estimate."""
        step = self.data.odometry[i]
        self.graph.add(odometry_factor(self.gtsam, i, step, self.odo))
        self.last_pose = self.last_pose.compose(self.gtsam.Pose2(step[0], 0.0, step[1]))
        self.values.insert(key_x(i + 1), self.last_pose)

    def update(self, force: bool = False):
        """One iSAM2 step; ``force`` relinearises past the threshold regardless of iSAM2's
        relinearizeSkip (10 by default: relinearisation is checked every 10th update)."""
        self.isam.update(self.graph, self.values, force_relinearize=force)
        self.graph, self.values = self.gtsam.NonlinearFactorGraph(), self.gtsam.Values()
        self.fresh = 0
        self.updates += 1
        return self.isam.calculateEstimate()

    def place_window(self, window: int, dr: np.ndarray, i: int) -> None:
        """At the end of ``window``: its EDM places the beacons it can, carried into the map by
        aligning its keyframes (dead-reckoned ``dr``) onto their current estimates."""
        from rangeslam.geometry.alignment import align

        estimate = self.update()
        rows = np.array(self.window_rows)
        sub = place_window(window, dr[:, :2], rows, self.data, self.cfg, self.log)
        new = [] if sub is None else [int(j) for j in sub.beacons if not self.placed[j]]
        if not new:
            return
        current = np.array(
            [
                [estimate.atPose2(key_x(int(p))).x(), estimate.atPose2(key_x(int(p))).y()]
                for p in sub.keyframes
            ]
        )
        to_map = align(dr[sub.keyframes, :2], current)  # rigid, handed like the odometry
        for j in new:
            self.place(j, to_map.apply(sub.positions[list(sub.beacons).index(j)][None, :])[0])
        self.last_pose = self.update(force=True).atPose2(key_x(i + 1))


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
    reached a usable window yet): it returns the odometry-only estimate with status
    NOT_IDENTIFIABLE and the unplaced beacons and unused ranges counted in ``message``. Positions
    that do not settle after the final updates give SOLVER_FAILED.

    Args:
        data, start_pose: as :func:`~rangeslam.beacons.beacon_slam`.
        update_every: new range factors between iSAM2 updates.
        relinearize_threshold: iSAM2's relinearisation threshold.
        factorization: "QR" (default) or "CHOLESKY" (iSAM2's; on Plaza1 GTSAM's example needs QR).
        initialisation: "edm", or "random": each beacon enters at its first range, drawn from
            N(0, I) m as in GTSAM's RangeISAMExample_plaza2 (needs ``rng``), for comparison.
        rng: random generator for ``initialisation="random"``.
        **settings: the fields of :class:`~rangeslam.beacons.options.BeaconSlamOptions`.
    """
    t0 = time.perf_counter()
    check_data(data)
    if isinstance(update_every, bool) or not (
        isinstance(update_every, int | np.integer) and update_every >= 1
    ):
        raise InvalidInputError(f"update_every must be a positive integer; got {update_every!r}")
    positive_number(relinearize_threshold, "relinearize_threshold")
    if factorization not in ("QR", "CHOLESKY"):
        raise InvalidInputError(f"factorization must be 'QR' or 'CHOLESKY'; got {factorization!r}")
    check_initialisation(initialisation, rng)
    cfg = BeaconSlamOptions.from_settings(settings)
    isam_cfg = IsamSettings(int(update_every), relinearize_threshold, factorization, initialisation)
    start = as_point(start_pose, "start_pose", dim=3)
    run = IsamRun(data, cfg, isam_cfg, start)
    consume(run, dead_reckoning(data.odometry, start), rng)
    estimate, poses, settled = settle(run)
    return _verdict(run, estimate, poses, settled, time.perf_counter() - t0)


def consume(run: IsamRun, dr: np.ndarray, rng) -> None:
    """Feed the odometry and ranges in time order, placing beacons at window ends and updating
    every ``update_every`` new ranges. ``dr`` (N + 1, 3) is causal: pose i uses steps before i."""
    data = run.data
    _, window_of_pose = windows(data, run.cfg.window_length)
    n_steps = len(data.odometry)
    run.take_ranges(0, rng)
    for i in range(n_steps):
        run.add_step(i)
        run.take_ranges(i + 1, rng)
        window_ends = i + 1 == n_steps or window_of_pose[i + 2] != window_of_pose[i + 1]
        if window_ends and not np.all(run.placed) and run.window_rows:
            run.place_window(int(window_of_pose[i + 1]), dr, i)
        if window_ends:
            run.window_rows = []
        if run.fresh >= run.isam_cfg.update_every:
            run.last_pose = run.update().atPose2(key_x(i + 1))


def settle(run: IsamRun):
    """At the end of the data, a few more updates (each one more Gauss-Newton step on the
    variables past the relinearisation threshold) until the poses settle: beacons placed late,
    e.g. by the last window of a short run, have had only one update otherwise. Returns the
    estimate, poses (N + 1, 3) and whether they settled."""
    n_poses = len(run.data.pose_time)
    estimate = run.update()
    poses = pose_array(estimate, n_poses)
    for _ in range(FINAL_UPDATES):
        before = poses
        estimate = run.update(force=True)
        poses = pose_array(estimate, n_poses)
        if np.max(np.abs(poses[:, :2] - before[:, :2])) < SETTLED:
            return estimate, poses, True
    return estimate, poses, False


def _verdict(run: IsamRun, estimate, poses, settled: bool, seconds: float) -> BeaconSlamResult:
    """The result: NOT_IDENTIFIABLE when a beacon ranged to was never placed, SOLVER_FAILED when
    the positions did not settle, else CONVERGED; the run's notes as the message."""
    data, cfg, placed = run.data, run.cfg, run.placed
    beacons = beacon_array(estimate, placed)
    scale, offset = calibration_arrays(estimate, cfg, data.n_beacons, placed)
    unused = sum(len(w) for w in run.waiting)
    notes = [f"{run.updates} iSAM2 updates"]
    if not settled:
        notes.append(f"not settled: positions still moved by >= {SETTLED} m after the last update")
    notes += run.log.notes()
    if not np.all(placed):
        notes.append(
            f"beacons never placed: {np.flatnonzero(~placed).tolist()} ({unused} ranges unused)"
        )
    if not all_heard_placed(data, placed):
        status = Status.NOT_IDENTIFIABLE
    else:
        status = Status.CONVERGED if settled else Status.SOLVER_FAILED
    if status is Status.CONVERGED:
        check = calibration_check(scale, offset, data.ranges, data.range_beacon)
        status = check.status
        notes += [check.reason] if check.reason else []
    random = run.isam_cfg.initialisation == "random"
    return BeaconSlamResult(
        method="isam2 random beacons" if random else "edm+isam2",
        pose_time=data.pose_time,
        poses=frozen(poses),
        beacons=frozen(beacons),
        range_bias=offset,
        range_inlier=range_inliers(data, poses, beacons, scale, offset, cfg),
        status=status,
        message="; ".join(notes),
        range_scale=scale,
        initial_poses=None,
        initial_beacons=frozen(run.beacons0),
        seconds=seconds,
    )
