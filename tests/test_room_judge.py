"""The one judge on a robust room reconstruction (rangeslam.localization.room_judge): the
ranges the fit left out are asked whether they place a wall or a loudspeaker elsewhere. Random
wrong picks place nothing (the answer stands, however many of a wall's echoes they are); a
coherent second wall in them is a rival, or beats the answer."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import Room, reconstruct_room
from rangeslam.app.experiments import wall_errors
from rangeslam.localization.room_judge import msac_deviance
from rangeslam.localization.room_reconstruction import JointWallModel
from rangeslam.sim.scenes import add_range_noise, echo_ranges, random_points_in_room
from rangeslam.status import Status

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
