"""Tests of rangeslam.geometry.room: convex rooms, their image sources and the mirror map."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.room import ImageSources, Room, reflect
from rangeslam.sim.scenes import random_convex_room, random_points_in_room

# (dim, n_walls) of rooms from random_convex_room, and (dim, n_points) of random point clouds
# whose hull is the room: the 4-point clouds are tetrahedra, the 3-point ones triangles.
ROOM_SHAPES = [(2, 3), (2, 4), (2, 6), (2, 9), (3, 7), (3, 8), (3, 10)]
CLOUD_SIZES = [(2, 3), (2, 6), (2, 10), (3, 4), (3, 6), (3, 9)]
IMAGE_ATOL = 1e-9  # metres, the acceptance tolerance for image-source positions


# ---- brute-force reference ------------------------------------------------------------------------
def _affine_reflection(normal: np.ndarray, offset: float) -> np.ndarray:
    """Homogeneous (d+1, d+1) matrix of x -> (I - 2 n n^T) x + 2 o n."""
    d = normal.shape[0]
    a = np.eye(d + 1)
    a[:d, :d] -= 2.0 * np.outer(normal, normal)
    a[:d, d] = 2.0 * offset * normal
    return a


def _brute_force_images(room: Room, source: np.ndarray, max_order: int):
    """Images for every wall sequence without immediate repeats, in (order, lexicographic) order.

    Returns (walls, positions, valid); validity is Borish's: every intermediate image lies on the
    room side of the wall it is reflected in next.
    """
    d, k = room.dim, room.n_walls
    mats = [_affine_reflection(n, o) for n, o in zip(room.normals, room.offsets, strict=True)]
    hom = np.append(source, 1.0)
    walls, positions, valid = [], [], []
    for order in range(1, max_order + 1):
        for seq in itertools.product(range(k), repeat=order):
            if any(a == b for a, b in itertools.pairwise(seq)):
                continue
            m = np.eye(d + 1)
            ok = True
            for w in seq:
                parent = (m @ hom)[:d]
                ok = ok and bool(room.normals[w] @ parent <= room.offsets[w] + 1e-9)
                m = mats[w] @ m
            walls.append(seq)
            positions.append((m @ hom)[:d])
            valid.append(ok)
    return walls, np.array(positions), np.array(valid)


def _random_inside(room: Room, rng: np.random.Generator) -> np.ndarray:
    """A random convex combination of the room's corners: inside even a sliver-thin room."""
    return rng.dirichlet(np.ones(len(room.vertices))) @ room.vertices


def _random_rooms(rng: np.random.Generator, dim: int) -> list[Room]:
    """A random convex room with 2d + 2 walls and the hull of a random point cloud of 2d + 2 points."""
    cloud = rng.uniform(0.0, 5.0, size=(2 * dim + 2, dim))
    return [random_convex_room(dim, 2 * dim + 2, rng=rng), Room.from_vertices(cloud)]


def _sorted_rows(points) -> np.ndarray:
    """Rows sorted lexicographically on values rounded to 1e-6 (order-free comparison of point sets)."""
    a = np.asarray(points, dtype=float)
    return a[np.lexsort(np.round(a, 6).T[::-1])]


