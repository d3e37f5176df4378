"""Incremental range-only SLAM with odometry: iSAM2 over the data in time order.

Each beacon is initialised from the first window whose EDM places it
(:mod:`rangeslam.beacons.windows`), and its earlier ranges join the graph then. Every factor is
GTSAM's own C++ (:mod:`rangeslam.beacons.native`): the range offset is a variable of the graph,
the range scale a secant step on its profile at each window end and at the end of the data,
after which the range factors are swapped for ones at the new scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_point, frozen
from rangeslam.beacons.batch import Refinement, refine
from rangeslam.beacons.data import RangeOdometry, all_heard_placed, check_data, dead_reckoning
from rangeslam.beacons.defaults import resolve_options
from rangeslam.beacons.graph import (
    beacon_array,
    gauge_prior,
    group_of_range,
    key_c,
    key_l,
    key_x,
    odometry_factor,
    pose_array,
    range_inliers,
)
from rangeslam.beacons.known import KnownBeacons, check_known_beacons, known_priors, known_start
from rangeslam.beacons.lm import LMReport
from rangeslam.beacons.native import NativeRanges, ScaleSecant, scale_step
from rangeslam.beacons.options import BeaconSlamOptions, check_initialisation, positive_number
from rangeslam.beacons.result import BeaconSlamResult, as_calibration, calibration_check
from rangeslam.beacons.windows import Initialisation, WindowLog, place_window, windows
from rangeslam.errors import InvalidInputError
from rangeslam.status import Status

__all__ = ["beacon_slam_incremental"]

# Forced updates at most, after a change of the range scale, for iSAM2 to settle at the new scale.
INNER_UPDATES = 4
# Levenberg-Marquardt iterations at most of the joint polish at the end of the data.
POLISH_ITERATIONS = 100
# End of data: at most this many extra iSAM2 updates, until no position moves by SETTLED [m].
FINAL_UPDATES = 10
SETTLED = 1e-6
# Regular updates between re-anchorings of the odometry prediction on iSAM2's estimate. Each
# re-anchoring computes the estimate (a back-substitution over the changed tree: on Plaza1, doing
# it after every update took about 30% of the run); between them new poses are predicted by
# composing the odometry onto the last anchor (benchmarks/README.md, "Plaza at scale").
REANCHOR_EVERY = 10


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

    def __init__(
        self,
        data: RangeOdometry,
        cfg: BeaconSlamOptions,
        isam_cfg: IsamSettings,
        start,
        known: KnownBeacons | None = None,
    ):
        """An iSAM2 instance and a graph holding the gauge prior on pose 0 at ``start`` (3,), or
        with ``known`` beacons their priors and a loose prior on pose 0 (module notes of
        :mod:`rangeslam.beacons.known`), the known beacons placed at their positions."""
        import gtsam

        self.gtsam, self.data, self.cfg, self.isam_cfg = gtsam, data, cfg, isam_cfg
        params = gtsam.ISAM2Params()
        params.setFactorization(isam_cfg.factorization)
        params.setRelinearizeThreshold(isam_cfg.relinearize_threshold)
        self.isam = gtsam.ISAM2(params)
        self.odo = gtsam.noiseModel.Diagonal.Sigmas(cfg.odometry_sigma)
        self.group, n_groups = group_of_range(data, cfg.per_beacon)
        self.native = NativeRanges(cfg, n_groups)
        self.secant = ScaleSecant(n_groups)
        self.scale_steps = self.ranges_at_scale_step = 0
        # iSAM2's index of each range's factor (-1: none yet), and of each group's offset prior
        self.factor_of_range = np.full(len(data.ranges), -1)
        self.prior_of_group: dict[int, int] = {}
        self.pending: list[tuple[str, int]] = []  # what each factor of ``graph`` is
        self.graph, self.values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.values.insert(key_x(0), gtsam.Pose2(*start))
        self.placed = np.zeros(data.n_beacons, dtype=bool)
        self.beacons0 = np.full((data.n_beacons, 2), np.nan)
        self.waiting: list[list[int]] = [[] for _ in range(data.n_beacons)]
        self.calibrated: set[int] = set()
        if known is None:
            self.add(gauge_prior(gtsam, start))
        else:
            loose = np.array([cfg.window_length, cfg.window_length, np.pi])
            model = gtsam.noiseModel.Diagonal.Sigmas(loose)
            self.add(gtsam.PriorFactorPose2(key_x(0), gtsam.Pose2(*start), model))
            for factor in known_priors(gtsam, known, cfg.range_sigma, key_l):
                self.add(factor)
            for j in np.flatnonzero(known.known):
                self.place(int(j), known.positions[j])
        self.window_rows: list[int] = []
        self.log = WindowLog()
        self.fresh = self.updates = self.k = 0
        self.last_pose = gtsam.Pose2(*start)

    def group_of_beacon(self) -> np.ndarray:
        """(B,) calibration group of each beacon."""
        return (
            np.arange(self.data.n_beacons)
            if self.cfg.per_beacon
            else np.zeros(self.data.n_beacons, dtype=int)
        )

    def add(self, factor, what: str = "", which: int = -1) -> None:
        """Queue ``factor`` for the next update; ``what`` "range" (range ``which``) or "prior"
        (of group ``which``) records its iSAM2 index then, for a later swap."""
        self.graph.add(factor)
        self.pending.append((what, which))

    def add_range(self, idx: int) -> None:
        """Add the native factor of range ``idx`` (its beacon is placed)."""
        d = self.data
        factor = self.native.factor(
            self.gtsam,
            int(d.range_pose[idx]),
            int(d.range_beacon[idx]),
            d.ranges[idx],
            int(self.group[idx]),
        )
        self.add(factor, "range", idx)

    def place(self, j: int, at: np.ndarray) -> None:
        """Beacon ``j`` enters at ``at`` (2,) (with its calibration group if new); its waiting
        ranges join the graph."""
        self.beacons0[j] = at
        self.values.insert(key_l(j), at)
        g = j if self.cfg.per_beacon else 0
        if g not in self.calibrated:
            if self.native.has_offset:
                self.values.insert(key_c(g), 0.0)
                self.add(self.native.offset_prior(self.gtsam, g), "prior", g)
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
        self.add(odometry_factor(self.gtsam, i, step, self.odo))
        self.last_pose = self.last_pose.compose(self.gtsam.Pose2(step[0], 0.0, step[1]))
        self.values.insert(key_x(i + 1), self.last_pose)

    def update(self, force: bool = False, remove: list[int] | None = None) -> None:
        """One iSAM2 step, removing the factors ``remove`` (iSAM2 indices); ``force``
        relinearises past the threshold regardless of iSAM2's relinearizeSkip (10 by default:
        relinearisation is checked every 10th update)."""
        result = self.isam.update(self.graph, self.values, remove or [], force_relinearize=force)
        for (what, which), index in zip(self.pending, result.getNewFactorsIndices(), strict=True):
            if what == "range":
                self.factor_of_range[which] = index
            elif what == "prior":
                self.prior_of_group[which] = index
        self.graph, self.values = self.gtsam.NonlinearFactorGraph(), self.gtsam.Values()
        self.pending = []
        self.fresh = 0
        self.updates += 1
        self.relinearized = result.getVariablesRelinearized()

    def converge(self, removals: list[int]) -> None:
        """Forced updates (the first removing ``removals``) until one relinearises no variable
        (every estimate within iSAM2's threshold of its linearisation point), at most
        :data:`INNER_UPDATES`: the graph's optimum at the current scale, where the scale's
        profile gradient holds."""
        self.update(force=True, remove=removals)
        for _ in range(INNER_UPDATES - 1):
            if self.relinearized == 0:
                return
            self.update(force=True)

    def pose(self, i: int):
        """The current estimate of pose ``i`` (Pose2), without computing the others."""
        return self.isam.calculateEstimatePose2(key_x(i))

    def step_scale(self, same_data: bool) -> list[int]:
        """A secant step on the range scale (:func:`~rangeslam.beacons.native.scale_step`);
        when it matters, every range factor and offset prior is swapped for one at the new
        scale. Returns the iSAM2 indices of the factors to remove at the next update (empty
        when the scale stays)."""
        rows = np.flatnonzero(self.factor_of_range >= 0)
        if not self.native.has_scale or len(rows) == 0:
            return []
        estimate = self.isam.calculateBestEstimate()  # full back-substitution, no wildfire
        groups = self.group[rows]
        new = scale_step(
            estimate,
            self.data,
            rows,
            groups,
            self.native,
            self.secant,
            same_data=same_data,
        )
        self.ranges_at_scale_step = len(rows)
        if new is None:
            return []
        self.native.scale_error = new
        return self.swap_ranges(rows)

    def swap_ranges(self, rows: np.ndarray) -> list[int]:
        """Queue replacements at the current scale for the factors of ranges ``rows`` and the
        offset priors; returns the iSAM2 indices of the factors they replace."""
        removals = [int(self.factor_of_range[i]) for i in rows]
        removals += list(self.prior_of_group.values())
        for idx in rows:
            self.add_range(int(idx))
        for g in list(self.prior_of_group):
            self.add(self.native.offset_prior(self.gtsam, g), "prior", g)
        self.scale_steps += 1
        return removals

    def rescale(self, i: int) -> None:
        """At a window end (pose ``i + 1``), once the ranges in the graph have doubled since the
        last scale step: a step on new data and one on the same data (which learns the profile's
        curvature), each followed by the update that swaps the range factors."""
        if np.sum(self.factor_of_range >= 0) < 2 * max(self.ranges_at_scale_step, 1):
            return
        self.converge([])
        for same_data in (False, True):
            removals = self.step_scale(same_data)
            if not removals:
                break
            self.converge(removals)
        self.last_pose = self.pose(i + 1)

    def place_window(self, window: int, dr: np.ndarray, i: int) -> None:
        """At the end of ``window``: its EDM places the beacons it can, carried into the map by
        aligning its keyframes (dead-reckoned ``dr``) onto their current estimates."""
        from rangeslam.geometry.alignment import align

        self.update()
        rows = np.array(self.window_rows)
        sub = place_window(window, dr[:, :2], rows, self.data, self.cfg, self.log)
        new = [] if sub is None else [int(j) for j in sub.beacons if not self.placed[j]]
        if not new:
            return
        current = np.array([self.pose(int(p)).translation() for p in sub.keyframes])
        to_map = align(dr[sub.keyframes, :2], current)  # rigid, handed like the odometry
        for j in new:
            self.place(j, to_map.apply(sub.positions[list(sub.beacons).index(j)][None, :])[0])
        self.update(force=True)
        self.last_pose = self.pose(i + 1)


def beacon_slam_incremental(
    data: RangeOdometry,
    *,
    start_pose: ArrayLike = (0.0, 0.0, 0.0),
    update_every: int = 25,
    relinearize_threshold: float = 0.1,
    factorization: str | None = None,
    initialisation: str = "edm",
    rng: np.random.Generator | None = None,
    beacons: ArrayLike | None = None,
    beacon_sigma: float | None = None,
    **settings,
) -> BeaconSlamResult:
    """Incremental range-only SLAM with odometry: iSAM2 over the data in time order.

    Each odometry step adds a pose (predicted from the latest estimate) and its between factor.
    A range to a placed beacon adds its factor; a range to a beacon not yet placed waits. When a
    window of ``window_length`` metres ends while beacons are missing, its EDM completion places
    the beacons it can (in the window's dead-reckoning frame, carried into the map by aligning
    the window's keyframes onto their current estimates) and their waiting ranges join. iSAM2
    updates after every ``update_every`` new ranges (as GTSAM's RangeISAMExample_plaza2) and at
    each window that placed beacons. Once every beacon is placed no SDP runs any more. Every factor
    given to iSAM2 is GTSAM's own (:mod:`rangeslam.beacons.native`): the range offset is a
    variable, the range scale a secant step on its profile each time the ranges in the graph
    have doubled. At the end of the data the joint model (scale and offset unknowns of the graph,
    as the batch) is polished from iSAM2's answer by Levenberg-Marquardt, so the answer is the
    batch's optimum when both reach its basin. Unlike the batch, a run in which no beacon is ever
    placed is not an error (the data may simply not have reached a usable window yet): it returns
    the odometry-only estimate with status NOT_IDENTIFIABLE and the unplaced beacons and unused
    ranges counted in ``message``. A polish that does not converge gives SOLVER_FAILED.

    Args:
        data, start_pose: as :func:`~rangeslam.beacons.beacon_slam`.
        update_every: new range factors between iSAM2 updates.
        relinearize_threshold: iSAM2's relinearisation threshold.
        factorization: iSAM2's "CHOLESKY" or "QR"; None (default) takes CHOLESKY after the EDM
            start (same answer as QR on Plaza1, 20% faster) and QR after a random one (with
            beacons drawn at random, GTSAM's example fails on Plaza1 with CHOLESKY).
        initialisation: "edm", or "random": each beacon enters at its first range, drawn from
            N(0, I) m as in GTSAM's RangeISAMExample_plaza2 (needs ``rng``), for comparison.
        rng: random generator for ``initialisation="random"``.
        beacons, beacon_sigma: known beacons, as :func:`~rangeslam.beacons.beacon_slam`'s: they
            fix the frame (fitted on the first windows' ranges to them,
            :func:`~rangeslam.beacons.known.known_start`) and are in the graph from the start,
            fixed or under their prior, here and in the polish.
        **settings: the fields of :class:`~rangeslam.beacons.options.BeaconSlamOptions`.
    """
    t0 = time.perf_counter()
    check_data(data)
    if isinstance(update_every, bool) or not (
        isinstance(update_every, int | np.integer) and update_every >= 1
    ):
        raise InvalidInputError(f"update_every must be a positive integer; got {update_every!r}")
    positive_number(relinearize_threshold, "relinearize_threshold")
    if factorization not in (None, "QR", "CHOLESKY"):
        raise InvalidInputError(
            f"factorization must be 'QR', 'CHOLESKY' or None; got {factorization!r}"
        )
    check_initialisation(initialisation, rng)
    if factorization is None:
        factorization = "CHOLESKY" if initialisation == "edm" else "QR"
    cfg = resolve_options(BeaconSlamOptions.from_settings(settings), data)
    isam_cfg = IsamSettings(int(update_every), relinearize_threshold, factorization, initialisation)
    start = as_point(start_pose, "start_pose", dim=3)
    known = check_known_beacons(beacons, beacon_sigma, data)
    dr = dead_reckoning(data.odometry, start)
    if known is not None:
        dr = known_start(data, dr, cfg.window_length, known)
    run = IsamRun(data, cfg, isam_cfg, dr[0], known)
    consume(run, dr, rng)
    estimate, poses, settled = settle(run)
    refined = polish(run, estimate, poses, POLISH_ITERATIONS, known)
    return _verdict(run, refined, settled, time.perf_counter() - t0)


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
            run.rescale(i)
        if run.fresh >= run.isam_cfg.update_every:
            run.update()
            if run.updates % REANCHOR_EVERY == 0:
                run.last_pose = run.pose(i + 1)


def settle(run: IsamRun):
    """At the end of the data, a few more updates (each one more Gauss-Newton step on the
    variables past the relinearisation threshold) until the poses settle: beacons placed late,
    e.g. by the last window of a short run, have had only one update otherwise. Returns the
    estimate, poses (N + 1, 3) and whether they settled."""
    n_poses = len(run.data.pose_time)
    run.converge([])
    poses = pose_array(run.isam.calculateEstimate(), n_poses)
    estimate = run.isam.calculateEstimate()
    for _ in range(FINAL_UPDATES):
        before = poses
        run.update(force=True)
        estimate = run.isam.calculateEstimate()
        poses = pose_array(estimate, n_poses)
        if np.max(np.abs(poses[:, :2] - before[:, :2])) < SETTLED:
            return estimate, poses, True
    return estimate, poses, False


def polish(
    run: IsamRun, estimate, poses: np.ndarray, max_iterations: int, known=None
) -> Refinement:
    """The joint model's optimum (:func:`~rangeslam.beacons.batch.refine`, the range scale and
    offset unknowns of the graph) from iSAM2's answer at the end of the data. The native run
    holds the scale between secant steps, and a map built at a scale a little off sits in a
    shallow valley that those steps leave only slowly (benchmarks/README.md, "Plaza at scale").
    With no beacon placed there is nothing to polish: iSAM2's odometry-only answer stands."""
    placed = run.placed
    beacons = beacon_array(estimate, placed)
    scale, offset = native_calibration(run, estimate)
    if not np.any(placed):
        report = LMReport(0, 0.0, 0.0, Status.CONVERGED, "nothing to polish: no beacon placed")
        return Refinement(poses, beacons, scale, offset, report)
    init = Initialisation(poses, beacons, placed, notes=[])
    columns = []
    if scale is not None:
        columns.append(run.native.scale_error)
    if offset is not None:
        c = run.native.offsets(estimate, np.arange(len(run.native.scale_error)))
        columns.append((1.0 + run.native.scale_error) * c)
    calibration0 = np.column_stack(columns) if columns else None
    return refine(run.data, init, run.cfg, max_iterations, calibration0, known=known)


def native_calibration(run: IsamRun, estimate):
    """Per-beacon range scale 1 + s and offset b = (1 + s) c (B,) from the run's native model
    (NaN for beacons never placed; None where the model has no such term)."""
    cfg, placed = run.cfg, run.placed
    if cfg.range_calibration is None:
        return None, None
    groups = run.group_of_beacon()
    k = 1.0 + run.native.scale_error[groups]
    offset = k * run.native.offsets(estimate, groups)
    scale, offset = np.where(placed, k, np.nan), np.where(placed, offset, np.nan)
    return (
        frozen(scale) if run.native.has_scale else None,
        frozen(offset) if run.native.has_offset else None,
    )


def _verdict(run: IsamRun, refined: Refinement, settled: bool, seconds: float):
    """The result: NOT_IDENTIFIABLE when a beacon ranged to was never placed, SOLVER_FAILED when
    the joint polish did not converge, else CONVERGED; the run's notes as the message."""
    data, cfg, placed = run.data, run.cfg, run.placed
    poses, beacons = refined.poses, refined.beacons
    scale, offset = refined.scale, refined.offset
    unused = sum(len(w) for w in run.waiting)
    report = refined.report
    notes = [
        f"{run.updates} iSAM2 updates, {run.scale_steps} range-scale steps; joint polish: "
        f"{report.message} ({report.iterations} iterations)"
    ]
    if not settled:
        notes.append(f"iSAM2 still moved positions by >= {SETTLED} m after its last update")
    notes += run.log.notes()
    if not np.all(placed):
        notes.append(
            f"beacons never placed: {np.flatnonzero(~placed).tolist()} ({unused} ranges unused)"
        )
    status = report.status if all_heard_placed(data, placed) else Status.NOT_IDENTIFIABLE
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
        range_bias=as_calibration(offset, cfg.per_beacon),
        range_inlier=range_inliers(data, poses, beacons, scale, offset, cfg),
        status=status,
        message="; ".join(notes),
        range_scale=as_calibration(scale, cfg.per_beacon),
        initial_poses=None,
        initial_beacons=frozen(run.beacons0),
        seconds=seconds,
    )
