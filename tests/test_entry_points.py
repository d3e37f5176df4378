"""Bad input refused at the door (issue 17, item 3), property-based, for the estimators of
localization/, mdu/ and the CRLBs.

Each entry point is called with one argument of a valid small problem replaced by something
hypothesis draws (wrong shapes, dtypes, NaN/inf, strings, negative numbers, rng in many forms; the
families of issue 35: magnitudes 1e-200..1e200, integers too large for a float, complex numbers,
numeric strings); whatever happens, only the package's errors (RangeSlamError subclasses) may
escape. Valid noise-free problems drawn by hypothesis (points in a box, well-spread geometry) must
come back close to the truth when the result says converged.
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np
import pytest
from hostile import hostile_values
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import rangeslam as rs
from rangeslam._validation import as_rng, as_scalar
from rangeslam.errors import InvalidInputError, RangeSlamError
from rangeslam.geometry.edm import range_matrix

# Bad values of every kind the fuzz of issue 17 passed: scalars of the wrong type or range, arrays
# of the wrong shape and dtype, empty arrays, objects.
ODD_VALUES = [
    None, True, False, -1, 0, 1, 2, 3, 4, 10**30, -0.0, 1.5, np.nan, np.inf, -np.inf, 1j, "x", "",
    b"3", [], [[]], [1, [2, 3]], {"a": 1}, object(), np.array(2.0), np.array([1.0, 2.0]),
    np.zeros((0, 3)), np.zeros((0,)), np.zeros((2, 3, 4)), np.array(["a", "b"]), np.array([1 + 2j]),
    np.array([np.nan]), np.int64(5), np.float32(0.5), np.bool_(True), np.array([True, False]),
    np.random.SeedSequence(1), np.random.PCG64(2), np.random.default_rng(3),
]  # fmt: skip


def odd_arrays():
    """Arrays of 0-3 dims, small sizes, any of float, int, bool, complex, object-free dtypes."""
    dtypes = st.sampled_from([np.float64, np.int64, np.bool_, np.complex128, np.float32])
    shapes = hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=7)
    return dtypes.flatmap(
        lambda dt: hnp.arrays(
            dt,
            shapes,
            elements=None if dt is not np.float64 else st.floats(-1e3, 1e3) | st.just(np.nan),
        )
    )


def bad_values():
    return st.one_of(
        st.sampled_from(ODD_VALUES),
        st.text(max_size=4),
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(-(10**20), 10**20),
        odd_arrays(),
        hostile_values(),
    )


def only_package_errors(call, kwargs):
    """Call; any exception must be one of the package's."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with contextlib.suppress(RangeSlamError):
            call(**kwargs)


def _fuzzed(base: dict, data) -> dict:
    """``base`` with one or two arguments replaced by drawn bad values."""
    names = data.draw(st.lists(st.sampled_from(sorted(base)), min_size=1, max_size=2, unique=True))
    out = dict(base)
    for name in names:
        out[name] = data.draw(bad_values(), label=name)
    return out


FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# Solvers that run an SDP when the draw happens to be valid: fewer examples.
FUZZ_SLOW = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _anchors_and_point(d):
    a = np.array([[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 3], [3, 3, 1], [1, 3, 3]], float)[:, :d]
    x = np.array([1.0, 1.2, 0.8])[:d]
    return a, x


def _mdu_scene(d, m=6, k=6):
    gen = np.random.default_rng(7)
    return gen.uniform(0, 3, (m, d)), gen.uniform(0, 3, (k, d))


@FUZZ
@given(data=st.data(), d=st.sampled_from([2, 3]))
def test_multilaterate_refuses_bad_input(data, d):
    """multilaterate / multilaterate_with_offset: only RangeSlamError escapes."""
    a, x = _anchors_and_point(d)
    r = np.linalg.norm(a - x, axis=1)
    base = dict(anchors=a, ranges=r, weights=None, mask=None, robust=True,
                inlier_threshold=None, max_hypotheses=30, rng=0)  # fmt: skip
    only_package_errors(rs.multilaterate, _fuzzed(base, data))
    base["ranges"] = r + 0.4
    only_package_errors(rs.multilaterate_with_offset, _fuzzed(base, data))


