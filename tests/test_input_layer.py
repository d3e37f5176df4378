"""One input layer (issue 35, item 3): the foreign exceptions, the hang and the bad input accepted
that the fuzz of issue 35 found, each refused with the package's own errors naming the argument.

Each test states one hole: before the change it raised a foreign exception (TypeError,
ValueError, LinAlgError, OverflowError, GTSAM's errors), hung, or returned an answer.
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rangeslam as rs
from rangeslam._validation import MAX_METRES, MIN_METRES, as_float_array, check_int
from rangeslam.acoustics import detect_echoes, room_from_rirs, track_echoes
from rangeslam.baselines.ekf_slam import MAX_STARTS, ekf_slam
from rangeslam.beacons import beacon_slam_incremental
from rangeslam.beacons.simulation import simulate_beacon_run
from rangeslam.datasets.rir_files import load_rirs
from rangeslam.errors import DataFormatError, InvalidInputError, RangeSlamError, SolverError
from rangeslam.geometry.edm import classical_mds, edm, range_matrix
from rangeslam.geometry.room import Room
from rangeslam.solvers.gtsam_graph import refine_graph
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import Status

FS = 8000


@pytest.fixture(autouse=True)
def _complex_warning_is_an_error():
    """A ComplexWarning means numpy dropped an imaginary part the input layer should refuse."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", np.exceptions.ComplexWarning)
        yield


def walk_scene(d=2, m=8, k=5, seed=0):
    """A walk of ``m`` steps among ``k`` landmarks in a 3 m box, its ranges and step lengths."""
    gen = np.random.default_rng(seed)
    x, s = gen.uniform(0, 3, (m, d)), gen.uniform(0, 3, (k, d))
    return x, s, range_matrix(x, s), np.linalg.norm(np.diff(x, axis=0), axis=1)


ANCHORS = np.array([[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 3], [3, 3, 1], [1, 3, 3]], float)
POINT = np.array([1.0, 1.2, 0.8])


# ---- ekf_slam options ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("turn_std", "0.5"),
        ("turn_std", None),
        ("turn_std", 1j),
        ("turn_std", np.array([1.0, 2.0])),
        ("turn_std", 1e308),
        ("noise_std", 1e300),
        ("init_tol", "1"),
        ("init_tol", 10**400),
        ("motion", np.array([1, 2])),
        ("n_starts", True),
        ("n_starts", 10**400),
        ("n_starts", MAX_STARTS + 1),
        ("init_steps", np.array([4, 5])),
        ("smooth", "yes"),
        ("smooth", 1),
        ("smooth", None),
    ],
)
def test_ekf_options_are_checked_at_the_door(name, value):
    """ekf_slam options of the wrong type (strings, None, complex, arrays), booleans as integers,
    integers beyond their limit (10**400 used to hang) and non-boolean switches: InvalidInputError
    naming the option (TypeError/ValueError in check_ekf_options, or accepted, before)."""
    _, _, r, _ = walk_scene()
    with pytest.raises(InvalidInputError, match=rf"^{name} must be .*; got"):
        ekf_slam(r, dim=2, rng=0, **{name: value})


def test_ekf_n_starts_upper_limit_is_stated():
    """The limit of n_starts is in the message and the docstring."""
    _, _, r, _ = walk_scene()
    with pytest.raises(
        InvalidInputError, match=rf"n_starts must be an integer in \[1, {MAX_STARTS}\]"
    ):
        ekf_slam(r, dim=2, n_starts=MAX_STARTS + 1)
    assert str(MAX_STARTS) in ekf_slam.__doc__


def test_check_int_upper_limit_and_bools():
    assert check_int(np.int64(5), "n", 1, 10) == 5
    for bad in (True, np.bool_(True), 11, 10**400, 2.0, "3"):
        with pytest.raises(InvalidInputError, match=r"n must be an integer in \[1, 10\]"):
            check_int(bad, "n", 1, 10)


# ---- refine_graph -----------------------------------------------------------------------------


