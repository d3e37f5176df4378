"""EDM windows of the trajectory, their submaps, and the stitching of the submaps into one map.

One SDP cannot take thousands of poses, so the trajectory is cut into windows of
``window_length`` metres of travel. Within a window dead reckoning is nearly rigid, so the
pose-pose block of the EDM is taken from it and the pose-beacon block holds the ranges: the EDM
completion (eq. 10, convex iteration, l1 fit) places the beacons heard from non-collinear poses
in the window's dead-reckoning frame. The ranges enter uncalibrated: the start only needs to be
within the refinement's reach. The stitching fits one rigid correction per window and one
position per beacon (GTSAM, Huber), with consecutive corrections tied by the odometry's drift.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rangeslam._robust import MAD_TO_STD
from rangeslam.beacons.data import RangeOdometry, compose_poses, path_length
from rangeslam.beacons.graph import placed_error
from rangeslam.beacons.options import BeaconSlamOptions
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.solvers.robust_kernels import robust_noise_model

__all__ = ["Submap"]

# Clarabel's KKT solves failed (NumericalError) on some noise-free simulated windows at its default
# static regularisation 1e-8 (1 of 11 seeds); at 1e-7 none of them did, and Plaza is unchanged.
WINDOW_SOLVER_OPTIONS = {"static_regularization_constant": 1e-7}
# Convex iterations per window. With range noise of a metre the eigen-gap never reaches the
# tolerance, so the iteration ran to its limit (20: up to 3.8 s a window on Plaza1); the start it
# gives GTSAM needs metres, not the last decimals of the rank.
WINDOW_ITERATIONS = 5
# A window whose EDM answer keeps more than this share of its trace beyond two dimensions
# (eigen-gap) is left out of the stitching. Plaza1's windows reach 0.05 after 5 iterations.
MAX_WINDOW_GAP = 0.1
# Stitching: drift of the dead reckoning between consecutive windows' corrections (sigma of x, y
# as a fraction of the window's length, heading [rad]: dead reckoning drifts with the distance
# travelled; 1 m on Plaza1's 150 m windows), the scale of a submap beacon's sigma and its floor
# as a fraction of ``min_spread`` (0.1 m on Plaza1).
STITCH_DRIFT_XY = 1.0 / 150.0
STITCH_DRIFT_THETA = 0.05
STITCH_BEACON_SIGMA = 1.0
STITCH_SIGMA_FLOOR = 0.1
# A beacon's 2-D position needs ranges from 3 poses off one line: a window shorter than this
# many mean steps cannot place one (and there would be up to N / 3 windows to stitch).
MIN_POSES_PER_WINDOW = 3


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


@dataclass(frozen=True, eq=False)
class WindowPicks:
    """The ranges of one window that enter its EDM: ``picks`` (k,) range rows, ``placed`` (b,)
    the beacons they reach (each heard enough, from poses spread enough)."""

    picks: np.ndarray
    placed: list[int]


@dataclass(frozen=True, eq=False)
class WindowEdm:
    """A window's partial EDM (eq. 9): ``sq`` (n, n) squared distances, ``weights`` (n, n),
    ``mask`` (n, n) observed entries; points are the ``poses`` (p,) keyframes, then the beacons."""

    sq: np.ndarray
    weights: np.ndarray
    mask: np.ndarray
    poses: np.ndarray


@dataclass(frozen=True, eq=False)
class Initialisation:
    """A start for the refinement: poses (N + 1, 3), beacons (B, 2) (NaN where not placed),
    ``placed`` (B,) and notes for the result's message."""

    poses: np.ndarray
    beacons: np.ndarray
    placed: np.ndarray
    notes: list[str]


