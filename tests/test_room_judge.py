"""The one judge on a robust room reconstruction (rangeslam.localization.room_judge): the
ranges the fit left out are asked whether they place a wall or a loudspeaker elsewhere. Random
wrong picks place nothing (the answer stands, however many of a wall's echoes they are); a
coherent second wall in them is a rival, or beats the answer."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import Room, reconstruct_room
from rangeslam.app.experiments import wall_errors
from rangeslam.evaluation.verdict_cases import make_case
from rangeslam.localization.room_judge import judge_room, mirror_alternatives, msac_deviance
from rangeslam.localization.room_reconstruction import JointFit, JointWallModel, RoomProblem
from rangeslam.sim.scenes import add_range_noise, echo_ranges, random_points_in_room
from rangeslam.status import Status
from rangeslam.verdict.judge import cost_level

ROOM = Room.shoebox([5.1, 3.7, 2.6])


def _scene(rng):
    """12 microphones and one loudspeaker in the shoebox, ranges with 1 mm noise."""
    mics = random_points_in_room(ROOM, 12, margin=0.3, rng=rng)
    source = random_points_in_room(ROOM, 1, margin=0.3, rng=rng)[0]
    return mics, source, add_range_noise(echo_ranges(ROOM, mics, source), 1e-3, rng=rng)


def test_msac_deviance_truncates_at_the_threshold():
    """sum of min(r^2, thr^2) / sigma^2 over the observed ranges only."""
    mics = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    theta = np.array([0.2, 0.3, 0.0, 2.0])  # a source, one wall y = 2
    ranges = np.array([[[0.3, 3.5], [0.9, 3.4], [0.9, 2.5]]])  # (J, M, 1 + K)
    model = JointWallModel(mics, ranges, np.ones((1, 3, 2), bool))
    res = model.all_residuals(theta)
    thr, sigma = 0.2, 0.1
    assert np.any(np.abs(res) > thr) and np.any(np.abs(res) < thr)  # both branches
    assert msac_deviance(model, theta, thr, sigma) == pytest.approx(
        np.sum(np.minimum(res**2, thr**2)) / sigma**2
    )
    model.use[0, 0, 0] = False
    assert msac_deviance(model, theta, thr, sigma) == pytest.approx(
        np.sum(np.minimum(res**2, thr**2)[model.use]) / sigma**2
    )


def test_random_wrong_echoes_of_a_wall_place_nothing(rng):
    """7 of a wall's 12 echoes wrong at random (0.3-2 m late): past the old majority count
    (which refused every such room), but the 7 cohere into no other wall, so the answer stands.
    Never converged and wrong; converged and right in at least 4 of 10 draws (measured: 29 of
    40; the others the fit dropped a right echo too and kept d + 1 = 4, unverified, or a chance
    agreement of wrong picks made a rival)."""
    right = 0
    for _ in range(10):
        mics, _, r = _scene(rng)
        wrong = rng.permutation(12)[:7]
        r[wrong, 2] += rng.uniform(0.3, 2.0, 7)
        res = reconstruct_room(mics, [r], rng=rng)
        good = wall_errors(ROOM, res.wall_normals, res.wall_offsets)[0].max() < 0.01
        assert good or res.status is not Status.CONVERGED, res.message
        right += res.status is Status.CONVERGED
    assert right >= 4


def test_a_coherent_second_wall_in_half_the_echoes_is_a_rival(rng):
    """6 of a wall's 12 echoes are the echoes of another wall (a plane 0.6 m behind it): the two
    walls fit the data as well; whichever the fit kept, the other is found among the ranges it
    left out and the answer is NOT_IDENTIFIABLE (or OUTLIERS when the fit kept the poorer), never
    CONVERGED."""
    for _ in range(3):
        mics, source, r = _scene(rng)
        far = Room.shoebox([5.1 + 0.6, 3.7, 2.6])  # the +x wall moved 0.6 m out
        other = echo_ranges(far, mics, source)
        k = int(np.argmax(np.abs(ROOM.normals @ np.array([1.0, 0, 0]) * (ROOM.offsets > 0.1))))
        half = rng.permutation(12)[:6]
        r[half, 1 + k] = other[half, 1 + k] + rng.normal(0, 1e-3, 6)
        res = reconstruct_room(mics, [r], rng=rng)
        assert res.status in (Status.NOT_IDENTIFIABLE, Status.OUTLIERS), res.message
        assert "left out" in res.message


def _model_at_truth(mics, source, ranges):
    """The joint model of one loudspeaker's ranges (scaled as reconstruct_room scales them: by
    their median) and theta at the truth, every range kept."""
    scale = float(np.median(ranges))
    centre = mics.mean(axis=0)
    mics_s, src_s = (mics - centre) / scale, (source - centre) / scale
    n, o = ROOM.normals, (ROOM.offsets - ROOM.normals @ centre) / scale
    observed = np.ones((1, *ranges.shape), bool)
    model = JointWallModel(mics_s, ranges[None] / scale, observed)
    theta = np.concatenate([src_s, (n * o[:, None]).ravel()])
    return model, theta


def _slab_scene(rng):
    """12 microphones in a 0.6 m slab (z = 0.6-1.2 m), one loudspeaker, 1 mm: the model at the
    truth, its thr and sigma (scaled), the ranges."""
    mics = random_points_in_room(ROOM, 12, margin=0.3, rng=rng)
    mics[:, 2] = 0.9 + rng.uniform(-0.3, 0.3, len(mics))
    source = random_points_in_room(ROOM, 1, margin=0.3, rng=rng)[0]
    r = add_range_noise(echo_ranges(ROOM, mics, source), 1e-3, rng=rng)
    model, theta = _model_at_truth(mics, source, r)
    scale = float(np.median(r))
    return mics, r, model, theta, 3.29e-3 / scale, 1e-3 / scale


def test_a_walls_other_side_changes_that_wall_alone(rng):
    """Each mirror alternative (microphones in a 0.6 m slab) moves one wall and nothing else
    (the loudspeaker and the other walls stay), the one its origin names."""
    *_, model, theta, thr, sigma = _slab_scene(rng)
    alternatives = list(mirror_alternatives(model, theta, model.use, thr, sigma))
    assert alternatives
    for alt in alternatives:
        moved = np.flatnonzero(np.any(alt.points != theta.reshape(-1, 3), axis=1))
        assert len(moved) == 1 and moved[0] == 1 + int(alt.origin.split()[1].rstrip(":"))
        assert alt.payload == "mirror"


def test_coplanar_microphones_hear_each_wall_on_both_sides(rng):
    """Microphones in one plane (a table, exact ranges): every wall's image off the plane has a
    mirror through it at the same ranges, so each wall's other side fits as well."""
    mics = random_points_in_room(ROOM, 8, margin=0.3, rng=rng)
    mics[:, 2] = 0.9
    source = random_points_in_room(ROOM, 1, margin=0.3, rng=rng)[0]
    model, theta = _model_at_truth(mics, source, echo_ranges(ROOM, mics, source))
    thr, sigma = 3.29e-3 / np.median(model.ranges), 1e-3 / np.median(model.ranges)
    base = msac_deviance(model, theta, thr, sigma)
    gaps = [a.deviance - base for a in mirror_alternatives(model, theta, model.use, thr, sigma)]
    assert len(gaps) >= 4 and max(gaps) < 1e-6


