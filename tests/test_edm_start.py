"""The cheap EDM start and the honestly chosen start of the graph (issue 18, items 1 and 2)."""

import dataclasses
import importlib
import re

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from rangeslam import InvalidInputError, align, calibrate
from rangeslam._blas import one_blas_thread
from rangeslam.app.regimes import RegimeCell, draw_scene, run_random_starts
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.room import Room
from rangeslam.mdu import slam
from rangeslam.mdu.landmark_mirrors import landmark_mirrors
from rangeslam.sim.scenes import random_points_in_room
from rangeslam.sim.trajectories import lemniscate, step_lengths
from rangeslam.status import Status

slam_module = importlib.import_module("rangeslam.mdu.slam")


@pytest.mark.slow
def test_cheap_start_matches_gtsam_best_of_three(rng):
    """Random non-planar walks, M = 8, 1 cm, +-20% bounds, noise not given to slam (the issue's
    first criterion, reduced to 8 walks): slam's success (< 10 cm) at least that of GTSAM best of
    3 random starts (given the noise), and its median error at most 1.15x theirs (1.05x in the
    issue, measured on 16 walks in benchmarks/README.md; 8 walks' medians scatter more)."""
    cell = RegimeCell("random", 8, True, 0.01)
    ours, peer = [], []
    for _ in range(8):
        scene = draw_scene(cell, rng)
        out = slam(scene.ranges, step_bounds=scene.step_bounds, mask=scene.mask, rng=rng)
        ours.append(align(out.receivers, scene.trajectory, reflection=True).rmse)
        best3 = run_random_starts(scene, cell, rng, budget=np.inf, max_starts=3)
        peer.append(align(best3.receivers, scene.trajectory, reflection=True).rmse)
    ours, peer = np.array(ours), np.array(peer)
    assert np.median(ours) <= 1.15 * np.median(peer), (ours, peer)
    assert np.mean(ours < 0.1) >= np.mean(peer < 0.1), (ours, peer)


@pytest.mark.parametrize("edm_start", ["cheap", pytest.param("full", marks=pytest.mark.slow)])
def test_exact_recovery_with_either_start(rng, edm_start):
    """Exact ranges of a non-planar walk without bounds: both schedules recover it to round-off."""
    cell = RegimeCell("random", 8, False, 1e-9)
    scene = draw_scene(cell, rng)
    exact = range_matrix(scene.trajectory, scene.landmarks)
    out = slam(exact, edm_start=edm_start, rng=rng)
    assert out.converged, out.message
    assert align(out.receivers, scene.trajectory, reflection=True).rmse < 1e-6


def test_a_lower_alternative_replaces_the_answer(rng):
    """The judge ranks the answer and its alternatives on one graph: an answer far above the
    minimum (the search's with one landmark moved 0.5 m) is replaced by the lowest alternative,
    named as such, refined again with covariances, back at the search's trajectory."""
    cell = RegimeCell("random", 8, True, 0.01)
    scene = draw_scene(cell, rng)
    problem = slam_module.parse_slam(
        scene.ranges, scene.step_bounds, None, 3, True, 0.01, None, None, "uniform", 0,
        slam_module.ConvexIterationOptions(),
    )  # fmt: skip
    search = slam_module.search_edm_runs(problem, rng)
    answer = search.best
    moved = answer.sources.copy()
    moved[0] += 0.5
    worse = dataclasses.replace(answer, sources=moved)
    found = dataclasses.replace(search, best=worse, runs=(worse,))
    best, _, _, judged, _ = slam_module.judged_answer(problem, found, rng)
    assert judged.judgement.replaced is not None
    assert best is not worse and best.start != "edm"
    assert best.fit.receiver_cov is not None  # refined again, with covariances
    assert align(best.receivers, answer.receivers, reflection=True).rmse < 0.01


