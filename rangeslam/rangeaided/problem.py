"""A range-aided SLAM problem: several robots' poses (SE(2) or SE(3)), landmarks, relative-pose
odometry with covariances, ranges pose-landmark and pose-pose, relative landmark observations,
priors, and the reference (truth) values kept apart.

This is the problem the range-aided SLAM community exchanges as PyFG text files (CORA: A.
Papalia et al., "Certifiably Correct Range-Aided SLAM", IEEE T-RO 2024;
:func:`rangeslam.datasets.pyfg.load_pyfg`); a one-robot 2-D beacon log
(:class:`rangeslam.beacons.RangeOdometry`) is one way to build it
(:meth:`RangeOdometry.to_problem <rangeslam.beacons.data.RangeOdometry.to_problem>`).

Conventions (the PyFG files'): a 2-D pose is (x, y, theta) [m, m, rad]; a 3-D pose is
(x, y, z, qx, qy, qz, qw) [m, unit quaternion, Hamilton, scalar last]. A relative pose of b in the
frame of a is the same tuple for T_a^-1 T_b. Covariances are in the tangent order of the tuple:
(x, y, theta) in 2-D, (x, y, z, then rotation) in 3-D, translation first (GTSAM's Pose3 has
rotation first: :mod:`rangeslam.rangeaided.gtsam_solve` permutes them).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from rangeslam._validation import frozen, shape_str
from rangeslam.errors import InvalidInputError

__all__ = [
    "LANDMARK_LETTER",
    "LandmarkObservations",
    "LandmarkPriors",
    "PosePriors",
    "RangeAidedProblem",
    "RangeMeasurements",
    "RelativePoses",
    "pose_width",
    "positive_definite",
    "tangent_width",
]

#: The letter of landmark names (L0, L1, ...); robots are the other capital letters.
LANDMARK_LETTER = "L"
#: Largest name index (A<index>, L<index>) accepted; beyond it a typo is more likely than data.
MAX_NAME_INDEX = 2**53
# Quaternions must have unit norm to this tolerance (files print them to 7 digits or more).
UNIT_TOLERANCE = 1e-5


def pose_width(dim: int) -> int:
    """Columns of a pose row: 3 in 2-D (x, y, theta), 7 in 3-D (x, y, z, qx, qy, qz, qw)."""
    return 3 if dim == 2 else 7


def tangent_width(dim: int) -> int:
    """Rows of a pose covariance: 3 in 2-D, 6 in 3-D (translation first, then rotation)."""
    return 3 if dim == 2 else 6


def _floats(value, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a fresh finite float64 array of ``shape`` (None: any length)."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must hold real numbers; got {value!r:.80}") from exc
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        want = shape_str(tuple("*" if s is None else s for s in shape))  # type: ignore[misc]
        raise InvalidInputError(f"{name} must have shape {want}; got {shape_str(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise InvalidInputError(f"{name} must be finite; entry {bad} is {arr[bad]}")
    return arr


def _indices(value, name: str, length: int | None, upper: int) -> np.ndarray:
    """``value`` as a fresh (length,) int64 array of indices in [0, upper)."""
    arr = np.asarray(value)
    if arr.size == 0:
        arr = arr.astype(np.int64)
    if arr.dtype.kind not in "iu" or arr.ndim != 1 or (length is not None and len(arr) != length):
        want = "*" if length is None else length
        raise InvalidInputError(
            f"{name} must be ({want},) integers; got {shape_str(arr.shape)} of dtype {arr.dtype}"
        )
    out = (arr < 0) | (arr >= upper)
    if np.any(out):
        i = int(np.argmax(out))
        raise InvalidInputError(f"{name} must lie in [0, {upper - 1}]; entry {i} is {arr[i]}")
    return arr.astype(np.int64)


def _covariances(value, name: str, n: int, k: int) -> np.ndarray:
    """(n, k, k) symmetric positive-definite covariances."""
    cov = _floats(value, name, (n, k, k))
    if not np.array_equal(cov, np.swapaxes(cov, 1, 2)):
        i = int(np.argmax(np.any(cov != np.swapaxes(cov, 1, 2), axis=(1, 2))))
        raise InvalidInputError(f"{name} must be symmetric; entry {i} is not")
    bad = ~positive_definite(cov)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise InvalidInputError(f"{name} must be positive definite; entry {i} is not")
    return cov


def positive_definite(cov: np.ndarray) -> np.ndarray:
    """(n,) True where the (n, k, k) symmetric ``cov`` is positive definite: a positive diagonal
    and a correlation matrix D^-1/2 C D^-1/2 with eigenvalues > 0 (scaled first, so variances
    of 1e-200 and 1e200 side by side are judged as well as unit ones)."""
    cov = np.asarray(cov, dtype=float)
    diag = np.diagonal(cov, axis1=1, axis2=2)
    ok = np.all(diag > 0, axis=1)
    if not np.any(ok):
        return ok
    s = 1.0 / np.sqrt(diag[ok])
    corr = cov[ok] * s[:, :, None] * s[:, None, :]
    ok[ok] = np.linalg.eigvalsh(corr).min(axis=1) > 0
    return ok


def _check_quaternions(values: np.ndarray, name: str, start: int) -> None:
    """Columns start..start+3 of ``values`` are unit quaternions (to :data:`UNIT_TOLERANCE`)."""
    norm = np.linalg.norm(values[:, start : start + 4], axis=1)
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    if np.any(off):
        i = int(np.argmax(off))
        raise InvalidInputError(
            f"{name}: the quaternion (columns {start}-{start + 3}) must have norm 1; entry {i} "
            f"has norm {norm[i]:.9g}"
        )


def _freeze(obj, **arrays) -> None:
    for key, arr in arrays.items():
        object.__setattr__(obj, key, frozen(arr))


@dataclass(frozen=True, eq=False)
class RelativePoses:
    """M relative-pose measurements (odometry, loop closures): pose b in the frame of pose a.

    Attributes:
        pose_a, pose_b: (M,) pose rows of the problem.
        values: (M, 3) (dx [m], dy [m], dtheta [rad]) in 2-D, (M, 7) (dx, dy, dz [m], qx, qy,
            qz, qw) in 3-D.
        covariance: (M, 3, 3) or (M, 6, 6), translation first [m^2, rad^2].
        time: (M,) the measurement's time stamp [s] (as the file has it).
    """

    pose_a: np.ndarray
    pose_b: np.ndarray
    values: np.ndarray
    covariance: np.ndarray
    time: np.ndarray

    def __post_init__(self) -> None:
        values = _floats(self.values, "odometry.values", (None, None))
        m = len(values)
        if values.shape[1] not in (3, 7):
            raise InvalidInputError(
                f"odometry.values must have shape (M, 3) (2-D) or (M, 7) (3-D); got "
                f"{shape_str(values.shape)}"
            )
        dim = 2 if values.shape[1] == 3 else 3
        if dim == 3:
            _check_quaternions(values, "odometry.values", 3)
        _freeze(
            self,
            pose_a=_indices(self.pose_a, "odometry.pose_a", m, MAX_NAME_INDEX),
            pose_b=_indices(self.pose_b, "odometry.pose_b", m, MAX_NAME_INDEX),
            values=values,
            covariance=_covariances(self.covariance, "odometry.covariance", m, tangent_width(dim)),
            time=_floats(self.time, "odometry.time", (m,)),
        )

    @classmethod
    def empty(cls, dim: int) -> RelativePoses:
        """No measurements, in ``dim`` dimensions."""
        w, k = pose_width(dim), tangent_width(dim)
        none = np.zeros(0, np.int64)
        return cls(none, none, np.zeros((0, w)), np.zeros((0, k, k)), np.zeros(0))


@dataclass(frozen=True, eq=False)
class RangeMeasurements:
    """R ranges from a pose to a landmark or to another pose (another robot's).

    Attributes:
        pose: (R,) pose row of the first end.
        other: (R,) landmark row where ``to_landmark``, else pose row, of the second end.
        to_landmark: (R,) bool: the second end is a landmark.
        ranges: (R,) measured distances [m], >= 0.
        variance: (R,) their variances [m^2], > 0.
        time: (R,) time stamps [s].
    """

    pose: np.ndarray
    other: np.ndarray
    to_landmark: np.ndarray
    ranges: np.ndarray
    variance: np.ndarray
    time: np.ndarray

    def __post_init__(self) -> None:
        r = _floats(self.ranges, "ranges.ranges", (None,))
        if np.any(r < 0):
            i = int(np.argmax(r < 0))
            raise InvalidInputError(f"ranges.ranges must be >= 0; entry {i} is {r[i]}")
        var = _floats(self.variance, "ranges.variance", (len(r),))
        if np.any(var <= 0):
            i = int(np.argmax(var <= 0))
            raise InvalidInputError(f"ranges.variance must be > 0; entry {i} is {var[i]}")
        mask = np.asarray(self.to_landmark)
        if mask.dtype != bool or mask.shape != r.shape:
            raise InvalidInputError(
                f"ranges.to_landmark must be ({len(r)},) bools; got {shape_str(mask.shape)} of "
                f"dtype {mask.dtype}"
            )
        _freeze(
            self,
            pose=_indices(self.pose, "ranges.pose", len(r), MAX_NAME_INDEX),
            other=_indices(self.other, "ranges.other", len(r), MAX_NAME_INDEX),
            to_landmark=mask.copy(),
            ranges=r,
            variance=var,
            time=_floats(self.time, "ranges.time", (len(r),)),
        )

    @classmethod
    def empty(cls) -> RangeMeasurements:
        """No ranges."""
        none = np.zeros(0, np.int64)
        return cls(none, none, np.zeros(0, bool), np.zeros(0), np.zeros(0), np.zeros(0))


@dataclass(frozen=True, eq=False)
class LandmarkObservations:
    """K relative landmark positions: the landmark in the frame of the pose.

    Attributes:
        pose: (K,) pose rows. landmark: (K,) landmark rows.
        values: (K, d) the landmark's position in the pose's frame [m].
        covariance: (K, d, d) [m^2].
        time: (K,) time stamps [s].
    """

    pose: np.ndarray
    landmark: np.ndarray
    values: np.ndarray
    covariance: np.ndarray
    time: np.ndarray

    def __post_init__(self) -> None:
        values = _floats(self.values, "landmark_observations.values", (None, None))
        k, d = values.shape
        if d not in (2, 3):
            raise InvalidInputError(
                f"landmark_observations.values must have shape (K, 2) or (K, 3); got "
                f"{shape_str(values.shape)}"
            )
        name = "landmark_observations"
        _freeze(
            self,
            pose=_indices(self.pose, f"{name}.pose", k, MAX_NAME_INDEX),
            landmark=_indices(self.landmark, f"{name}.landmark", k, MAX_NAME_INDEX),
            values=values,
            covariance=_covariances(self.covariance, f"{name}.covariance", k, d),
            time=_floats(self.time, f"{name}.time", (k,)),
        )

    @classmethod
    def empty(cls, dim: int) -> LandmarkObservations:
        """No observations, in ``dim`` dimensions."""
        none = np.zeros(0, np.int64)
        return cls(none, none, np.zeros((0, dim)), np.zeros((0, dim, dim)), np.zeros(0))


@dataclass(frozen=True, eq=False)
class PosePriors:
    """Q priors on poses. Attributes: pose (Q,) rows; values (Q, 3) or (Q, 7) poses;
    covariance (Q, 3, 3) or (Q, 6, 6), translation first; time (Q,) [s]."""

    pose: np.ndarray
    values: np.ndarray
    covariance: np.ndarray
    time: np.ndarray

    def __post_init__(self) -> None:
        values = _floats(self.values, "pose_priors.values", (None, None))
        q = len(values)
        if values.shape[1] not in (3, 7):
            raise InvalidInputError(
                f"pose_priors.values must have shape (Q, 3) or (Q, 7); got "
                f"{shape_str(values.shape)}"
            )
        dim = 2 if values.shape[1] == 3 else 3
        if dim == 3:
            _check_quaternions(values, "pose_priors.values", 3)
        _freeze(
            self,
            pose=_indices(self.pose, "pose_priors.pose", q, MAX_NAME_INDEX),
            values=values,
            covariance=_covariances(
                self.covariance, "pose_priors.covariance", q, tangent_width(dim)
            ),
            time=_floats(self.time, "pose_priors.time", (q,)),
        )

    @classmethod
    def empty(cls, dim: int) -> PosePriors:
        """No priors, in ``dim`` dimensions."""
        k = tangent_width(dim)
        return cls(np.zeros(0, np.int64), np.zeros((0, pose_width(dim))), np.zeros((0, k, k)),
                   np.zeros(0))  # fmt: skip


@dataclass(frozen=True, eq=False)
class LandmarkPriors:
    """Q priors on landmarks. Attributes: landmark (Q,) rows; values (Q, d) positions [m];
    covariance (Q, d, d) [m^2]; time (Q,) [s]."""

    landmark: np.ndarray
    values: np.ndarray
    covariance: np.ndarray
    time: np.ndarray

    def __post_init__(self) -> None:
        values = _floats(self.values, "landmark_priors.values", (None, None))
        q, d = values.shape
        if d not in (2, 3):
            raise InvalidInputError(
                f"landmark_priors.values must have shape (Q, 2) or (Q, 3); got "
                f"{shape_str(values.shape)}"
            )
        _freeze(
            self,
            landmark=_indices(self.landmark, "landmark_priors.landmark", q, MAX_NAME_INDEX),
            values=values,
            covariance=_covariances(self.covariance, "landmark_priors.covariance", q, d),
            time=_floats(self.time, "landmark_priors.time", (q,)),
        )

    @classmethod
    def empty(cls, dim: int) -> LandmarkPriors:
        """No priors, in ``dim`` dimensions."""
        return cls(np.zeros(0, np.int64), np.zeros((0, dim)), np.zeros((0, dim, dim)),
                   np.zeros(0))  # fmt: skip


@dataclass(frozen=True, eq=False)
class RangeAidedProblem:
    """A range-aided SLAM problem, validated at construction (InvalidInputError naming the
    field). P poses of one or more robots, L landmarks, d = ``dim``.

    Attributes:
        dim: 2 (poses SE(2), landmarks in the plane) or 3 (SE(3), points in space).
        robots: the robots' letters, distinct capital letters other than ``L`` ("A", "B", ...).
        pose_robot: (P,) each pose's robot, an index into ``robots``.
        pose_index: (P,) each pose's number in its robot's trajectory (pose "A12" is robot "A",
            index 12), >= 0; the poses are sorted by (robot, index), without repeats: a robot's
            poses are its trajectory in time order.
        pose_time: (P,) each pose's time [s].
        landmark_ids: (L,) each landmark's number (landmark "L3" has id 3), distinct (the
            loader sorts them; a converted beacon log keeps its beacons' order).
        odometry: relative poses between poses (odometry steps and any loop closures).
        ranges: ranges pose-landmark and pose-pose.
        landmark_observations: landmark positions in a pose's frame (default: none).
        pose_priors, landmark_priors: priors (default: none).
        truth_poses: (P, 3) or (P, 7) reference poses (the data set's ground truth), or None.
        truth_landmarks: (L, d) reference landmark positions, or None.
    """

    dim: int
    robots: tuple[str, ...]
    pose_robot: np.ndarray
    pose_index: np.ndarray
    pose_time: np.ndarray
    landmark_ids: np.ndarray
    odometry: RelativePoses
    ranges: RangeMeasurements
    landmark_observations: LandmarkObservations | None = None
    pose_priors: PosePriors | None = None
    landmark_priors: LandmarkPriors | None = None
    truth_poses: np.ndarray | None = field(default=None)
    truth_landmarks: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        dim = self.dim
        if isinstance(dim, bool) or dim not in (2, 3):
            raise InvalidInputError(f"dim must be 2 or 3; got {dim!r}")
        self._check_robots()
        n_poses = self._check_poses()
        ids = _indices(self.landmark_ids, "landmark_ids", None, MAX_NAME_INDEX)
        if len(np.unique(ids)) != len(ids):
            raise InvalidInputError("landmark_ids must be distinct; some id is repeated")
        _freeze(self, landmark_ids=ids)
        for name, kind in (
            ("landmark_observations", LandmarkObservations),
            ("pose_priors", PosePriors),
            ("landmark_priors", LandmarkPriors),
        ):
            if getattr(self, name) is None:
                object.__setattr__(self, name, kind.empty(dim))
        self._check_records(n_poses, len(ids))
        self._check_truth(n_poses, len(ids))

    def _check_robots(self) -> None:
        robots = self.robots
        if (
            not isinstance(robots, tuple)
            or not robots
            or not all(
                isinstance(r, str)
                and len(r) == 1
                and r.isupper()
                and r.isascii()
                and r != LANDMARK_LETTER
                for r in robots
            )
            or len(set(robots)) != len(robots)
        ):
            raise InvalidInputError(
                f"robots must be a non-empty tuple of distinct capital letters other than "
                f"{LANDMARK_LETTER!r}; got {robots!r:.80}"
            )

    def _check_poses(self) -> int:
        robot = _indices(self.pose_robot, "pose_robot", None, len(self.robots))
        n = len(robot)
        if n < 1:
            raise InvalidInputError("pose_robot must name at least one pose; got none")
        index = _indices(self.pose_index, "pose_index", n, MAX_NAME_INDEX)
        same = robot[1:] == robot[:-1]
        unsorted = (robot[1:] < robot[:-1]) | (same & (index[1:] <= index[:-1]))
        if np.any(unsorted):
            i = int(np.argmax(unsorted)) + 1
            raise InvalidInputError(
                f"pose_robot and pose_index must be sorted by (robot, index) without repeats; "
                f"pose {i} ({self.robots[robot[i]]}{index[i]}) is not"
            )
        _freeze(self, pose_robot=robot, pose_index=index,
                pose_time=_floats(self.pose_time, "pose_time", (n,)))  # fmt: skip
        return n

    def _check_records(self, n_poses: int, n_marks: int) -> None:
        dim = self.dim
        checks = (
            ("odometry", RelativePoses, pose_width(dim), (("pose_a", n_poses), ("pose_b", n_poses))),
            ("ranges", RangeMeasurements, None, (("pose", n_poses),)),
            ("landmark_observations", LandmarkObservations, dim,
             (("pose", n_poses), ("landmark", n_marks))),
            ("pose_priors", PosePriors, pose_width(dim), (("pose", n_poses),)),
            ("landmark_priors", LandmarkPriors, dim, (("landmark", n_marks),)),
        )  # fmt: skip
        for name, kind, width, refs in checks:
            record = getattr(self, name)
            if not isinstance(record, kind):
                raise InvalidInputError(
                    f"{name} must be a {kind.__name__}; got {type(record).__name__}"
                )
            if width is not None and record.values.shape[1] != width:
                raise InvalidInputError(
                    f"{name}.values must have {width} columns in {dim}-D; got "
                    f"{record.values.shape[1]}"
                )
            for attr, upper in refs:
                _indices(getattr(record, attr), f"{name}.{attr}", None, max(upper, 1))
                if upper == 0 and len(getattr(record, attr)):
                    raise InvalidInputError(f"{name}.{attr} refers to a landmark; there are none")
        r = self.ranges
        upper = np.where(r.to_landmark, n_marks, n_poses)
        bad = r.other >= upper
        if np.any(bad):
            i = int(np.argmax(bad))
            what = "landmark" if r.to_landmark[i] else "pose"
            raise InvalidInputError(
                f"ranges.other must be a {what} row below {upper[i]}; entry {i} is {r.other[i]}"
            )

    def _check_truth(self, n_poses: int, n_marks: int) -> None:
        if self.truth_poses is not None:
            poses = _floats(self.truth_poses, "truth_poses", (n_poses, pose_width(self.dim)))
            if self.dim == 3:
                _check_quaternions(poses, "truth_poses", 3)
            _freeze(self, truth_poses=poses)
        if self.truth_landmarks is not None:
            marks = _floats(self.truth_landmarks, "truth_landmarks", (n_marks, self.dim))
            _freeze(self, truth_landmarks=marks)

    @property
    def n_poses(self) -> int:
        """P."""
        return len(self.pose_robot)

    @property
    def n_landmarks(self) -> int:
        """L."""
        return len(self.landmark_ids)

    @property
    def pose_names(self) -> tuple[str, ...]:
        """(P,) names as the files write them: "A0", "B17"."""
        return tuple(
            f"{self.robots[r]}{i}" for r, i in zip(self.pose_robot, self.pose_index, strict=True)
        )

    @property
    def landmark_names(self) -> tuple[str, ...]:
        """(L,) names: "L0", "L3"."""
        return tuple(f"{LANDMARK_LETTER}{i}" for i in self.landmark_ids)

    def robot_rows(self, robot: int) -> np.ndarray:
        """Pose rows of robot number ``robot`` (an index into ``robots``), in index order."""
        if (
            isinstance(robot, bool)
            or not isinstance(robot, int | np.integer)
            or not (0 <= robot < len(self.robots))
        ):
            raise InvalidInputError(
                f"robot must be an integer in [0, {len(self.robots) - 1}]; got {robot!r}"
            )
        return np.flatnonzero(self.pose_robot == robot)

    def same_as(self, other: RangeAidedProblem) -> bool:
        """True when every field of ``other`` equals this one's exactly (arrays bit for bit)."""
        return isinstance(other, RangeAidedProblem) and all(
            _same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self)
        )


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and bool(np.all(a.view(np.uint8) == b.view(np.uint8)))
            if a.size
            else a.shape == b.shape
        )
    if hasattr(a, "__dataclass_fields__") and type(a) is type(b):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    return a == b
