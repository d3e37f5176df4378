"""Simulated measurements: range matrices, noise, missing entries, outliers, random rooms and arrays.

Every random function takes ``rng`` (a ``numpy.random.Generator``, a seed, or None) and never
touches global random state. Ranges are distances in metres; masks are True where observed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_dim, as_mask, as_points, as_ranges, as_rng, as_scalar
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.room import Room

__all__ = [
    "add_outliers",
    "add_range_noise",
    "echo_ranges",
    "random_convex_room",
    "random_mask",
    "random_points_in_room",
    "range_matrix",
    "walk_in_random_room",
]


def echo_ranges(room: Room, receivers: ArrayLike, source: ArrayLike) -> np.ndarray:
    """(M, 1+K) distances from receivers to the source (column 0) and its K first-order images.

    Receivers must be inside the room (the image-source model describes echoes heard inside it).
    """
    rec = as_points(receivers, "receivers", dim=room.dim)
    inside = room.contains(rec, margin=-1e-9 * room.size)
    if not inside.all():
        raise InvalidInputError(
            f"receivers must be inside the room; receiver {int(np.argmin(inside))} is not"
        )
    src = np.asarray(source, dtype=float)
    images = room.image_sources(src, order=1).positions
    return range_matrix(rec, np.vstack([src[None, :], images]))


def _check_sigma(sigma: float, name: str = "sigma") -> float:
    return as_scalar(sigma, name, low=0.0, expected="a finite number >= 0")


def _check_fraction(p: float, name: str) -> float:
    return as_scalar(p, name, low=0.0, high=1.0, expected="in [0, 1]")


# The largest simulated mask or set of points, entries (10^8 booleans: 100 MB).
MAX_ENTRIES = 100_000_000


# Most walls of a random convex room (each draw is tried up to 1000 times).
MAX_WALLS = 100


def _check_shape(shape, name: str = "shape") -> tuple[int, ...]:
    """A shape: a tuple (or list) of integers >= 0 with at most MAX_ENTRIES entries in all."""
    if isinstance(shape, int | np.integer) and not isinstance(shape, bool):
        shape = (shape,)
    if not isinstance(shape, tuple | list) or not all(
        isinstance(n, int | np.integer) and not isinstance(n, bool) and 0 <= n <= MAX_ENTRIES
        for n in shape
    ):
        raise InvalidInputError(f"{name} must be a tuple of integers >= 0; got {shape!r:.80}")
    if np.prod([float(n) for n in shape]) > MAX_ENTRIES:
        raise InvalidInputError(f"{name} must hold at most {MAX_ENTRIES} entries; got {shape}")
    return tuple(int(n) for n in shape)


def add_range_noise(ranges: ArrayLike, sigma: float, *, rng=None) -> np.ndarray:
    """Ranges plus i.i.d. N(0, sigma^2) noise (metres); a new array.

    A noisy range below zero is folded back (|r + e|): distances cannot be negative. This only
    happens for ranges within a few sigma of zero.
    """
    rng = as_rng(rng)
    r = as_ranges(ranges, "ranges", shape=(None,) * np.ndim(ranges))
    sigma = _check_sigma(sigma)
    return np.abs(r + sigma * rng.standard_normal(r.shape))


def random_mask(shape: tuple[int, ...], missing_fraction: float, *, rng=None) -> np.ndarray:
    """Boolean mask of the given shape, True where observed, each entry missing with the given probability."""
    rng = as_rng(rng)
    p = _check_fraction(missing_fraction, "missing_fraction")
    return rng.random(_check_shape(shape)) >= p


def add_outliers(
    ranges: ArrayLike,
    fraction: float,
    *,
    min_error: float = 0.2,
    max_error: float = 2.0,
    mask: ArrayLike | None = None,
    rng=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt a fraction of the observed ranges, as wrong echo picks do.

    Each chosen range moves by a random sign times a uniform error in [min_error, max_error] metres
    (a shortening that would go below zero becomes a lengthening). Returns ``(corrupted, is_outlier)``, both of the shape of ``ranges``.
    """
    rng = as_rng(rng)
    observed = as_mask(mask, "mask", shape=np.shape(ranges))
    r = as_ranges(ranges, "ranges", shape=(None,) * np.ndim(ranges), observed=observed)
    p = _check_fraction(fraction, "fraction")
    min_error = as_scalar(min_error, "min_error")
    max_error = as_scalar(max_error, "max_error")
    if not 0 <= min_error <= max_error:
        raise InvalidInputError(f"need 0 <= min_error <= max_error; got {min_error}, {max_error}")
    is_outlier = observed & (rng.random(r.shape) < p)
    err = rng.uniform(min_error, max_error, r.shape) * rng.choice([-1.0, 1.0], r.shape)
    out = np.array(ranges, dtype=float, copy=True)  # unobserved entries come back as given
    # A shortening that would go below zero lengthens instead, so |change| stays in the interval.
    err = np.where(r + err < 0, -err, err)
    out[is_outlier] = r[is_outlier] + err[is_outlier]
    return out, is_outlier


