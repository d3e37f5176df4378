"""Issue 35, S3 and S4: the mirror and planarity checks cover every source and landmark.

S3: six Fig. 3 microphones moved onto one plane, fitted in 3-D: every source's mirror image
through that plane fits the ranges, but least squares bends the microphones a few millimetres
towards each source's side, so against them held fixed half the mirrors cost tens of noise
variances more and went unflagged (one 7.7 m off). S4: a walk of 3 steps in a plane under 3-D
landmarks, fitted with ``dim=2`` and no ``noise_std``: the landmarks' heights fold into their
in-plane distances (0.6-3.3 m off) and the planarity F-test, with one redundant range in 3-D,
cannot see it: it was CONVERGED.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import rangeslam
from rangeslam.app.experiments import fig3_scene
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.planarity import blind_power, planarity_power
from rangeslam.sim.trajectories import lemniscate
from rangeslam.status import Status

_ROOM = (5.0, 4.0, 2.6)


def _noted(message: str) -> set[int]:
    """The source indices a verdict's "noted: source i ... (also noted: sources j, k)" names."""
    named = {int(i) for i in re.findall(r"noted: source (\d+)", message)}
    for group in re.findall(r"also noted: sources ([\d, ]+)", message):
        named |= {int(i) for i in group.split(",")}
    return named


def _flat_fig3(rng: np.random.Generator, sigma: float = 1e-3):
    """The Fig. 3 scene with its 6 microphones moved onto the plane z = 1.3 m: (mics (6, 3) and
    ranges (6, 6) with ``sigma`` metres of noise, all drawn from ``rng``)."""
    scene = fig3_scene(rng)
    mics = scene.mics.copy()
    mics[:, 2] = 1.3
    ranges = range_matrix(mics, scene.sources)
    return mics, ranges + sigma * rng.standard_normal(ranges.shape)


def _check_every_mirror_flagged(res) -> None:
    """Every source of ``res`` (a Calibration of a flat array) more than 0.2 m off the
    microphones' plane is in ``ambiguous_sources``, and the message names every flagged one."""
    centre = res.receivers.mean(axis=0)
    normal = np.linalg.svd(res.receivers - centre)[2][-1]
    height = np.abs((res.sources - centre) @ normal)
    flagged = np.flatnonzero(res.ambiguous_sources)
    assert res.ambiguous_sources[height > 0.2].all(), (height, flagged, res.message)
    assert set(flagged) <= _noted(res.message), (flagged, res.message)


def test_flat_array_flags_every_source_mirror_issue_case():
    """The issue's case (``fig3_scene(default_rng(0))``, noise from ``default_rng(1000)``, 1 mm):
    sources 2, 4 and 5 were flagged, 0, 1 and 3 not (held-fixed gaps 25-48 noise variances,
    0.1-1.3 noise variances with the microphones refitted)."""
    scene = fig3_scene(np.random.default_rng(0))
    mics = scene.mics.copy()
    mics[:, 2] = 1.3
    ranges = range_matrix(mics, scene.sources)
    ranges = ranges + 1e-3 * np.random.default_rng(1000).standard_normal(ranges.shape)
    res = rangeslam.calibrate(ranges, dim=3, noise_std=1e-3, rng=0)
    assert res.ambiguous_sources.all(), res.message
    _check_every_mirror_flagged(res)


@pytest.mark.slow
def test_flat_array_flags_every_source_mirror(rng):
    """Fresh flat arrays (1 mm noise): at an answer whose microphones are right (within 2.5 cm
    RMS), every source off the plane is flagged with its mirror image and named (12 fresh
    draws: 62 of 72 sources flagged before, 70 after; the other two sat within 6 cm of the
    plane, folded into it, with no mirror image of their own). Answers further off are wrong
    local minima (issue 35, S2), where a flipped source can refit into a third configuration;
    they are left out."""
    checked = 0
    for _ in range(6):
        mics, ranges = _flat_fig3(rng)
        res = rangeslam.calibrate(ranges, dim=3, noise_std=1e-3, rng=rng)
        if align(res.receivers, mics, reflection=True).rmse > 0.025:
            continue
        checked += 1
        _check_every_mirror_flagged(res)
        assert np.isfinite(res.source_mirrors[res.ambiguous_sources]).all()
    assert checked >= 2


