"""Loader for the CMU Plaza range-only SLAM data sets (Plaza1, Plaza2), as shipped with GTSAM.

J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground
truth", Journal of Field Robotics 26(9), 2009. A robot drives around a plaza and measures ranges
to radio beacons (the robot's radio is sender 2); its odometry, the surveyed beacon positions and
a ground-truth path are included. Everything is 2-D, metres, radians and seconds.

Files (in GTSAM's example data, ``gtsam.findExampleDataFile``, or in ``data_dir``):

- ``<name>_DR.txt``: one odometry step per row: time [s], distance travelled [m], heading change
  [rad]. Whitespace separated, CRLF line ends, no header.
- ``<name>_TD.txt``: one range per row: time [s], sender id, beacon id, range [m].
- ``<name>_.mat``: ``GT`` (time, x, y, heading), the ground truth, and ``TL`` (id, x, y), the
  surveyed beacons. The file also holds copies of DR and TD (identical to the text files) and
  ``DRp``, a dead-reckoned path that this loader does not read (its step directions are about
  0.27 rad off its own headings on Plaza1: it is not DR integrated in any convention tried).

What was measured on Plaza1 (tests/test_plaza.py asserts these):

- 9,657 odometry steps at 5.0 Hz over 1,933.2 s; 3,529 ranges to beacons 0, 1, 5 and 6.
- ``GT`` has one row more than DR: row 0 is the start pose, 0.20 s before the first step, and
  rows 1.. are at exactly the odometry times. Its heading column is the start heading plus the
  running sum of the odometry's heading changes (to 1e-13 rad, modulo 2 pi), so ground-truth
  heading is not independent of the odometry; only the positions are.
- The TD file is three time-sorted blocks that overlap in time (time jumps back at rows 1989 and
  2867); the loader sorts the ranges by time (stable) and keeps each one's file row in
  ``range_row`` and the rows where time went back in ``range_time_jumps``. Nothing is dropped.
- Ranges are biased: range minus true distance (truth interpolated at the range time) has mean
  2.60, 2.90, 2.79 and 2.88 m for beacons 0, 1, 5 and 6 (all ranges: 2.79 m) with standard
  deviation 1.0 to 1.3 m.
- The robot stands still for the first 44.8 s of ground truth (within 1 cm of its start pose)
  and is under way at about 0.6 m/s by 48 s; the odometry creeps about 6 cm meanwhile.
"""

from __future__ import annotations

import logging
import math
import os
import zlib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_point, frozen, shape_str
from rangeslam.errors import DataFormatError, InvalidInputError

__all__ = ["PLAZA_CITATION", "PLAZA_NAMES", "PlazaDataset", "PlazaFileNotFoundError", "plaza"]

log = logging.getLogger(__name__)

# Ids are read as float64 from text and MATLAB files: beyond 2^53 they are no longer exact.
MAX_EXACT_ID = 2**53


class PlazaFileNotFoundError(InvalidInputError, FileNotFoundError):
    """A CMU Plaza file is missing: the package's InvalidInputError, and the FileNotFoundError
    that :func:`plaza` documents."""


PLAZA_NAMES = ("Plaza1", "Plaza2")

PLAZA_CITATION = (
    'J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with '
    'ground truth", Journal of Field Robotics 26(9), 2009.'
)