def test_a_wall_on_the_wrong_side_is_not_converged():
    """Frozen converged-wrong (verdict benchmark seed 1654471242, "shoebox 1 cm", seed
    57145121: 8 microphones 0.6 m thick, 1 cm): wall 0 was placed by the other side of its
    image (normal 23 degrees off, the walls 8.6 cm RMS off against a 0.63 cm bound) and said
    CONVERGED. Its true side fits within 2.1 noise variances of it: NOT_IDENTIFIABLE, wall 0
    named."""
    case = make_case("reconstruct_room", "shoebox 1 cm", 57145121)
    out = case.run()
    assert not out.converged and "wall 0: the other side" in out.message, out.message


def test_a_wall_fitted_on_the_wrong_side_of_its_image_is_refused(rng):
    """The fit's wall placed by the other side of its image where that side fits far worse (the
    worst of the slab's mirror alternatives, over 10 times the level above the truth), the fit
    keeping the ranges within its threshold: refused, never CONVERGED (OUTLIERS when it dropped
    that wall's ranges, as it does here: the true wall is where they place it; NO_AGREEMENT
    when a fit kept them and the other side is lower)."""
    mics, r, model, theta, thr, sigma = _slab_scene(rng)
    base = msac_deviance(model, theta, thr, sigma)
    wrong = max(mirror_alternatives(model, theta, model.use, thr, sigma), key=lambda a: a.deviance)
    assert wrong.deviance - base > 10 * cost_level()
    prob = RoomProblem(mics, r[None], model.use, mics.mean(axis=0), float(np.median(r)),
                       model.mics, model.ranges)  # fmt: skip
    kept = model.use & (np.abs(model.all_residuals(wrong.points.ravel())) <= thr)
    fit = JointFit(wrong.points.ravel(), kept, sigma, 0, None)
    (status, text), *_ = judge_room(prob, fit, thr)
    assert status in (Status.OUTLIERS, Status.NO_AGREEMENT), text
    assert f"wall {wrong.origin.split()[1]}" in text, text
