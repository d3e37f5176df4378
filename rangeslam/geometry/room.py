"""Convex polyhedral rooms and their image sources (paper, section 2 and Fig. 1). Pure numpy/scipy.

A room is the intersection of K half-spaces ``n_k . x <= o_k`` with outward unit normals ``n_k``
(rows of ``normals``, shape (K, d)) and offsets ``o_k``; wall k is the plane ``n_k . x = o_k``.
Works in 2-D (polygons) and 3-D (polyhedra). Points are rows, shape (N, d), in metres.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from rangeslam._validation import (
    as_float_array,
    as_point,
    as_points,
    check_metres,
    frozen,
    shape_str,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError

__all__ = ["ImageSources", "Room", "reflect"]

# Relative tolerance (to the room's size) for "on a plane", "inside" and redundant-plane tests.
_GEOM_RTOL = 1e-9


def reflect(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Mirror points (N, d) across the plane ``normal . x = offset`` (``normal`` unit length).

    This is the paper's image-source formula s_k = s + 2<p_k - s, n_k> n_k with <p_k, n_k> = o_k.
    """
    return points + 2.0 * (offset - points @ normal)[:, None] * normal[None, :]


@dataclass(frozen=True)
class ImageSources:
    """Image sources of one source in a room, orders 1..max_order.

    Attributes:
        positions: (J, d) image-source positions in metres, sorted by order, then by wall sequence.
        walls: J tuples; ``walls[j]`` is the sequence of wall indices reflected in, first to last.
        orders: (J,) reflection order of each image (``len(walls[j])``).
        valid: (J,) Borish's validity test: the parent image lies on the room side of the last wall
            it is reflected in. Every first-order image of a source inside a convex room is valid;
            in a box the invalid ones up to order 3 are the sequences (a, b, a) with b perpendicular
            to a (they coincide with the image in b), in other rooms more fail. Visibility from a
            given receiver is not tested.
    """

    positions: np.ndarray
    walls: tuple[tuple[int, ...], ...]
    orders: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return len(self.walls)


