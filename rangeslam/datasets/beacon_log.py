"""Beacon logs as plain CSV: odometry and ranges to beacons, with optional truth and known beacons.

The format (one file, one record a line, the first field says which; blank lines and lines
starting with ``#`` are comments; fields separated by commas, spaces around them ignored)::

    # rangeslam beacon log 1
    # range_sigma = 0.05                       (optional: the ranges' stated noise, metres)
    # odometry_sigma = 0.0005 0.0005 0.002     (optional: along, across [m], heading [rad])
    # wheel_base = 0.35                        (wheels records only: left to right wheel [m])
    start, 0.0                                 time [s] of pose 0
    odometry, 0.2, 0.01, 0.001                 time [s] of the pose it reaches, distance [m]
                                               (negative: backwards), heading change [rad]
    speed, 0.4, 0.05, 0.005                    or: time [s] of the pose it reaches, linear
                                               speed v [m/s], turn rate omega [rad/s]
    wheels, 0.6, 0.049, 0.051                  or: time [s] of the pose it reaches, left and
                                               right wheel linear speeds [m/s]
    range, 0.2, 7, 1.234                       time [s], beacon id (integer), range [m]
    truth, 0.2, 0.01, 0.0, 0.001               optional: time of a pose, x, y [m], heading [rad]
    beacon, 7, 1.5, -0.3, known                optional: beacon id, x, y [m], "known" (given to
                                               the estimator) or "truth" (evaluation only)

Each ``odometry``, ``speed`` or ``wheels`` record is one step to a new pose at its time; the three
kinds may be mixed and are in time order (each time after the one before, else the record's line
is named). Each step moves, then turns (as GTSAM's Plaza examples). Speeds are the mean over the
step, from the previous pose's time to the record's (encoder counts over the interval): the step is
the unicycle integrated at those speeds, distance v * dt and heading change omega * dt, with a
differential drive's v = (v_left + v_right) / 2 and omega = (v_right - v_left) / wheel_base. The
path length and heading change are exact; the arc's chord, at half the heading change, is taken
along the step's starting heading, as a Pose2(d, 0, dtheta) increment does (a sideways error of
about d * dtheta / 2 a step, the same as in ``odometry`` records written from such an arc).

A first row of column names (no field a number, the first naming no record, e.g.
``kind, time, a, b``) is a header and skipped. A comment ``# name = value`` is a setting: the
names are those above (:data:`BEACON_LOG_SETTINGS`); any other name, a name set twice, or a
setting's name without "=" is refused, naming the line (``# range_sigam = 0.05`` silently left the
noise to the data). Any other comment is free text.

A range joins the first pose at or after its time (as :func:`rangeslam.datasets.plaza` does);
ranges after the last pose are refused. Truth rows, when given, give every pose (in pose order).
Beacon ids are any integers >= 0 (rows of the result in increasing id order, as
:meth:`~rangeslam.beacons.RangeOdometry.from_beacon_ids`).
"""

from __future__ import annotations

import csv
import difflib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rangeslam._validation import frozen
from rangeslam.beacons.data import RangeOdometry
from rangeslam.errors import InvalidInputError

__all__ = [
    "BEACON_LOG_FIELDS",
    "BEACON_LOG_KINDS",
    "BEACON_LOG_SETTINGS",
    "ODOMETRY_FORMS",
    "STEP_KINDS",
    "BeaconLog",
    "is_beacon_log",
    "is_header",
    "load_beacon_log",
    "write_beacon_log",
]

#: The first field of a record, and how many numbers follow it (truth: 2 or 3).
BEACON_LOG_KINDS = {
    "start": (1,),
    "odometry": (3,),
    "speed": (3,),
    "wheels": (3,),
    "range": (3,),
    "truth": (3, 4),
    "beacon": (3,),
}
#: The name of each number of a record, as errors name them.
BEACON_LOG_FIELDS = {
    "start": ("time",),
    "odometry": ("time", "distance", "heading change"),
    "speed": ("time", "v", "omega"),
    "wheels": ("time", "v_left", "v_right"),
    "range": ("time", "beacon id", "range"),
    "truth": ("time", "x", "y", "heading"),
    "beacon": ("beacon id", "x", "y"),
}
#: The ``# name = value`` settings a log may state, and how many positive numbers each holds
#: (module notes); any other ``# name = ...`` comment is refused, naming these.
BEACON_LOG_SETTINGS = {"range_sigma": 1, "odometry_sigma": 3, "wheel_base": 1}
#: The records that are one odometry step each (module notes).
STEP_KINDS = ("odometry", "speed", "wheels")
#: How :func:`write_beacon_log` writes the odometry: increments, (v, omega) or wheel speeds.
ODOMETRY_FORMS = ("increments", "speed", "wheels")
# A comment that states a setting: a name (words, underscores), then "=".
SETTING = re.compile(r"^\s*([A-Za-z_][\w \-]*?)\s*=(.*)$")


