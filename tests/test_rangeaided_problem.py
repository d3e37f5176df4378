"""RangeAidedProblem: validation at construction (errors naming the field), the beacon-log
converter both ways, the pose algebra, and PyFG round trips of random problems (hypothesis)."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rangeslam.beacons import RangeOdometry, dead_reckoning
from rangeslam.datasets.pyfg import load_pyfg, write_pyfg
from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided import (
    LandmarkObservations,
    LandmarkPriors,
    PosePriors,
    RangeAidedProblem,
    RangeMeasurements,
    RelativePoses,
)
from rangeslam.rangeaided import poses as se


def _unit(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _spd(rng, n, k):
    a = rng.normal(size=(n, k, k))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(k)
    return 0.5 * (cov + np.swapaxes(cov, 1, 2))


def random_problem(rng, dim: int, n_robots: int = 2, per_robot: int = 4, n_marks: int = 3):
    """A valid problem with every measurement kind: odometry chains, ranges pose-landmark and
    pose-pose, observations, priors, truth."""
    rows = per_robot * n_robots
    k = 3 if dim == 2 else 6

    def poses(n):
        t = rng.normal(size=(n, dim)) * 10
        return (
            np.column_stack([t, rng.normal(size=n)])
            if dim == 2
            else np.column_stack([t, _unit(rng, n)])
        )

    a = np.array([r * per_robot + i for r in range(n_robots) for i in range(per_robot - 1)])
    n_r = 7
    pose = rng.integers(0, rows, n_r)
    to_mark = rng.random(n_r) < 0.5
    other = np.where(to_mark, rng.integers(0, n_marks, n_r), rng.integers(0, rows, n_r))
    return RangeAidedProblem(
        dim=dim,
        robots=("A", "C", "Z")[:n_robots],
        pose_robot=np.repeat(np.arange(n_robots), per_robot),
        pose_index=np.tile(np.arange(per_robot) * 3 + 5, n_robots),
        pose_time=rng.normal(size=rows) * 1e9,
        landmark_ids=np.array([7, 0, 12])[:n_marks],
        odometry=RelativePoses(a, a + 1, poses(len(a)), _spd(rng, len(a), k), rng.random(len(a))),
        ranges=RangeMeasurements(
            pose, other, to_mark, rng.random(n_r) * 30, rng.random(n_r) + 1e-3, rng.random(n_r)
        ),
        landmark_observations=LandmarkObservations(
            np.array([0, 1]),
            np.array([2, 0]),
            rng.normal(size=(2, dim)),
            _spd(rng, 2, dim),
            rng.random(2),
        ),
        pose_priors=PosePriors(np.array([0]), poses(1), _spd(rng, 1, k), rng.random(1)),
        landmark_priors=LandmarkPriors(
            np.array([1]), rng.normal(size=(1, dim)), _spd(rng, 1, dim), rng.random(1)
        ),
        truth_poses=poses(rows),
        truth_landmarks=rng.normal(size=(n_marks, dim)),
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_random_problems_round_trip(tmp_path, rng, dim):
    """A problem with every kind of record written and read back is the same problem, bit for
    bit, after the loader's one canonicalisation (landmarks sorted by id)."""
    p = random_problem(rng, dim)
    q = load_pyfg(write_pyfg(p, tmp_path / "p.pyfg"))
    assert q.landmark_names == ("L0", "L7", "L12")
    r = load_pyfg(write_pyfg(q, tmp_path / "q.pyfg"))
    assert q.same_as(r)
    order = np.argsort(p.landmark_ids)
    np.testing.assert_array_equal(q.truth_landmarks, p.truth_landmarks[order])
    np.testing.assert_array_equal(q.odometry.covariance, p.odometry.covariance)
    np.testing.assert_array_equal(q.ranges.ranges, p.ranges.ranges)


FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(values=st.lists(FINITE, min_size=12, max_size=12), positive=st.lists(
    st.floats(min_value=1e-300, max_value=1e300), min_size=3, max_size=3))  # fmt: skip