@dataclass(frozen=True)
class Room:
    """A convex polyhedral room ``{x : normals @ x <= offsets}`` in 2-D or 3-D.

    Build it with :meth:`shoebox`, :meth:`polygon`, :meth:`from_vertices` or :meth:`from_planes`;
    the constructor checks that every plane bounds the room, that the room is bounded and that it
    has a non-empty interior.

    Attributes:
        normals: (K, d) outward unit normals, one per wall.
        offsets: (K,) offsets: wall k is ``normals[k] . x = offsets[k]``.
    """

    normals: np.ndarray
    offsets: np.ndarray
    _interior: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        normals = np.array(self.normals, dtype=float)
        offsets = np.array(self.offsets, dtype=float)
        if normals.ndim != 2 or normals.shape[1] not in (2, 3):
            raise InvalidInputError(
                f"normals must have shape (K, d) with d in (2, 3); got {shape_str(normals.shape)}"
            )
        k, d = normals.shape
        if offsets.shape != (k,):
            raise InvalidInputError(
                f"offsets must have shape ({k},); got {shape_str(offsets.shape)}"
            )
        if not (np.all(np.isfinite(normals)) and np.all(np.isfinite(offsets))):
            raise InvalidInputError("normals and offsets must be finite")
        norms = np.linalg.norm(normals, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-9):
            raise InvalidInputError(
                "normals must be unit vectors (use Room.from_planes to normalise); "
                f"norms are {np.round(norms, 6).tolist()}"
            )
        if k < d + 1:
            raise DegenerateGeometryError(
                f"a bounded room in {d}-D needs at least {d + 1} walls; got {k}"
            )
        interior = _chebyshev_centre(normals, offsets)
        _check_bounded(normals, offsets)
        object.__setattr__(self, "normals", frozen(normals))
        object.__setattr__(self, "offsets", frozen(offsets))
        object.__setattr__(self, "_interior", frozen(interior))
        # Every plane must carry a facet (d affinely independent vertices); a redundant plane is
        # not a wall and would produce meaningless image sources.
        verts = self.vertices
        tol = _GEOM_RTOL * max(1.0, float(np.ptp(verts, axis=0).max()))
        # A plane given twice carries the same facet twice; the copy is redundant as well.
        for i, j in itertools.combinations(range(k), 2):
            if np.allclose(normals[i], normals[j], rtol=0, atol=1e-9) and (
                abs(offsets[i] - offsets[j]) <= tol
            ):
                raise DegenerateGeometryError(
                    f"planes {i} and {j} are the same plane (normal {np.round(normals[i], 6).tolist()}, "
                    f"offset {offsets[i]:.6g}): it is redundant"
                )
        for i in range(k):
            on = verts[np.abs(verts @ normals[i] - offsets[i]) <= tol]
            if len(on) < d or np.linalg.matrix_rank(on - on[0], tol=tol) < d - 1:
                raise DegenerateGeometryError(
                    f"plane {i} (normal {np.round(normals[i], 6).tolist()}, offset {offsets[i]:.6g}) "
                    "does not bound the room: it is redundant or touches it only at a lower-dimensional face"
                )

    # ---- constructors -------------------------------------------------------------------------
    @classmethod
    def from_planes(cls, normals: ArrayLike, points: ArrayLike) -> Room:
        """Room from K planes, each an outward normal (K, d) (any length > 0) and a point on it (K, d)."""
        normals = as_float_array(normals, "normals")
        points = as_float_array(points, "points")
        if normals.ndim != 2 or normals.shape[1] not in (2, 3):
            raise InvalidInputError(
                f"normals must have shape (K, d) with d in (2, 3); got {shape_str(normals.shape)}"
            )
        if points.shape != normals.shape:
            raise InvalidInputError(
                f"points must have the shape of normals {shape_str(normals.shape)}; got {shape_str(points.shape)}"
            )
        if not (np.all(np.isfinite(normals)) and np.all(np.isfinite(points))):
            raise InvalidInputError("normals and points must be finite")
        check_metres(points, "points", min_scale=False)
        norms = np.linalg.norm(normals, axis=1)
        if np.any(norms < 1e-12):
            raise InvalidInputError(
                f"normals must be non-zero; row {int(np.argmin(norms))} is zero"
            )
        unit = normals / norms[:, None]
        return cls(unit, np.einsum("kd,kd->k", unit, points))

    @classmethod
    def shoebox(cls, dims: ArrayLike) -> Room:
        """Axis-aligned box [0, L_1] x ... x [0, L_d].

        Walls in the order (x = 0, x = L_1, y = 0, y = L_2[, z = 0, z = L_3]), the order of the
        dEchorate echo columns (west, east, south, north, floor, ceiling).
        """
        dims = as_float_array(dims, "dims")
        if dims.ndim != 1 or dims.shape[0] not in (2, 3):
            raise InvalidInputError(
                f"dims must have shape (d,) with d in (2, 3); got {shape_str(dims.shape)}"
            )
        if not np.all(np.isfinite(dims)) or np.any(dims <= 0):
            raise InvalidInputError(f"dims must be finite and positive; got {dims.tolist()}")
        check_metres(dims, "dims", "room dimensions")
        d = dims.shape[0]
        normals = np.repeat(np.eye(d), 2, axis=0) * np.tile([-1.0, 1.0], d)[:, None]
        offsets = np.ravel(np.column_stack([np.zeros(d), dims]))
        return cls(normals, offsets)

    @classmethod
    def from_vertices(cls, vertices: ArrayLike) -> Room:
        """The convex hull of points (N, d) as a room; coplanar hull facets are merged into one wall."""
        verts = as_points(vertices, "vertices", min_points=3)
        d = verts.shape[1]
        try:
            hull = ConvexHull(verts)
        except QhullError as exc:
            raise DegenerateGeometryError(
                f"vertices must span a {d}-D region with non-empty interior; Qhull says: {str(exc).splitlines()[0]}"
            ) from exc
        eqs = hull.equations  # rows [n, -o]: n . x - o <= 0 inside, n unit
        scale = max(1.0, float(np.ptp(verts, axis=0).max()))
        walls: list[np.ndarray] = []
        for eq in eqs:
            if not any(np.allclose(eq, w, atol=1e-9 * scale) for w in walls):
                walls.append(eq)
        planes = np.array(walls)
        return cls(planes[:, :d], -planes[:, d])

    @classmethod
    def polygon(cls, vertices: ArrayLike) -> Room:
        """A convex polygon (2-D room) from its corners (N, 2), in either winding order.

        Every corner must be a corner of the convex hull: a non-convex polygon is refused rather
        than silently replaced by its hull.
        """
        verts = as_points(vertices, "vertices", dim=2, min_points=3)
        try:
            hull = ConvexHull(verts)
        except QhullError as exc:
            raise DegenerateGeometryError("vertices of a polygon must not be collinear") from exc
        if len(hull.vertices) != len(verts):
            inner = sorted(set(range(len(verts))) - set(hull.vertices.tolist()))
            raise InvalidInputError(
                f"vertices must form a convex polygon; corners {inner} are not on its convex hull"
            )
        return cls.from_vertices(verts)

    # ---- properties ---------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.normals.shape[1])

    @property
    def n_walls(self) -> int:
        return int(self.normals.shape[0])

    @property
    def interior_point(self) -> np.ndarray:
        """A point deep inside the room (the centre of its largest inscribed ball), shape (d,)."""
        return self._interior

    @cached_property
    def vertices(self) -> np.ndarray:
        """(V, d) corners of the room (scipy's half-space intersection)."""
        halfspaces = np.column_stack([self.normals, -self.offsets])
        pts = HalfspaceIntersection(halfspaces, self._interior).intersections
        scale = max(1.0, float(np.abs(pts).max()))
        uniq = np.unique(
            np.round(pts / (1e-9 * scale)).astype(np.int64), axis=0, return_index=True
        )[1]
        return frozen(pts[np.sort(uniq)])

    @cached_property
    def wall_centroids(self) -> np.ndarray:
        """(K, d) centroid of each wall's face (the mean of its vertices; p_k of the paper)."""
        tol = _GEOM_RTOL * max(1.0, float(np.ptp(self.vertices, axis=0).max()))
        dist = np.abs(self.vertices @ self.normals.T - self.offsets)  # (V, K)
        return frozen(
            np.array([self.vertices[dist[:, k] <= tol].mean(axis=0) for k in range(self.n_walls)])
        )

    @cached_property
    def volume(self) -> float:
        """Volume in m^3 (area in m^2 in 2-D)."""
        return float(ConvexHull(self.vertices).volume)

    @cached_property
    def size(self) -> float:
        """Diameter of the bounding box, a length scale for tolerances (metres)."""
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))

    def contains(self, points: ArrayLike, *, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: True where a point is inside the room, at least ``margin`` metres from every wall."""
        pts = as_points(points, "points", dim=self.dim)
        return np.all(pts @ self.normals.T <= self.offsets - margin, axis=1)

    def distance_to_walls(self, points: ArrayLike) -> np.ndarray:
        """(N, K) signed distances to each wall's plane, positive inside."""
        pts = as_points(points, "points", dim=self.dim)
        return self.offsets[None, :] - pts @ self.normals.T

    # ---- image sources ------------------------------------------------------------------------
    def image_sources(self, source: ArrayLike, order: int = 1) -> ImageSources:
        """Image sources of ``source`` (d,) up to ``order`` reflections (paper, Fig. 1).

        Order 1 gives K images in wall order; order r adds the images of the order r-1 images in every
        wall but the one they were last reflected in (a second reflection in the same wall would
        undo the first), K (K-1)^(r-1) of them.
        """
        src = as_point(source, "source", dim=self.dim)
        if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
            raise InvalidInputError(f"order must be an integer >= 1; got {order!r}")
        tol = _GEOM_RTOL * self.size
        if not self.contains(src[None, :], margin=-tol)[0]:
            dist = self.distance_to_walls(src[None, :])[0]
            raise InvalidInputError(
                f"source must be inside the room; {src.tolist()} is {-dist.min():.6g} m outside wall "
                f"{int(np.argmin(dist))}"
            )
        positions: list[np.ndarray] = []
        walls: list[tuple[int, ...]] = []
        valid: list[np.ndarray] = []
        parents = src[None, :]
        parent_walls: list[tuple[int, ...]] = [()]
        parent_valid = np.array([True])
        for _ in range(order):
            new_pos, new_walls, new_valid = [], [], []
            for i, (pw, pv) in enumerate(zip(parent_walls, parent_valid, strict=True)):
                p = parents[i]
                for k in range(self.n_walls):
                    if pw and pw[-1] == k:
                        continue
                    new_pos.append(reflect(p[None, :], self.normals[k], self.offsets[k])[0])
                    new_walls.append((*pw, k))
                    new_valid.append(pv and (p @ self.normals[k] < self.offsets[k] + tol))
            parents = np.array(new_pos)
            parent_walls = new_walls
            parent_valid = np.array(new_valid)
            positions.append(parents)
            walls.extend(new_walls)
            valid.append(parent_valid)
        return ImageSources(
            positions=frozen(np.vstack(positions)),
            walls=tuple(walls),
            orders=frozen(np.array([len(w) for w in walls])),
            valid=frozen(np.concatenate(valid)),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Room):
            return NotImplemented
        return np.array_equal(self.normals, other.normals) and np.array_equal(
            self.offsets, other.offsets
        )

    __hash__ = None  # type: ignore[assignment]


def _chebyshev_centre(normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Centre of the largest ball inside {n . x <= o} (linear program); refuses an empty interior."""
    k, d = normals.shape
    # maximise r  s.t.  n_k . x + r <= o_k (unit normals), r >= 0; variables (x, r).
    c = np.zeros(d + 1)
    c[-1] = -1.0
    a_ub = np.column_stack([normals, np.ones(k)])
    scale = max(1.0, float(np.abs(offsets).max()))
    bounds = [(None, None)] * d + [(0, 1e6 * scale)]
    res = linprog(c, A_ub=a_ub, b_ub=offsets, bounds=bounds, method="highs")
    if res.status != 0 or res.x[-1] <= _GEOM_RTOL * scale:
        raise DegenerateGeometryError(
            "the planes must enclose a region with non-empty interior; "
            + ("the intersection is empty or flat" if res.status in (0, 2) else res.message)
        )
    return res.x[:d]


def _check_bounded(normals: np.ndarray, offsets: np.ndarray) -> None:
    """Refuse an unbounded intersection: maximise +-x_i over the room for every axis."""
    d = normals.shape[1]
    for i, sign in itertools.product(range(d), (1.0, -1.0)):
        c = np.zeros(d)
        c[i] = -sign
        res = linprog(c, A_ub=normals, b_ub=offsets, bounds=[(None, None)] * d, method="highs")
        if res.status == 3:
            raise DegenerateGeometryError(
                f"the planes must bound a finite room; it extends to {'+' if sign > 0 else '-'}infinity "
                f"along axis {i} (add walls whose normals point that way)"
            )