def test_refine_graph_refuses_a_source_without_ranges():
    """An all-False mask column (a source no range reaches) is unobservable: InvalidInputError
    naming mask and the column (GTSAM's ValueError from the covariance, before)."""
    x, s, r, _ = walk_scene(3, 5, 4, seed=2)
    mask = np.ones(r.shape, bool)
    mask[:, 1] = False
    with pytest.raises(InvalidInputError, match=r"mask column 1 .*source 1"):
        refine_graph(x, s, r, noise_std=0.01, mask=mask)


def test_refine_graph_refuses_a_receiver_without_ranges_or_steps():
    x, s, r, _ = walk_scene(3, 5, 4, seed=2)
    mask = np.ones(r.shape, bool)
    mask[2, :] = False
    with pytest.raises(InvalidInputError, match=r"mask row 2 .*receiver 2"):
        refine_graph(x, s, r, noise_std=0.01, mask=mask)


@pytest.mark.parametrize("case", ["source on a receiver", "duplicated receivers"])
def test_refine_graph_from_coincident_points_is_a_solver_error(case):
    """Starting points that coincide (a source on a receiver, every receiver at one point) make
    the range factors' Jacobian NaN: SolverError (LinAlgError from the SVD, before)."""
    x, s, r, steps = walk_scene(3, 5, 4, seed=2)
    if case == "source on a receiver":
        start, src, kw = x, x[:4], dict(max_iterations=0)
    else:
        start, src, kw = np.repeat(x[:1], 5, axis=0), s, dict(step_bounds=(0.9 * steps, steps))
    with pytest.raises(SolverError, match="covariances undefined"):
        refine_graph(start, src, r, noise_std=0.01, **kw)


# ---- huge integers, scaled problems, complex numbers, strings ---------------------------------


def _rir():
    x = np.zeros(800)
    x[100], x[300] = 1.0, 0.5
    return x


def test_floats_given_as_huge_integers_are_refused(tmp_path):
    """An integer too large for a float (10**400) as fs, c or max_step: InvalidInputError naming
    it (OverflowError, before)."""
    with pytest.raises(InvalidInputError, match=r"^fs must be"):
        detect_echoes(_rir(), 10**400)
    dets = [detect_echoes(_rir(), FS) for _ in range(3)]
    with pytest.raises(InvalidInputError, match=r"^max_step must be"):
        track_echoes(dets, 10**400)
    with pytest.raises(InvalidInputError, match=r"^c must be"):
        track_echoes(dets, 0.5, c=10**400)
    with pytest.raises(InvalidInputError, match=r"^fs must be"):
        rs.run_rirs(np.tile(_rir(), (4, 1)), 10**400, mics=np.eye(4, 3))
    with pytest.raises(InvalidInputError, match=r"^c must be"):
        rs.run_rirs(np.tile(_rir(), (4, 1)), FS, c=10**400, mics=np.eye(4, 3))
    np.savez(tmp_path / "x.npz", rirs=np.ones((3, 10)))
    with pytest.raises(InvalidInputError, match=r"^fs must be"):
        load_rirs(tmp_path / "x.npz", fs=10**400)


@pytest.mark.parametrize("scale", [1e200, 1e-200, 1e13, 1e-10])
def test_problems_scaled_beyond_metres_are_refused(scale):
    """Coordinates and ranges scaled by 1e200 or 1e-200 (or just beyond MAX_METRES or below
    MIN_METRES): InvalidInputError naming the argument at the input layer (LinAlgError in the
    SR-LS, OverflowError or 'residuals are not finite', before)."""
    r_pt = np.linalg.norm(ANCHORS - POINT, axis=1)
    with pytest.raises(InvalidInputError, match=r"^anchors must be coordinates in metres"):
        rs.multilaterate(ANCHORS * scale, r_pt * scale)
    _, _, r, steps = walk_scene()
    with pytest.raises(InvalidInputError, match=r"^ranges must be ranges in metres"):
        ekf_slam(r * scale, dim=2, rng=0)
    with pytest.raises(InvalidInputError, match=r"^ranges must be ranges in metres"):
        rs.calibrate(r * scale, dim=2, max_attempts=1, rng=0)
    with pytest.raises(InvalidInputError, match=r"^ranges must be ranges in metres"):
        rs.slam(r * scale, step_bounds=(steps * scale, steps * scale), dim=2, rng=0)


