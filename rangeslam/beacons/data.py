"""Range-odometry data: odometry and ranges to beacons, validated, and dead reckoning.

Data: :class:`RangeOdometry` (``RangeOdometry.from_plaza`` for the CMU Plaza sets: J. Djugash,
B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground truth",
Journal of Field Robotics 26(9), 2009).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, frozen, shape_str
from rangeslam.errors import InvalidInputError

if TYPE_CHECKING:
    from rangeslam.rangeaided.problem import RangeAidedProblem

__all__ = ["MAX_BEACONS", "RangeOdometry", "dead_reckoning", "path_length"]

# Beacons are rows of (B, ...) arrays and variables of the factor graph: an index beyond this is
# refused (one stray id of 10^12 used to allocate ~931 GiB). Sparse or large ids are mapped to
# compact rows by RangeOdometry.from_beacon_ids, which keeps the ids in ``beacon_ids``.
MAX_BEACONS = 100_000
IDS_HINT = (
    " (range_beacon holds row indices; for beacon ids that are large or sparse use "
    "RangeOdometry.from_beacon_ids, which maps them to rows and keeps them in beacon_ids)"
)


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class RangeOdometry:
    """Odometry and ranges to beacons, validated. N odometry steps, R ranges, B beacons.

    Attributes:
        pose_time: (N + 1,) time of each pose [s], strictly increasing (pose 0 is the start).
        odometry: (N, 2) per step: distance travelled [m] and heading change [rad]; step k
            takes pose k to pose k + 1, moving then turning (Pose2(d, 0, dtheta)). A negative
            distance is a step backwards (the heading unchanged by it); the windows and the
            derived defaults count the path's length, |d|.
        range_pose: (R,) index of the pose each range was measured from, non-decreasing (time
            order, which the incremental mode needs).
        range_beacon: (R,) beacon of each range, a row index 0..B-1 (B <= MAX_BEACONS).
        ranges: (R,) measured ranges [m], > 0 (uncalibrated: see ``range_calibration``).
        n_beacons: B (default: the largest index in ``range_beacon`` + 1).
        beacon_ids: (B,) the caller's id of each beacon row, distinct integers >= 0 (default
            0..B-1): a result's beacon row k is the beacon ``beacon_ids[k]``. Any ids, however
            large or sparse: :meth:`from_beacon_ids`.
    """

    pose_time: np.ndarray
    odometry: np.ndarray
    range_pose: np.ndarray
    range_beacon: np.ndarray
    ranges: np.ndarray
    n_beacons: int | None = None
    beacon_ids: np.ndarray | None = None

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
            rows = _as_index(self.range_beacon, "range_beacon", len(r), MAX_BEACONS, IDS_HINT)
            b = int(np.max(rows)) + 1
        if isinstance(b, bool) or not isinstance(b, int | np.integer) or not 1 <= b <= MAX_BEACONS:
            raise InvalidInputError(
                f"n_beacons must be a positive integer <= {MAX_BEACONS}; got {self.n_beacons!r}"
            )
        beacon = _as_index(self.range_beacon, "range_beacon", len(r), int(b), IDS_HINT)
        ids = np.arange(int(b), dtype=np.int64)
        if self.beacon_ids is not None:
            ids = _as_index(self.beacon_ids, "beacon_ids", int(b), 2**62)
            if len(np.unique(ids)) != len(ids):
                raise InvalidInputError("beacon_ids must be distinct; some id is repeated")
        for name, value in (
            ("pose_time", t),
            ("odometry", odo),
            ("range_pose", pose),
            ("range_beacon", beacon),
            ("ranges", r),
            ("beacon_ids", ids),
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
    def from_beacon_ids(
        cls,
        pose_time: ArrayLike,
        odometry: ArrayLike,
        range_pose: ArrayLike,
        range_ids: ArrayLike,
        ranges: ArrayLike,
    ) -> RangeOdometry:
        """Like :meth:`create`, with each range's beacon given by any id (R,) (integers >= 0, any
        size, in any order): the distinct ids become rows 0..B-1 in increasing order and are kept
        in ``beacon_ids``, so a result's beacon row k is beacon ``beacon_ids[k]``."""
        shape = np.shape(range_ids) if isinstance(range_ids, list | tuple | np.ndarray) else ()
        if len(shape) != 1:
            raise InvalidInputError(
                f"range_ids must be a 1-D sequence of integer ids, one per range; got {range_ids!r:.80}"
            )
        ids = _as_index(range_ids, "range_ids", shape[0], 2**62)
        unique, rows = np.unique(ids, return_inverse=True)
        if len(unique) > MAX_BEACONS:
            raise InvalidInputError(
                f"range_ids must name at most {MAX_BEACONS} beacons; got {len(unique)}"
            )
        return cls(pose_time, odometry, range_pose, rows, ranges, len(unique), unique)

    @classmethod
    def from_plaza(cls, data) -> RangeOdometry:
        """The odometry and ranges of a :class:`~rangeslam.datasets.PlazaDataset` (beacons as its
        rows, with its ids in ``beacon_ids``; each range at the first pose at or after its time,
        as GTSAM's Plaza examples do)."""
        return cls(
            data.pose_time,
            data.odometry,
            data.range_pose,
            data.range_beacon_index,
            data.ranges,
            len(data.beacon_ids),
            data.beacon_ids,
        )

    def to_problem(
        self,
        *,
        odometry_sigma: ArrayLike | None = None,
        range_sigma: float | None = None,
        truth_poses: ArrayLike | None = None,
        truth_beacons: ArrayLike | None = None,
    ) -> RangeAidedProblem:
        """This log as a :class:`~rangeslam.rangeaided.RangeAidedProblem` (one robot, 2-D,
        odometry Pose2(d, 0, dtheta) with covariance diag(``odometry_sigma``^2), ranges with
        variance ``range_sigma``^2; None: derived from the data as beacon_slam does).
        :func:`rangeslam.rangeaided.convert.problem_from_range_odometry` has the details."""
        from rangeslam.rangeaided.convert import problem_from_range_odometry

        return problem_from_range_odometry(
            self, odometry_sigma=odometry_sigma, range_sigma=range_sigma,
            truth_poses=truth_poses, truth_beacons=truth_beacons,
        )  # fmt: skip

    @classmethod
    def from_problem(cls, problem: RangeAidedProblem) -> RangeOdometry:
        """The beacon log a one-robot 2-D :class:`~rangeslam.rangeaided.RangeAidedProblem` is
        (:func:`rangeslam.rangeaided.convert.range_odometry_from_problem`)."""
        from rangeslam.rangeaided.convert import range_odometry_from_problem

        return range_odometry_from_problem(problem)

    def first(self, n_poses: int) -> RangeOdometry:
        """The first ``n_poses`` poses (n_poses - 1 odometry steps) and the ranges among them."""
        if not (isinstance(n_poses, int | np.integer) and 2 <= n_poses <= len(self.pose_time)):
            raise InvalidInputError(
                f"n_poses must be an integer in [2, {len(self.pose_time)}]; got {n_poses!r}"
            )
        keep = self.range_pose < n_poses
        return RangeOdometry(
            self.pose_time[:n_poses],
            self.odometry[: n_poses - 1],
            self.range_pose[keep],
            self.range_beacon[keep],
            self.ranges[keep],
            self.n_beacons,
            self.beacon_ids,
        )