def test_property_any_finite_numbers_round_trip(tmp_path, values, positive):
    """Any finite float64 (subnormals, -0.0, 1e308) in any numeric field reads back bit for bit."""
    v = values
    lines = [f"VERTEX_SE2 {v[0]!r} A0 {v[1]!r} {v[2]!r} {v[3]!r}", f"VERTEX_XY L0 {v[4]!r} {v[5]!r}",
             f"VERTEX_SE2 {v[6]!r} A1 {v[7]!r} {v[8]!r} {v[9]!r}",
             f"EDGE_SE2 {v[10]!r} A0 A1 {v[11]!r} {v[1]!r} {v[2]!r} {positive[0]!r} 0.0 0.0 "
             f"{positive[1]!r} 0.0 {positive[2]!r}",
             f"EDGE_RANGE {v[3]!r} A1 L0 {abs(v[4])!r} {positive[1]!r}"]  # fmt: skip
    path = tmp_path / "h.pyfg"
    path.write_text("\n".join(lines) + "\n")
    p = load_pyfg(path)
    assert p.truth_poses[0, 0].tobytes() == np.float64(v[1]).tobytes()
    assert load_pyfg(write_pyfg(p, tmp_path / "w.pyfg")).same_as(p)


TOKENS = ["VERTEX_SE2", "VERTEX_XY", "EDGE_SE2", "EDGE_RANGE", "EDGE_SE3:QUAT", "VERTEX_SE3:QUAT",
          "EDGE_SE2_XY", "A0", "L0", "B1", "1.5", "-0", "nan", "1e999", "x", "", "L", "A", "0x1p3",
          "1_0"]  # fmt: skip
GARBAGE = st.one_of(
    st.text(max_size=80), st.lists(st.sampled_from(TOKENS), max_size=14).map(" ".join)
)


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(line=GARBAGE, where=st.integers(0, 3))
def test_property_garbage_lines_raise_invalid_input(tmp_path, line, where):
    """A random line anywhere in a valid file either still makes a valid file or raises
    InvalidInputError (DataFormatError), never another exception."""
    lines = ["VERTEX_SE2 0 A0 0 0 0", "VERTEX_SE2 1 A1 1 0 0", "VERTEX_XY L0 3 4",
             "EDGE_RANGE 1 A1 L0 4.4 0.25"]  # fmt: skip
    lines.insert(where, line.replace("\r", " ").replace("\n", " "))
    path = tmp_path / "g.pyfg"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
    with contextlib.suppress(InvalidInputError):
        load_pyfg(path)


# ------------------------------------------------------------------------- problem validation
def _with(p: RangeAidedProblem, **changes) -> RangeAidedProblem:
    from dataclasses import fields

    kw = {f.name: getattr(p, f.name) for f in fields(p)}
    kw.update(changes)
    return RangeAidedProblem(**kw)


def test_problem_fields_are_checked(rng):
    """Each field is validated at construction and the error names it."""
    p = random_problem(rng, 2)
    cases = [
        ({"dim": 4}, "dim must be 2 or 3"),
        ({"robots": ("A", "L")}, "robots must be a non-empty tuple"),
        ({"robots": ["A", "C"]}, "robots must be a non-empty tuple"),
        ({"pose_robot": p.pose_robot[::-1].copy()}, "must be sorted by .robot, index."),
        ({"pose_robot": p.pose_robot + 5}, r"pose_robot must lie in \[0, 1\]"),
        ({"pose_index": p.pose_index[:3]}, r"pose_index must be \(8,\) integers"),
        ({"pose_time": np.full(8, np.nan)}, "pose_time must be finite"),
        ({"landmark_ids": np.array([1, 1, 2])}, "landmark_ids must be distinct"),
        ({"truth_poses": np.zeros((8, 2))}, r"truth_poses must have shape \(8, 3\)"),
        ({"truth_landmarks": np.zeros((2, 2))}, r"truth_landmarks must have shape \(3, 2\)"),
        ({"odometry": "steps"}, "odometry must be a RelativePoses"),
        ({"pose_priors": PosePriors(np.array([99]), np.zeros((1, 3)), np.eye(3)[None], [0.0])},
         r"pose_priors.pose must lie in \[0, 7\]"),
    ]  # fmt: skip
    for change, match in cases:
        with pytest.raises(InvalidInputError, match=match):
            _with(p, **change)
    with pytest.raises(InvalidInputError, match=r"odometry.values must have 7 columns in 3-D"):
        _with(p, dim=3, truth_poses=None, pose_priors=None, landmark_priors=None,
              landmark_observations=None, truth_landmarks=None)  # fmt: skip
    r = p.ranges
    bad_other = RangeMeasurements(r.pose, r.other + 50, r.to_landmark, r.ranges, r.variance, r.time)
    with pytest.raises(InvalidInputError, match=r"ranges.other must be a (landmark|pose) row"):
        _with(p, ranges=bad_other)


