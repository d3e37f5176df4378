"""Known beacons: surveyed positions given to :func:`~rangeslam.beacons.beacon_slam`.

Some beacons' positions are known (a survey): they fix the map's frame, so pose 0 is no longer the
gauge; each known beacon is held at its position, exactly (``beacon_sigma`` None: a prior of
:data:`FIXED_SIGMA` range sigmas) or under an isotropic prior of ``beacon_sigma`` metres. The range
calibration (scale and offset, :data:`~rangeslam.beacons.options.RANGE_CALIBRATIONS`) stays an
unknown of the graph and is fitted with the poses.

The incremental estimator (:func:`~rangeslam.beacons.beacon_slam_incremental`) takes them the same
way, causally: :func:`known_start` fits the same rigid motion on the ranges of the first windows
only (until ranges reach two known beacons), and pose 0 enters iSAM2 there under a loose prior (a
window's length, pi rad) in place of the gauge; the known beacons are in the graph from the start.

The start: the dead-reckoned path is moved rigidly (x, y, heading; no reflection, the odometry
has a handedness) onto the known beacons by least squares on the ranges to them, from
:data:`ALIGN_HEADINGS` headings (the lowest cost kept); beacons not known are placed by the EDM
windows in the dead-reckoning frame and moved with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam._validation import as_float_array, frozen, shape_str
from rangeslam.beacons.data import RangeOdometry, compose_poses
from rangeslam.errors import InvalidInputError

__all__ = [
    "ALIGN_HEADINGS",
    "FIXED_SIGMA",
    "KnownBeacons",
    "align_path",
    "check_known_beacons",
    "check_known_positions",
    "known_initialisation",
    "known_priors",
    "known_start",
    "move_to_known_frame",
]

#: A fixed beacon's prior sigma, in range sigmas: far below any range's say, and still a prior
#: (a constraint of zero sigma has no whitened form).
FIXED_SIGMA = 1e-4
#: Starting headings of the rigid fit of the dead-reckoned path onto the known beacons.
ALIGN_HEADINGS = 12


@dataclass(frozen=True, eq=False)  # arrays
class KnownBeacons:
    """Beacons whose positions are given: ``positions`` (B, 2) (NaN rows: not known),
    ``known`` (B,) which rows are, and ``sigma`` the prior sigma [m] (None: fixed)."""

    positions: np.ndarray
    known: np.ndarray
    sigma: float | None

    def prior_sigma(self, range_sigma: float) -> float:
        """The prior sigma [m] of a known beacon in the graph."""
        return FIXED_SIGMA * range_sigma if self.sigma is None else self.sigma


def check_known_beacons(beacons, beacon_sigma, data: RangeOdometry) -> KnownBeacons | None:
    """``beacons`` (B, 2) with NaN rows for beacons not known, validated against ``data``
    (None: no beacon known). At least two rows at distinct points must be known (two fix the
    frame, given the odometry's handedness). ``beacon_sigma``: None (fixed) or a positive number
    [m]. InvalidInputError names the argument."""
    return check_known_positions(beacons, beacon_sigma, data.n_beacons)


def check_known_positions(beacons, beacon_sigma, n_beacons: int) -> KnownBeacons | None:
    """:func:`check_known_beacons` for data of ``n_beacons`` beacons (B), e.g. a Plaza set."""
    if beacons is None:
        if beacon_sigma is not None:
            raise InvalidInputError("beacon_sigma needs beacons (the known positions); got None")
        return None
    arr = as_float_array(beacons, "beacons")
    if arr.shape != (n_beacons, 2):
        raise InvalidInputError(
            f"beacons must have shape ({n_beacons}, 2) (one row per beacon of the data, NaN "
            f"for those not known); got {shape_str(arr.shape)}"
        )
    known = np.all(np.isfinite(arr), axis=1)
    partial = ~known & np.any(np.isfinite(arr), axis=1)
    if np.any(partial) or np.any(np.isinf(arr)):
        i = int(np.argmax(partial | np.any(np.isinf(arr), axis=1)))
        raise InvalidInputError(
            f"beacons rows must be two finite numbers or both NaN (not known); row {i} is {arr[i]}"
        )
    if len(np.unique(arr[known], axis=0)) < 2:
        raise InvalidInputError(
            f"beacons must give at least two distinct positions (they fix the map's frame); got "
            f"{int(known.sum())} known row(s)"
        )
    sigma = None
    if beacon_sigma is not None:
        from rangeslam.beacons.options import positive_number

        sigma = positive_number(beacon_sigma, "beacon_sigma")
    return KnownBeacons(positions=frozen(arr), known=frozen(known), sigma=sigma)


def align_path(data: RangeOdometry, dr: np.ndarray, known: KnownBeacons) -> np.ndarray:
    """(3,) the rigid motion (x, y, heading) taking the dead-reckoned poses ``dr`` (N + 1, 3) onto
    the known beacons' frame: least squares on the ranges to known beacons (soft-L1, so a few
    wrong ranges do not steer it), from ALIGN_HEADINGS headings about the beacons' centroid."""
    from scipy.optimize import least_squares

    use = known.known[data.range_beacon]
    if not np.any(use):
        raise InvalidInputError("beacons: no range reaches a known beacon; nothing ties the path")
    xy = dr[data.range_pose[use], :2]
    target = known.positions[data.range_beacon[use]]
    ranges = data.ranges[use]
    beacon_mean, path_mean = known.positions[known.known].mean(axis=0), dr[:, :2].mean(axis=0)
    scale = max(float(np.median(ranges)), 1e-9)

    def residuals(t):
        c, s = np.cos(t[2]), np.sin(t[2])
        moved = xy @ np.array([[c, s], [-s, c]]) + t[:2]
        return (np.linalg.norm(moved - target, axis=1) - ranges) / scale

    best = None
    for heading in np.linspace(0.0, 2 * np.pi, ALIGN_HEADINGS, endpoint=False):
        c, s = np.cos(heading), np.sin(heading)  # the path's centroid onto the beacons'
        t0 = np.array([*(beacon_mean - np.array([[c, -s], [s, c]]) @ path_mean), heading])
        fit = least_squares(residuals, t0, loss="soft_l1", f_scale=0.1)
        if best is None or fit.cost < best.cost:
            best = fit
    return best.x


