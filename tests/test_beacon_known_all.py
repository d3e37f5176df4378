"""Known beacons in the incremental estimator and the baselines (issue 36, item 2): the same
``beacons`` / ``beacon_sigma`` arguments as beacon_slam (run here too), the beacons kept where given when fixed,
and the APE (mean position error after rigid alignment) with every beacon known at or below the
APE without them in a 3 x 3 m room. The seeds were drawn after the change."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import InvalidInputError, align
from rangeslam.baselines import ekf_range_odometry, gtsam_range_example
from rangeslam.beacons import beacon_slam, beacon_slam_incremental, simulate_beacon_run
from rangeslam.status import Status

pytest.importorskip("gtsam")

HELD_OUT_SEEDS = (608824, 233218, 537491, 310215)
RANGE_STD = 0.05
# The room of test_beacon_known: beacons in the corners of a 3 x 3 m room round a 2.0 x 2.5 m
# path, ranges 3 % long with an offset of one range sigma.
CORNERS = np.array([[-0.9, -0.2], [1.9, -0.2], [1.9, 2.6], [-0.9, 2.6]])
ROOM = dict(
    n_steps=2000, step_length=0.005, radius=0.45, beacons=CORNERS, range_std=RANGE_STD,
    odometry_std=(2.5e-4, 0.002), range_scale=1.03, range_offset=RANGE_STD,
)  # fmt: skip
STATED = dict(range_sigma=RANGE_STD, odometry_sigma=(2.5e-4, 2.5e-4, 0.002))
ESTIMATORS = {
    "batch": lambda data, seed, **kw: beacon_slam(data, **STATED, **kw),
    "isam2": lambda data, seed, **kw: beacon_slam_incremental(data, **STATED, **kw),
    "ekf": lambda data, seed, **kw: ekf_range_odometry(data, rng=seed, **kw),
    "gtsam example": lambda data, seed, **kw: gtsam_range_example(
        data, rng=np.random.default_rng(seed), **kw
    ),
}


def _ape(result, run) -> float:
    return float(align(result.poses[:, :2], run.poses[:, :2]).errors.mean())


@pytest.fixture(scope="module")
def rooms():
    return {s: simulate_beacon_run(np.random.default_rng(s), **ROOM) for s in HELD_OUT_SEEDS}


@pytest.mark.parametrize("name", ESTIMATORS)
def test_all_beacons_known_and_fixed_do_not_raise_the_ape(rooms, name):
    """Over four held-out seeds the mean APE with every beacon known and fixed is at or below
    the mean APE without them, and the fixed beacons stay where given (to 1e-3 range sigma).
    Per seed it is not always so for the GTSAM example: its 100 m range sigma leaves it close to
    dead reckoning in a room, with or without the beacons (it says NOT_IDENTIFIABLE, the ranges
    moved nothing, once the beacons start at the truth). The others converge."""
    with_known, without = [], []
    for seed, run in rooms.items():
        plain = ESTIMATORS[name](run.data, seed)
        known = ESTIMATORS[name](run.data, seed, beacons=run.beacons)
        np.testing.assert_allclose(known.beacons, run.beacons, atol=1e-3 * RANGE_STD)
        if name != "gtsam example":
            assert known.status is Status.CONVERGED, known.message
        without.append(_ape(plain, run))
        with_known.append(_ape(known, run))
    assert np.mean(with_known) <= np.mean(without), (with_known, without)


@pytest.mark.parametrize("name", ["batch", "isam2", "ekf"])
def test_two_known_beacons_under_a_prior(rooms, name):
    """Two beacons surveyed to one range sigma, the other two unknown: converged, the known two
    within three sigmas of where they were surveyed, the APE within the range sigma."""
    seed = HELD_OUT_SEEDS[0]
    run = rooms[seed]
    given = run.beacons + np.random.default_rng(seed + 1).normal(0, RANGE_STD, (4, 2))
    given[2:] = np.nan
    res = ESTIMATORS[name](run.data, seed, beacons=given, beacon_sigma=RANGE_STD)
    assert res.status is Status.CONVERGED, res.message
    assert np.all(np.linalg.norm(res.beacons[:2] - given[:2], axis=1) < 3 * RANGE_STD)
    assert _ape(res, run) < RANGE_STD


@pytest.mark.parametrize("name", ESTIMATORS)
@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(beacons=np.zeros((3, 2))), r"beacons must have shape \(4, 2\)"),
        (dict(beacons=np.full((4, 2), np.nan)), "at least two distinct positions"),
        (dict(beacon_sigma=0.1), "beacon_sigma needs beacons"),
        (dict(beacons=CORNERS, beacon_sigma=-1.0), "beacon_sigma"),
    ],
)
def test_bad_known_beacons_are_refused_naming_the_argument(rooms, name, kw, match):
    run = rooms[HELD_OUT_SEEDS[0]]
    with pytest.raises(InvalidInputError, match=match):
        ESTIMATORS[name](run.data, 0, **kw)


def test_isam2_takes_the_frame_from_the_known_beacons(rooms):
    """A start pose wrong by metres and a radian: the known beacons (fixed) give the frame, fitted
    on the first windows' ranges; the path within the range sigma of the truth with no alignment
    at all (measured 0.12-0.21 sigma on the four seeds)."""
    for run in rooms.values():
        res = beacon_slam_incremental(
            run.data, beacons=run.beacons, start_pose=(5.0, 5.0, 1.0), **STATED
        )
        assert res.status is Status.CONVERGED, res.message
        error = np.linalg.norm(res.poses[:, :2] - run.poses[:, :2], axis=1)
        assert np.mean(error) < RANGE_STD


@pytest.mark.parametrize("seed", (711549, 292970))
def test_ekf_with_a_start_outside_the_beacons_frame_is_inconsistent(seed):
    """With the beacons known, ``start_pose`` is taken as exact in their frame. A start 0.3 m and
    0.2 rad off left the filter CONVERGED at 0.11-0.19 m APE (0.01 with the right start), its
    gate throwing out 25-407 of about 800 ranges and keeping the rest up to its edge; it is now
    INCONSISTENT: the kept ranges fit the answer worse than the range noise allows (chi-square
    at CHI2_LEVEL). The rule was set on seeds 11-13; these seeds were drawn after it. The right
    start stays CONVERGED."""
    run = simulate_beacon_run(np.random.default_rng(seed), **ROOM)
    right = ekf_range_odometry(run.data, rng=seed, beacons=run.beacons)
    off = ekf_range_odometry(run.data, rng=seed, beacons=run.beacons, start_pose=[0.3, 0.3, 0.2])
    assert right.status is Status.CONVERGED, right.message
    assert off.status is Status.INCONSISTENT, off.message
    assert "ranges kept fit the answer to" in off.message


def test_ekf_with_wrong_picks_gated_stays_converged():
    """5 % of the ranges 5-10 m long (late arrivals): the gate rejects them and the kept ranges
    fit the noise, so the answer is CONVERGED with the gated count in its message, as without
    them (seed drawn after the rule)."""
    kw = dict(range_scale=1.05, range_offset=0.3)
    clean = simulate_beacon_run(np.random.default_rng(219061), **kw)
    dirty = simulate_beacon_run(np.random.default_rng(219061), outlier_fraction=0.05, **kw)
    assert ekf_range_odometry(clean.data, rng=0).status is Status.CONVERGED
    res = ekf_range_odometry(dirty.data, rng=0)
    assert res.status is Status.CONVERGED, res.message
    assert _ape(res, dirty) < 0.3
