"""Walls found jointly by several loudspeakers from echoes too few to label per loudspeaker."""

import numpy as np
import pytest

from rangeslam.acoustics.echoes import EchoDetection
from rangeslam.acoustics.joint_room import WALL_MATCH_METRES
from rangeslam.acoustics.labelling import EchoLabelling
from rangeslam.acoustics.shared_walls import shared_walls
from rangeslam.app.experiments import demo_rooms
from rangeslam.geometry.room import Room
from rangeslam.sim.scenes import random_points_in_room
from rangeslam.status import Status

C, FS = 343.0, 48000.0
CUT = 6  # the cut corner's wall in demo_rooms()["cut corner"]
CLUTTER = 10  # random peaks per microphone, beyond the direct path (free peaks of a session: 5-15)
M = 8


def _visible(room: Room, source, mics, k: int) -> np.ndarray:
    """(M,) True where the specular point of wall k from ``source`` to a microphone is on the
    wall's face."""
    n, o = room.normals[k], room.offsets[k]
    img = source - 2.0 * (n @ source - o) * n
    t = (o - mics @ n) / ((img - mics) @ n)
    q = mics + t[:, None] * (img - mics)
    return np.all(q @ room.normals.T <= room.offsets + 1e-9, axis=1)


def _scene(rng, need: tuple[int, int]):
    """M microphones and two loudspeakers in the cut-corner room, drawn until loudspeaker j sees
    the cut wall from at least need[j] microphones."""
    room = demo_rooms()["cut corner"]
    for _ in range(500):
        mics = random_points_in_room(room, M, margin=0.5, rng=rng)
        sources = random_points_in_room(room, 2, margin=0.5, rng=rng)
        vis = [_visible(room, s, mics, CUT) for s in sources]
        if all(v.sum() >= k for v, k in zip(vis, need, strict=True)):
            return room, mics, sources, vis
    raise AssertionError("no scene drawn")  # pragma: no cover


def _labelled(room: Room, mics, source, heard: np.ndarray, rng):
    """Exact detections of ``source``: the direct path, the six other walls' echoes (labelled),
    the cut wall's where ``heard`` (M,), and CLUTTER random peaks; and the labelling of the
    direct path and the six walls, as label_echoes would give it."""
    tol = C / FS
    imgs = room.image_sources(source).positions[:CUT]
    cut = room.image_sources(source).positions[CUT]
    m_n = len(mics)
    dets, peaks = [], np.full((m_n, 1 + CUT), -1)
    ranges = np.zeros((m_n, 1 + CUT))
    for m, mic in enumerate(mics):
        r = np.linalg.norm(np.vstack([source, imgs]) - mic, axis=1)
        extra = [np.linalg.norm(cut - mic)] if heard[m] else []
        clutter = rng.uniform(r[0] + 0.1, 15.0, CLUTTER)
        times = np.concatenate([r, extra, clutter]) / C
        order = np.argsort(times)
        peaks[m] = np.argsort(order)[: 1 + CUT]
        ranges[m] = r
        dets.append(EchoDetection(times=times[order], amplitudes=np.ones(len(times)),
                                  direct=int(peaks[m, 0]), noise_level=0.0, threshold=0.0, fs=FS))  # fmt: skip
    lab = EchoLabelling(
        ranges=ranges, mask=np.ones((m_n, 1 + CUT), bool), source=np.asarray(source, float),
        images=imgs, residuals=np.zeros((m_n, 1 + CUT)), peaks=peaks, normal_std=np.zeros(CUT),
        higher_order=np.empty((0, 3)), n_higher_order=np.zeros(m_n, int),
        n_unassigned=np.zeros(m_n, int), tolerance=tol, fit_tolerance=tol / 8,
        status=Status.CONVERGED, message="",
    )  # fmt: skip
    return lab, dets


def _heard(vis: np.ndarray, k: int) -> np.ndarray:
    """The first k microphones that see the wall (the others' echoes merged, say)."""
    out = np.zeros(len(vis), bool)
    out[np.flatnonzero(vis)[:k]] = True
    return out


def _search(rng, counts: tuple[int, int]):
    """shared_walls on a scene whose loudspeakers hear the cut wall at ``counts`` microphones;
    (the room, the result, the (M,) microphones each loudspeaker hears it at)."""
    room, mics, sources, vis = _scene(rng, counts)
    heard = [_heard(v, k) for v, k in zip(vis, counts, strict=True)]
    got = [_labelled(room, mics, s, h, rng) for s, h in zip(sources, heard, strict=True)]
    box = Room(room.normals[:CUT], room.offsets[:CUT])
    labs, dets = [g[0] for g in got], [g[1] for g in got]
    found = shared_walls(labs, dets, mics, box, c=C, min_cut=WALL_MATCH_METRES, rng=rng)
    return room, found, heard


@pytest.mark.parametrize("counts", [(3, 3), (4, 2), (5, 1)])
def test_a_wall_too_few_microphones_of_each_loudspeaker_hear_is_found_jointly(rng, counts):
    """The cut wall heard by two loudspeakers at 3 + 3, 4 + 2 or 5 + 1 microphones (label_echoes
    needs 5 or more of one), among 10 random peaks a microphone (exact data): one wall found, the
    true one (normal and offset to 1e-6), with exactly those echoes."""
    room, found, _ = _search(rng, counts)
    assert len(found.walls) == 1, found
    wall = found.walls[0]
    np.testing.assert_allclose(wall.normal, room.normals[CUT], atol=1e-6)
    np.testing.assert_allclose(wall.offset, room.offsets[CUT], atol=1e-6)
    assert sorted(wall.support.tolist()) == sorted(counts)


def test_an_echo_set_too_small_for_a_wall_is_reported_unexplained(rng):
    """The cut wall heard at 4 microphones of loudspeaker 0 and 1 of loudspeaker 1 (5 echoes for
    3 unknowns, one fewer than JOINT_WALL_RANGES): no wall added, and a note names loudspeaker
    0's four microphones as left unexplained."""
    _, found, heard = _search(rng, (4, 1))
    assert found.walls == ()
    named = f"loudspeaker 0 at microphones {np.flatnonzero(heard[0]).tolist()}"
    assert any(named in note for note in found.unexplained), found.unexplained


def test_clutter_alone_gives_no_wall(rng):
    """No cut-wall echo, 10 random peaks a microphone: no wall found."""
    _, found, _ = _search(rng, (0, 0))
    assert found.walls == ()