@FUZZ
@given(data=st.data())
def test_crlbs_refuse_bad_input(data):
    """mdu_crlb, multilateration_crlb, wall_crlb: only RangeSlamError escapes."""
    x, s = _mdu_scene(3, 7, 7)
    only_package_errors(
        rs.mdu_crlb, _fuzzed(dict(receivers=x, sources=s, sigma=0.01, mask=None, gauge="all"), data)
    )
    a, p = _anchors_and_point(3)
    only_package_errors(
        rs.multilateration_crlb, _fuzzed(dict(anchors=a, point=p, sigma=0.01, mask=None), data)
    )
    normals = np.array([[1.0, 0, 0], [0, 0, 1.0]])
    base = dict(mics=x, sources=s[:1], normals=normals, offsets=np.array([5.0, 4.0]),
                sigma=0.01, points=None, mask=None)  # fmt: skip
    only_package_errors(rs.wall_crlb, _fuzzed(base, data))


def _room_ranges(d):
    """Mics (6, d), one source and its images in walls x = 5 and y = 4: ranges (6, 3)."""
    mics = np.array(
        [[1, 1, 1], [2, 1, 1.5], [1, 2, 1.2], [1.5, 1.5, 2], [2, 2, 1], [1.2, 1.8, 1.7]]
    )
    mics = mics[:, :d]
    src = np.array([3.0, 2.5, 1.4])[:d]
    images = np.array([src, src, src])
    images[1, 0] = 10.0 - src[0]
    images[2, 1] = 8.0 - src[1]
    return mics, range_matrix(mics, images)


@FUZZ_SLOW
@given(data=st.data(), d=st.sampled_from([2, 3]))
def test_reconstruct_room_refuses_bad_input(data, d):
    """reconstruct_room / reconstruct_room_unknown_emission: only RangeSlamError escapes."""
    mics, r = _room_ranges(d)
    base = dict(mics=mics, ranges=r, mask=None, robust=True, inlier_threshold=None,
                max_hypotheses=20, rng=0)  # fmt: skip
    only_package_errors(rs.reconstruct_room, _fuzzed(base, data))
    base.update(ranges=r + 0.3, c=None)
    only_package_errors(rs.reconstruct_room_unknown_emission, _fuzzed(base, data))


@FUZZ_SLOW
@given(data=st.data())
def test_calibrate_refuses_bad_input(data):
    """calibrate and calibrate_unknown_emission (2-D, few points, one short run): only
    RangeSlamError escapes."""
    x, s = _mdu_scene(2)
    r = range_matrix(x, s)
    base = dict(ranges=r, dim=2, mask=None, noise_std=None, max_attempts=1, random_starts=0,
                fit_weight=10.0, max_iterations=3, gap_tol=1e-6, rng=0)  # fmt: skip
    only_package_errors(rs.calibrate, _fuzzed(dict(base, refine=True, robust=False), data))
    base.update(ranges=r + 0.2, groups=None, c=None, offsets0=None)
    only_package_errors(rs.calibrate_unknown_emission, _fuzzed(base, data))


@FUZZ_SLOW
@given(data=st.data())
def test_slam_refuses_bad_input(data):
    """slam (2-D walk of 6 steps, 5 landmarks, one short run): only RangeSlamError escapes."""
    x, s = _mdu_scene(2, 6, 5)
    r = range_matrix(x, s)
    steps = np.linalg.norm(np.diff(x, axis=0), axis=1)
    base = dict(ranges=r, step_bounds=(0.5 * steps, 1.5 * steps), mask=None, dim=2, refine=True,
                noise_std=None, robust=None, step_sigma=None, step_prior="uniform",
                max_attempts=1, extra_starts=0, fit_weight=10.0, max_iterations=3, rng=0)  # fmt: skip
    only_package_errors(rs.slam, _fuzzed(base, data))


@settings(max_examples=200, deadline=None)
@given(value=st.one_of(bad_values(), st.integers(0, 2**64)))
def test_as_rng_accepts_spec7_and_refuses_the_rest(value):
    """as_rng gives a Generator for every SPEC 7 form and InvalidInputError for anything else."""
    spec7 = (
        value is None
        or isinstance(value, np.random.SeedSequence | np.random.BitGenerator | np.random.Generator)
        or (
            isinstance(value, int | np.integer)
            and not isinstance(value, bool | np.bool_)
            and value >= 0
        )
    )
    if spec7:
        assert isinstance(as_rng(value), np.random.Generator)
    else:
        with pytest.raises(InvalidInputError, match="rng must be"):
            as_rng(value)