def move_to_known_frame(
    dr: np.ndarray, beacons: np.ndarray, motion: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N + 1, 3) and beacons (B, 2) (NaN rows kept) moved by the rigid ``motion``."""
    poses = compose_poses(motion, dr)
    c, s = np.cos(motion[2]), np.sin(motion[2])
    moved = beacons @ np.array([[c, s], [-s, c]]) + motion[:2]
    return poses, moved


def known_initialisation(data, dr, cfg, known: KnownBeacons, unknown_start):
    """A start in the known beacons' frame: ``unknown_start(data, dr, cfg)`` places the beacons
    not known (an :class:`~rangeslam.beacons.windows.Initialisation` in the dead-reckoning frame,
    e.g. the EDM windows; not called when every beacon heard is known), then poses and beacons
    move rigidly onto the known ones (:func:`align_path`) and the known take their positions."""
    from rangeslam.beacons.windows import Initialisation

    heard = np.isin(np.arange(data.n_beacons), data.range_beacon)
    notes = [f"{int(known.known.sum())} known beacons ({_how(known)})"]
    if np.any(heard & ~known.known):
        init = unknown_start(data, dr, cfg)
        poses, beacons, placed = init.poses, np.array(init.beacons), np.array(init.placed)
        notes += init.notes
    else:
        poses, beacons = dr, np.full((data.n_beacons, 2), np.nan)
        placed = np.zeros(data.n_beacons, dtype=bool)
    poses, beacons = move_to_known_frame(poses, beacons, align_path(data, dr, known))
    beacons[known.known] = known.positions[known.known]
    placed = placed | known.known
    return Initialisation(poses=poses, beacons=beacons, placed=placed, notes=notes)


def _how(known: KnownBeacons) -> str:
    return "fixed" if known.sigma is None else f"prior sigma {known.sigma:g} m"


def known_priors(gtsam, known: KnownBeacons, range_sigma: float, key_of) -> list:
    """One PriorFactorPoint2 per known beacon (keys ``key_of(j)``) at its position."""
    model = gtsam.noiseModel.Isotropic.Sigma(2, known.prior_sigma(range_sigma))
    return [
        gtsam.PriorFactorPoint2(key_of(int(j)), known.positions[j], model)
        for j in np.flatnonzero(known.known)
    ]


def known_start(data: RangeOdometry, dr: np.ndarray, window_length: float, known: KnownBeacons):
    """The dead-reckoned poses ``dr`` (N + 1, 3) moved into the known beacons' frame by the rigid
    motion :func:`align_path` fits on the data up to the end of the first window (of
    ``window_length`` metres) after which ranges have reached two known beacons (all the data if
    they never do): what an incremental run has seen when it starts. Returns the moved poses."""
    from rangeslam.beacons.windows import windows

    _, window_of_pose = windows(data, window_length)
    reach = known.known[data.range_beacon]
    n_poses = len(data.pose_time)
    for window in range(int(window_of_pose[-1]) + 1):
        n_poses = int(np.searchsorted(window_of_pose, window, side="right"))
        seen = data.range_pose < n_poses
        if len(np.unique(data.range_beacon[seen & reach])) >= 2:
            break
    prefix = data.first(max(n_poses, 2))
    return compose_poses(align_path(prefix, dr[: max(n_poses, 2)], known), dr)
