"""Simulated recordings with their ground truth: what ``rangeslam simulate`` writes for ``run``.

:func:`room_recording`: RIRs of one loudspeaker at M fixed microphones in a convex room (Problem
1). :func:`walk_recording`: RIRs of one loudspeaker along a microphone's walk on the lemniscate of
eq. (12), several RIRs a step (the SLAM steps are every ``rirs_per_step``-th RIR: echoes move up to
38 cm a 33 cm step, so one RIR a step cannot be followed; benchmarks/README.md, "From RIRs").
Both via pyroomacoustics (:mod:`rangeslam.sim.rir`); points are rows (N, 3), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_rng, frozen
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.room import Room
from rangeslam.sim.rir import room_rirs
from rangeslam.sim.scenes import random_points_in_room
from rangeslam.sim.trajectories import lemniscate, step_lengths

__all__ = ["RoomRecording", "WalkRecording", "room_recording", "walk_recording"]

#: pyroomacoustics' speed of sound, m/s (its ``constants.get("c")``), the c of every simulation.
SIMULATION_C = 343.0


@dataclass(frozen=True, eq=False)
class RoomRecording:
    """RIRs of one loudspeaker at M known microphones, and the truth.

    Attributes:
        rirs: (M, L) RIRs, sample n at time n / fs after the emission.
        fs: sampling rate, Hz. c: speed of sound, m/s.
        mics: (M, 3) microphone positions, metres.
        source: (3,) loudspeaker position, metres.
        room: the true room (wall k: ``room.normals[k] . x = room.offsets[k]``).
        room_size: (3,) the shoebox's size, metres, when the room is one; else None.
    """

    rirs: np.ndarray
    fs: float
    c: float
    mics: np.ndarray
    source: np.ndarray
    room: Room
    room_size: np.ndarray | None


@dataclass(frozen=True, eq=False)
class WalkRecording:
    """RIRs of one loudspeaker along a microphone's walk, F frames, M steps, and the truth.

    Attributes:
        rirs: (F, L) one RIR a frame. fs: Hz. c: m/s.
        frames: (F, 3) the microphone at every RIR, metres.
        keyframes: (M,) the frames that are SLAM steps.
        step_bounds: (2, M - 1) lower and upper bound on each step, metres (centred on the truth).
        source: (3,) loudspeaker. landmarks: (K, 3) the loudspeaker (row 0) and its valid image
            sources up to the simulated reflection order (what the walk can find).
        room: the true room. room_size: (3,) the shoebox's size.
    """

    rirs: np.ndarray
    fs: float
    c: float
    frames: np.ndarray
    keyframes: np.ndarray
    step_bounds: np.ndarray
    source: np.ndarray
    landmarks: np.ndarray
    room: Room
    room_size: np.ndarray

    @property
    def trajectory(self) -> np.ndarray:
        """(M, 3) the microphone at the steps."""
        return self.frames[self.keyframes]


def _check_source(room: Room, source: ArrayLike, margin: float) -> np.ndarray:
    src = np.asarray(source, dtype=float).reshape(-1)
    if src.shape != (3,) or not np.all(np.isfinite(src)):
        raise InvalidInputError(f"source must be (3,) finite metres; got {source!r}")
    if not room.contains(src[None], margin=margin)[0]:
        raise InvalidInputError(
            f"source must lie in the room, at least {margin:g} m from every wall; got "
            f"{src.tolist()} (distances to the walls {np.round(room.distance_to_walls(src[None])[0], 3).tolist()} m)"
        )
    return src


def _add_noise(rirs: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    """White N(0, (noise * peak)^2) added to every sample, peak the largest |sample|."""
    if not (np.isfinite(noise) and noise >= 0):
        raise InvalidInputError(f"noise must be >= 0 (a fraction of the peak); got {noise!r}")
    if noise == 0:
        return rirs
    return rirs + rng.normal(0.0, noise * np.abs(rirs).max(), rirs.shape)


def room_recording(
    room: Room,
    *,
    n_mics: int = 8,
    source: ArrayLike | None = None,
    fs: int = 48000,
    absorption: float = 0.2,
    max_order: int = 3,
    margin: float = 0.5,
    noise: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> RoomRecording:
    """Microphones uniform in ``room`` (3-D), ``margin`` m from the walls, and a loudspeaker
    (uniform likewise, or ``source`` (3,)); their RIRs (image source method, ``max_order``, one
    ``absorption`` for every wall) with white noise of std ``noise`` times the largest sample."""
    rng = as_rng(rng)
    if not isinstance(room, Room) or room.dim != 3:
        raise InvalidInputError(f"room must be a 3-D rangeslam Room; got {room!r:.80}")
    if isinstance(n_mics, bool) or not isinstance(n_mics, int | np.integer) or n_mics < 4:
        raise InvalidInputError(f"n_mics must be an integer >= 4 (3-D); got {n_mics!r}")
    mics = random_points_in_room(room, int(n_mics), margin=margin, rng=rng)
    if source is None:
        src = random_points_in_room(room, 1, margin=margin, rng=rng)[0]
    else:
        src = _check_source(room, source, 0.0)
    rirs = room_rirs(room, src, mics, fs=fs, absorption=absorption, max_order=max_order)
    size = np.round(room.vertices.max(axis=0), 9)
    box = Room.shoebox(size)
    is_box = box.normals.shape == room.normals.shape and bool(
        np.allclose(box.normals, room.normals) and np.allclose(box.offsets, room.offsets)
    )
    return RoomRecording(
        rirs=frozen(_add_noise(rirs, noise, rng)),
        fs=float(fs),
        c=SIMULATION_C,
        mics=frozen(mics),
        source=frozen(src),
        room=room,
        room_size=frozen(size) if is_box else None,
    )


def _walk_source(room: Room, frames: np.ndarray, clearance: float, rng) -> np.ndarray:
    """A loudspeaker uniform in the room, 0.5 m from the walls and ``clearance`` m from the walk."""
    for _ in range(1000):
        src = random_points_in_room(room, 1, margin=0.5, rng=rng)[0]
        if np.linalg.norm(frames - src, axis=1).min() >= clearance:
            return src
    raise InvalidInputError(
        f"could not place a loudspeaker {clearance:g} m from the walk and 0.5 m from the walls"
    )


def walk_recording(
    room_size: ArrayLike = (5.0, 4.0, 2.6),
    *,
    n_steps: int = 15,
    rirs_per_step: int = 8,
    step: float = 0.3,
    bound: float = 0.2,
    source: ArrayLike | None = None,
    clearance: float = 1.0,
    fs: int = 16000,
    absorption: float = 0.2,
    max_order: int = 3,
    noise: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> WalkRecording:
    """The Fig. 5 walk as RIRs: a microphone on the lemniscate of eq. (12) (centred in the
    shoebox ``room_size``, 0.9 m high, random phase), ``n_steps`` steps of parameter ``step`` (0.3:
    about 33 cm) with ``rirs_per_step`` RIRs a step; step bounds +-``bound`` of each true step,
    centred (the paper's +-20 %). The loudspeaker is ``source`` or uniform in the room, 0.5 m from
    the walls and ``clearance`` m from the walk (a loudspeaker on the path would be walked into)."""
    rng = as_rng(rng)
    for name, value, low in (("n_steps", n_steps, 3), ("rirs_per_step", rirs_per_step, 1)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
            raise InvalidInputError(f"{name} must be an integer >= {low}; got {value!r}")
    if not 0 <= bound < 1:
        raise InvalidInputError(f"bound must be in [0, 1) (a fraction of each step); got {bound!r}")
    room = Room.shoebox(room_size)
    size = room.vertices.max(axis=0)
    k = int(rirs_per_step)
    frames = lemniscate(
        (n_steps - 1) * k + 1,
        step=step / k,
        phase=rng.uniform(0, 2 * np.pi),
        centre=size[:2] / 2,
        height=min(0.9, size[2] / 2),
    )
    if not room.contains(frames, margin=0.1).all():
        raise InvalidInputError(
            f"room_size {size.tolist()} is too small for the walk (a lemniscate 3 m x 0.7 m, 0.1 m "
            "from the walls): at least 3.2 x 0.9 x 0.3 m"
        )
    if source is None:
        src = _walk_source(room, frames, clearance, rng)
    else:
        src = _check_source(room, source, 0.0)
    rirs = room_rirs(room, src, frames, fs=fs, absorption=absorption, max_order=max_order)
    keys = np.arange(0, len(frames), k)
    steps = step_lengths(frames[keys])
    images = room.image_sources(src, max(int(max_order), 1))
    landmarks = np.vstack([src, images.positions[images.valid & (images.orders <= max_order)]])
    return WalkRecording(
        rirs=frozen(_add_noise(rirs, noise, rng)),
        fs=float(fs),
        c=SIMULATION_C,
        frames=frozen(frames),
        keyframes=frozen(keys),
        step_bounds=frozen(np.vstack([(1 - bound) * steps, (1 + bound) * steps])),
        source=frozen(src),
        landmarks=frozen(landmarks),
        room=room,
        room_size=frozen(size),
    )