@dataclass(frozen=True, eq=False)  # arrays
class BeaconLog:
    """A loaded beacon log.

    Attributes:
        data: the odometry and ranges (:class:`~rangeslam.beacons.RangeOdometry`).
        truth: (N + 1, 3) true poses (heading NaN when not given), or None.
        beacons: (B, 2) true beacon positions (NaN rows where not given), or None.
        known: (B, 2) beacon positions given as known (NaN rows for the others), or None.
        range_sigma: the stated range noise [m], or None.
        odometry_sigma: (3,) the stated odometry noise, or None.
        path: the file.
        range_lines: (R,) int, the file's line of each range of ``data`` (in its order), so a
            range can be named by its line.
    """

    data: RangeOdometry
    truth: np.ndarray | None
    beacons: np.ndarray | None
    known: np.ndarray | None
    range_sigma: float | None
    odometry_sigma: np.ndarray | None
    path: Path
    range_lines: np.ndarray | None = None


def is_beacon_log(path: Path) -> bool:
    """True when ``path`` is a .csv / .txt file whose first record (after a header row, if
    any) is a beacon log's, or which starts with the ``# rangeslam beacon log`` comment."""
    path = Path(path)
    if not path.is_file() or path.suffix.lower() not in (".csv", ".txt"):
        return False
    with open(path, newline="", errors="replace") as fh:
        first = True
        for line in fh:
            text = line.strip()
            if text.lower().startswith("# rangeslam beacon log"):
                return True
            if text and not text.startswith("#"):
                fields = [f.strip() for f in text.split(",")]
                if first and is_header(fields):
                    first = False
                    continue
                return fields[0].lower() in BEACON_LOG_KINDS
    return False


def is_header(fields: list[str]) -> bool:
    """True when a first row ``fields`` is a header (column names): its first field names no
    record and none of its fields is a number."""
    if fields[0].lower() in BEACON_LOG_KINDS:
        return False
    for f in fields:
        try:
            float(f)
        except ValueError:
            continue
        return False
    return True


def _lines(path: Path) -> list[str]:
    """The file's lines; InvalidInputError naming the file when it is not text."""
    try:
        return path.read_text().splitlines()
    except UnicodeDecodeError as exc:
        raise InvalidInputError(
            f"{path}: not a text file ({exc.reason} at byte {exc.start}); a beacon log is CSV "
            "text (rangeslam run --help)"
        ) from exc


def _records(path: Path):
    """(line number, kind, fields) of each record, and the ``# name = value`` settings as
    {name: (line number, value)}. A first row of column names (a header) is skipped."""
    records, settings = [], {}
    header_allowed = True
    for number, line in enumerate(_lines(path), start=1):
        text = line.strip()
        if not text:
            continue
        if text.startswith("#"):
            _comment(path, number, text.lstrip("#").strip(), settings)
            continue
        try:
            fields = [f.strip() for f in next(csv.reader([text]))]
        except csv.Error as exc:
            raise InvalidInputError(f"{path}, line {number}: not a CSV row ({exc})") from exc
        if header_allowed and is_header(fields):
            header_allowed = False
            continue
        header_allowed = False
        kind = fields[0].lower()
        if kind not in BEACON_LOG_KINDS:
            raise InvalidInputError(
                f"{path}, line {number}: the first field must be one of "
                f"{sorted(BEACON_LOG_KINDS)}; got {fields[0]!r:.40} (a beacon log's format: "
                "rangeslam run --help)"
            )
        records.append((number, kind, fields[1:]))
    if not records:
        raise InvalidInputError(
            f"{path}: no records (empty, or only comments); a beacon log has a start record, "
            "odometry and range records (rangeslam run --help)"
        )
    return records, settings