@dataclass(frozen=True, eq=False)  # arrays: compared by identity, hashable
class PlazaDataset:
    """One CMU Plaza data set: odometry, ranges to radio beacons, surveyed beacons, ground truth.

    Arrays are read-only, points are rows, lengths in metres, angles in radians, times in seconds
    (the files' clock; the three streams share it).

    Attributes:
        name: "Plaza1" or "Plaza2".
        odometry_time: (N,) time of each odometry step, strictly increasing.
        odometry: (N, 2) per step: distance travelled [m] (>= 0) and heading change [rad].
        range_time: (R,) time of each range, sorted (stable; see ``range_row``).
        range_sender: (R,) id of the radio that sent the ping (2, the robot, in both files).
        range_beacon: (R,) id of the beacon ranged to; every id is one of ``beacon_ids``.
        ranges: (R,) measured ranges [m], as in the file (biased; see :meth:`range_bias`).
        range_row: (R,) 1-based row of each range in the TD file.
        range_time_jumps: 1-based TD rows whose time is earlier than the row before (the file
            is a concatenation of time-sorted blocks; Plaza1 has two jumps, Plaza2 none).
        beacon_ids: (B,) ids of the surveyed beacons, in the file's order.
        beacons: (B, 2) surveyed beacon positions, rows matching ``beacon_ids``.
        truth_time: (T,) ground-truth times, strictly increasing.
        truth: (T, 3) ground truth x, y [m] and heading [rad] as in the file (Plaza1 wraps it into
            [-pi/2, 3 pi/2), Plaza2 into [-pi, pi]; compare headings modulo 2 pi).
        citation: the reference to cite when using the data.
    """

    name: str
    odometry_time: np.ndarray
    odometry: np.ndarray
    range_time: np.ndarray
    range_sender: np.ndarray
    range_beacon: np.ndarray
    ranges: np.ndarray
    range_row: np.ndarray
    range_time_jumps: tuple[int, ...]
    beacon_ids: np.ndarray
    beacons: np.ndarray
    truth_time: np.ndarray
    truth: np.ndarray
    citation: str = PLAZA_CITATION

    @property
    def beacon_index(self) -> MappingProxyType[int, int]:
        """Read-only mapping from beacon id to its row in ``beacons``."""
        return MappingProxyType({int(b): i for i, b in enumerate(self.beacon_ids)})

    @property
    def range_beacon_index(self) -> np.ndarray:
        """(R,) row in ``beacons`` of each range's beacon: ``beacons[range_beacon_index]``."""
        order = np.argsort(self.beacon_ids)
        return order[np.searchsorted(self.beacon_ids, self.range_beacon, sorter=order)]

    @property
    def pose_time(self) -> np.ndarray:
        """(N + 1,) time of each pose: the start (``truth_time[0]``), then each odometry step.

        Pose k is the robot after odometry step k (row k of :meth:`dead_reckoning`).
        """
        return frozen(np.concatenate([[self.truth_time[0]], self.odometry_time]))

    @property
    def range_pose(self) -> np.ndarray:
        """(R,) index of the pose each range is attached to: the first pose at or after its time.

        The convention of GTSAM's RangeISAMExample_plaza2 (a range joins the graph with the first
        odometry step whose time is not earlier). Ranges after the last step (none in either
        file) go to the last pose.
        """
        idx = np.searchsorted(self.pose_time, self.range_time, side="left")
        return frozen(np.minimum(idx, len(self.pose_time) - 1))

    def truth_at(self, times: ArrayLike) -> np.ndarray:
        """(n, 2) ground-truth positions at ``times`` (a scalar or 1-D), linearly interpolated.

        Times outside [truth_time[0], truth_time[-1]] raise InvalidInputError rather than being
        clamped to an end (np.interp's default) or returned as NaN: both would pass silently into
        an error statistic. Every odometry and range time of both files lies inside the span.
        """
        t = as_float_array(times, "times")
        if t.ndim > 1:
            raise InvalidInputError(f"times must be a scalar or 1-D; got {shape_str(t.shape)}")
        t = np.atleast_1d(t)
        lo, hi = self.truth_time[0], self.truth_time[-1]
        outside = ~((t >= lo) & (t <= hi))  # also catches NaN
        if np.any(outside):
            i = int(np.argmax(outside))
            raise InvalidInputError(
                f"times must lie in the ground-truth span [{lo:.3f}, {hi:.3f}] s; "
                f"times[{i}] = {t[i]} ({int(outside.sum())} of {t.size} outside)"
            )
        x = np.interp(t, self.truth_time, self.truth[:, 0])
        y = np.interp(t, self.truth_time, self.truth[:, 1])
        return np.column_stack([x, y])

    def range_errors(self) -> np.ndarray:
        """(R,) each range minus the true distance from the robot (truth at the range time)."""
        robot = self.truth_at(self.range_time)
        true = np.linalg.norm(robot - self.beacons[self.range_beacon_index], axis=1)
        return self.ranges - true

    def range_bias(self) -> np.ndarray:
        """(B,) mean of range minus true distance per beacon, rows matching ``beacon_ids``.

        NaN for a beacon that was never ranged to.
        """
        err = self.range_errors()
        idx = self.range_beacon_index
        out = np.full(len(self.beacon_ids), np.nan)
        for b in range(len(self.beacon_ids)):
            if np.any(idx == b):
                out[b] = err[idx == b].mean()
        return out

    def dead_reckoning(self, start_pose: ArrayLike) -> np.ndarray:
        """(N + 1, 3) poses x, y, heading from integrating the odometry from ``start_pose``.

        Row 0 is ``start_pose`` (x, y, heading); row k is the pose after step k, at
        ``odometry_time[k - 1]``. On Plaza1 ``truth[0]`` is the pose before the first step and its
        heading is the odometry's. There is no default because that does not carry over: GTSAM's
        RangeISAMExample_plaza2 starts Plaza2 from pi + its ground-truth heading (not checked
        here; Plaza2 is kept as unseen data).

        Each step moves first and turns after: x += d cos(theta), y += d sin(theta), then
        theta += dtheta, i.e. the pose composed with Pose2(d, 0, dtheta), as GTSAM's Plaza
        examples use the odometry. Predicting each ground-truth pose from the one before, this
        convention is 2x closer than turn-then-move on the 3,498 Plaza1 steps that move more
        than 0.1 m and turn by more than 0.03 rad (median error 4.9 mm against 10.0 mm); over the
        whole path the two differ
        little (from truth[0], move-then-turn is 0.81 m off within the first 10 m, 1.17 m within
        50 m, 2.13 m at worst up to 1,000 m and 4.39 m at the end, after 1,861 m of odometry).
        Headings are not wrapped.
        """
        from rangeslam.beacons.data import dead_reckoning

        return dead_reckoning(self.odometry, as_point(start_pose, "start_pose", dim=3))