def test_mirror_not_flagged_off_a_flat_array(rng):
    """The refit is only tried where the microphones may be flat: the Fig. 3 scene as drawn
    (microphones in a 1 m cube) flags no source (0 of 72 on 12 draws, as before)."""
    for _ in range(2):
        scene = fig3_scene(rng)
        ranges = scene.ranges + 1e-3 * rng.standard_normal(scene.ranges.shape)
        res = rangeslam.calibrate(ranges, dim=3, noise_std=1e-3, rng=rng)
        assert not res.ambiguous_sources.any(), res.message


def _planar_walk(rng: np.random.Generator, m: int, sigma: float, *, flat_landmarks=False):
    """A lemniscate walk of ``m`` positions at z = 0.9 m (steps of 0.3 m, random phase) under a
    loudspeaker uniform in the room and its 6 first-order images (moved into the walk's plane
    with ``flat_landmarks``): (ranges (m, 7) with ``sigma`` metres of noise, step bounds +-20%)."""
    walk = lemniscate(m, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    source = rng.uniform([0.5, 0.5, 0.5], [4.5, 3.5, 2.1])
    landmarks = np.vstack(
        [source, rangeslam.Room.shoebox(_ROOM).image_sources(source, 1).positions]
    )
    if flat_landmarks:
        landmarks[:, 2] = walk[0, 2]
    ranges = range_matrix(walk, landmarks) + sigma * rng.standard_normal((m, 7))
    steps = np.linalg.norm(np.diff(walk, axis=0), axis=1)
    return ranges, (0.8 * steps, 1.2 * steps)


@pytest.mark.parametrize(
    ("m", "noise_std"),
    [
        (3, None),
        pytest.param(4, None, marks=pytest.mark.slow),
        pytest.param(3, 1e-3, marks=pytest.mark.slow),
    ],
)
def test_slam_dim_2_under_3d_landmarks_is_not_converged(rng, m, noise_std):
    """A planar walk of 2 or 3 steps under 3-D landmarks, fitted with dim=2, is not CONVERGED
    (6 fresh walks with bounds each, before: 6 of 6 converged without noise_std at 2 and 3
    steps, 2 of 6 with it at 2 steps, landmarks 1.2-9.4 m off), and the message names every
    landmark reported ambiguous."""
    for _ in range(3):
        ranges, bounds = _planar_walk(rng, m, 1e-3)
        res = rangeslam.slam(ranges, dim=2, step_bounds=bounds, noise_std=noise_std, rng=rng)
        assert not res.converged, res.message
        if res.status is Status.NOT_IDENTIFIABLE:  # else its residuals failed first
            assert "cannot be shown planar" in res.message
            assert set(np.flatnonzero(res.ambiguous_landmarks)) <= _noted(res.message)


def test_slam_dim_2_planar_data_with_noise_std_still_converges(rng):
    """The blind test is only reported without noise_std (the residual test against it then
    sees a fold): planar landmarks on the same walks with noise_std given still converge, and
    exact planar data converge without it."""
    converged = 0
    for _ in range(3):
        ranges, bounds = _planar_walk(rng, 6, 1e-3, flat_landmarks=True)
        res = rangeslam.slam(ranges, dim=2, step_bounds=bounds, noise_std=1e-3, rng=rng)
        converged += res.converged
        assert "cannot be shown planar" not in res.message
    assert converged >= 2
    ranges, bounds = _planar_walk(rng, 4, 0.0, flat_landmarks=True)
    res = rangeslam.slam(ranges, dim=2, step_bounds=bounds, rng=rng)
    assert "cannot be shown planar" not in res.message


def test_planarity_power():
    """The fold the F-test misses, in noise shares of the residual, for 7 landmarks: blind with
    3 or 4 positions (no or one redundant range in 3-D), not from 5."""

    def power(m):
        n = m + 7
        return planarity_power(n - 3, 7 * m - (2 * n - 3))

    assert power(3) == np.inf
    assert power(4) > blind_power() > power(5)
    assert power(5) == pytest.approx(17.5, abs=0.1)
    assert power(10) < power(6) < power(5)


def _bent_fit(rng, heights_std: float, sigma: float):
    """8 receivers and 7 sources in a 4 m square, heights ``heights_std`` metres about z = 1,
    ranges with ``sigma`` noise, the 3-D least-squares fit from the truth: (points (15, 3),
    ranges, observed)."""
    from rangeslam.solvers.least_squares import refine_unfolding

    pts = np.column_stack([rng.uniform(0, 4, (15, 2)), 1.0 + heights_std * rng.standard_normal(15)])
    ranges = range_matrix(pts[:8], pts[8:]) + sigma * rng.standard_normal((8, 7))
    observed = np.ones((8, 7), dtype=bool)
    start = pts + 0.02 * rng.standard_normal(pts.shape)
    fit = refine_unfolding(start[:8], start[8:], ranges, observed)
    return np.vstack([fit.receivers, fit.sources]), ranges, observed


def test_flat_points_refitted_in_a_plane_fit_as_well(rng):
    """flat_fit_check: a flat scene fitted in 3-D (the noise bends it centimetres off its plane)
    refits in 2-D at a cost within chi-square(N - d) of the 3-D one: NOT_IDENTIFIABLE, the test's
    numbers in the reason. A 3-D scene thinner than the old one-range flatness limit at the
    noise given (heights 0.6 m RMS, 3 cm: 2.57 sqrt(sigma scale) = 0.9 m) is not flat: its planar
    refit costs thousands of noise variances more. Exact data: the check needs a noise level."""
    from rangeslam.mdu.planarity import flat_fit_check
    from rangeslam.verdict import flatness_check

    for _ in range(3):
        points, ranges, observed = _bent_fit(rng, 0.0, 1e-3)
        check = flat_fit_check(points, 8, ranges, observed, 1e-3, "the scene")
        assert check.status is Status.NOT_IDENTIFIABLE
        spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)[-1]
        assert spread > 1e-3  # bent off the plane by the noise
        points, ranges, observed = _bent_fit(rng, 0.6, 1e-2)
        assert flat_fit_check(points, 8, ranges, observed, 3e-2, "the scene").passed
        assert not flatness_check(points, 3e-2, float(np.median(ranges)), "").passed
    assert flat_fit_check(points, 8, ranges, observed, None, "the scene").passed