def _finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise InvalidInputError(f"{name} must be finite; entry {bad} is {arr[bad]}")


def _as_index(value: ArrayLike, name: str, length: int, upper: int, hint: str = "") -> np.ndarray:
    """``value`` as (length,) int64 indices in [0, upper), else InvalidInputError naming ``name``."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be ({length},) integers; got {value!r:.80}") from exc
    if arr.dtype.kind not in "iuf":
        raise InvalidInputError(f"{name} must hold integers; got dtype {arr.dtype}")
    if arr.shape != (length,):
        raise InvalidInputError(f"{name} must have shape ({length},); got {shape_str(arr.shape)}")
    integral = arr.dtype.kind in "iu" or (
        arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))
    )
    if not integral:
        raise InvalidInputError(f"{name} must hold integers; got dtype {arr.dtype}")
    out = (arr < 0) | (arr >= upper)  # compared before the cast: 1e30 or 2**64 - 1 would wrap
    if np.any(out):
        i = int(np.argmax(out))
        raise InvalidInputError(
            f"{name} must lie in [0, {upper - 1}]; entry {i} is {arr[i]}"
            + (hint if arr[i] >= upper else "")
        )
    return arr.astype(np.int64)


def check_data(data) -> None:
    """InvalidInputError unless ``data`` is a :class:`RangeOdometry`."""
    if not isinstance(data, RangeOdometry):
        raise InvalidInputError(
            f"data must be a RangeOdometry (see RangeOdometry.create); got {type(data).__name__}"
        )


def all_heard_placed(data: RangeOdometry, placed: np.ndarray) -> bool:
    """Every beacon that was ranged to got a position (beacons never heard do not count)."""
    heard = np.isin(np.arange(data.n_beacons), data.range_beacon)
    return bool(np.all(placed[heard]))


def path_length(odometry: np.ndarray) -> np.ndarray:
    """(N + 1,) length of the path travelled to each pose [m]: the running sum of |d| (a step
    backwards lengthens the path too)."""
    return np.concatenate([[0.0], np.cumsum(np.abs(odometry[:, 0]))])


def dead_reckoning(odometry: np.ndarray, start_pose: np.ndarray) -> np.ndarray:
    """(N + 1, 3) poses from integrating (N, 2) odometry (distance [m], heading change [rad]).

    Each step moves, then turns: the pose composed with Pose2(d, 0, dtheta).
    """
    d, dtheta = odometry[:, 0], odometry[:, 1]
    theta = start_pose[2] + np.concatenate([[0.0], np.cumsum(dtheta)])
    x = start_pose[0] + np.concatenate([[0.0], np.cumsum(d * np.cos(theta[:-1]))])
    y = start_pose[1] + np.concatenate([[0.0], np.cumsum(d * np.sin(theta[:-1]))])
    return np.column_stack([x, y, theta])


def compose_poses(frame: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Poses (n, 3) expressed in ``frame`` (3,) or per-pose frames (n, 3), moved to the world."""
    frame = np.broadcast_to(frame, poses.shape)
    c, s = np.cos(frame[:, 2]), np.sin(frame[:, 2])
    x = frame[:, 0] + c * poses[:, 0] - s * poses[:, 1]
    y = frame[:, 1] + s * poses[:, 0] + c * poses[:, 1]
    return np.column_stack([x, y, frame[:, 2] + poses[:, 2]])