def random_points_in_room(
    room: Room, n: int, *, margin: float = 0.0, rng=None, max_tries: int = 10_000
) -> np.ndarray:
    """(n, d) points uniform in the room, at least ``margin`` metres from every wall (rejection sampling)."""
    rng = as_rng(rng)
    if not isinstance(n, int | np.integer) or n < 0:
        raise InvalidInputError(f"n must be a non-negative integer; got {n!r}")
    lo, hi = room.vertices.min(axis=0), room.vertices.max(axis=0)
    out: list[np.ndarray] = []
    got = 0
    for _ in range(max_tries):
        cand = rng.uniform(lo, hi, size=(max(4 * (n - got), 16), room.dim))
        keep = cand[room.contains(cand, margin=margin)]
        out.append(keep[: n - got])
        got += len(out[-1])
        if got >= n:
            return np.vstack(out) if out else np.empty((0, room.dim))
    raise InvalidInputError(
        f"could not place {n} points {margin} m inside the room; margin too large?"
    )


def _spread_directions(n: int, dim: int, rng: np.random.Generator) -> np.ndarray:
    """n unit vectors spread over the circle/sphere: even angles (2-D) or a Fibonacci sphere (3-D),
    randomly rotated, each jittered by about a third of the spacing."""
    if dim == 2:
        angles = 2 * np.pi * (np.arange(n) + rng.uniform(-0.3, 0.3, n)) / n + rng.uniform(
            0, 2 * np.pi
        )
        return np.column_stack([np.cos(angles), np.sin(angles)])
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    base = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    dirs = base @ q.T + rng.normal(scale=0.6 / np.sqrt(n), size=(n, 3))
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def random_convex_room(
    dim: int,
    n_walls: int,
    *,
    inner_radius: float = 2.0,
    radius_spread: float = 0.5,
    rng=None,
) -> Room:
    """A random convex room with ``n_walls`` walls, none of them redundant.

    Walls are tangent planes to spheres of radius in [inner_radius, inner_radius + radius_spread]
    around a random centre, with outward normals spread over the circle or sphere (evenly spaced,
    randomly rotated and jittered); draws that leave the room unbounded, make
    a wall redundant, or put a corner more than 2.5 outer radii (d + 1 for a simplex) from the
    centre are rejected. ``n_walls`` >= d + 1 (a simplex) and typically up to ~12.
    """
    from rangeslam.errors import DegenerateGeometryError

    rng = as_rng(rng)
    dim = as_dim(dim)
    n_walls = as_scalar(
        n_walls, "n_walls", low=dim + 1, integer=True, expected=f"an integer >= {dim + 1}"
    )
    if n_walls > MAX_WALLS:
        raise InvalidInputError(f"n_walls must be at most {MAX_WALLS}; got {n_walls}")
    inner_radius = as_scalar(inner_radius, "inner_radius", low=0.0, low_open=True)
    radius_spread = as_scalar(radius_spread, "radius_spread", low=0.0)
    centre = rng.uniform(2.0, 4.0, dim)
    for _ in range(1000):
        normals = _spread_directions(n_walls, dim, rng)
        radii = inner_radius + radius_spread * rng.random(n_walls)
        try:
            room = Room(normals, normals @ centre + radii)
        except DegenerateGeometryError:
            continue
        # Reject spiky rooms: no corner farther than 2.5 times the outer radius from the centre.
        # A d-simplex around a ball of radius r has a corner at least d r from its centre (the
        # regular one exactly), so 2.5 would refuse every tetrahedron: simplices get d + 1.
        spike = 2.5 if n_walls > dim + 1 else max(2.5, dim + 1.0)
        if np.linalg.norm(room.vertices - centre, axis=1).max() <= spike * (
            inner_radius + radius_spread
        ):
            return room
    raise InvalidInputError(
        f"could not draw a bounded room with {n_walls} non-redundant walls in {dim}-D"
    )


def walk_in_random_room(
    m: int,
    *,
    n_images: int = 6,
    step_length: float = 0.3,
    turn_std: float = 0.5,
    rng=None,
) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random non-planar 3-D walk of ``m`` steps of ``step_length`` metres (turn std
    ``turn_std`` rad, :func:`rangeslam.sim.trajectories.random_walk`) in a random convex room of
    6 walls, and its landmarks: a loudspeaker uniform in the room and its ``n_images``
    first-order image sources nearest the walk. Returns (trajectory (M, 3), landmarks
    (1 + n_images, 3)), metres."""
    from rangeslam.sim.trajectories import random_walk

    rng = as_rng(rng)
    room = random_convex_room(3, 6, rng=rng)
    start = random_points_in_room(room, 1, margin=0.5, rng=rng)[0]
    traj = random_walk(
        m, start=start, step_length=step_length, turn_std=turn_std, room=room, rng=rng
    )
    speaker = random_points_in_room(room, 1, margin=0.3, rng=rng)[0]
    images = room.image_sources(speaker, 1).positions
    near = np.argsort(np.linalg.norm(images - traj.mean(axis=0), axis=1))[:n_images]
    return traj, np.vstack([speaker, images[near]])
