"""PyFG text files: range-aided SLAM problems as the CORA benchmark publishes them.

A. Papalia, A. Fishberg, B. W. O'Neill, J. P. How, D. M. Rosen and J. J. Leonard, "Certifiably
Correct Range-Aided SLAM", IEEE Transactions on Robotics, 2024 (the benchmark files; the format is
that of MarineRoboticsGroup/PyFactorGraph). :func:`load_pyfg` reads a file into a
:class:`~rangeslam.rangeaided.RangeAidedProblem`; :func:`write_pyfg` writes one back.

One record a line, fields separated by white space, the first field names the record:

=========================  ===================================================================
``VERTEX_SE2``             t name x y theta
``VERTEX_SE3:QUAT``        t name x y z qx qy qz qw
``VERTEX_XY``              name x y
``VERTEX_XYZ``             name x y z
``VERTEX_SE2:PRIOR``       t name x y theta, then the 6 of the covariance's upper triangle
``VERTEX_SE3:QUAT:PRIOR``  t name x y z qx qy qz qw, then 21 (6 x 6, translation first)
``VERTEX_XY:PRIOR``        t name x y, then 3
``VERTEX_XYZ:PRIOR``       t name x y z, then 6
``EDGE_SE2``               t a b dx dy dtheta, then 6: pose b in the frame of pose a
``EDGE_SE3:QUAT``          t a b dx dy dz qx qy qz qw, then 21
``EDGE_SE2_XY``            t a b dx dy, then 3: landmark b in the frame of pose a
``EDGE_SE3_XYZ``           t a b dx dy dz, then 6
``EDGE_RANGE``             t a b range variance
=========================  ===================================================================

Names are a capital letter and a number: ``L3`` is landmark 3, any other letter a robot's pose
(``A0``, ``A1``, ... robot A's trajectory; ``B0`` ... the next robot's). A vertex's values are the
data set's reference (ground truth), kept apart as ``truth_poses`` / ``truth_landmarks``. The upper
triangles are row by row and hold covariances, not information matrices: on Plaza1 the odometry's
0.01 m^2 and the ranges' 0.24 m^2 are the size of their errors against the reference, where the
information reading would make them 10 m and 2 m (tests/test_pyfg.py measures it).

The writer prints every number with ``repr`` (the shortest string that reads back to the same
float), so ``load_pyfg(write_pyfg(p))`` is ``p`` bit for bit.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rangeslam.datasets.paths import data_path
from rangeslam.errors import DataFormatError, InvalidInputError
from rangeslam.rangeaided.problem import (
    LANDMARK_LETTER,
    LandmarkObservations,
    LandmarkPriors,
    PosePriors,
    RangeAidedProblem,
    RangeMeasurements,
    RelativePoses,
    pose_width,
    positive_definite,
    tangent_width,
)

__all__ = ["PYFG_CITATION", "RECORDS", "load_pyfg", "write_pyfg"]

PYFG_CITATION = (
    "A. Papalia, A. Fishberg, B. W. O'Neill, J. P. How, D. M. Rosen and J. J. Leonard, "
    '"Certifiably Correct Range-Aided SLAM", IEEE Transactions on Robotics, 2024.'
)


@dataclass(frozen=True)
class Record:
    """One record kind: its group, dimension (None: either), whether it has a time stamp, how
    many names, values and covariance rows (``cov`` k: k(k+1)/2 numbers; 0: a range's variance)."""

    group: str
    dim: int | None
    timed: bool
    names: int
    values: int
    cov: int

    @property
    def n_fields(self) -> int:
        """Fields of the line after the record's name."""
        tri = self.cov * (self.cov + 1) // 2 if self.cov else 1 if self.group == "range" else 0
        return int(self.timed) + self.names + self.values + tri


#: Every record kind read and written, by its first field.
RECORDS: dict[str, Record] = {
    "VERTEX_SE2": Record("pose", 2, True, 1, 3, 0),
    "VERTEX_SE3:QUAT": Record("pose", 3, True, 1, 7, 0),
    "VERTEX_XY": Record("landmark", 2, False, 1, 2, 0),
    "VERTEX_XYZ": Record("landmark", 3, False, 1, 3, 0),
    "VERTEX_SE2:PRIOR": Record("pose_prior", 2, True, 1, 3, 3),
    "VERTEX_SE3:QUAT:PRIOR": Record("pose_prior", 3, True, 1, 7, 6),
    "VERTEX_XY:PRIOR": Record("landmark_prior", 2, True, 1, 2, 2),
    "VERTEX_XYZ:PRIOR": Record("landmark_prior", 3, True, 1, 3, 3),
    "EDGE_SE2": Record("odometry", 2, True, 2, 3, 3),
    "EDGE_SE3:QUAT": Record("odometry", 3, True, 2, 7, 6),
    "EDGE_SE2_XY": Record("observation", 2, True, 2, 2, 2),
    "EDGE_SE3_XYZ": Record("observation", 3, True, 2, 3, 3),
    "EDGE_RANGE": Record("range", None, True, 2, 1, 0),
}
# The kind of each group per dimension, for the writer.
KIND_OF = {(r.group, r.dim): kind for kind, r in RECORDS.items()}
NAME = re.compile(r"([A-Z])(0|[1-9][0-9]{0,15})")


@dataclass
class Parsed:
    """The records of a file by group: line numbers, times, names, values, covariances."""

    path: Path
    dim: int | None = None
    dim_line: int = 0
    groups: dict = field(default_factory=dict)

    def add(self, group: str, line: int, time: float, names, values, cov) -> None:
        rows = self.groups.setdefault(group, {"line": [], "time": [], "names": [], "values": [],
                                              "cov": []})  # fmt: skip
        rows["line"].append(line)
        rows["time"].append(time)
        rows["names"].append(names)
        rows["values"].append(values)
        rows["cov"].append(cov)

    def rows(self, group: str) -> dict:
        return self.groups.get(group, {"line": [], "time": [], "names": [], "values": [],
                                       "cov": []})  # fmt: skip

    def error(self, line: int, message: str) -> DataFormatError:
        return DataFormatError(f"{self.path}, line {line}: {message}")


def _name(parsed: Parsed, line: int, text: str) -> tuple[str, int]:
    match = NAME.fullmatch(text)
    if match is None:
        raise parsed.error(
            line, f"variable name {text!r:.40} is not a capital letter and a number (A0, L3)"
        )
    return match.group(1), int(match.group(2))


def _numbers(parsed: Parsed, line: int, texts: list[str]) -> list[float]:
    out = []
    for text in texts:
        try:
            value = float(text)
        except ValueError:
            raise parsed.error(line, f"{text!r:.40} is not a number") from None
        if not math.isfinite(value):
            raise parsed.error(line, f"{text!r:.40} is not a finite number")
        out.append(value)
    return out


def _upper_to_matrix(tri: list[float], k: int) -> np.ndarray:
    """(k, k) symmetric matrix from its upper triangle read row by row."""
    mat = np.zeros((k, k))
    rows, cols = np.triu_indices(k)
    mat[rows, cols] = tri
    mat[cols, rows] = tri
    return mat


def _parse_line(parsed: Parsed, line: int, fields_: list[str]) -> None:
    kind = fields_[0]
    spec = RECORDS.get(kind)
    if spec is None:
        raise parsed.error(
            line, f"unknown record {kind!r:.60}; known records: {', '.join(RECORDS)}"
        )
    if len(fields_) - 1 != spec.n_fields:
        raise parsed.error(
            line, f"{kind} takes {spec.n_fields} fields after its name; got {len(fields_) - 1}"
        )
    if spec.dim is not None:
        if parsed.dim is None:
            parsed.dim, parsed.dim_line = spec.dim, line
        elif parsed.dim != spec.dim:
            raise parsed.error(
                line, f"{kind} is a {spec.dim}-D record; line {parsed.dim_line} made the file "
                f"{parsed.dim}-D"
            )  # fmt: skip
    at = 1
    time = 0.0
    if spec.timed:
        time = _numbers(parsed, line, [fields_[1]])[0]
        at = 2
    names = [_name(parsed, line, t) for t in fields_[at : at + spec.names]]
    numbers = _numbers(parsed, line, fields_[at + spec.names :])
    values, rest = numbers[: spec.values], numbers[spec.values :]
    cov = _upper_to_matrix(rest, spec.cov) if spec.cov else rest
    parsed.add(spec.group, line, time, names, values, cov)


def _parse(path: Path) -> Parsed:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{path}: not a text file ({exc})") from exc
    except OSError as exc:
        raise DataFormatError(f"{path}: not readable ({exc})") from exc
    parsed = Parsed(path)
    for line, row in enumerate(text.splitlines(), start=1):
        fields_ = row.split()
        if fields_:
            _parse_line(parsed, line, fields_)
    if parsed.dim is None or not parsed.rows("pose")["line"]:
        raise DataFormatError(f"{path}: no pose (VERTEX_SE2 or VERTEX_SE3:QUAT records)")
    return parsed


def _table(parsed: Parsed, group: str, landmark: bool) -> tuple[list, dict]:
    """The variables of ``group`` ('pose' or 'landmark'), sorted: [(letter, index, record)]
    and {(letter, index): row}; a repeated name or a pose called L is refused."""
    rows = parsed.rows(group)
    seen: dict = {}
    for k, ((letter, index),) in enumerate(rows["names"]):
        line = rows["line"][k]
        if (letter == LANDMARK_LETTER) != landmark:
            what = (
                "a landmark (letter L)"
                if landmark
                else f"a pose (any letter but {LANDMARK_LETTER})"
            )
            raise parsed.error(line, f"{letter}{index} must name {what}")
        if (letter, index) in seen:
            raise parsed.error(
                line,
                f"{letter}{index} is defined again (first on line {rows['line'][seen[letter, index]]})",
            )
        seen[letter, index] = k
    order = sorted(seen)
    return [seen[key] for key in order], {key: row for row, key in enumerate(order)}


def _lookup(parsed: Parsed, group: str, position: int, table: dict, what: str) -> np.ndarray:
    """(n,) rows of the ``position``-th name of each record of ``group`` in ``table``."""
    rows = parsed.rows(group)
    out = np.empty(len(rows["line"]), np.int64)
    for k, names in enumerate(rows["names"]):
        key = names[position]
        if key not in table:
            letter, index = key
            raise parsed.error(
                rows["line"][k], f"{letter}{index} must be a {what} defined by a VERTEX record"
            )
        out[k] = table[key]
    return out


def _first_bad(parsed: Parsed, group: str, bad: np.ndarray, message: str) -> None:
    if np.any(bad):
        k = int(np.argmax(bad))
        raise parsed.error(parsed.rows(group)["line"][k], message)


def _arrays(parsed: Parsed, group: str, width: int, k: int) -> tuple[np.ndarray, ...]:
    """(values (n, width), covariances (n, k, k), times (n,)) of ``group``, checked: unit
    quaternions (3-D poses), positive-definite covariances."""
    rows = parsed.rows(group)
    n = len(rows["line"])
    values = np.array(rows["values"], dtype=np.float64).reshape(n, width)
    cov = np.array(rows["cov"], dtype=np.float64).reshape(n, k, k) if k else None
    if width == 7:
        norm = np.linalg.norm(values[:, 3:], axis=1)
        _first_bad(parsed, group, np.abs(norm - 1) > 1e-5, "the quaternion must have norm 1")
    if cov is not None and n:
        bad = ~positive_definite(cov)
        _first_bad(parsed, group, bad, "the covariance must be positive definite")
    return values, cov, np.array(rows["time"], dtype=np.float64)


def _ranges(parsed: Parsed, poses: dict, marks: dict) -> RangeMeasurements:
    """The EDGE_RANGE records: a pose first (a range landmark-pose is turned round)."""
    rows = parsed.rows("range")
    n = len(rows["line"])
    first, other = np.empty(n, np.int64), np.empty(n, np.int64)
    to_mark = np.zeros(n, bool)
    for k, (a, b) in enumerate(rows["names"]):
        if a in marks and b in poses:
            a, b = b, a
        if a not in poses or not (b in poses or b in marks):
            missing = a if a not in poses and a not in marks else b
            text = f"{missing[0]}{missing[1]}"
            if missing[0] == LANDMARK_LETTER and missing in marks:
                raise parsed.error(rows["line"][k], "a range between two landmarks is not used")
            raise parsed.error(rows["line"][k], f"{text} is not defined by a VERTEX record")
        first[k], to_mark[k] = poses[a], b in marks
        other[k] = marks[b] if to_mark[k] else poses[b]
    values = np.array(rows["values"], dtype=np.float64).reshape(n)
    var = np.array(rows["cov"], dtype=np.float64).reshape(n)
    _first_bad(parsed, "range", values < 0, "a range must be >= 0")
    _first_bad(parsed, "range", ~(var > 0), "a range's variance must be > 0")
    return RangeMeasurements(first, other, to_mark, values, var, np.array(rows["time"]))


def _problem(parsed: Parsed) -> RangeAidedProblem:
    dim = parsed.dim
    w, k = pose_width(dim), tangent_width(dim)
    pose_order, poses = _table(parsed, "pose", landmark=False)
    mark_order, marks = _table(parsed, "landmark", landmark=True)
    truth, _, times = _arrays(parsed, "pose", w, 0)
    truth_marks = _arrays(parsed, "landmark", dim, 0)[0]
    robots = tuple(sorted({letter for letter, _ in poses}))
    odo = _arrays(parsed, "odometry", w, k)
    obs = _arrays(parsed, "observation", dim, dim)
    pose_prior = _arrays(parsed, "pose_prior", w, k)
    mark_prior = _arrays(parsed, "landmark_prior", dim, dim)
    return RangeAidedProblem(
        dim=dim,
        robots=robots,
        pose_robot=np.array([robots.index(letter) for letter, _ in poses], np.int64),
        pose_index=np.array([index for _, index in poses], np.int64),
        pose_time=times[pose_order],
        landmark_ids=np.array([index for _, index in marks], np.int64),
        odometry=RelativePoses(
            _lookup(parsed, "odometry", 0, poses, "pose"),
            _lookup(parsed, "odometry", 1, poses, "pose"),
            *odo,
        ),
        ranges=_ranges(parsed, poses, marks),
        landmark_observations=LandmarkObservations(
            _lookup(parsed, "observation", 0, poses, "pose"),
            _lookup(parsed, "observation", 1, marks, "landmark"),
            *obs,
        ),
        pose_priors=PosePriors(_lookup(parsed, "pose_prior", 0, poses, "pose"), *pose_prior),
        landmark_priors=LandmarkPriors(
            _lookup(parsed, "landmark_prior", 0, marks, "landmark"), *mark_prior
        ),
        truth_poses=truth[pose_order],
        truth_landmarks=truth_marks[mark_order],
    )


def load_pyfg(path: str | os.PathLike[str]) -> RangeAidedProblem:
    """Read the PyFG file ``path`` (a path, or a name under the data folder:
    :func:`rangeslam.datasets.data_path`, e.g. ``"pyfg/plaza1.pyfg"``) into a
    :class:`~rangeslam.rangeaided.RangeAidedProblem`.

    Poses are sorted by robot letter and number, landmarks by number; measurements keep the
    file's order within each kind (a range written landmark first is turned round). The
    vertices' values are the reference: ``truth_poses`` (P, 3) or (P, 7), ``truth_landmarks``
    (L, d).

    Raises:
        DataNotFoundError: no such file (the paths tried named).
        DataFormatError (an InvalidInputError) naming the file and the line: an unknown record
        (named), a wrong number of fields, a field that is not a finite number, a bad variable
        name, a variable defined twice or used without its VERTEX record, 2-D and 3-D records
        mixed, a quaternion off unit norm, a covariance not positive definite, a negative range
        or a variance <= 0. A file without poses is refused naming the file.
    """
    p = data_path(path, what="PyFG file")
    if not p.is_file():
        raise DataFormatError(f"PyFG file {p} is a directory, not a file")
    parsed = _parse(p)
    try:
        return _problem(parsed)
    except DataFormatError:
        raise
    except InvalidInputError as exc:  # a check of the problem's own, without a line
        raise DataFormatError(f"{p}: {exc}") from exc


def _text(x) -> str:
    """The shortest decimal string that reads back to the same float64."""
    return repr(float(x))


def _join(*parts) -> str:
    return " ".join(_text(v) if not isinstance(v, str) else v for v in parts)


def _upper(cov: np.ndarray) -> list[float]:
    return list(cov[np.triu_indices(len(cov))])


def _lines(problem: RangeAidedProblem, poses: np.ndarray, marks: np.ndarray):
    """The file's lines, one record each: vertices, priors, odometry, observations, ranges."""
    dim, names, mark_names = problem.dim, problem.pose_names, problem.landmark_names
    kind = {group: KIND_OF.get((group, dim)) for group, _ in KIND_OF}
    for t, name, value in zip(problem.pose_time, names, poses, strict=True):
        yield _join(kind["pose"], t, name, *value)
    for name, value in zip(mark_names, marks, strict=True):
        yield _join(kind["landmark"], name, *value)
    pp, lp = problem.pose_priors, problem.landmark_priors
    for t, i, value, cov in zip(pp.time, pp.pose, pp.values, pp.covariance, strict=True):
        yield _join(kind["pose_prior"], t, names[i], *value, *_upper(cov))
    for t, i, value, cov in zip(lp.time, lp.landmark, lp.values, lp.covariance, strict=True):
        yield _join(kind["landmark_prior"], t, mark_names[i], *value, *_upper(cov))
    o = problem.odometry
    for t, a, b, value, cov in zip(o.time, o.pose_a, o.pose_b, o.values, o.covariance, strict=True):
        yield _join(kind["odometry"], t, names[a], names[b], *value, *_upper(cov))
    s = problem.landmark_observations
    for t, a, b, value, cov in zip(s.time, s.pose, s.landmark, s.values, s.covariance, strict=True):
        yield _join(kind["observation"], t, names[a], mark_names[b], *value, *_upper(cov))
    r = problem.ranges
    for t, a, b, to_mark, dist, var in zip(
        r.time, r.pose, r.other, r.to_landmark, r.ranges, r.variance, strict=True
    ):
        yield _join("EDGE_RANGE", t, names[a], mark_names[b] if to_mark else names[b], dist, var)


def write_pyfg(
    problem: RangeAidedProblem,
    path: str | os.PathLike[str],
    *,
    poses=None,
    landmarks=None,
) -> Path:
    """Write ``problem`` to the PyFG file ``path`` (overwritten) and return its path.

    The vertices carry ``poses`` (P, 3) or (P, 7) and ``landmarks`` (L, d) when given (an
    estimate, say), else the problem's reference values. Numbers are written with ``repr``, so
    :func:`load_pyfg` reads back the same problem bit for bit.

    Raises:
        InvalidInputError: ``problem`` is not a RangeAidedProblem; no values for the vertices
        (neither ``poses`` nor ``truth_poses``; likewise landmarks); values of the wrong shape.
    """
    if not isinstance(problem, RangeAidedProblem):
        raise InvalidInputError(
            f"problem must be a RangeAidedProblem; got {type(problem).__name__}"
        )
    if not isinstance(path, str | os.PathLike) or str(path) == "":
        raise InvalidInputError(f"path must be a file path; got {path!r:.80}")
    values = []
    for given, truth, name, shape in (
        (poses, problem.truth_poses, "poses", (problem.n_poses, pose_width(problem.dim))),
        (landmarks, problem.truth_landmarks, "landmarks", (problem.n_landmarks, problem.dim)),
    ):
        if given is None and truth is None and shape[0]:
            raise InvalidInputError(
                f"{name}: the problem has no reference values (truth_{name}), and a PyFG file "
                f"gives every variable a value; pass {name}= (an estimate)"
            )
        arr = np.zeros(shape) if given is None and truth is None else np.asarray(
            truth if given is None else given, dtype=np.float64
        )  # fmt: skip
        if arr.shape != shape or not np.all(np.isfinite(arr)):
            raise InvalidInputError(f"{name} must be finite with shape {shape}; got {arr.shape}")
        values.append(arr)
    out = Path(path)
    with out.open("w", encoding="ascii") as f:
        for line in _lines(problem, *values):
            f.write(line + "\n")
    return out