def test_record_fields_are_checked():
    """The measurement records check their own shapes and values."""
    one = np.array([0])
    with pytest.raises(InvalidInputError, match=r"odometry.covariance must be positive definite"):
        RelativePoses(one, one, np.zeros((1, 3)), -np.eye(3)[None], [0.0])
    with pytest.raises(InvalidInputError, match=r"odometry.covariance must be symmetric"):
        RelativePoses(
            one, one, np.zeros((1, 3)), np.array([[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]]), [0.0]
        )
    with pytest.raises(InvalidInputError, match=r"odometry.values must have shape \(M, 3\)"):
        RelativePoses(one, one, np.zeros((1, 4)), np.eye(4)[None], [0.0])
    with pytest.raises(InvalidInputError, match=r"the quaternion .columns 3-6. must have norm 1"):
        RelativePoses(one, one, np.zeros((1, 7)), np.eye(6)[None], [0.0])
    with pytest.raises(InvalidInputError, match=r"ranges.ranges must be >= 0"):
        RangeMeasurements(one, one, np.array([True]), [-1.0], [1.0], [0.0])
    with pytest.raises(InvalidInputError, match=r"ranges.variance must be > 0"):
        RangeMeasurements(one, one, np.array([True]), [1.0], [0.0], [0.0])
    with pytest.raises(InvalidInputError, match=r"ranges.to_landmark must be \(1,\) bools"):
        RangeMeasurements(one, one, np.array([1]), [1.0], [1.0], [0.0])
    with pytest.raises(InvalidInputError, match=r"ranges.pose must be \(1,\) integers"):
        RangeMeasurements(np.array([0.5]), one, np.array([True]), [1.0], [1.0], [0.0])
    with pytest.raises(InvalidInputError, match=r"landmark_observations.values must have shape"):
        LandmarkObservations(one, one, np.zeros((1, 4)), np.eye(4)[None], [0.0])
    with pytest.raises(InvalidInputError, match=r"landmark_priors.values must have shape"):
        LandmarkPriors(one, np.zeros((1, 1)), np.eye(1)[None], [0.0])
    with pytest.raises(InvalidInputError, match=r"pose_priors.values must have shape"):
        PosePriors(one, np.zeros((1, 2)), np.eye(2)[None], [0.0])


# ------------------------------------------------------------------------------ conversions
def test_beacon_log_round_trip(rng):
    """RangeOdometry -> RangeAidedProblem -> RangeOdometry is the identity; the problem's
    odometry dead-reckons to the log's own dead reckoning (move, then turn) exactly."""
    n = 40
    odo = np.column_stack([rng.random(n), rng.normal(size=n) * 0.2])
    pose = np.sort(rng.integers(0, n + 1, 30))
    data = RangeOdometry.from_beacon_ids(np.arange(n + 1.0), odo, pose, rng.choice([9, 4, 70], 30),
                                         rng.random(30) * 20 + 1)  # fmt: skip
    p = data.to_problem(odometry_sigma=[0.1, 0.05, 0.01], range_sigma=0.3)
    assert p.robots == ("A",) and p.n_poses == n + 1
    np.testing.assert_array_equal(p.landmark_ids, [4, 9, 70])
    np.testing.assert_array_equal(p.ranges.variance, np.full(30, 0.09))
    np.testing.assert_allclose(p.odometry.covariance[0], np.diag([0.01, 0.0025, 1e-4]))
    back = RangeOdometry.from_problem(p)
    for name in ("pose_time", "odometry", "range_pose", "range_beacon", "ranges", "beacon_ids"):
        np.testing.assert_array_equal(getattr(back, name), getattr(data, name))
    start = np.array([1.0, 2.0, 0.3])
    np.testing.assert_allclose(se.dead_reckoning(start, p.odometry.values),
                               dead_reckoning(odo, start), atol=1e-12)  # fmt: skip
    derived = data.to_problem()
    assert derived.odometry.covariance.shape == (n, 3, 3)