def windows(data: RangeOdometry, length: float) -> tuple[np.ndarray, np.ndarray]:
    """(N + 1,) distance travelled at each pose [m] and (N + 1,) its window (``length`` m each).

    InvalidInputError naming window_length when ``length`` is under
    :data:`MIN_POSES_PER_WINDOW` mean steps of ``data``: such windows hold too few poses to place
    a beacon (a 2-D position needs ranges from 3 poses off one line), and their number, which
    the stitching loops over, grows without bound as ``length`` shrinks.
    """
    travelled = path_length(data.odometry)
    shortest = MIN_POSES_PER_WINDOW * travelled[-1] / len(data.odometry)
    if length < shortest:
        raise InvalidInputError(
            f"window_length must be >= {shortest:.4g} m for this data ({MIN_POSES_PER_WINDOW} "
            f"mean steps of {travelled[-1] / len(data.odometry):.4g} m: a window needs ranges "
            f"from {MIN_POSES_PER_WINDOW} poses to place a beacon); got {length:g}"
        )
    return travelled, np.floor(travelled / length).astype(int)


def pick_window_ranges(
    dr_xy: np.ndarray, rows: np.ndarray, data: RangeOdometry, cfg: BeaconSlamOptions
) -> WindowPicks | None:
    """The beacons a window can place and up to ``keyframes`` of its ranges ``rows`` (evenly in
    time, shared among the beacons); None when no beacon qualifies."""
    range_pose, range_beacon = data.range_pose, data.range_beacon
    beacon_ids, counts = np.unique(range_beacon[rows], return_counts=True)
    n_heard = int(np.sum(counts >= cfg.min_ranges))
    if n_heard == 0:
        return None
    picks_per_beacon = max(cfg.min_ranges, cfg.keyframes // n_heard)
    chosen: list[np.ndarray] = []
    placed: list[int] = []
    for b, c in zip(beacon_ids, counts, strict=True):
        if c < cfg.min_ranges:
            continue
        mine = rows[range_beacon[rows] == b]
        spaced = np.linspace(0, len(mine) - 1, min(picks_per_beacon, len(mine)))
        pick = mine[np.unique(spaced.round().astype(int))]
        xy = dr_xy[range_pose[pick]]
        sv = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
        if sv[-1] / np.sqrt(len(pick)) < cfg.min_spread:
            continue
        chosen.append(pick)
        placed.append(int(b))
    if not placed:
        return None
    return WindowPicks(picks=np.concatenate(chosen), placed=placed)


def window_edm(
    dr_xy: np.ndarray, sel: WindowPicks, data: RangeOdometry, pose_weight: float
) -> WindowEdm:
    """The window's partial EDM: dead-reckoned pose-pose distances (weight ``pose_weight``),
    the picked ranges pose-beacon (weight 1; two ranges from one pose to one beacon: their
    mean), beacon-beacon unknown."""
    picks = sel.picks
    poses, pose_of = np.unique(data.range_pose[picks], return_inverse=True)
    p = len(poses)
    n = p + len(sel.placed)
    col = {b: p + i for i, b in enumerate(sel.placed)}
    sq = np.zeros((n, n))
    weights = np.zeros((n, n))
    diff = dr_xy[poses][:, None, :] - dr_xy[poses][None, :, :]
    sq[:p, :p] = np.sum(diff**2, axis=-1)
    weights[:p, :p] = pose_weight
    total = np.zeros((n, n))
    hits = np.zeros((n, n))
    for r_idx, i in zip(picks, pose_of, strict=True):
        j = col[int(data.range_beacon[r_idx])]
        total[i, j] += data.ranges[r_idx]
        hits[i, j] += 1
    seen = hits > 0
    sq[seen] = (total[seen] / hits[seen]) ** 2
    weights[seen] = 1.0
    sq = np.maximum(sq, sq.T)
    weights = np.maximum(weights, weights.T)
    mask = weights > 0
    np.fill_diagonal(mask, False)
    return WindowEdm(sq=sq, weights=weights, mask=mask, poses=poses)


def beacon_spread(
    dr_xy: np.ndarray, rows: np.ndarray, data: RangeOdometry, placed: list[int], positions
) -> tuple[np.ndarray, np.ndarray]:
    """(b,) robust spread (MAD_TO_STD x MAD) of each placed beacon's range residuals in the
    window [m], and (b,) how many ranges it has there."""
    spread = np.empty(len(placed))
    count = np.empty(len(placed), dtype=int)
    for i, b in enumerate(placed):
        mine = rows[data.range_beacon[rows] == b]
        res = (
            np.linalg.norm(dr_xy[data.range_pose[mine]] - positions[i], axis=1) - data.ranges[mine]
        )
        spread[i] = MAD_TO_STD * np.median(np.abs(res - np.median(res)))
        count[i] = len(mine)
    return spread, count


class ProblemCache:
    """Compiled window SDPs by size, reused across windows and beacons (cvxpy compiles a problem
    once; later solves only load new data: the "warm" part of a cheap EDM start)."""

    def __init__(self) -> None:
        self.problems: dict[int, object] = {}

    def for_points(self, n: int):
        """The l1 EDM completion SDP of ``n`` fully observed points (built on first use)."""
        from rangeslam.solvers.sdp import EDMCompletionSDP

        if n not in self.problems:
            mask = ~np.eye(n, dtype=bool)
            self.problems[n] = EDMCompletionSDP(
                mask, loss="l1", solver_options=WINDOW_SOLVER_OPTIONS
            )
        return self.problems[n]


def place_beacon(
    dr_xy: np.ndarray, pick: np.ndarray, beacon: int, data: RangeOdometry, cfg, cache
) -> tuple[np.ndarray, float, np.ndarray]:
    """One beacon of a window by EDM completion (eq. 10, l1 fit) of its picked ranges ``pick``
    and their dead-reckoned poses: returns its position (2,) in the dead-reckoning frame, the
    eigen-gap of the answer and the poses (k,) used.

    The points are the poses, then the beacon; every pair is observed (pose-pose from dead
    reckoning, weight ``pose_weight``; pose-beacon the ranges, weight 1). With the pose-pose
    block known, the beacons of a window decouple (their mutual distances are unobserved), so
    one small SDP per beacon gives what the window's joint SDP gave at a fraction of its cost
    (an interior-point step on a PSD cone of n points costs about n^6).
    """
    from rangeslam.geometry.alignment import align
    from rangeslam.solvers.sdp import complete_edm

    edm = window_edm(dr_xy, WindowPicks(picks=pick, placed=[beacon]), data, cfg.pose_weight)
    completion = complete_edm(
        edm.sq,
        edm.mask,
        2,
        loss="l1",
        weights=edm.weights,
        max_iterations=WINDOW_ITERATIONS,
        problem=cache.for_points(len(edm.sq)),
    )
    p = len(edm.poses)
    fit = align(completion.points[:p], dr_xy[edm.poses], reflection=True)
    return fit.apply(completion.points[p:])[0], completion.eigen_gap, edm.poses


def window_submap(
    window: int,
    dr_xy: np.ndarray,
    rows: np.ndarray,
    data: RangeOdometry,
    cfg: BeaconSlamOptions,
    cache: ProblemCache | None = None,
) -> tuple[Submap | None, list[int]]:
    """EDM completion of one window (eq. 9 with the receiver block known from dead reckoning).

    The beacons placed are those heard at least ``min_ranges`` times from poses whose RMS spread
    across their principal direction is at least ``min_spread`` metres (collinear poses leave a
    beacon's mirror image equally good). Up to ``keyframes`` ranges are taken, evenly in time and
    shared among the beacons; each beacon is placed by :func:`place_beacon` (l1 fit: robust to
    wrong ranges). The completed points are aligned onto the dead-reckoned poses (reflection
    allowed: an EDM has no handedness, the odometry has), which carries the beacon into the
    dead-reckoning frame. A beacon whose answer is not 2-D (eigen-gap over
    :data:`MAX_WINDOW_GAP`) is left out. Returns the submap (None when no beacon is placed) and
    the beacons left out for not being 2-D. SolverError from the SDP propagates.
    """
    sel = pick_window_ranges(dr_xy, rows, data, cfg)
    if sel is None:
        return None, []
    cache = ProblemCache() if cache is None else cache
    placed, positions, gaps, used, not_2d = [], [], [], [], []
    for beacon in sel.placed:
        pick = sel.picks[data.range_beacon[sel.picks] == beacon]
        position, gap, poses = place_beacon(dr_xy, pick, beacon, data, cfg, cache)
        if gap > MAX_WINDOW_GAP:
            not_2d.append(beacon)
            continue
        placed.append(beacon)
        positions.append(position)
        gaps.append(gap)
        used.append(poses)
    if not placed:
        return None, not_2d
    positions = np.array(positions)
    spread, count = beacon_spread(dr_xy, rows, data, placed, positions)
    sub = Submap(
        window=window,
        beacons=np.array(placed),
        positions=positions,
        counts=count,
        spread=spread,
        eigen_gap=max(gaps),
        keyframes=np.unique(np.concatenate(used)),
    )
    return sub, not_2d


@dataclass
class WindowLog:
    """Windows whose SDP failed and (window, beacon) answers left out for not being 2-D, for the
    result's message."""

    failed: list[str] = field(default_factory=list)
    far_from_2d: list[tuple[int, int]] = field(default_factory=list)

    def notes(self) -> list[str]:
        """The log as notes for the result's message."""
        out = []
        if self.far_from_2d:
            out.append(
                f"{len(self.far_from_2d)} (window, beacon) placements left out: their EDM was "
                f"not 2-D (eigen-gap > {MAX_WINDOW_GAP:g}): {self.far_from_2d[:5]}"
            )
        if self.failed:
            out.append(f"{len(self.failed)} window SDPs failed ({self.failed[0]})")
        return out


def place_window(
    w: int,
    dr_xy: np.ndarray,
    rows: np.ndarray,
    data: RangeOdometry,
    cfg: BeaconSlamOptions,
    log: WindowLog,
    cache: ProblemCache | None = None,
) -> Submap | None:
    """The submap of window ``w`` (its ranges ``rows``), or None when it places no beacon or its
    SDP fails; failures and beacons whose EDM is not 2-D are recorded in ``log``. ``cache``: the
    compiled SDPs to reuse (:class:`ProblemCache`)."""
    try:
        sub, not_2d = window_submap(w, dr_xy, rows, data, cfg, cache)
    except SolverError as exc:
        log.failed.append(f"window {w}: {exc}")
        return None
    log.far_from_2d += [(w, int(b)) for b in not_2d]
    return sub


def stitch_graph(submaps: list[Submap], n_windows: int, n_beacons: int, cfg: BeaconSlamOptions):
    """The stitching graph and its start: T_0 = identity (gauge), consecutive T_w equal up to the
    drift (:data:`STITCH_DRIFT_XY` window lengths), beta_j = T_w(p_jw) (Huber) per beacon placed
    in window w, beta_j starting at the mean of its p_jw. Returns (graph, values, placed
    (n_beacons,))."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(
        gtsam.PriorFactorPose2(_key_t(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6))
    )
    drift_xy = STITCH_DRIFT_XY * cfg.window_length
    drift = gtsam.noiseModel.Diagonal.Sigmas(np.array([drift_xy, drift_xy, STITCH_DRIFT_THETA]))
    for w in range(n_windows):
        values.insert(_key_t(w), gtsam.Pose2())
        if w > 0:
            graph.add(gtsam.BetweenFactorPose2(_key_t(w - 1), _key_t(w), gtsam.Pose2(), drift))
    placed = np.zeros(n_beacons, dtype=bool)
    sums = np.zeros((n_beacons, 2))
    for s in submaps:
        for j, p, spread, count in zip(s.beacons, s.positions, s.spread, s.counts, strict=True):
            floor = STITCH_SIGMA_FLOOR * cfg.min_spread
            sigma = STITCH_BEACON_SIGMA * max(spread, floor) / np.sqrt(max(count, 1) / 10.0)
            model = robust_noise_model(gtsam, gtsam.noiseModel.Isotropic.Sigma(2, sigma), "huber")
            keys = [_key_t(s.window), _key_b(int(j))]
            graph.add(gtsam.CustomFactor(model, keys, placed_error(p)))
            placed[j] = True
            sums[j] += p
    counts = np.zeros(n_beacons)
    for s in submaps:
        counts[s.beacons] += 1
    for j in np.flatnonzero(placed):
        values.insert(_key_b(int(j)), sums[j] / counts[j])
    return graph, values, placed


def stitch(
    submaps: list[Submap], n_windows: int, n_beacons: int, cfg: BeaconSlamOptions
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fuse the windows' beacons: one rigid correction per window and one position per beacon.

    Unknowns: T_w (Pose2) taking window w's dead-reckoning frame to the map, beta_j (Point2)
    (:func:`stitch_graph`), solved by GTSAM's Levenberg-Marquardt. Returns corrections
    (n_windows, 3), beacons (n_beacons, 2) (NaN if never placed) and which beacons were placed.
    """
    import gtsam

    graph, values, placed = stitch_graph(submaps, n_windows, n_beacons, cfg)
    params = gtsam.LevenbergMarquardtParams()
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    corrections = np.array(
        [
            [*result.atPose2(_key_t(w)).translation(), result.atPose2(_key_t(w)).theta()]
            for w in range(n_windows)
        ]
    )
    beacons = np.full((n_beacons, 2), np.nan)
    for j in np.flatnonzero(placed):
        beacons[j] = result.atPoint2(_key_b(int(j)))
    return corrections, beacons, placed


def _key_t(w: int) -> int:
    import gtsam

    return gtsam.symbol("t", w)


def _key_b(j: int) -> int:
    import gtsam

    return gtsam.symbol("b", j)


def window_submaps(
    data: RangeOdometry, dr: np.ndarray, window_of_pose: np.ndarray, cfg: BeaconSlamOptions
) -> tuple[list[Submap], WindowLog]:
    """Step 2 of the batch: the submap of every window that places a beacon, and the log."""
    n_windows = int(window_of_pose[-1]) + 1
    window_of_range = window_of_pose[data.range_pose]
    submaps, log, cache = [], WindowLog(), ProblemCache()
    for w in range(n_windows):
        rows = np.flatnonzero(window_of_range == w)
        if len(rows) == 0:
            continue
        sub = place_window(w, dr[:, :2], rows, data, cfg, log, cache)
        if sub is not None:
            submaps.append(sub)
    if not submaps:
        raise SolverError(
            "no window placed any beacon (too few ranges, collinear paths, or every SDP failed"
            + (f": {log.failed[0]}" if log.failed else "")
            + ")"
        )
    return submaps, log


def edm_initialisation(
    data: RangeOdometry, dr: np.ndarray, cfg: BeaconSlamOptions
) -> Initialisation:
    """Steps 2-3 of :func:`~rangeslam.beacons.beacon_slam`: window EDMs, stitching, and the
    dead-reckoned poses ``dr`` (N + 1, 3) moved by the corrections interpolated along the path
    (by distance travelled). SolverError when no window places any beacon."""
    travelled, window_of_pose = windows(data, cfg.window_length)
    n_windows = int(window_of_pose[-1]) + 1
    submaps, log = window_submaps(data, dr, window_of_pose, cfg)
    corrections, beacons0, placed = stitch(submaps, n_windows, data.n_beacons, cfg)
    centres = (np.arange(n_windows) + 0.5) * cfg.window_length
    corrections[:, 2] = np.unwrap(corrections[:, 2])  # theta() is wrapped; interpolate unwrapped
    frames = np.column_stack([np.interp(travelled, centres, corrections[:, k]) for k in range(3)])
    # Window 0's correction is the identity (the stitching's gauge), so pose 0 stays at start.
    poses0 = compose_poses(frames, dr)
    notes = [f"{len(submaps)} of {n_windows} windows placed beacons", *log.notes()]
    return Initialisation(poses=poses0, beacons=beacons0, placed=placed, notes=notes)