def test_collinear_points_in_2d_refitted_on_a_line_fit_as_well(rng):
    """flat_fit_check in 2-D: 5 receivers and 5 sources on a line with 1 mm noise, fitted in the
    plane from 1 cm off it, refit on the line (SciPy's trust-region fit of |t_i - t_j|) as well:
    NOT_IDENTIFIABLE; spread 0.5 m off the line: passed."""
    from rangeslam.mdu.planarity import flat_fit_check
    from rangeslam.solvers.least_squares import refine_unfolding

    observed = np.ones((5, 5), dtype=bool)
    for spread, flat in ((0.0, True), (0.5, False)):
        pts = np.column_stack([rng.uniform(0, 4, 10), spread * rng.standard_normal(10)])
        ranges = range_matrix(pts[:5], pts[5:]) + 1e-3 * rng.standard_normal((5, 5))
        start = pts + 0.01 * rng.standard_normal(pts.shape)
        fit = refine_unfolding(start[:5], start[5:], ranges, observed)
        answer = np.vstack([fit.receivers, fit.sources])
        check = flat_fit_check(answer, 5, ranges, observed, 1e-3, "x")
        assert check.passed is not flat, check.reason


def test_a_flat_scene_fitted_with_offsets_is_not_converged(rng):
    """A flat scene (10 receivers and 12 sources on z = 1 in a 4 m square, 1 mm) fitted with an
    emission offset per group of 4 sources and a clock offset per receiver: the flat refit would
    hold the fitted offsets fixed (not the nested model), so the one-range flatness bound decides
    (the nested test passed 5 of 5 such scenes as CONVERGED, 2-6 cm off)."""
    groups = np.repeat([0, 1, 2], 4)
    pts = np.column_stack([rng.uniform(0, 4, (22, 2)), np.ones(22)])
    clocks = rng.uniform(-0.3, 0.3, 10)
    ranges = range_matrix(pts[:10], pts[10:]) + (clocks - clocks.mean())[:, None]
    ranges += rng.uniform(-0.5, 0.5, 3)[groups] + 1e-3 * rng.standard_normal((10, 12))
    out = rangeslam.calibrate_unknown_emission(
        ranges, groups, noise_std=1e-3, receiver_offsets=True, rng=rng
    )
    assert out.status is Status.NOT_IDENTIFIABLE