@settings(max_examples=200, deadline=None)
@given(value=bad_values())
def test_as_scalar_only_package_errors(value):
    """as_scalar returns a finite float or raises InvalidInputError naming the argument."""
    try:
        out = as_scalar(value, "knob", low=0.0)
    except InvalidInputError as exc:
        assert "knob" in str(exc)
    else:
        assert isinstance(out, float) and np.isfinite(out) and out >= 0


# ---- valid noise-free problems: converged means close to the truth -------------------------


def _spread(points: np.ndarray) -> float:
    """Smallest singular value of the centred points over their largest (1 = isotropic)."""
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return sv[-1] / sv[0] if sv[0] > 0 else 0.0


box_points = lambda n, d: hnp.arrays(  # noqa: E731
    np.float64, (n, d), elements=st.floats(0.0, 4.0, allow_subnormal=False)
)


@settings(max_examples=40, deadline=None)
@given(d=st.sampled_from([2, 3]), data=st.data())
def test_multilaterate_exact_recovery(d, data):
    """Anchors in a 4 m box with affine spread >= 0.2, the point in the box at least 0.1 m from
    every anchor, exact ranges: converged and within 1e-6 m of the truth; with an offset, the
    offset within 1e-6 m too."""
    a = data.draw(box_points(d + 3, d), label="anchors")
    x = data.draw(box_points(1, d), label="point")[0]
    assume(_spread(a) > 0.2 and np.min(np.linalg.norm(a - x, axis=1)) > 0.1)
    r = np.linalg.norm(a - x, axis=1)
    out = rs.multilaterate(a, r)
    assert out.converged, out.message
    np.testing.assert_allclose(out.position, x, atol=1e-6, rtol=0)
    off = rs.multilaterate_with_offset(a, r + 0.37)
    if off.converged:
        np.testing.assert_allclose(off.position, x, atol=1e-6, rtol=0)
        assert abs(off.offset - 0.37) < 1e-6


#: Well-spread 2-D layouts (receivers on a pentagon-ish ring, sources on a larger one), metres;
#: hypothesis jitters each point by up to 0.3 m, which keeps them spread and apart.
RING_RECEIVERS = np.array([[0.0, 0.0], [1.5, 0.2], [1.8, 1.6], [0.4, 1.9], [-0.5, 1.0], [0.8, 0.9]])
RING_SOURCES = np.array(
    [[-2.0, -1.5], [3.5, -1.0], [3.8, 3.2], [-1.2, 3.6], [1.0, -2.5], [4.5, 1.2]]
)


def jitter(n, d):
    return hnp.arrays(np.float64, (n, d), elements=st.floats(-0.3, 0.3, allow_subnormal=False))


@settings(max_examples=6, deadline=None)
@given(dx=jitter(6, 2), ds=jitter(6, 2))
def test_calibrate_exact_recovery(dx, ds):
    """6 receivers and 6 sources in 2-D, each within 0.3 m of a well-spread layout, exact ranges:
    calibrate says converged (with noise_std 0 the residual test is exact) and the receivers are
    within 1e-4 m of the truth after rigid alignment (with reflection)."""
    x, s = RING_RECEIVERS + dx, RING_SOURCES + ds
    out = rs.calibrate(range_matrix(x, s), dim=2, noise_std=0.0, max_attempts=4, rng=0)
    assert out.converged, out.message
    assert rs.align(out.receivers, x, reflection=True).rmse < 1e-4


@settings(max_examples=4, deadline=None)
@given(
    walk=hnp.arrays(np.float64, (8, 2), elements=st.floats(0.15, 0.5)),
    signs=hnp.arrays(np.bool_, (8, 2)),
    ds=jitter(6, 2),
)
def test_slam_known_steps_exact_recovery(walk, signs, ds):
    """A 2-D walk of 8 steps (each coordinate of a step 0.15-0.5 m, either sign) among 6
    landmarks within 0.3 m of a well-spread layout, exact ranges and the known step lengths
    (lower = upper): converged and within 1e-4 m of the truth after alignment."""
    traj = np.cumsum(np.where(signs, walk, -walk), axis=0)
    traj = traj - traj.mean(axis=0) + np.array([1.0, 1.0])
    land = RING_SOURCES + ds
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    assume(_spread(traj) > 0.1)
    r = range_matrix(traj, land)
    out = rs.slam(r, step_bounds=(steps, steps), dim=2, noise_std=0.0, max_attempts=4, rng=0)
    assert out.converged, out.message
    assert rs.align(out.receivers, traj, reflection=True).rmse < 1e-4
