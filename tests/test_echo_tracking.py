"""Echo tracking for a moving microphone (rangeslam.acoustics.tracking): association on synthetic
detections, and the walk from simulated RIRs end to end."""

from __future__ import annotations

import numpy as np
import pytest

from rangeslam import InvalidInputError, Room, align
from rangeslam.acoustics.echoes import SPEED_OF_SOUND, EchoDetection
from rangeslam.acoustics.tracking import EchoTracks, track_echoes
from rangeslam.acoustics.walk import walk_from_rirs
from rangeslam.app.experiments import FIG5_ROOM_SIZE
from rangeslam.geometry.edm import range_matrix
from rangeslam.sim.rir import shoebox_rirs
from rangeslam.sim.scenes import random_points_in_room
from rangeslam.sim.trajectories import lemniscate, step_lengths
from rangeslam.status import Status

FS = 16000.0
C = SPEED_OF_SOUND


def detections(curves: np.ndarray, rng=None, jitter: float = 0.0) -> list[EchoDetection]:
    """One EchoDetection per frame from (F, K) ranges (column 0 the direct path; NaN: missed),
    shuffled within each frame as a detector would sort them (by time)."""
    out = []
    for row in curves:
        r = row[np.isfinite(row)]
        if jitter and rng is not None:
            r = r + rng.normal(0, jitter, r.shape)
        order = np.argsort(r)
        r = r[order]
        direct = int(np.flatnonzero(order == 0)[0])
        out.append(
            EchoDetection(
                times=r / C,
                amplitudes=1.0 / r,
                direct=direct,
                noise_level=1e-6,
                threshold=1e-5,
                fs=FS,
            )
        )
    return out


def walk_ranges(points: np.ndarray, n_frames: int, step: float) -> np.ndarray:
    """(F, K) ranges from a straight walk along x, ``step`` metres a frame, to ``points``."""
    path = np.column_stack([np.arange(n_frames) * step, np.zeros(n_frames), np.zeros(n_frames)])
    return range_matrix(path, points)


def test_crossing_echoes_are_not_swapped_and_merged_peaks_are_masked():
    # Two image sources whose ranges cross (one nears, one recedes) and a third far off; the
    # direct path is column 0. At the crossing the detector sees one merged peak.
    pts = np.array([[1.0, 0.5, 0.0], [3.0, 2.0, 0.3], [-1.0, 2.05, 0.3], [0.5, -6.0, 0.0]])
    truth = walk_ranges(pts, 60, 0.04)
    merged = truth.copy()
    close = np.abs(truth[:, 1] - truth[:, 2]) < 2 * C / FS
    assert close.any() and not close.all()  # the test crosses
    merged[close, 2] = np.nan
    merged[close, 1] = 0.5 * (truth[close, 1] + truth[close, 2])
    tr = track_echoes(detections(merged), 0.05)
    assert tr.n_tracks == 4
    # each column follows one image source, exactly where it has an entry
    for col in range(1, 4):
        ok = tr.mask[:, col]
        err = np.abs(tr.ranges[ok, col][:, None] - truth[ok][:, 1:])
        landmark = np.bincount(err.argmin(axis=1)).argmax()
        assert np.all(err[:, landmark] < 1e-9), f"column {col} left its echo"
    # the merged peak went to neither: those entries are masked, flagged occluded
    crossing_cols = [c for c in range(1, 4) if tr.occluded[:, c].any()]
    assert len(crossing_cols) == 2
    for c in crossing_cols:
        assert not np.any(tr.mask[close, c])
    np.testing.assert_allclose(tr.ranges[:, 0], truth[:, 0])
    assert np.all(np.isnan(tr.ranges[~tr.mask]))


def followed(tr: EchoTracks, truth: np.ndarray, tol: float) -> np.ndarray:
    """(K,) the landmark (column of ``truth``, the direct path excluded) each echo column of
    ``tr`` follows; asserts that every entry of a column is within ``tol`` of that landmark."""
    which = np.zeros(tr.n_tracks, dtype=int)
    for col in range(1, tr.n_tracks):
        ok = tr.mask[:, col]
        err = np.abs(tr.ranges[ok, col][:, None] - truth[ok][:, 1:])
        which[col] = 1 + np.bincount(err.argmin(axis=1)).argmax()
        assert np.all(err[:, which[col] - 1] < tol), f"column {col} mixes echoes (or clutter)"
    return which


def coverage(tr: EchoTracks, which: np.ndarray, landmark: int) -> float:
    """Share of frames at which some column following ``landmark`` has an entry."""
    return float(np.any(tr.mask[:, which == landmark], axis=1).mean())