# ---- reflect --------------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_reflect_is_an_involution_fixing_the_plane(rng, dim):
    """Reflecting twice is the identity, points on the plane are fixed, and the plane bisects x, x'."""
    n = rng.normal(size=dim)
    n /= np.linalg.norm(n)
    o = rng.normal()
    x = rng.normal(size=(20, dim))
    x1 = reflect(x, n, o)
    np.testing.assert_allclose(reflect(x1, n, o), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose((x + x1) / 2 @ n, o, rtol=0, atol=1e-12)
    shift = x1 - x
    np.testing.assert_allclose(shift - np.outer(shift @ n, n), 0.0, rtol=0, atol=1e-12)
    on_plane = x - (x @ n - o)[:, None] * n
    np.testing.assert_allclose(reflect(on_plane, n, o), on_plane, rtol=0, atol=1e-12)


# ---- constructors and properties -----------------------------------------------------------------
def test_shoebox_wall_order_and_outward_normals():
    """shoebox walls are x=0, x=L1, y=0, y=L2, z=0, z=L3 with outward unit normals."""
    room = Room.shoebox([4.0, 5.0, 3.0])
    expected = np.array(
        [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], dtype=float
    )
    np.testing.assert_array_equal(room.normals, expected)
    np.testing.assert_array_equal(room.offsets, [0.0, 4.0, 0.0, 5.0, 0.0, 3.0])
    assert room.dim == 3 and room.n_walls == 6


@pytest.mark.parametrize("dim", [2, 3])
def test_shoebox_vertices_volume_and_distances(rng, dim):
    """A box has the 2^d corners, volume prod(L), and signed wall distances (x, L-x, ...)."""
    dims = rng.uniform(1.0, 6.0, size=dim)
    room = Room.shoebox(dims)
    corners = np.array(list(itertools.product(*[(0.0, L) for L in dims])))
    got = _sorted_rows(room.vertices)
    np.testing.assert_allclose(got, _sorted_rows(corners), rtol=0, atol=1e-9)
    assert room.volume == pytest.approx(np.prod(dims), rel=1e-12)
    assert room.size == pytest.approx(np.linalg.norm(dims), rel=1e-12)
    x = rng.uniform(0.0, 1.0, size=(5, dim)) * dims
    want = np.column_stack([c for i in range(dim) for c in (x[:, i], dims[i] - x[:, i])])
    np.testing.assert_allclose(room.distance_to_walls(x), want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_normals_are_outward_unit_vectors(rng, dim):
    """Every wall normal has unit length and points away from the room's interior."""
    for room in _random_rooms(rng, dim):
        np.testing.assert_allclose(np.linalg.norm(room.normals, axis=1), 1.0, rtol=0, atol=1e-12)
        inside = room.interior_point
        # moving from the interior along n_k reaches wall k: n_k . x grows towards o_k
        assert np.all(room.normals @ inside < room.offsets)
        assert room.contains(inside[None, :], margin=1e-3)[0]


@pytest.mark.parametrize("dim", [2, 3])
def test_contains_inside_outside_and_margin(dim):
    """contains() is True inside, False outside, and honours the margin from the nearest wall."""
    room = Room.shoebox([3.0, 4.0, 2.5][:dim])
    centre = np.array([1.5, 2.0, 1.25][:dim])
    near = centre.copy()
    near[0] = 0.2  # 0.2 m from the wall x = 0
    outside = centre.copy()
    outside[0] = -0.1
    pts = np.array([centre, near, outside])
    np.testing.assert_array_equal(room.contains(pts), [True, True, False])
    np.testing.assert_array_equal(room.contains(pts, margin=0.1), [True, True, False])
    np.testing.assert_array_equal(room.contains(pts, margin=0.3), [True, False, False])
    np.testing.assert_array_equal(room.contains(pts, margin=-0.2), [True, True, True])


def test_polygon_area_matches_shoelace(rng):
    """A random convex polygon's area equals the shoelace formula, in either winding order."""
    angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, size=7))
    radius = rng.uniform(1.0, 3.0)
    pts = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)]) + rng.normal(size=2)
    x, y = pts[:, 0], pts[:, 1]
    shoelace = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    ccw, cw = Room.polygon(pts), Room.polygon(pts[::-1])
    assert ccw.volume == pytest.approx(shoelace, rel=1e-12)
    assert cw.volume == pytest.approx(shoelace, rel=1e-12)
    assert ccw.n_walls == 7
    got = _sorted_rows(ccw.vertices)
    np.testing.assert_allclose(got, _sorted_rows(pts), rtol=0, atol=1e-9)


def test_from_vertices_of_cube_merges_coplanar_facets():
    """The hull of a cube's 8 corners (12 triangles in Qhull) is a room with 6 walls and volume 1."""
    room = Room.from_vertices(list(itertools.product([0.0, 1.0], repeat=3)))
    assert room.n_walls == 6
    assert room.volume == pytest.approx(1.0, rel=1e-12)
    assert len(room.vertices) == 8
    # the same planes as the unit shoebox, in some order
    box = Room.shoebox([1.0, 1.0, 1.0])
    planes = {
        tuple(np.round(np.append(n, o), 9) + 0.0)
        for n, o in zip(room.normals, room.offsets, strict=True)
    }
    want = {tuple(np.append(n, o)) for n, o in zip(box.normals, box.offsets, strict=True)}
    assert planes == want


