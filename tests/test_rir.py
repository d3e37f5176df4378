"""pyroomacoustics at the boundary: RIRs with time zero at the emission, points as rows."""

import numpy as np
import pytest

from rangeslam import InvalidInputError
from rangeslam.rir import shoebox_rirs

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
        ({"fs": 16000.5}, "fs must be a positive whole number"),
        ({"fs": -8000}, "fs must be a positive whole number"),
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