def plaza(name: str = "Plaza1", *, data_dir: str | Path | None = None) -> PlazaDataset:
    """Load the CMU Plaza data set ``name`` ("Plaza1" or "Plaza2"); nothing is downloaded.

    The files come from the installed GTSAM's example data (``gtsam.findExampleDataFile``) or,
    when ``data_dir`` is given, from that directory (``<name>_DR.txt``, ``<name>_TD.txt``,
    ``<name>_.mat``). Cite J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios:
    five data sets with ground truth", Journal of Field Robotics 26(9), 2009 (``citation``).

    Raises:
        InvalidInputError: ``name`` is not one of :data:`PLAZA_NAMES`.
        PlazaFileNotFoundError (an InvalidInputError and a FileNotFoundError): a file is missing
            (the message names it). InvalidInputError: ``data_dir`` is not a path.
        DataFormatError: a row is malformed or truncated, holds a non-finite value, goes back in
            time (odometry, ground truth), or ranges to a beacon that was not surveyed; the
            message names the file and the 1-based row.
    """
    if not isinstance(name, str) or name not in PLAZA_NAMES:
        raise InvalidInputError(
            f"name must be one of {', '.join(repr(n) for n in PLAZA_NAMES)}; got {name!r}"
        )
    dr_path, td_path, mat_path = (
        _locate(f"{name}{suffix}", data_dir) for suffix in ("_DR.txt", "_TD.txt", "_.mat")
    )

    truth, tl = _read_mat(mat_path)
    beacon_ids = tl[:, 0].astype(np.int64)

    dr = _read_table(dr_path, ("time", "distance", "heading change"))
    _check_increasing(dr[:, 0], dr_path, "time")
    if np.any(dr[:, 1] < 0):
        row = int(np.argmax(dr[:, 1] < 0)) + 1
        raise DataFormatError(
            f"{dr_path}, row {row}: distance travelled must be >= 0; got {dr[row - 1, 1]}"
        )

    td = _read_table(td_path, ("time", "sender id", "beacon id", "range"))
    for col, what in ((1, "sender id"), (2, "beacon id")):
        bad = (td[:, col] != np.round(td[:, col])) | (np.abs(td[:, col]) >= MAX_EXACT_ID)
        if np.any(bad):
            row = int(np.argmax(bad)) + 1
            raise DataFormatError(
                f"{td_path}, row {row}: {what} must be an integer below 2^53; got "
                f"{td[row - 1, col]}"
            )
    if np.any(td[:, 3] <= 0):
        row = int(np.argmax(td[:, 3] <= 0)) + 1
        raise DataFormatError(f"{td_path}, row {row}: range must be > 0 m; got {td[row - 1, 3]}")
    range_beacon = td[:, 2].astype(np.int64)
    unknown = ~np.isin(range_beacon, beacon_ids)
    if np.any(unknown):
        row = int(np.argmax(unknown)) + 1
        raise DataFormatError(
            f"{td_path}, row {row}: beacon id {range_beacon[row - 1]} is not among the surveyed "
            f"beacons {sorted(int(b) for b in beacon_ids)} (TL in {mat_path.name})"
        )
    jumps = tuple(int(i) + 2 for i in np.flatnonzero(np.diff(td[:, 0]) < 0))
    order = np.argsort(td[:, 0], kind="stable")
    if jumps:
        log.info(
            "%s: time goes back at rows %s; ranges sorted by time (none dropped)", td_path, jumps
        )

    return PlazaDataset(
        name=name,
        odometry_time=frozen(dr[:, 0].copy()),
        odometry=frozen(dr[:, 1:3].copy()),
        range_time=frozen(td[order, 0]),
        range_sender=frozen(td[order, 1].astype(np.int64)),
        range_beacon=frozen(range_beacon[order]),
        ranges=frozen(td[order, 3]),
        range_row=frozen(order + 1),
        range_time_jumps=jumps,
        beacon_ids=frozen(beacon_ids),
        beacons=frozen(tl[:, 1:3].copy()),
        truth_time=frozen(truth[:, 0].copy()),
        truth=frozen(truth[:, 1:4].copy()),
    )


