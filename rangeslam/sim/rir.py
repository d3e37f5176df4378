"""Room impulse responses simulated with pyroomacoustics (image source method), at the boundary
of the package: points as rows (N, 3) here, as columns there; time zero at the emission here,
while pyroomacoustics' fractional-delay filters add a fixed delay of half their length.

:func:`shoebox_rirs` for shoeboxes, :func:`room_rirs` for any convex polyhedral
:class:`~rangeslam.geometry.room.Room` (walls built as pyroomacoustics polygons, one per plane, with an
absorption per wall). For a moving microphone pass its positions along the trajectory as the
receivers: one RIR per step (the room is static, so each step is a snapshot).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, as_scalar
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.room import Room

__all__ = ["room_rirs", "shoebox_rirs"]


def shoebox_rirs(
    room_size: ArrayLike,
    source: ArrayLike,
    receivers: ArrayLike,
    *,
    fs: int = 16000,
    absorption: float = 0.2,
    max_order: int = 3,
    duration: float | None = None,
) -> np.ndarray:
    """RIRs (M, L) from one source to M receivers in a shoebox [0, Lx] x [0, Ly] x [0, Lz].

    Args:
        room_size: (3,) metres. source: (3,) metres. receivers: (M, 3) metres, inside the room.
        fs: sampling rate, Hz. absorption: energy absorption of every wall, in (0, 1].
        max_order: image sources up to this reflection order.
        duration: seconds kept (default: long enough for every simulated arrival).

    Sample n is time n / fs after the emission (pyroomacoustics' filter delay removed).
    """
    import pyroomacoustics as pra

    size = as_float_array(room_size, "room_size")
    if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size <= 0):
        raise InvalidInputError(f"room_size must be 3 positive lengths; got {room_size!r}")
    src = as_points(np.atleast_2d(as_float_array(source, "source")), "source", dim=3)[0]
    rec = as_points(receivers, "receivers", dim=3)
    for name, pts in (("source", src[None]), ("receivers", rec)):
        outside = np.any((pts <= 0) | (pts >= size), axis=1)
        if outside.any():
            raise InvalidInputError(
                f"{name} must lie inside the room; row {int(np.argmax(outside))} does not"
            )
    duration = _check_options(absorption, fs, max_order, duration)
    room = pra.ShoeBox(
        size, fs=int(fs), materials=pra.Material(float(absorption)), max_order=int(max_order)
    )
    return _simulate(room, src, rec, fs, duration)


def room_rirs(
    room: Room,
    source: ArrayLike,
    receivers: ArrayLike,
    *,
    fs: int = 16000,
    absorption: float | ArrayLike = 0.2,
    max_order: int = 3,
    duration: float | None = None,
) -> np.ndarray:
    """RIRs (M, L) from one source to M receivers in a convex polyhedral room (3-D).

    Args:
        room: the room (:class:`~rangeslam.geometry.room.Room`, 3-D); wall k is the face on plane k.
        source: (3,) metres. receivers: (M, 3) metres, inside the room.
        fs, max_order, duration: as :func:`shoebox_rirs`.
        absorption: energy absorption in (0, 1], one for every wall or (K,) one per wall in the
            order of ``room.normals``.

    Each wall is the polygon of the room's vertices on its plane, ordered counter-clockwise about
    the outward normal. On a shoebox the result equals :func:`shoebox_rirs` (test).
    """
    import pyroomacoustics as pra

    if not isinstance(room, Room) or room.dim != 3:
        raise InvalidInputError(f"room must be a 3-D rangeslam Room; got {room!r:.80}")
    k = room.n_walls
    absorb = (
        np.broadcast_to(as_float_array(absorption, "absorption"), (k,)).copy()
        if np.ndim(absorption) in (0, 1) and np.size(absorption) in (1, k)
        else None
    )
    if absorb is None:
        raise InvalidInputError(
            f"absorption must be one number or one per wall ({k}); got {absorption!r}"
        )
    for a in absorb:
        duration = _check_options(a, fs, max_order, duration)
    src = as_points(np.atleast_2d(as_float_array(source, "source")), "source", dim=3)[0]
    rec = as_points(receivers, "receivers", dim=3)
    for name, pts in (("source", src[None]), ("receivers", rec)):
        outside = ~room.contains(pts, margin=1e-9)
        if outside.any():
            raise InvalidInputError(
                f"{name} must lie inside the room; row {int(np.argmax(outside))} does not"
            )
    walls = [
        pra.wall_factory(corners.T, [float(absorb[w])], [0.0], name=f"wall{w}")
        for w, corners in enumerate(_wall_polygons(room))
    ]
    sim = pra.Room(walls, fs=int(fs), max_order=int(max_order))
    return _simulate(sim, src, rec, fs, duration)


def _wall_polygons(room: Room) -> list[np.ndarray]:
    """(n_k, 3) corners of each wall face, counter-clockwise about its outward normal."""
    verts = room.vertices
    tol = 1e-9 * max(1.0, room.size)
    polygons = []
    for normal, offset in zip(room.normals, room.offsets, strict=True):
        on = verts[np.abs(verts @ normal - offset) <= tol * 1e3]
        centre = on.mean(axis=0)
        u = on[0] - centre
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        angle = np.arctan2((on - centre) @ v, (on - centre) @ u)
        polygons.append(on[np.argsort(angle)])
    return polygons


# Limits of the simulation's sizes: beyond them pyroomacoustics (image sources ~ order^3, samples
# ~ fs * duration per receiver) exhausts memory instead of failing.
#: Below this sampling rate (Hz) an RIR has too few samples to hold a room's echoes.
MIN_SIM_FS = 1000
MAX_SIM_FS = 1_000_000
MAX_SIM_ORDER = 30
MAX_SIM_DURATION = 10.0


def _check_options(absorption: float, fs, max_order, duration=None) -> float | None:
    """Check absorption in (0, 1], fs a whole number of Hz in [MIN_SIM_FS, MAX_SIM_FS], max_order an
    integer in [0, MAX_SIM_ORDER], duration None or seconds in (0, MAX_SIM_DURATION]; returns
    the duration as a float (or None)."""
    as_scalar(absorption, "absorption", low=0.0, high=1.0, low_open=True, expected="in (0, 1]")
    what = f"a whole number of Hz in [{MIN_SIM_FS}, {MAX_SIM_FS}]"
    rate = as_scalar(fs, "fs", low=MIN_SIM_FS, high=MAX_SIM_FS, expected=what)
    if not float(rate).is_integer():
        raise InvalidInputError(f"fs must be {what}; got {fs!r:.80}")
    as_scalar(
        max_order, "max_order", low=0, high=MAX_SIM_ORDER, integer=True,
        expected=f"an integer >= 0 (at most {MAX_SIM_ORDER})",
    )  # fmt: skip
    return as_scalar(
        duration, "duration", low=0.0, low_open=True, high=MAX_SIM_DURATION, allow_none=True,
        expected=f"None or seconds in (0, {MAX_SIM_DURATION:g}]",
    )  # fmt: skip


def _simulate(room, src: np.ndarray, rec: np.ndarray, fs, duration: float | None) -> np.ndarray:
    """Add the source and receivers, compute, remove the filter delay, pad to one length."""
    import pyroomacoustics as pra

    room.add_source(src)
    room.add_microphone_array(rec.T)
    room.compute_rir()
    delay = pra.constants.get("frac_delay_length") // 2
    rirs = [np.asarray(room.rir[m][0])[delay:] for m in range(len(rec))]
    length = max(len(r) for r in rirs) if duration is None else round(duration * fs)
    out = np.zeros((len(rec), length))
    for m, r in enumerate(rirs):
        n = min(len(r), length)
        out[m, :n] = r[:n]
    return out