def test_scale_limits_leave_valid_problems_alone():
    """At the edges (MAX_METRES, MIN_METRES) and for one point near the origin, nothing is
    refused, and the arrays come back unchanged."""
    assert MAX_METRES == 1e12 and MIN_METRES == 1e-9
    np.testing.assert_array_equal(range_matrix([[0.0, 0.0]], [[MAX_METRES, 0.0]]), [[MAX_METRES]])
    # the geometry helpers take any finite coordinates: estimators apply them to their answers
    np.testing.assert_array_equal(range_matrix([[0.0, 0.0]], [[1e-12, 0.0]]), [[1e-12]])
    np.testing.assert_array_equal(range_matrix([[0.0, 0.0]], [[1e13, 0.0]]), [[1e13]])
    assert rs.Room.shoebox((5.0, 3.0)).contains(np.array([[1e-12, 0.0]]))[0]
    fit = rs.align(ANCHORS * MIN_METRES, ANCHORS * MIN_METRES)
    np.testing.assert_allclose(fit.errors, 0.0, rtol=0, atol=1e-6 * MIN_METRES)


@pytest.mark.parametrize(
    "call",
    [
        lambda: rs.multilaterate(ANCHORS + 0j, np.linalg.norm(ANCHORS - POINT, axis=1)),
        lambda: rs.multilaterate(ANCHORS, np.linalg.norm(ANCHORS - POINT, axis=1) + 0j),
        lambda: rs.calibrate(walk_scene()[2] + 0j, dim=2, max_attempts=1, rng=0),
        lambda: ekf_slam(walk_scene()[2] + 0j, dim=2, rng=0),
        lambda: range_matrix(ANCHORS + 0j, ANCHORS),
        lambda: edm(ANCHORS + 0j),
        lambda: rs.align(ANCHORS, ANCHORS + 1e-3j),
        lambda: detect_echoes(_rir() + 0j, FS),
        lambda: rs.Room.shoebox([5 + 0j, 3]),
    ],
)
def test_complex_arrays_are_refused(call):
    """Complex arrays, even with zero imaginary part: InvalidInputError 'not complex' (numpy
    dropped the imaginary part with a ComplexWarning and the answer CONVERGED, before)."""
    with pytest.raises(InvalidInputError, match="real numbers, not complex"):
        call()


def test_as_float_array_refuses_strings_objects_and_overflow():
    for bad, match in (
        (["0.1", "0.2"], "not <U3"),
        ([1.0, "2"], "real numbers, not <U"),
        ([1.0, 2.0, b"3"], "real numbers, not"),
        ([1.0, 2j], "not complex"),
        ([1.0, 10**400], "array of real numbers"),
        ([[1.0, 2.0], [3.0]], "array of real numbers"),
        ({"a": 1}, "array of real numbers"),
    ):
        with pytest.raises(InvalidInputError, match=rf"^v must be .*{match}"):
            as_float_array(bad, "v")
    got = as_float_array([1, 2.5, np.float32(0.5), True], "v")
    assert got.dtype == float and got.tolist() == [1.0, 2.5, 0.5, 1.0]


def test_numeric_strings_in_step_bounds_are_refused():
    """Step bounds of numeric strings: InvalidInputError naming step_bounds (parsed by numpy and
    used, before)."""
    _, _, r, steps = walk_scene()
    lower, upper = [f"{v:.3f}" for v in 0.9 * steps], [f"{v:.3f}" for v in 1.1 * steps]
    with pytest.raises(InvalidInputError, match=r"^step_bounds lower must be"):
        StepBounds.parse((lower, upper), len(steps))
    with pytest.raises(InvalidInputError, match=r"^step_bounds"):
        rs.slam(r, step_bounds=(lower, upper), dim=2, max_attempts=1, rng=0)
    with pytest.raises(InvalidInputError, match=r"^step_bounds"):
        StepBounds(lower=lower, upper=upper)