def _comment(path: Path, number: int, text: str, settings: dict) -> None:
    """Record the setting a comment ``text`` states in ``settings``; refuse an unknown or
    repeated name, or a known name without "=" (a typo would otherwise change the result)."""
    known = ", ".join(BEACON_LOG_SETTINGS)
    match = SETTING.match(text)
    if match is None:
        first = re.split(r"[\s:]+", text, maxsplit=1)[0].lower()
        if first in BEACON_LOG_SETTINGS:
            raise InvalidInputError(
                f"{path}, line {number}: write the setting as '# {first} = value'; got {text!r:.60}"
            )
        return
    name, value = match.group(1).strip().lower(), match.group(2).strip()
    if name not in BEACON_LOG_SETTINGS:
        close = difflib.get_close_matches(name, BEACON_LOG_SETTINGS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise InvalidInputError(
            f"{path}, line {number}: unknown setting {name!r:.40}{hint}; the settings are "
            f"{known} (a comment that is not a setting must not start with 'name =')"
        )
    if name in settings:
        raise InvalidInputError(
            f"{path}, line {number}: {name} is set again (first on line {settings[name][0]})"
        )
    settings[name] = (number, value)


def _numbers(path, number, kind, fields, *, keep_last_word=False) -> list[float]:
    """The record's numbers, checked against BEACON_LOG_KINDS; InvalidInputError naming the line."""
    if keep_last_word:
        fields = fields[:-1]
    if len(fields) not in BEACON_LOG_KINDS[kind]:
        want = " or ".join(str(n) for n in BEACON_LOG_KINDS[kind])
        raise InvalidInputError(
            f"{path}, line {number}: a {kind} record has {want} numbers; got {len(fields)}"
        )
    try:
        values = [float(f) for f in fields]
    except ValueError as exc:
        raise InvalidInputError(f"{path}, line {number}: {kind}: {exc}") from exc
    if not np.all(np.isfinite(values)):
        bad = int(np.argmax(~np.isfinite(values)))
        raise InvalidInputError(
            f"{path}, line {number}: {kind}: numbers must be finite; "
            f"{BEACON_LOG_FIELDS[kind][bad]} is {values[bad]}"
        )
    if kind in ("range", "beacon"):
        _check_range_record(path, number, kind, values)
    return values


def _check_range_record(path, number: int, kind: str, values: list[float]) -> None:
    """A beacon id (integer >= 0) and, in a range record, a range > 0; naming the line."""
    beacon = values[1] if kind == "range" else values[0]
    if beacon != round(beacon) or beacon < 0:
        raise InvalidInputError(
            f"{path}, line {number}: {kind}: the beacon id must be an integer >= 0; got {beacon:g}"
        )
    if kind == "range" and values[2] <= 0:
        raise InvalidInputError(
            f"{path}, line {number}: range: the range must be > 0 metres; got {values[2]:g}"
        )


def _setting(path, settings, name):
    """The value of the setting ``name`` (a float, or an array of BEACON_LOG_SETTINGS[name]
    numbers), or None when the log does not state it."""
    if name not in settings:
        return None
    size = BEACON_LOG_SETTINGS[name]
    number, text = settings[name]
    try:
        values = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError as exc:
        raise InvalidInputError(f"{path}, line {number}: {name}: {exc}") from exc
    if values.shape != (size,) or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise InvalidInputError(
            f"{path}, line {number}: {name} must be {size} positive number(s); got {text!r:.60}"
        )
    return float(values[0]) if size == 1 else values


def _sorted_rows(path, records) -> dict[str, list]:
    """The records by kind (step records, in file order, under "steps"), each checked: (line,
    numbers, last word of a beacon record) per record; (line, kind, numbers) per step."""
    rows: dict[str, list] = {kind: [] for kind in BEACON_LOG_KINDS if kind not in STEP_KINDS}
    rows["steps"] = []
    for number, kind, fields in records:
        is_beacon = kind == "beacon"
        if is_beacon and (not fields or fields[-1].lower() not in ("known", "truth")):
            raise InvalidInputError(
                f"{path}, line {number}: a beacon record ends in 'known' or 'truth'"
            )
        values = _numbers(path, number, kind, fields, keep_last_word=is_beacon)
        if kind in STEP_KINDS:
            rows["steps"].append((number, kind, values))
        else:
            rows[kind].append((number, values, fields[-1].lower() if is_beacon else None))
    starts = [number for number, _, _ in rows["start"]]
    if len(starts) != 1:
        where = f" (lines {', '.join(map(str, starts))})" if starts else ""
        raise InvalidInputError(
            f"{path}: a beacon log has one start record; got {len(starts)}{where} ('start, "
            "time' gives the time of pose 0)"
        )
    if not rows["steps"] or not rows["range"]:
        raise InvalidInputError(
            f"{path}: a beacon log needs odometry (odometry, speed or wheels) and range records; "
            f"it has {len(rows['steps'])} and {len(rows['range'])}"
        )
    return rows


def load_beacon_log(path: str | Path) -> BeaconLog:
    """Read a beacon log (module notes). InvalidInputError names the file and, for a record or
    a setting, its line."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"beacon log {path} is not a file")
    records, settings = _records(path)
    rows = _sorted_rows(path, records)
    wheel_base = _setting(path, settings, "wheel_base")
    pose_time, odometry = steps_from_records(
        path, rows["steps"], rows["start"][0][1][0], wheel_base
    )
    rng_rows = np.array([v for _, v, _ in rows["range"]])
    order = np.argsort(rng_rows[:, 0], kind="stable")
    rng_rows = rng_rows[order]
    lines = np.array([number for number, _, _ in rows["range"]], dtype=np.int64)[order]
    pose = np.searchsorted(pose_time, rng_rows[:, 0], side="left")
    if np.any(pose >= len(pose_time)):
        late = int(lines[np.argmax(pose >= len(pose_time))])
        raise InvalidInputError(
            f"{path}, line {late}: a range after the last pose's time ({pose_time[-1]:g} s)"
        )
    try:
        data = RangeOdometry.from_beacon_ids(
            pose_time, odometry, pose, rng_rows[:, 1].astype(np.int64), rng_rows[:, 2]
        )
    except InvalidInputError as exc:  # what the records' own checks cannot see (sizes)
        raise InvalidInputError(f"{path}: {exc}") from exc
    truth = _truth(path, rows["truth"], len(pose_time))
    beacons, known = _beacons(path, rows["beacon"], data.beacon_ids)
    return BeaconLog(
        data=data,
        truth=truth,
        beacons=beacons,
        known=known,
        range_sigma=_setting(path, settings, "range_sigma"),
        odometry_sigma=_setting(path, settings, "odometry_sigma"),
        path=path,
        range_lines=frozen(lines),
    )


def steps_from_records(path, steps, start_time: float, wheel_base: float | None):
    """Pose times (N + 1,) and odometry (N, 2) from the step records ``steps`` (line number, kind,
    numbers) in file order: increments as given, speeds integrated over each step (module notes).
    InvalidInputError names the line and field: a time not after the one before (dt <= 0), or
    a wheels record without ``# wheel_base``."""
    pose_time = np.empty(len(steps) + 1)
    pose_time[0] = start_time
    odometry = np.empty((len(steps), 2))
    for k, (number, kind, values) in enumerate(steps):
        t, a, b = values
        dt = t - pose_time[k]
        if dt <= 0:
            raise InvalidInputError(
                f"{path}, line {number}: {kind}: time must be after the previous pose's "
                f"({pose_time[k]!r}); got {t!r} (dt = {dt:.6g} s)"
            )
        pose_time[k + 1] = t
        if kind == "odometry":
            odometry[k] = a, b
        elif kind == "speed":
            odometry[k] = a * dt, b * dt
        else:
            if wheel_base is None:
                raise InvalidInputError(
                    f"{path}, line {number}: a wheels record needs the wheel base: a "
                    f"'# wheel_base = metres' line (wheel_base is missing)"
                )
            odometry[k] = 0.5 * (a + b) * dt, (b - a) / wheel_base * dt
    return pose_time, odometry


def _truth(path, rows, n_poses) -> np.ndarray | None:
    """(n_poses, 3) the truth records' poses in file order (heading NaN where not given)."""
    if not rows:
        return None
    if len(rows) != n_poses:
        raise InvalidInputError(
            f"{path}, lines {rows[0][0]} to {rows[-1][0]}: truth records must give every pose "
            f"({n_poses}, one per start or step record); got {len(rows)}"
        )
    out = np.full((n_poses, 3), np.nan)
    for i, (_, values, _) in enumerate(rows):
        out[i, : len(values) - 1] = values[1:]
    return frozen(out)


def _beacons(path, rows, ids) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(B, 2) true and known beacon positions from the beacon records (NaN rows where not
    given; None when none is)."""
    if not rows:
        return None, None
    truth = np.full((len(ids), 2), np.nan)
    known = np.full((len(ids), 2), np.nan)
    row_of = {int(b): k for k, b in enumerate(ids)}
    for number, values, what in rows:
        if int(values[0]) not in row_of:
            raise InvalidInputError(
                f"{path}, line {number}: beacon {values[0]:g} has no range in the log"
            )
        target = known if what == "known" else truth
        target[row_of[int(values[0])]] = values[1:]
    has = lambda a: frozen(a) if np.any(np.isfinite(a)) else None  # noqa: E731
    return has(truth), has(known)


def write_beacon_log(
    path: str | Path,
    data: RangeOdometry,
    *,
    truth: np.ndarray | None = None,
    beacons: np.ndarray | None = None,
    known: np.ndarray | None = None,
    range_sigma: float | None = None,
    odometry_sigma=None,
    odometry_as: str = "increments",
    wheel_base: float | None = None,
) -> Path:
    """Write ``data`` (and the optional truth poses (N + 1, 3), true beacons and known beacons
    (B, 2), stated noise) as a beacon log; each range at its pose's time. The odometry as
    ``odometry_as`` (:data:`ODOMETRY_FORMS`): ``odometry`` records, ``speed`` records (each
    step's mean v, omega) or ``wheels`` records (left and right speeds, ``wheel_base`` [m]
    given). Returns the path."""
    if odometry_as not in ODOMETRY_FORMS:
        raise InvalidInputError(f"odometry_as must be one of {ODOMETRY_FORMS}; got {odometry_as!r}")
    if odometry_as == "wheels":
        from rangeslam.beacons.options import positive_number

        if wheel_base is None:
            raise InvalidInputError("wheel_base is needed to write wheel speeds; got None")
        wheel_base = positive_number(wheel_base, "wheel_base")
    path = Path(path)
    lines = ["# rangeslam beacon log 1"]
    if odometry_as == "wheels":
        lines.append(f"# wheel_base = {_f(wheel_base)}")
    if range_sigma is not None:
        lines.append(f"# range_sigma = {_f(range_sigma)}")
    if odometry_sigma is not None:
        lines.append("# odometry_sigma = " + " ".join(_f(v) for v in odometry_sigma))
    lines.append(f"start,{_f(data.pose_time[0])}")
    lines += _step_lines(data, odometry_as, wheel_base)
    for p, b, r in zip(data.range_pose, data.range_beacon, data.ranges, strict=True):
        lines.append(f"range,{_f(data.pose_time[p])},{int(data.beacon_ids[b])},{_f(r)}")
    for t, pose in zip(data.pose_time, [] if truth is None else truth, strict=False):
        lines.append(f"truth,{_f(t)}," + ",".join(_f(v) for v in pose))
    for label, table in (("truth", beacons), ("known", known)):
        for b, xy in zip(data.beacon_ids, [] if table is None else table, strict=False):
            if np.all(np.isfinite(xy)):
                lines.append(f"beacon,{int(b)},{_f(xy[0])},{_f(xy[1])},{label}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _step_lines(data: RangeOdometry, odometry_as: str, wheel_base: float | None) -> list[str]:
    """The step records of ``data`` in the form ``odometry_as``."""
    dt = np.diff(data.pose_time)
    d, dtheta = data.odometry[:, 0], data.odometry[:, 1]
    if odometry_as == "increments":
        kind, a, b = "odometry", d, dtheta
    elif odometry_as == "speed":
        kind, a, b = "speed", d / dt, dtheta / dt
    else:
        v, omega = d / dt, dtheta / dt
        kind, a, b = "wheels", v - 0.5 * omega * wheel_base, v + 0.5 * omega * wheel_base
    return [
        f"{kind},{_f(t)},{_f(x)},{_f(y)}" for t, x, y in zip(data.pose_time[1:], a, b, strict=True)
    ]


def _f(value) -> str:
    """A number as the shortest text that reads back to the same float."""
    return repr(float(value))