def test_landmarks_of_a_planar_walk_are_reported_with_their_mirror_images(rng):
    """The lemniscate of eq. (12) lies in the plane z = 0.9: every landmark off that plane fits
    as well on either side. Both sides are reported: ``ambiguous_landmarks`` all True and
    ``landmark_mirrors`` the reflections, to round-off."""
    traj = lemniscate(10, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    landmarks = np.array([[1.0, 0.5, 2.0], [-1.5, 2.0, 0.1], [0.5, -1.0, 3.1], [2.0, 1.0, -0.5]])
    steps = step_lengths(traj)
    out = slam(range_matrix(traj, landmarks), step_bounds=(0.8 * steps, 1.2 * steps), rng=rng)
    assert out.ambiguous_landmarks.all(), out.ambiguous_landmarks
    a = align(out.receivers, traj, reflection=True)
    got, other = a.apply(out.sources), a.apply(out.landmark_mirrors)
    mirrored = landmarks * [1, 1, -1] + [0, 0, 1.8]
    for k in range(len(landmarks)):  # one of the two positions is the truth, the other its mirror
        pair = {tuple(np.round(got[k], 5)), tuple(np.round(other[k], 5))}
        assert pair == {tuple(np.round(landmarks[k], 5)), tuple(np.round(mirrored[k], 5))}


def test_the_message_notes_every_ambiguous_landmark(rng):
    """A noisy planar walk in the Fig. 5 room (the loudspeaker and its 6 images): the message's
    note names every landmark that ``ambiguous_landmarks`` reports (it named only the first),
    judged on the same ranges at the same noise (converged, or not identifiable when the judge
    of issue 42 finds a rival trajectory)."""
    room = Room.shoebox([5.0, 4.0, 2.6])
    traj = lemniscate(8, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    source = random_points_in_room(room, 1, rng=rng)[0]
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    steps = step_lengths(traj)
    for noise_std in (0.01, None):
        ranges = range_matrix(traj, landmarks) + 0.01 * rng.standard_normal((8, 7))
        out = slam(ranges, step_bounds=(0.8 * steps, 1.2 * steps), noise_std=noise_std, rng=rng)
        # the note is the verdict's on the answer; the judge may then find that a landmark's
        # other side moves the trajectory beyond its confidence region: NOT_IDENTIFIABLE
        assert out.status in (Status.CONVERGED, Status.NOT_IDENTIFIABLE), out.message
        first = re.findall(r"noted: source (\d+) ", out.message)
        also = re.findall(r"also noted: sources ([0-9, ]+)", out.message)
        noted = {int(i) for i in first} | {int(i) for g in also for i in g.split(",")}
        assert out.ambiguous_landmarks.sum() >= 2, out.ambiguous_landmarks
        assert set(np.flatnonzero(out.ambiguous_landmarks)) <= noted, out.message


def test_landmarks_of_a_non_planar_walk_are_not_ambiguous(rng):
    """A walk that leaves its plane decides each landmark's side: none is reported ambiguous,
    through ``slam`` and :func:`landmark_mirrors` alike."""
    cell = RegimeCell("random", 10, True, 1e-9)
    scene = draw_scene(cell, rng)
    exact = range_matrix(scene.trajectory, scene.landmarks)
    check = landmark_mirrors(
        scene.trajectory, scene.landmarks, exact, np.ones(exact.shape, bool), 0.001, 1e-9
    )
    assert not check.ambiguous.any() and np.isnan(check.mirrors).all()
    out = slam(exact, step_bounds=scene.step_bounds, rng=rng)
    assert out.converged, out.message
    assert not out.ambiguous_landmarks.any()


@pytest.mark.parametrize("bad", ["quick", 1, None])
def test_unknown_edm_start_refused(rng, bad):
    landmarks = rng.uniform(-2.0, 2.0, size=(7, 3))
    r = range_matrix(lemniscate(8, step=0.3) + rng.normal(0, 0.1, (8, 3)), landmarks)
    with pytest.raises(InvalidInputError, match="edm_start must be one of"):
        slam(r, edm_start=bad)
    with pytest.raises(InvalidInputError, match="edm_start must be one of"):
        calibrate(r, edm_start=bad)


def test_one_blas_thread_limits_and_restores():
    """Inside the context BLAS runs on one thread; after it, as before."""
    before = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    with one_blas_thread():
        inside = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    after = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    assert inside and all(n == 1 for n in inside)
    assert after == before