def test_spurious_peaks_do_not_become_tracks(rng):
    # six spurious peaks a frame, fresh each frame; a clutter peak that comes as near a track's
    # prediction as its own echo ends the track (a new one takes over): fragments, never mixes
    pts = np.array([[1.0, 0.5, 0.0], [3.0, 2.0, 0.3], [0.5, -4.0, 0.0]])
    truth = walk_ranges(pts, 40, 0.04)
    clutter = rng.uniform(1.0, 6.0, size=(40, 6))
    tr = track_echoes(detections(np.hstack([truth, clutter])), 0.05)
    which = followed(tr, truth, 1e-3)  # a clutter peak nearer than that is as good as the echo
    assert set(which[1:]) == {1, 2}
    assert tr.n_tracks <= 4
    for landmark in (1, 2):
        assert coverage(tr, which, landmark) >= 0.75
    assert tr.unassigned >= 40 * 6 - 10


def test_timing_noise_within_the_tolerance_is_followed(rng):
    pts = np.array([[1.0, 0.5, 0.0], [3.0, 2.0, 0.3], [0.5, -4.0, 1.0]])
    truth = walk_ranges(pts, 50, 0.04)
    jitter = 0.05 * C / FS
    tr = track_echoes(detections(truth, rng, jitter=jitter), 0.05)
    which = followed(tr, truth, 6 * jitter)
    for landmark in (1, 2):
        assert coverage(tr, which, landmark) >= 0.9


def test_rows_picks_frames():
    pts = np.array([[1.0, 0.5, 0.0], [3.0, 2.0, 0.3], [0.5, -4.0, 1.0]])
    tr = track_echoes(detections(walk_ranges(pts, 20, 0.04)), 0.05)
    sub = tr.rows([0, 5, 10])
    assert isinstance(sub, EchoTracks)
    np.testing.assert_array_equal(sub.ranges, tr.ranges[[0, 5, 10]])
    assert sub.mask.shape == (3, tr.n_tracks)


def test_bad_input_is_refused_naming_the_argument():
    pts = np.array([[1.0, 0.5, 0.0], [3.0, 2.0, 0.3]])
    dets = detections(walk_ranges(pts, 10, 0.04))
    with pytest.raises(InvalidInputError, match="detections"):
        track_echoes(dets[:1], 0.05)
    with pytest.raises(InvalidInputError, match="detections"):
        track_echoes([*dets[:3], "x"], 0.05)
    other = EchoDetection(dets[1].times, dets[1].amplitudes, 0, 1e-6, 1e-5, 48000.0)
    with pytest.raises(InvalidInputError, match=r"detections\[1\]"):
        track_echoes([dets[0], other, *dets[2:]], 0.05)
    with pytest.raises(InvalidInputError, match="max_step"):
        track_echoes(dets, np.full(3, 0.05))
    with pytest.raises(InvalidInputError, match="max_step"):
        track_echoes(dets, -0.05)
    for name, value in (("tolerance", 0.0), ("merge_distance", -1.0), ("c", np.nan)):
        with pytest.raises(InvalidInputError, match=name):
            track_echoes(dets, 0.05, **{name: value})
    for name, value in (("max_gap", -1), ("confirm", 1), ("min_length", 0), ("max_gap", 1.5)):
        with pytest.raises(InvalidInputError, match=name):
            track_echoes(dets, 0.05, **{name: value})


# ---- the walk from RIRs ------------------------------------------------------------------------


def fig5_walk(rng, frames_per_step: int, m: int = 15, fs: int = 16000):
    """The Fig. 5 lemniscate (M steps of t = 0.3) with ``frames_per_step`` RIRs a step, a
    loudspeaker uniform in the room, pyroomacoustics RIRs (order 3, absorption 0.2)."""
    k = frames_per_step
    traj = lemniscate((m - 1) * k + 1, step=0.3 / k, phase=rng.uniform(0, 2 * np.pi))
    room = Room.shoebox(FIG5_ROOM_SIZE)
    src = random_points_in_room(room, 1, rng=rng)[0]
    rirs = shoebox_rirs(FIG5_ROOM_SIZE, src, traj, fs=fs, absorption=0.2, max_order=3)
    keys = np.arange(0, len(traj), k)
    steps = step_lengths(traj[keys])
    landmarks = np.vstack([src, room.image_sources(src, 1).positions])
    return rirs, traj[keys], keys, (0.8 * steps, 1.2 * steps), landmarks


