"""pyroomacoustics at the boundary: RIRs with time zero at the emission, points as rows."""

import numpy as np
import pytest

from rangeslam import InvalidInputError
from rangeslam.sim.rir import shoebox_rirs

C = 343.0  # pyroomacoustics' default speed of sound


def test_direct_path_and_first_echo_arrive_when_the_geometry_says(rng):
    """The direct path peaks at |r - s| / c within a sample (time zero is the emission:
    pyroomacoustics' filter delay is removed), nothing comes before it, and the floor echo is
    where its image source says."""
    size = np.array([5.0, 4.0, 2.6])
    src = np.array([1.3, 2.2, 1.5])
    mics = rng.uniform([0.5, 0.5, 0.5], size - 0.5, (4, 3))
    fs = 16000
    rirs = shoebox_rirs(size, src, mics, fs=fs, max_order=1, absorption=0.2)
    assert rirs.shape[0] == 4
    for h, mic in zip(rirs, mics, strict=True):
        direct = np.linalg.norm(mic - src) / C * fs
        near = np.arange(int(direct) - 4, int(direct) + 5)
        assert abs(near[np.argmax(np.abs(h[near]))] - direct) <= 1.0
        # before it, at most the ringing of the 81-tap fractional-delay filter (40 samples)
        if direct > 45:
            assert np.abs(h[: int(direct) - 41]).max() < 0.05 * np.abs(h[near]).max()
        floor_image = src * [1, 1, -1]
        echo = np.linalg.norm(mic - floor_image) / C * fs
        window = slice(int(echo) - 3, int(echo) + 4)
        assert np.abs(h[window]).max() > 0.1 * np.abs(h).max()


def test_duration_fixes_the_length():
    rirs = shoebox_rirs([5, 4, 2.6], [1, 1, 1], [[2, 2, 1]], duration=0.05, max_order=1)
    assert rirs.shape == (1, 800)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fs": 16000.5}, "fs must be a whole number of Hz in"),
        ({"fs": -8000}, "fs must be a whole number of Hz in"),
        ({"max_order": -1}, "max_order must be an integer >= 0"),
        ({"absorption": 0.0}, r"absorption must be in \(0, 1\]"),
        ({"room_size": [5, 4]}, "room_size must be 3 positive lengths"),
        ({"receivers": [[6.0, 1.0, 1.0]]}, "receivers must lie inside the room; row 0"),
        ({"source": [1.0, -1.0, 1.0]}, "source must lie inside the room"),
    ],
)
def test_bad_input(kwargs, match):
    args = {"room_size": [5, 4, 2.6], "source": [1, 1, 1], "receivers": [[2, 2, 1]]}
    args.update(kwargs)
    with pytest.raises(InvalidInputError, match=match):
        shoebox_rirs(args.pop("room_size"), args.pop("source"), args.pop("receivers"), **args)


def test_room_rirs_equal_shoebox_rirs_on_a_shoebox(rng):
    """The general convex-room path (walls as polygons) against pyroomacoustics' ShoeBox, up to
    second order at random positions. (At third order pyroomacoustics' general image-source model
    can count one arrival twice when a path passes exactly by an edge: seen once, at source
    (1.2, 2.1, 1.4) and microphone (4.0, 3.3, 2.2) in a 5 x 4 x 3 m room; 0 of 10 random
    configurations.)"""
    from rangeslam import Room
    from rangeslam.sim.rir import room_rirs

    size = np.array([5.0, 4.0, 3.0])
    src = rng.uniform(0.3, size - 0.3)
    mics = rng.uniform(0.3, size - 0.3, (3, 3))
    for order in (1, 2):
        a = shoebox_rirs(size, src, mics, fs=16000, absorption=0.25, max_order=order)
        b = room_rirs(Room.shoebox(size), src, mics, fs=16000, absorption=0.25, max_order=order)
        assert a.shape == b.shape
        assert np.abs(a - b).max() < 1e-3 * np.abs(a).max()


def test_room_rirs_in_a_non_shoebox_room(rng):
    """A room with a cut corner and a sloping ceiling: the direct path and every first-order echo
    arrive where the image sources say (within a sample); a wall given absorption 1 sends back
    nothing."""
    from rangeslam import Room
    from rangeslam.sim.rir import room_rirs

    base = np.array([[0, 0], [5, 0], [5, 3], [4, 4], [0, 4]], dtype=float)
    verts = np.vstack(
        [np.column_stack([base, np.zeros(5)]), np.column_stack([base, 2.6 + 0.1 * base[:, 0]])]
    )
    room = Room.from_vertices(verts)
    src = np.array([1.5, 1.8, 1.2])
    mics = np.array([[3.2, 1.1, 1.0], [2.4, 3.0, 1.6]])
    fs = 48000
    rirs = room_rirs(room, src, mics, fs=fs, absorption=0.2, max_order=1)
    images = room.image_sources(src, 1).positions
    checked = 0
    for h, mic in zip(rirs, mics, strict=True):
        arrivals = np.linalg.norm(np.vstack([src, images]) - mic, axis=1) / C * fs
        for k, point in enumerate(np.vstack([src, images])):
            if np.sum(np.abs(arrivals - arrivals[k]) < 2.0) > 1:
                continue  # two arrivals within 2 samples merge into one peak
            if k > 0:  # the echo exists only if its reflection point lies on the wall's face
                n, o = room.normals[k - 1], room.offsets[k - 1]
                hit = mic + (o - n @ mic) / (n @ (point - mic)) * (point - mic)
                if not room.contains(hit[None, :], margin=-1e-9)[0]:
                    continue
            t = np.linalg.norm(mic - point) / C * fs
            near = np.arange(int(t) - 3, int(t) + 4)
            assert abs(near[np.argmax(np.abs(h[near]))] - t) <= 1.0
            checked += 1
    assert checked >= 2 * (1 + room.n_walls) - 4  # nearly every echo is visible and apart here
    # wall 0 fully absorbent: its echo is gone (the others keep theirs)
    absorb = np.full(room.n_walls, 0.2)
    absorb[0] = 1.0
    quiet = room_rirs(room, src, mics[:1], fs=fs, absorption=absorb, max_order=1)[0]
    t = round(np.linalg.norm(mics[0] - images[0]) / C * fs)
    loud = rirs[0]
    assert np.abs(quiet[t - 1 : t + 2]).max() < 0.05 * np.abs(loud[t - 1 : t + 2]).max()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(absorption=[0.2, 0.3]), "absorption must be one number or one per wall"),
        (dict(absorption=1.5), r"absorption must be in \(0, 1\]"),
        (dict(source=[9.0, 1.0, 1.0]), "source must lie inside the room"),
        (dict(fs=0), "fs must be a whole number of Hz in"),
    ],
)
def test_room_rirs_bad_input(kwargs, match):
    from rangeslam import Room
    from rangeslam.sim.rir import room_rirs

    args = dict(source=[1.0, 1.0, 1.0], receivers=[[2.0, 2.0, 1.0]])
    with pytest.raises(InvalidInputError, match=match):
        room_rirs(Room.shoebox([5.0, 4.0, 3.0]), **{**args, **kwargs})
    with pytest.raises(InvalidInputError, match="room must be a 3-D rangeslam Room"):
        room_rirs(Room.polygon([[0, 0], [4, 0], [4, 3], [0, 3]]), [1, 1], [[2, 2]])