# ---- the single entry points of the list ------------------------------------------------------


def test_calibrate_unknown_emission_refuses_an_empty_array():
    """A (0, 0) ranges array: InvalidInputError (ValueError from an empty max, before)."""
    with pytest.raises(InvalidInputError, match=r"^ranges must hold at least one range"):
        rs.calibrate_unknown_emission(np.zeros((0, 0)))


@pytest.mark.parametrize(
    "window", [(np.nan, 0.01), (0.0, np.inf), ("0", "0.01"), (0.0, 10**400), (0.0, 1j)]
)
def test_detect_echoes_noise_window_is_checked(window):
    """noise_window with NaN, infinity, strings, huge integers or complex: InvalidInputError
    naming noise_window (ValueError from ceil(NaN), before; strings were parsed)."""
    with pytest.raises(InvalidInputError, match=r"^noise_window must be"):
        detect_echoes(_rir(), FS, noise_window=window)


@pytest.mark.parametrize(
    "value", ["abc", [[0, 1], [1]], [["0", "1"], ["1", "0"]], [[0, 1j], [1j, 0]]]
)
def test_classical_mds_refuses_non_numeric_matrices(value):
    """classical_mds on a string, a ragged list, strings or complex numbers: InvalidInputError
    naming edm_matrix (TypeError/ValueError, before)."""
    with pytest.raises(InvalidInputError, match=r"^edm_matrix must be"):
        classical_mds(value, 2)


@pytest.mark.parametrize("dim", [True, 2.0, "2", 10**400])
def test_classical_mds_refuses_bad_dim(dim):
    with pytest.raises(InvalidInputError, match=r"^dim must be"):
        classical_mds(np.zeros((3, 3)), dim)


@pytest.mark.parametrize("dims", ["5x3", "53", ["5", "3"], [5, 3j], [5, 10**400]])
def test_shoebox_refuses_non_numeric_dims(dims):
    """Room.shoebox("5x3"): InvalidInputError naming dims (ValueError from numpy, before)."""
    with pytest.raises(InvalidInputError, match=r"^dims must be"):
        Room.shoebox(dims)


@pytest.mark.parametrize("name", ["reflection", "scale"])
@pytest.mark.parametrize("value", [np.array([True, False]), "yes", 1, None])
def test_align_switches_must_be_booleans(name, value):
    """align(reflection=array): InvalidInputError naming the switch (ValueError, before)."""
    with pytest.raises(InvalidInputError, match=rf"^{name} must be True or False"):
        rs.align(ANCHORS, ANCHORS, **{name: value})


@pytest.mark.parametrize("pose", [(1e200, 0.0, 0.0), (0.0, 0.0, 1e200), (0.0, 10**400, 0.0)])
def test_beacon_slam_incremental_refuses_a_far_start_pose(pose):
    """A start pose at 1e200: InvalidInputError naming start_pose (GTSAM RuntimeError in the
    incremental estimator, before)."""
    run = simulate_beacon_run(np.random.default_rng(0), n_steps=30, radius=3.0, range_std=0.05)
    with pytest.raises(InvalidInputError, match=r"^start_pose must be"):
        beacon_slam_incremental(run.data, start_pose=pose)
    with pytest.raises(InvalidInputError, match=r"^start_pose must be"):
        rs.beacon_slam(run.data, start_pose=pose)


@pytest.mark.parametrize("template", [(0.001, 1e-6), (0.001, 0.0), ("0", "0.001"), (0.0, 1j)])
def test_room_from_rirs_refuses_an_empty_or_reversed_template(template):
    """direct_template whose window ends at (or before) the direct peak, or given as strings
    or complex: InvalidInputError naming direct_template (used as a one-sample or parsed
    template, before)."""
    rirs = np.tile(_rir(), (6, 1))
    with pytest.raises(InvalidInputError, match=r"^direct_template must be"):
        room_from_rirs(rirs, FS, ANCHORS, c=343.0, direct_template=template)