@pytest.mark.slow
def test_walk_from_rirs_end_to_end(rng):
    """The Fig. 5 walk as RIRs (8 a step), end to end: converged, the ranges used timed to a
    quarter of a sample, the trajectory within 1 cm RMS (after rigid alignment with reflection).
    benchmarks/bench_walk_rirs.py compares it with exact ranges and matched noise (12 walks:
    0.12-2.30 mm against 0.34-4.28 mm; the issue's 1.5x met by the mean, by 10 of 12 walks)."""
    rirs, traj, keys, bounds, landmarks = fig5_walk(rng, 8)
    w = walk_from_rirs(rirs, FS, step_bounds=bounds, keyframes=keys, rng=rng)
    assert w.converged, w.message
    assert w.trajectory.shape == (15, 3) and w.landmarks.shape[0] == len(w.columns)
    assert w.columns[0] == (0,) and len(w.landmarks) >= 4
    # the ranges used: each column's entries against the nearest image source (orders 0-3)
    room = Room.shoebox(FIG5_ROOM_SIZE)
    images = np.vstack([landmarks[0], room.image_sources(landmarks[0], 3).positions])
    truth_all = range_matrix(traj, images)
    used = np.concatenate(
        [
            np.abs(w.ranges[w.mask[:, c], c][:, None] - truth_all[w.mask[:, c]]).min(axis=1)
            for c in range(w.ranges.shape[1])
        ]
    )
    assert np.sqrt(np.mean(used**2)) < 0.25 * C / FS
    err = align(w.trajectory, traj, reflection=True).rmse
    assert err <= 0.01, f"trajectory error {err:.4f} m"


def test_walk_from_rirs_with_too_few_echoes_is_not_converged(rng):
    """One RIR a 33 cm step (the paper's spacing): echoes of orders 1-3, mostly within 15 cm of
    one another, move up to 38 cm a step, so no curve can be followed: said, never answered."""
    rirs, _, _, bounds, _ = fig5_walk(rng, 1, m=6)
    w = walk_from_rirs(rirs, FS, step_bounds=bounds, rng=rng, n_start=4)
    assert w.status in (Status.NOT_IDENTIFIABLE, Status.SOLVER_FAILED), w.message
    assert "tracked" in w.message or "EDM start" in w.message, w.message
    assert w.slam is None and w.ranges is None and w.mask is None and w.columns == ()


@pytest.mark.slow
def test_walk_with_wrong_step_bounds_is_not_converged(rng):
    """Bounds 1.17-1.43x the true steps (10 steps): not converged (the answer sits on the bounds,
    or LM does not settle), never an answer off by decimetres presented as converged."""
    rirs, _, keys, (lo, hi), _ = fig5_walk(rng, 8, m=10)
    w = walk_from_rirs(
        rirs, FS, step_bounds=(1.3 * 0.9 * lo / 0.8, 1.3 * 1.1 * hi / 1.2), keyframes=keys, rng=rng
    )
    assert not w.converged and w.message
    # on the bounds (NOT_IDENTIFIABLE), LM unsettled (SOLVER_FAILED), the residual test failed
    # (INCONSISTENT) or wrong links left a tail of residuals (OUTLIERS)
    assert w.status in (
        Status.NOT_IDENTIFIABLE,
        Status.SOLVER_FAILED,
        Status.INCONSISTENT,
        Status.OUTLIERS,
    )


def test_walk_from_rirs_bad_input(rng):
    rirs, _, _, bounds, _ = fig5_walk(rng, 1, m=6)
    with pytest.raises(InvalidInputError, match="keyframes"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, keyframes=[0, 3, 2])
    with pytest.raises(InvalidInputError, match="keyframes"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, keyframes=[0, 1, 99])
    with pytest.raises(InvalidInputError, match="bounds"):
        walk_from_rirs(rirs, FS, step_bounds=(bounds[0][:-1], bounds[1][:-1]))
    with pytest.raises(InvalidInputError, match="dim"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, dim=4)
    with pytest.raises(InvalidInputError, match="n_start"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, n_start=2)
    with pytest.raises(InvalidInputError, match="min_hits"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, min_hits=1)
    with pytest.raises(InvalidInputError, match="rirs"):
        walk_from_rirs(rirs[:2], FS, step_bounds=(bounds[0][:1], bounds[1][:1]))
    with pytest.raises(InvalidInputError, match="keyframes"):
        walk_from_rirs(rirs, FS, step_bounds=(bounds[0][:3], bounds[1][:3]), keyframes=[0, 1, 2, 3])
    with pytest.raises(InvalidInputError, match="min_hits"):
        walk_from_rirs(rirs, FS, step_bounds=bounds, min_hits=7)
    for bad in (-1.0, np.nan, "3"):
        with pytest.raises(InvalidInputError, match="isolation"):
            walk_from_rirs(rirs, FS, step_bounds=bounds, isolation=bad)


def test_walk_with_a_step_bounded_by_zero_runs(rng):
    """A step bounded by [0, 0] (standing still) is valid input: no error about max_step."""
    rirs, _, _, (lo, hi), _ = fig5_walk(rng, 1, m=6)
    lo, hi = lo.copy(), hi.copy()
    lo[2] = hi[2] = 0.0
    w = walk_from_rirs(np.vstack([rirs[:3], rirs[2:5]]), FS, step_bounds=(lo, hi), rng=rng)
    assert isinstance(w.converged, bool) and w.message