@pytest.mark.parametrize("dim", [2, 3])
def test_from_vertices_of_point_cloud_is_its_hull(rng, dim):
    """from_vertices contains every point, its corners are hull points, its volume the hull's."""
    cloud = rng.uniform(0.0, 5.0, size=(15, dim))
    room = Room.from_vertices(cloud)
    hull = ConvexHull(cloud)
    assert np.all(room.contains(cloud, margin=-1e-9))
    assert room.volume == pytest.approx(hull.volume, rel=1e-9)
    corners = cloud[hull.vertices]
    got = _sorted_rows(room.vertices)
    np.testing.assert_allclose(got, _sorted_rows(corners), rtol=0, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_from_planes_normalises_normals(rng, dim):
    """from_planes with scaled normals and arbitrary points on the walls gives the shoebox."""
    dims = rng.uniform(1.0, 5.0, size=dim)
    box = Room.shoebox(dims)
    scales = rng.uniform(0.1, 10.0, size=box.n_walls)
    # a point on wall k: the projection of a random point onto the plane
    pts = rng.normal(size=(box.n_walls, dim))
    pts += (box.offsets - np.einsum("kd,kd->k", box.normals, pts))[:, None] * box.normals
    room = Room.from_planes(box.normals * scales[:, None], pts)
    np.testing.assert_allclose(room.normals, box.normals, rtol=0, atol=1e-15)
    np.testing.assert_allclose(room.offsets, box.offsets, rtol=0, atol=1e-12)


def test_room_copies_and_freezes_its_arrays():
    """Room keeps its own read-only copies: editing the caller's arrays does not change it."""
    normals = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    offsets = np.array([0.0, 2.0, 0.0, 3.0])
    room = Room(normals, offsets)
    normals[1] = [0.0, 1.0]
    offsets[:] = 7.0
    assert room == Room.shoebox([2.0, 3.0])
    with pytest.raises(ValueError, match="read-only"):
        room.offsets[0] = 1.0


# ---- image sources --------------------------------------------------------------------------------
def _check_against_brute_force(room: Room, source: np.ndarray) -> None:
    images = room.image_sources(source, order=3)
    walls, positions, valid = _brute_force_images(room, source, 3)
    assert isinstance(images, ImageSources)
    assert images.walls == tuple(walls)
    np.testing.assert_allclose(images.positions, positions, rtol=0, atol=IMAGE_ATOL)
    np.testing.assert_array_equal(images.orders, [len(w) for w in walls])
    np.testing.assert_array_equal(images.valid, valid)


@pytest.mark.parametrize(("dim", "n_walls"), ROOM_SHAPES)
def test_image_sources_of_random_rooms_match_brute_force(rng, dim, n_walls):
    """Images up to order 3 in random_convex_room rooms equal composed reflections (1e-9 m)."""
    room = random_convex_room(dim, n_walls, rng=rng)
    source = random_points_in_room(room, 1, margin=0.05, rng=rng)[0]
    _check_against_brute_force(room, source)


@pytest.mark.parametrize(("dim", "n_points"), CLOUD_SIZES)
def test_image_sources_of_point_cloud_hulls_match_brute_force(rng, dim, n_points):
    """Images up to order 3 in the hull of random points equal composed reflections (1e-9 m)."""
    cloud = rng.uniform(0.0, 5.0, size=(n_points, dim))
    room = Room.from_vertices(cloud)
    source = rng.dirichlet(np.ones(n_points)) @ cloud  # inside, even when the hull is a sliver
    _check_against_brute_force(room, source)


@pytest.mark.parametrize(("dim", "n_walls"), ROOM_SHAPES)
def test_image_source_counts_per_order(rng, dim, n_walls):
    """Order r contributes K (K-1)^(r-1) images; lower orders are a prefix of higher ones."""
    room = random_convex_room(dim, n_walls, rng=rng)
    src = room.interior_point
    k = room.n_walls
    full = room.image_sources(src, order=3)
    for r in (1, 2, 3):
        assert np.sum(full.orders == r) == k * (k - 1) ** (r - 1)
        part = room.image_sources(src, order=r)
        n = sum(k * (k - 1) ** (q - 1) for q in range(1, r + 1))
        assert len(part) == n
        assert part.walls == full.walls[:n]
        np.testing.assert_array_equal(part.positions, full.positions[:n])
    assert np.all(np.diff(full.orders) >= 0)
    assert all(a != b for w in full.walls for a, b in itertools.pairwise(w))


@pytest.mark.parametrize("dim", [2, 3])
def test_reflecting_an_image_back_gives_its_parent(rng, dim):
    """Mirroring each image across its last wall gives the image of the shorter sequence (or s)."""
    room = random_convex_room(dim, 2 * dim + 1, rng=rng)
    src = random_points_in_room(room, 1, margin=0.05, rng=rng)[0]
    images = room.image_sources(src, order=3)
    index = {w: j for j, w in enumerate(images.walls)}
    for j, w in enumerate(images.walls):
        last = w[-1]
        back = reflect(images.positions[j][None, :], room.normals[last], room.offsets[last])[0]
        parent = src if len(w) == 1 else images.positions[index[w[:-1]]]
        np.testing.assert_allclose(back, parent, rtol=0, atol=IMAGE_ATOL)


@pytest.mark.parametrize("dim", [2, 3])
def test_first_order_images_are_valid_and_outside(rng, dim):
    """Every first-order image is Borish-valid and lies beyond its wall, as far as the source is inside."""
    for room in _random_rooms(rng, dim):
        src = _random_inside(room, rng)
        images = room.image_sources(src, order=1)
        assert images.valid.all()
        dist_src = room.distance_to_walls(src[None, :])[0]
        dist_img = room.distance_to_walls(images.positions)[
            np.arange(room.n_walls), np.arange(room.n_walls)
        ]
        np.testing.assert_allclose(dist_img, -dist_src, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_shoebox_image_validity_up_to_order_three(rng, dim):
    """In a box all images of orders 1-2 are valid; of order 3 all but the duplicates (a, b, a).

    Borish's test rejects a sequence that reflects in wall a, then in a wall b perpendicular to a,
    then in a again: the parent lies beyond a, and the image coincides with the first-order image
    of b. So "every image of a box is valid" holds only for sequences without such a repeat.
    """
    room = Room.shoebox(rng.uniform(2.0, 6.0, size=dim))
    src = random_points_in_room(room, 1, margin=0.05, rng=rng)[0]
    images = room.image_sources(src, order=3)
    k = 2 * dim
    assert len(images) == k + k * (k - 1) + k * (k - 1) ** 2
    axis = [w // 2 for w in range(k)]  # walls 2i, 2i+1 are perpendicular to axis i
    for j, w in enumerate(images.walls):
        duplicate = len(w) == 3 and w[0] == w[2] and axis[w[1]] != axis[w[0]]
        assert images.valid[j] == (not duplicate), w
        if duplicate:
            first = images.positions[images.walls.index((w[1],))]
            np.testing.assert_allclose(images.positions[j], first, rtol=0, atol=IMAGE_ATOL)
    assert np.sum(~images.valid) == k * (k - 2)


def test_chamfered_square_has_an_invalid_second_order_image():
    """Reflecting in a chamfer then in the wall behind it gives an invalid image (parent beyond wall)."""
    # square [0, 4]^2 with the corner x + y > 6 cut off; walls: W, E, S, N, chamfer
    room = Room.from_planes(
        [[-1, 0], [1, 0], [0, -1], [0, 1], [1, 1]], [[0, 0], [4, 0], [0, 0], [0, 4], [3, 3]]
    )
    images = room.image_sources([1.0, 1.0], order=2)
    j = images.walls.index((4, 1))
    np.testing.assert_allclose(images.positions[images.walls.index((4,))], [5.0, 5.0], atol=1e-12)
    np.testing.assert_allclose(images.positions[j], [3.0, 5.0], atol=1e-12)
    assert not images.valid[j]
    assert images.valid[images.walls.index((0, 4))]


# ---- bad input ------------------------------------------------------------------------------------
_SQUARE_N = [[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]]


@pytest.mark.parametrize(
    ("normals", "offsets", "match"),
    [
        ([1.0, 0.0, 0.0], [0.0], r"normals must have shape \(K, d\).*got \(3,?\)"),
        (np.eye(4), np.zeros(4), r"normals must have shape \(K, d\).*got \(4, 4\)"),
        (_SQUARE_N, [0.0, 1.0, 0.0], r"offsets must have shape \(4,\); got \(3,?\)"),
        (_SQUARE_N, [0.0, np.inf, 0.0, 1.0], "must be finite"),
        ([[-1.0, np.nan], [1, 0], [0, -1], [0, 1]], [0.0, 1.0, 0.0, 1.0], "must be finite"),
        ([[-2.0, 0.0], [1, 0], [0, -1], [0, 1]], [0.0, 1.0, 0.0, 1.0], "unit vectors"),
    ],
)
def test_room_rejects_malformed_planes(normals, offsets, match):
    """Room() refuses wrong shapes, non-finite values and non-unit normals with InvalidInputError."""
    with pytest.raises(InvalidInputError, match=match):
        Room(normals, offsets)


_S3 = 3.0**-0.5
_S2 = 2.0**-0.5


@pytest.mark.parametrize(
    ("normals", "offsets", "match"),
    [
        # too few walls
        ([[-1, 0], [0, -1]], [0.0, 0.0], r"in 2-D needs at least 3 walls; got 2"),
        ([[-1, 0, 0], [0, -1, 0], [_S3, _S3, _S3]], [0.0, 0.0, 1.0], r"3-D needs at least 4 walls"),
        # unbounded: a half-strip in 2-D, a slab-like prism and an octant cut in 3-D
        ([[-1, 0], [1, 0], [0, -1]], [0.0, 1.0, 0.0], "must bound a finite room"),
        ([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 0, -1]], [0, 1, 0, 0], "must bound a finite room"),
        (
            [[-1, 0, 0], [0, -1, 0], [0, 0, -1], [-_S3, -_S3, -_S3]],
            [0.0, 0.0, 0.0, -1.0],
            "must bound a finite room",
        ),
        # empty interior: contradictory planes, and a flat (zero-width) room
        (_SQUARE_N, [-1.0, 0.0, 0.0, 1.0], "non-empty interior"),
        (_SQUARE_N, [0.0, 0.0, 0.0, 1.0], "non-empty interior"),
        # redundant planes: one that misses the room, one touching only a corner, a repeated one
        ([*_SQUARE_N, [1.0, 0.0]], [0.0, 1.0, 0.0, 1.0, 5.0], "plane 4 .* does not bound the room"),
        ([*_SQUARE_N, [_S2, _S2]], [0.0, 1.0, 0.0, 1.0, 2 * _S2], "plane 4 .* does not bound"),
        ([*_SQUARE_N, [1.0, 0.0]], [0.0, 1.0, 0.0, 1.0, 1.0], "planes 1 and 4 are the same plane"),
    ],
)
def test_room_rejects_degenerate_geometry(normals, offsets, match):
    """Room() refuses too few walls, unbounded or empty rooms and redundant planes."""
    with pytest.raises(DegenerateGeometryError, match=match):
        Room(np.array(normals, dtype=float), offsets)


@pytest.mark.parametrize(
    ("normals", "points", "match"),
    [
        ([1.0, 0.0], [0.0, 0.0], r"normals must have shape \(K, d\)"),
        (
            _SQUARE_N,
            np.zeros((3, 2)),
            r"points must have the shape of normals \(4, 2\); got \(3, 2\)",
        ),
        (_SQUARE_N, [[0, 0], [1, 0], [0, np.nan], [0, 1]], "must be finite"),
        ([[-1, 0], [0, 0], [0, -1], [0, 1]], np.zeros((4, 2)), "row 1 is zero"),
    ],
)
def test_from_planes_rejects_bad_input(normals, points, match):
    """from_planes refuses wrong shapes, non-finite values and zero normals."""
    with pytest.raises(InvalidInputError, match=match):
        Room.from_planes(normals, points)


@pytest.mark.parametrize(
    ("dims", "match"),
    [
        ([1.0], r"dims must have shape \(d,\).*got \(1,?\)"),
        ([[1.0, 2.0]], r"got \(1, 2\)"),
        ([1.0, 0.0], "finite and positive"),
        ([1.0, -2.0, 3.0], "finite and positive"),
        ([1.0, np.inf], "finite and positive"),
    ],
)
def test_shoebox_rejects_bad_dims(dims, match):
    """shoebox refuses dims of the wrong shape or with non-positive or infinite lengths."""
    with pytest.raises(InvalidInputError, match=match):
        Room.shoebox(dims)


def test_polygon_rejects_non_convex_and_collinear():
    """polygon refuses a non-convex outline (naming the inner corner) and collinear corners."""
    with pytest.raises(InvalidInputError, match=r"convex polygon; corners \[2\]"):
        Room.polygon([[0, 0], [2, 0], [1, 0.5], [2, 2], [0, 2]])
    with pytest.raises(DegenerateGeometryError, match="must not be collinear"):
        Room.polygon([[0, 0], [1, 1], [2, 2], [3, 3]])
    with pytest.raises(InvalidInputError, match=r"shape \(N, d\) with d = 2"):
        Room.polygon([[0, 0, 0], [1, 0, 0], [0, 1, 0]])


def test_from_vertices_rejects_flat_and_too_few_points():
    """from_vertices refuses coplanar points in 3-D and fewer than three points."""
    with pytest.raises(DegenerateGeometryError, match="non-empty interior"):
        Room.from_vertices([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.3, 0]])
    with pytest.raises(InvalidInputError, match="at least 3 points"):
        Room.from_vertices([[0, 0], [1, 1]])


@pytest.mark.parametrize("order", [0, -1, 1.5, "2", None])
def test_image_sources_rejects_bad_order(order):
    """image_sources refuses an order that is not an integer >= 1."""
    room = Room.shoebox([3.0, 4.0])
    with pytest.raises(InvalidInputError, match="order must be an integer >= 1"):
        room.image_sources([1.0, 1.0], order=order)


@pytest.mark.parametrize("dim", [2, 3])
def test_image_sources_rejects_bad_source(dim):
    """image_sources refuses a source outside the room, of the wrong dimension or non-finite."""
    room = Room.shoebox([3.0, 4.0, 2.5][:dim])
    outside = np.full(dim, 1.0)
    outside[1] = 4.5
    with pytest.raises(
        InvalidInputError, match=r"source must be inside the room.*0\.5 m outside wall 3"
    ):
        room.image_sources(outside)
    with pytest.raises(InvalidInputError, match=rf"source must have shape \({dim},\)"):
        room.image_sources(np.ones(dim + 1))
    with pytest.raises(InvalidInputError, match="source must be finite"):
        room.image_sources(np.full(dim, np.nan))


def test_contains_rejects_points_of_wrong_dimension():
    """contains() refuses points whose dimension differs from the room's."""
    with pytest.raises(InvalidInputError, match=r"points must have shape \(N, d\) with d = 2"):
        Room.shoebox([1.0, 1.0]).contains([[0.5, 0.5, 0.5]])


def test_wall_centroids_of_a_shoebox():
    """The centroid of each shoebox wall is the centre of that face."""
    room = Room.shoebox([4.0, 3.0, 2.0])
    expected = [[0, 1.5, 1], [4, 1.5, 1], [2, 0, 1], [2, 3, 1], [2, 1.5, 0], [2, 1.5, 2]]
    np.testing.assert_allclose(room.wall_centroids, expected, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_wall_centroids_lie_on_their_walls(rng, dim):
    """In random convex rooms every wall centroid is on its own plane and inside the closed room."""
    room = random_convex_room(dim, dim + 4, rng=rng)
    c = room.wall_centroids
    np.testing.assert_allclose(np.einsum("kd,kd->k", room.normals, c), room.offsets, atol=1e-9)
    assert room.contains(c, margin=-1e-9).all()


def test_image_sources_refuse_boolean_order():
    """order=True is a bool, not an order."""
    with pytest.raises(InvalidInputError, match="order must be an integer"):
        Room.shoebox([4.0, 3.0, 2.0]).image_sources([1.0, 1.0, 1.0], order=True)


@pytest.mark.parametrize(
    ("normals", "points", "match"),
    [
        ([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]], [[10**400, 0], [0, 1], [0, 0]], "points must be"),
        ([["1", 0.0], [0.0, 1.0], [-1.0, -1.0]], [[1.0, 0], [0, 1], [0, 0]], "normals must be"),
        ([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]], [[1.0, 0], [0, 1j], [0, 0]], "not complex"),
        ([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]], [[1e13, 0], [0, 1], [0, 0]], "magnitude"),
    ],
)
def test_room_from_planes_refuses_hostile_values(normals, points, match):
    """The fuzz found OverflowError and ValueError from numpy here (big integers, strings)."""
    with pytest.raises(InvalidInputError, match=match):
        Room.from_planes(normals, points)