def test_npz_with_two_column_mics_is_refused(tmp_path):
    """mics (M, 2) in an npz: DataFormatError naming the file and the key (loaded, before)."""
    path = tmp_path / "flat.npz"
    np.savez(path, rirs=np.ones((3, 10)), fs=16000.0, mics=np.zeros((3, 2)))
    with pytest.raises(DataFormatError, match=r"flat\.npz: mics must have shape \(3, 3\)"):
        load_rirs(path)
    np.savez(path, rirs=np.ones((3, 10)), fs=16000.0, mics_v3=np.zeros((3, 2)))
    with pytest.raises(DataFormatError, match=r"flat\.npz: mics_v3 must have shape \(3, 3\)"):
        load_rirs(path)


# ---- property: a valid problem scaled by 10^k, k in -200..200 --------------------------------

SCALE_EXPONENTS = st.integers(-200, 200) | st.sampled_from([-10, -9, 12, 13])


def only_package_errors(call, *args, **kwargs):
    """Call; any exception must be one of the package's (RangeSlamError)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with contextlib.suppress(RangeSlamError):
            return call(*args, **kwargs)
    return None


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(k=SCALE_EXPONENTS, d=st.sampled_from([2, 3]))
def test_scaled_points_and_ranges_only_package_errors(k, d):
    """Multilateration, the geometry and the CRLBs on a valid problem whose coordinates and
    ranges are scaled by 10^k: only the package's errors escape; inside [MIN_METRES, MAX_METRES]
    multilaterate still finds the scaled point."""
    scale = 10.0**k
    a, x = ANCHORS[:, :d] * scale, POINT[:d] * scale
    with np.errstate(over="ignore"):  # the scaled ranges themselves may overflow to inf
        r = np.linalg.norm(a - x, axis=1)
    out = only_package_errors(rs.multilaterate, a, r)
    if out is not None and out.converged:
        np.testing.assert_allclose(out.position, x, rtol=1e-6, atol=0)
    only_package_errors(rs.multilaterate_with_offset, a, r + 0.3 * scale)
    only_package_errors(rs.multilateration_crlb, a, x, sigma=1e-3 * scale)
    only_package_errors(range_matrix, a, a)
    only_package_errors(rs.align, a, a[::-1], reflection=True, scale=True)
    only_package_errors(classical_mds, np.square(r)[:, None] + np.square(r)[None, :], d)
    only_package_errors(rs.Room.shoebox, np.full(d, 3.0 * scale))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(k=SCALE_EXPONENTS)
def test_scaled_walks_only_package_errors(k):
    """ekf_slam, refine_graph and calibrate (2-D, short runs) on a valid walk scaled by 10^k:
    only the package's errors escape."""
    scale = 10.0**k
    x, s, r, steps = walk_scene()
    x, s, r, steps = x * scale, s * scale, r * scale, steps * scale
    only_package_errors(ekf_slam, r, dim=2, n_starts=2, rng=0)
    only_package_errors(refine_graph, x, s, r, noise_std=1e-3 * scale, max_iterations=5)
    only_package_errors(
        rs.calibrate, r[:6, :5], dim=2, max_attempts=1, max_iterations=3, random_starts=0, rng=0
    )
    only_package_errors(rs.mdu_crlb, x, s, sigma=1e-3 * scale)


@pytest.mark.parametrize("sigma", [1e-320, 1e200, np.full(6, 1e-300)])
def test_multilateration_crlb_sigma_limits(sigma):
    """sigma beyond [1e-100, 1e100] m (as mdu_crlb takes it): InvalidInputError naming sigma
    (LinAlgError 'Eigenvalues did not converge' at 1e-320, before)."""
    with pytest.raises(InvalidInputError, match=r"^sigma must be in \[1e-100, 1e100\] metres"):
        rs.multilateration_crlb(ANCHORS, POINT, sigma)