def _locate(filename: str, data_dir: str | Path | None) -> Path:
    if data_dir is not None:
        if not isinstance(data_dir, str | os.PathLike) or (
            isinstance(data_dir, str) and ("\x00" in data_dir or not data_dir)
        ):
            raise InvalidInputError(
                f"data_dir must be a directory path (str or Path) or None; got {data_dir!r:.80}"
            )
        path = Path(data_dir) / filename
        if not path.is_file():
            raise PlazaFileNotFoundError(f"CMU Plaza file not found: {path} (data_dir={data_dir})")
        return path
    import gtsam  # the example data ships with GTSAM's Python wheel

    try:
        return Path(gtsam.findExampleDataFile(filename))
    except (OSError, RuntimeError) as exc:
        raise PlazaFileNotFoundError(
            f"CMU Plaza file {filename} not found in the installed GTSAM's example data ({exc}); "
            "pass data_dir= with the directory that holds it"
        ) from exc


def _read_table(path: Path, columns: tuple[str, ...]) -> np.ndarray:
    """Rows of whitespace-separated numbers, exactly len(columns) per row, all finite."""
    n = len(columns)
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{path}: not a text file of numbers ({exc})") from exc
    if not text.strip():
        raise DataFormatError(f"{path}: no rows")
    lines = text.split("\n")
    if lines[-1].strip():
        # every row of the shipped files ends with a line break; without one the last number may
        # have been cut short and still parse (4.6e-005 -> 4.6e-00)
        raise DataFormatError(
            f"{path}, row {len(lines)}: the last row has no line end (truncated file?)"
        )
    lines = lines[:-1]
    out = np.empty((len(lines), n))
    for row, line in enumerate(lines, start=1):
        fields = line.split()
        if len(fields) != n:
            raise DataFormatError(
                f"{path}, row {row}: expected {n} numbers ({', '.join(columns)}), "
                f"got {len(fields)}: {line.strip()!r:.120}"
            )
        try:
            vals = [float(v) for v in fields]
        except ValueError as exc:
            raise DataFormatError(f"{path}, row {row}: {exc}") from exc
        for v, col in zip(vals, columns, strict=True):
            if not math.isfinite(v):
                raise DataFormatError(f"{path}, row {row}: {col} must be finite; got {v}")
        out[row - 1] = vals
    return out


def _check_increasing(t: np.ndarray, path: Path, what: str) -> None:
    back = np.diff(t) <= 0
    if np.any(back):
        i = int(np.argmax(back))
        raise DataFormatError(
            f"{path}, row {i + 2}: {what} must increase strictly; {t[i + 1]} follows {t[i]}"
        )


def _read_mat(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(T, 4) ground truth GT (time, x, y, heading) and (B, 3) beacons TL (id, x, y)."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    try:
        mat = loadmat(path, variable_names=["GT", "TL"])
    except (MatReadError, ValueError, TypeError, IndexError, OSError, EOFError, zlib.error) as exc:
        raise DataFormatError(f"{path}: not a readable MATLAB file ({exc})") from exc
    arrays = {}
    for key, cols, what in (("GT", 4, "time, x, y, heading"), ("TL", 3, "id, x, y")):
        if key not in mat:
            found = ", ".join(k for k in ("GT", "TL") if k in mat) or "neither"
            raise DataFormatError(
                f"{path}: variable {key!r} ({what}) is missing (found: {found}; truncated file?)"
            )
        arr = np.asarray(mat[key])
        if arr.ndim != 2 or arr.shape[1] != cols or arr.shape[0] < 1:
            raise DataFormatError(
                f"{path}: {key} must have shape (*, {cols}) ({what}); got {shape_str(arr.shape)}"
            )
        try:
            arr = arr.astype(float)
        except (TypeError, ValueError) as exc:
            raise DataFormatError(f"{path}: {key} must hold numbers ({exc})") from exc
        if not np.all(np.isfinite(arr)):
            row, col = np.argwhere(~np.isfinite(arr))[0]
            raise DataFormatError(
                f"{path}: {key} row {row + 1}, column {col + 1} must be finite; got {arr[row, col]}"
            )
        arrays[key] = arr
    truth, tl = arrays["GT"], arrays["TL"]
    _check_increasing(truth[:, 0], path, "GT time")
    ids = tl[:, 0]
    if (
        np.any(ids != np.round(ids))
        or np.any(np.abs(ids) >= MAX_EXACT_ID)
        or len(np.unique(ids)) != len(ids)
    ):
        raise DataFormatError(f"{path}: TL ids must be distinct integers; got {ids.tolist()}")
    return truth, tl