def test_conversion_refusals(rng):
    """A problem that is not a beacon log is refused with the reasons; bad noise is named."""
    with pytest.raises(InvalidInputError, match=r"3-D with 2 robots"):
        RangeOdometry.from_problem(random_problem(rng, 3))
    data = RangeOdometry.create([0.0, 1.0], [[1.0, 0.0]], [1], [0], [3.0])
    with pytest.raises(InvalidInputError, match=r"odometry_sigma must be 3 positive numbers"):
        data.to_problem(odometry_sigma=[0.1, 0.1])
    with pytest.raises(InvalidInputError, match=r"range_sigma must be a positive number"):
        data.to_problem(range_sigma=-1.0)
    from rangeslam.rangeaided.convert import (
        problem_from_range_odometry,
        range_odometry_from_problem,
    )

    with pytest.raises(InvalidInputError, match=r"data must be a RangeOdometry"):
        problem_from_range_odometry("log")
    with pytest.raises(InvalidInputError, match=r"problem must be a RangeAidedProblem"):
        range_odometry_from_problem("log")
    p = data.to_problem()
    sideways = _with(p, odometry=RelativePoses([0], [1], [[1.0, 0.5, 0.0]], np.eye(3)[None], [1.0]))
    with pytest.raises(InvalidInputError, match=r"sideways"):
        RangeOdometry.from_problem(sideways)


# --------------------------------------------------------------------------------- pose algebra
@pytest.mark.parametrize("dim", [2, 3])
def test_compose_and_relative_are_inverse(rng, dim):
    """a o (a^-1 o b) = b, and dead reckoning composes the steps in turn (exact to rounding)."""
    n = 50
    t = rng.normal(size=(n, dim))
    rot = rng.normal(size=n) if dim == 2 else _unit(rng, n) * np.sign(_unit(rng, n)[:, 3:] + 2)
    a = np.column_stack([t, rot])
    b = np.column_stack(
        [rng.normal(size=(n, dim)), rng.normal(size=n) if dim == 2 else _unit(rng, n)]
    )
    back = se.compose(a, se.relative(a, b))
    np.testing.assert_allclose(se.positions(back), se.positions(b), atol=1e-12)
    if dim == 3:
        np.testing.assert_allclose(np.abs(np.sum(back[:, 3:] * b[:, 3:], axis=1)), 1, atol=1e-12)
    walk = se.dead_reckoning(a[:1], b)
    step = a[:1]
    for k in range(n):
        step = se.compose(step, b[k : k + 1])
    np.testing.assert_allclose(se.positions(walk[-1:]), se.positions(step), atol=1e-9)
    with pytest.raises(InvalidInputError, match=r"start must be one pose"):
        se.dead_reckoning(a[:2], b)
    with pytest.raises(InvalidInputError, match=r"a must have shape \(n, 3\) or \(n, 7\)"):
        se.compose(np.zeros((2, 4)), b[:2])


def test_quaternion_matrix_round_trip(rng):
    """matrix_to_quaternion inverts quaternion_to_matrix (qw >= 0), near every branch."""
    q = np.vstack([_unit(rng, 200), np.eye(4), [[0.7071, 0.7071, 0, 0]]])
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q = q * np.where(q[:, 3:] < 0, -1.0, 1.0)
    back = se.matrix_to_quaternion(se.quaternion_to_matrix(q))
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)