def test_ekf_noise_far_beyond_the_scene_is_a_solver_error():
    """noise_std of 1e8 m on a 3 m scene (within MAX_METRES) leaves the window fit's information
    matrix indefinite in floating point: SolverError (LinAlgError from the Cholesky, before)."""
    _, _, r, _ = walk_scene()
    with pytest.raises(SolverError, match="information matrix is not positive definite"):
        ekf_slam(r, dim=2, noise_std=1e8, rng=0)


@pytest.mark.slow
def test_ekf_answer_collapsed_below_a_nanometre_is_not_an_input_error():
    """An EKF answer that collapses towards the origin (noise_std of 1e6 m on a 3 m scene) is
    judged, not refused as if the caller had passed it: range_matrix takes any finite points."""
    _, _, r, _ = walk_scene()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = ekf_slam(r, dim=2, rng=0, smooth=True, noise_std=1e6)
    assert isinstance(out.status, Status) and out.receivers.shape == (8, 2)


@pytest.mark.parametrize(
    ("name", "value"),
    [("dim", "3"), ("dim", True), ("rtol", np.array([1e-9, 1e-9])), ("rtol", 10**400)],
)
def test_is_edm_options_are_checked(name, value):
    """is_edm(dim="3") or rtol as an array or a 401-digit integer: InvalidInputError naming the
    option (TypeError, ValueError or OverflowError, before: benchmarks/fuzz_entry_points.py)."""
    with pytest.raises(InvalidInputError, match=rf"^{name} must be"):
        rs.is_edm(np.zeros((3, 3)), **{name: value})


@pytest.mark.parametrize("bad", [True, 0, 10**6, 2.5, "100"])
def test_beacon_slam_max_iterations_is_an_integer_within_its_limit(bad):
    """``max_iterations=True`` was accepted; the limit (MAX_LM_ITERATIONS) is stated."""
    from rangeslam.beacons.simulation import simulate_beacon_run

    run = simulate_beacon_run(np.random.default_rng(0), n_steps=60, radius=5.0, range_std=0.05)
    with pytest.raises(InvalidInputError, match="max_iterations"):
        rs.beacon_slam(run.data, max_iterations=bad)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise_std": 2.2e154}, "noise_std"),
        ({"max_attempts": 10**6}, "max_attempts"),
        ({"max_iterations": True}, "max_iterations"),
        ({"random_starts": 10**9}, "random_starts"),
    ],
)
def test_calibration_counts_and_noise_have_upper_limits(kwargs, match):
    """noise_std near 2.2e154 overflowed calibrate_unknown_emission's chi-square test; the
    search's counts had no upper limit (a run that never passes would go on for days)."""
    ranges = np.ones((6, 6))
    with pytest.raises(InvalidInputError, match=match):
        rs.calibrate(ranges, **kwargs)
    if "noise_std" in kwargs:
        with pytest.raises(InvalidInputError, match=match):
            rs.calibrate_unknown_emission(ranges, **kwargs)


@pytest.mark.parametrize("estimator", ["multilaterate", "multilaterate_with_offset"])
def test_multilateration_noise_std_has_an_upper_limit(estimator):
    """noise_std=1e171 overflowed the chi-square test (the fuzz at seed 522445)."""
    rng = np.random.default_rng(522445)
    anchors = rng.uniform(0.0, 4.0, (8, 3))
    ranges = np.linalg.norm(anchors - rng.uniform(0.0, 4.0, 3), axis=1)
    with pytest.raises(InvalidInputError, match="noise_std"):
        getattr(rs, estimator)(anchors, ranges, noise_std=1e171)


def test_wall_crlb_refuses_offsets_beyond_metres():
    """Wall offsets of 4e157 m reached LAPACK (LinAlgError: the fuzz at seed 900171)."""
    room = rs.Room.shoebox([4.0, 3.0, 2.5])
    rng = np.random.default_rng(900171)
    mics = rng.uniform(0.5, 2.0, (6, 3))
    source = np.array([[1.0, 1.0, 1.0]])
    offsets = np.array(room.offsets, dtype=float)
    offsets[0] = 4e157
    with pytest.raises(InvalidInputError, match="offsets"):
        rs.wall_crlb(mics, source, room.normals, offsets, 1e-3)
