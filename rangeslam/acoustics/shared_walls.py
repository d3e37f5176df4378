"""Walls that several loudspeakers hear, each at too few microphones to label it alone.

:func:`~rangeslam.acoustics.labelling.label_echoes` accepts an image source when ``min_mics``
microphones (at least five: four fit any point) agree on it. A small wall (the cut corner of
``rangeslam simulate room --room cut-corner``: 1.1 m wide) reflects a loudspeaker towards only
the microphones whose specular point falls on it; the others do not hear that echo at all (the
image is not visible from them), and a visible echo merged with another arrival is not timed
cleanly. So each loudspeaker may hear the wall cleanly at four microphones or fewer, and the
wall is missed although the data show it.

A wall is three unknowns; every loudspeaker's image in it is then known (its reflection in the
plane, section 2 of the paper), so the echoes of all loudspeakers check one wall jointly.
:func:`shared_walls` searches the echo peaks that no labelled image source took:

1. Hypotheses: image points of loudspeaker j trilaterated from one free peak at each of three
   microphones (:func:`~rangeslam.acoustics.label_search.hypotheses`; every triple of
   microphones when there are few, since a small wall may be heard at close microphones only),
   beyond the source from every microphone.
2. Each hypothesis is a wall, the bisector of loudspeaker j and the point. It must leave every
   microphone and loudspeaker inside and cut the room found so far (the other walls) by more
   than ``min_cut`` (else it is a known wall). An echo supports it when loudspeaker k's image
   in the wall predicts a free peak within k's fit tolerance and the specular point (where the
   path from the image to the microphone crosses the wall) lies on the wall's face: inside the
   room found so far. Hypotheses with a fourth echo are kept.
3. Accepted, most checked first: a wall fitted jointly to its echoes by least squares (echoes
   collected again until stable) that keeps ``JOINT_WALL_RANGES`` echoes, ``JOINT_WALL_CHECKS``
   of them from loudspeakers other than the one with most (whose echoes alone fix a point), and
   whose image of that loudspeaker is not one of its images of order 2 or 3 in the walls found
   (those echoes are explained without a new wall), and that the echoes it predicts do not deny
   (``WALL_CONTRADICTED_MISSING`` of them absent, more than present, as a wall one loudspeaker
   labelled is checked in :mod:`rangeslam.acoustics.joint_room`). Its peaks are then taken and
   the room cut by it; the search is repeated while it adds a wall.

What is left unexplained is reported: the echo sets (up to three walls, best checked first) that
fit one admissible wall, not denied, with five echoes or more (two more than its unknowns) but
are not accepted (see :class:`SharedWalls`).
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from rangeslam._robust import MAD_TO_STD
from rangeslam.acoustics.echoes import EchoDetection
from rangeslam.acoustics.label_search import Peaks, Triples, batch_refine, hypotheses
from rangeslam.acoustics.labelling import EchoLabelling
from rangeslam.geometry.room import Room
from rangeslam.verdict.thresholds import (
    JOINT_WALL_CHECKS,
    JOINT_WALL_RANGES,
    WALL_CONTRADICTED_MISSING,
)

logger = logging.getLogger(__name__)

__all__ = [
    "WALL_MATCH_DEGREES",
    "WALL_MATCH_METRES",
    "SharedWall",
    "SharedWalls",
    "bisector_planes",
    "denied",
    "is_higher_order_image",
    "predicted_echoes",
    "predicted_present",
    "shared_walls",
]

#: Two walls are one wall when their outward normals are within this many degrees and their
#: offsets within WALL_MATCH_METRES (:func:`rangeslam.acoustics.joint_room.match_walls`, and the
#: notes here). A labelled wall is within a degree and a centimetre on simulated RIRs
#: (tests/test_run_sessions.py); distinct walls of a room differ by far more.
WALL_MATCH_DEGREES = 10.0
WALL_MATCH_METRES = 0.15

# Microphone triples tried per loudspeaker: all of them up to 16 microphones (C(16, 3) = 560);
# and peak triples per microphone triple.
_TRIPLES = 560
_MAX_HYPOTHESES = 20_000
# Walls added at most (each search pass adds one).
_MAX_WALLS = 3
# Notes on echo sets left unexplained, at most; two sets whose walls match are one.
_NOTES = 3
_SAME_COS = math.cos(math.radians(WALL_MATCH_DEGREES))
# Reflections of the walls found that may explain an echo set (as label_echoes, step 4).
_ORDER = 3
# Candidates refitted at most in a pass (the best first).
_MAX_TRIALS = 50
# Re-fits of a wall (fit, collect its echoes again).
_REFITS = 4
# Echoes of one loudspeaker that fix a point (3-D trilateration, two mirror solutions): a
# hypothesis; and the fewest echoes a refitted wall keeps.
_TRIPLE = 3
_POINT_MICS = 4
# Hypotheses scored at once (memory: (N, J, M, 3) specular points).
_CHUNK = 20_000


@dataclass(frozen=True)
class SharedWall:
    """A wall found jointly. J loudspeakers, M microphones.

    Attributes:
        normal: (3,) outward unit normal. offset: metres (the wall is ``normal . x = offset``).
        ranges: (J, M) metres: loudspeaker j's echo of the wall at microphone m; NaN where none.
        peaks: (J, M) index of that echo in the detection's peaks; -1 where none.
    """

    normal: np.ndarray
    offset: float
    ranges: np.ndarray
    peaks: np.ndarray

    @property
    def support(self) -> np.ndarray:
        """(J,) echoes of each loudspeaker."""
        return (self.peaks >= 0).sum(axis=1)


@dataclass(frozen=True)
class SharedWalls:
    """Result of :func:`shared_walls`.

    Attributes:
        walls: the walls found jointly (none when the labelled ones explain the echoes).
        unexplained: notes on echo sets left unexplained: at least five echoes (two more than
            a wall's unknowns) fit one admissible wall, but fewer than ``JOINT_WALL_RANGES`` in
            all or fewer than ``JOINT_WALL_CHECKS`` from loudspeakers other than the one with
            most.
    """

    walls: tuple[SharedWall, ...]
    unexplained: tuple[str, ...]


@dataclass(frozen=True)
class _Scene:
    """What the search knows: microphones, loudspeakers, free peaks, the room so far."""

    pts: np.ndarray  # (M, 3)
    sources: np.ndarray  # (J, 3)
    peaks: list  # J Peaks: the echo peaks no labelled point took
    fit_tol: np.ndarray  # (J,) metres
    sigma: np.ndarray  # (J,) metres: the robust spread of the direct paths
    tol: np.ndarray  # (J,) metres: the labellings' tolerances
    heard: np.ndarray  # (J, M) bool: the labelling heard an echo of a wall there
    room: Room  # the room of the walls found so far
    verts: np.ndarray  # its vertices
    min_cut: float  # metres: a new wall cuts the room by more


def _free_peaks(
    lab: EchoLabelling, dets: Sequence[EchoDetection], pts, c: float, freed: Sequence[int] = ()
) -> Peaks:
    """Loudspeaker ``lab``'s echo peaks that its labelling did not give to the direct path or an
    image source (first or higher order), at or after the direct path; the peaks of its columns
    ``freed`` (walls left out) count as free."""
    d_src = np.linalg.norm(pts - lab.source, axis=1)
    ranges = [np.asarray(det.times, dtype=float) * c for det in dets]
    usable = []
    for m, taken in enumerate(_taken(lab, pts, ranges, freed)):
        u = ranges[m] >= d_src[m] - lab.tolerance
        u[taken] = False
        usable.append(u)
    return Peaks(ranges, usable)


def _taken(lab: EchoLabelling, pts, ranges, freed: Sequence[int] = ()) -> list[list[int]]:
    """Per microphone, the peaks (of ``ranges``, M lists, metres) of the labelling's columns (but
    ``freed``) and of its higher-order points (the peak nearest each point's predicted range,
    within the fit tolerance)."""
    keep = np.setdiff1d(np.arange(lab.peaks.shape[1]), np.asarray(freed, dtype=int))
    out = [[int(p) for p in lab.peaks[m, keep] if p >= 0] for m in range(len(pts))]
    for x in lab.higher_order:
        pred = np.linalg.norm(pts - x, axis=1)
        for m, r in enumerate(ranges):
            if len(r):
                e = np.abs(r - pred[m])
                if e.min() <= lab.fit_tolerance:
                    out[m].append(int(np.argmin(e)))
    return out


def _spread(lab: EchoLabelling) -> float:
    """The robust spread of the direct paths' residuals (floored at a quarter of the fit
    tolerance), as the labelling took it."""
    res = lab.residuals[:, 0][lab.mask[:, 0]]
    dof = max(len(res) - 3, 1)
    sigma = MAD_TO_STD * float(np.median(np.abs(res))) * np.sqrt(len(res) / dof) if len(res) else 0
    return max(float(sigma), lab.fit_tolerance / 4.0)


def bisector_planes(x: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) unit normals and (N,) offsets of the bisectors of ``s`` (3,) and points x (N, 3)."""
    n = x - s
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return n, np.einsum("nd,nd->n", n, (x + s) / 2.0)


def _admissible(scene: _Scene, n: np.ndarray, o: np.ndarray) -> np.ndarray:
    """(N,) True for planes with every microphone and loudspeaker inside that cut the room found
    so far by more than ``min_cut`` (a plane that does not is a known wall, or none)."""
    inside = np.all(np.concatenate([scene.pts, scene.sources]) @ n.T < o, axis=0)
    depth = (scene.verts @ n.T - o).max(axis=0)
    return inside & (depth > scene.min_cut)


def _support(scene: _Scene, n: np.ndarray, o: np.ndarray):
    """Echoes of the walls (n (N, 3), o (N,)): (N, J, M) peak index (-1: none) and |range
    error| of each loudspeaker's image at each microphone. An echo counts when a free peak is
    within the fit tolerance and its specular point is on the wall's face (inside the room so
    far, within the labelling's tolerance)."""
    pts, room = scene.pts, scene.room
    n_n, j_n, m_n = len(n), len(scene.sources), len(pts)
    idx = np.full((n_n, j_n, m_n), -1)
    err = np.full((n_n, j_n, m_n), np.inf)
    for j, s in enumerate(scene.sources):
        y = s - 2.0 * (n @ s - o)[:, None] * n  # (N, 3) the image of s in each wall
        diff = y[:, None, :] - pts[None]  # (N, M, 3)
        dist = np.linalg.norm(diff, axis=2)
        # admissible walls have every microphone inside and the image outside: n . diff > 0
        t = (o[:, None] - np.einsum("nd,md->nm", n, pts)) / np.einsum("nd,nmd->nm", n, diff)
        q = pts[None] + t[..., None] * diff  # specular points
        face = np.all(q @ room.normals.T <= room.offsets + scene.tol[j], axis=2)
        i, e = scene.peaks[j].nearest(dist)
        hit = (e <= scene.fit_tol[j]) & face & (t > 0) & (t < 1)
        idx[:, j] = np.where(hit, i, -1)
        err[:, j] = np.where(hit, e, np.inf)
    return idx, err


def _triples(pts: np.ndarray, usable: np.ndarray, rng) -> list[np.ndarray]:
    """Every triple of usable microphones when there are at most _TRIPLES (a small wall may be
    heard at four close microphones only, whose triangles are small), else _TRIPLES of those
    with large triangles (:class:`~rangeslam.acoustics.label_search.Triples`)."""
    idx = np.flatnonzero(usable).tolist()
    if math.comb(len(idx), 3) <= _TRIPLES:
        return [np.array(t) for t in itertools.combinations(idx, 3)]
    return Triples(pts, usable, rng).next(_TRIPLES)


def _hypotheses(scene: _Scene, j: int, rng) -> np.ndarray:
    """Step 1: points (N, 3) of loudspeaker j trilaterated from a free peak at each of three of
    its microphones, beyond its source from every microphone, moved onto their peaks."""
    pts, peaks = scene.pts, scene.peaks[j]
    usable = np.array([len(r) > 0 for r, _ in peaks.lists])
    if usable.sum() < _TRIPLE:
        return np.empty((0, 3))
    cap = 3.0 * scene.tol[j]
    xs, gates = [np.empty((0, 3))], [np.empty((0, len(pts)))]
    for trip in _triples(pts, usable, rng):
        x, g = hypotheses(
            pts, trip, peaks.lists, peaks, scene.sigma[j], scene.fit_tol[j], cap, _TRIPLE,
            _MAX_HYPOTHESES, rng,
        )  # fmt: skip
        xs.append(x)
        gates.append(g)
    x, g = np.vstack(xs), np.vstack(gates)
    d_src = np.linalg.norm(pts - scene.sources[j], axis=1)
    ok = np.all(np.linalg.norm(x[:, None, :] - pts[None], axis=2) >= d_src - scene.tol[j], axis=1)
    return batch_refine(x[ok], pts, peaks, (g[ok], scene.fit_tol[j]))


def _fit_wall(scene: _Scene, j: int, x0: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The image of loudspeaker j (3,) whose wall fits the echoes ``idx`` (J, M) of every
    loudspeaker in least squares (each loudspeaker's image the reflection in that wall)."""
    sel = np.argwhere(idx >= 0)
    r = np.array([scene.peaks[k].ranges[m][idx[k, m]] for k, m in sel])
    s = scene.sources[sel[:, 0]]
    mics = scene.pts[sel[:, 1]]

    def residuals(x):
        n, o = bisector_planes(x[None], scene.sources[j])
        y = s - 2.0 * (s @ n[0] - o[0])[:, None] * n[0]
        return np.linalg.norm(y - mics, axis=1) - r

    return least_squares(residuals, x0, method="lm").x


def _refine(scene: _Scene, j: int, x0: np.ndarray):
    """Fit the wall of loudspeaker j's point x0 to the echoes it collects, again until they are
    stable. Returns (normal, offset, (J, M) peaks, (J, M) errors) or None when it leaves the
    admissible walls or keeps fewer than four echoes."""
    x, seen = np.asarray(x0, dtype=float), None
    for _ in range(_REFITS):
        n, o = bisector_planes(x[None], scene.sources[j])
        if not _admissible(scene, n, o)[0]:
            return None
        idx, err = _support(scene, n, o)
        if (idx[0] >= 0).sum() < _POINT_MICS:
            return None
        if seen is not None and np.array_equal(seen, idx[0]):
            break
        seen = idx[0]
        x = _fit_wall(scene, j, x, idx[0])
    return n[0], float(o[0]), idx[0], err[0]


def _checks(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(echoes, checks) of walls' (..., J, M) peaks: checks are the echoes of loudspeakers other
    than the one with most (whose echoes alone fix a point)."""
    per = (idx >= 0).sum(axis=-1)
    return per.sum(axis=-1), per.sum(axis=-1) - per.max(axis=-1)


def _candidates(scene: _Scene, rng) -> list[tuple[int, np.ndarray, int, int]]:
    """Steps 1-2: (loudspeaker, point, echoes, checks) of the admissible hypotheses whose own
    three echoes hold with at least one more echo (of any loudspeaker), most checks first, then
    most echoes."""
    out = []
    for j, s in enumerate(scene.sources):
        x_all = _hypotheses(scene, j, rng)
        for start in range(0, len(x_all), _CHUNK):
            x = x_all[start : start + _CHUNK]
            n, o = bisector_planes(x, s)
            ok = _admissible(scene, n, o)
            x, n, o = x[ok], n[ok], o[ok]
            idx, _ = _support(scene, n, o)
            own = (idx[:, j] >= 0).sum(axis=1) >= _TRIPLE
            total, checks = _checks(idx)
            keep = np.flatnonzero(own & (total >= _POINT_MICS))
            out += [(j, x[h], int(total[h]), int(checks[h])) for h in keep]
    out.sort(key=lambda c: (-c[3], -c[2]))
    return out


def _higher_order(scene: _Scene, n: np.ndarray, o: float, idx: np.ndarray) -> bool:
    """True when the image, in the wall (n, o), of the loudspeaker with most echoes ``idx``
    (J, M) is one of its images of order 2 or 3 in the walls found (within 3 tolerances): its
    echoes are then explained without a new wall (as step 4 of label_echoes tells them)."""
    k = int(np.argmax((idx >= 0).sum(axis=1)))
    s = scene.sources[k]
    return is_higher_order_image(scene.room, s, s - 2.0 * (n @ s - o) * n, scene.tol[k])


def is_higher_order_image(room: Room, source: np.ndarray, point: np.ndarray, tol: float) -> bool:
    """True when ``point`` (3,) is within 3 ``tol`` of an image of ``source`` of order 2 or 3 in
    ``room``'s walls (an echo a first-order image would take, explained without a new wall)."""
    images = room.image_sources(np.asarray(source, dtype=float), order=_ORDER)
    far = images.positions[images.orders >= 2]
    return bool(len(far) and np.linalg.norm(far - point, axis=1).min() <= 3.0 * tol)


def predicted_echoes(
    room: Room, mics: np.ndarray, source: np.ndarray, normal: np.ndarray, offset: float, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Where the wall (``normal``, ``offset``) predicts an echo of ``source`` (3,) at ``mics``
    (M, 3): (M,) True where the specular point (where the path from the source's image to the
    microphone crosses the wall) lies on the wall's face (``room`` holds it, within ``tol``),
    and (M,) the predicted ranges, metres."""
    diff = source - 2.0 * (normal @ source - offset) * normal - mics  # image minus microphones
    t = (offset - mics @ normal) / (diff @ normal)
    q = mics + t[:, None] * diff
    face = np.all(q @ room.normals.T <= room.offsets + tol, axis=1)
    return face & (t > 0) & (t < 1), np.linalg.norm(diff, axis=1)


def predicted_present(
    ranges: Sequence[np.ndarray], pred: np.ndarray, where: np.ndarray, tol: float, known=None
) -> tuple[int, int]:
    """(tested, present): of the microphones ``where`` (M,) bool whose predicted range ``pred``
    (M,) is within the span of their detected ``ranges`` (M lists), those with a peak within
    ``tol`` of it (or ``known`` (M,) bool: an echo already taken for it)."""
    tested = present = 0
    for m in np.flatnonzero(where):
        r = ranges[m]
        if not len(r) or pred[m] > r.max() + tol:
            continue
        tested += 1
        present += int((known is not None and known[m]) or np.abs(r - pred[m]).min() <= tol)
    return tested, present


def denied(tested, present):
    """True where predicted echoes deny a wall: at least ``WALL_CONTRADICTED_MISSING`` of the
    ``tested`` absent, more than are ``present`` (scalars or arrays)."""
    missing = np.asarray(tested) - present
    return (missing >= WALL_CONTRADICTED_MISSING) & (present < missing)


def _contradicted(scene: _Scene, n: np.ndarray, o: float, idx: np.ndarray) -> bool:
    """True when the echoes that the wall (n, o) predicts deny it (as
    :func:`rangeslam.acoustics.joint_room.room_from_loudspeakers` checks a wall one loudspeaker
    labelled): at microphones whose specular point lies on its face (the room found so far holds
    it, within the labelling's tolerance), where the loudspeaker heard a wall (its labelling or
    ``idx`` (J, M)) and the predicted range is within the span of the peaks, at least
    ``WALL_CONTRADICTED_MISSING`` have no detected peak (free or taken) within the labelling's
    tolerance, more than have one (:func:`predicted_echoes`, :func:`predicted_present`)."""
    tested = present = 0
    for k, s in enumerate(scene.sources):
        on_face, pred = predicted_echoes(scene.room, scene.pts, s, n, o, scene.tol[k])
        heard = scene.heard[k] | (idx[k] >= 0)
        t_k, p_k = predicted_present(
            scene.peaks[k].ranges, pred, on_face & heard, scene.tol[k], known=idx[k] >= 0
        )
        tested += t_k
        present += p_k
    logger.debug(
        "wall %s %.3f: %d predicted echoes present, %d absent",
        np.round(n, 3).tolist(), o, present, tested - present,
    )  # fmt: skip
    return bool(denied(tested, present))


def _search(scene: _Scene, rng) -> tuple[SharedWall | None, list[str]]:
    """Step 3, one pass: the first candidate that keeps JOINT_WALL_RANGES echoes with
    JOINT_WALL_CHECKS checks after its fit and is no higher-order image; else None. Also notes on
    up to _NOTES walls of five echoes or more left unexplained, best checked first."""
    notes: list[str] = []
    seen: list[tuple[np.ndarray, float]] = []
    for j, x, _, _ in _candidates(scene, rng)[:_MAX_TRIALS]:
        fit = _refine(scene, j, x)
        if fit is None:
            continue
        n, o, idx, _ = fit
        total, checks = (int(v) for v in _checks(idx))
        if total <= _POINT_MICS or _higher_order(scene, n, o, idx):
            continue
        if _contradicted(scene, n, o, idx):
            continue
        if total >= JOINT_WALL_RANGES and checks >= JOINT_WALL_CHECKS:
            r = np.full(idx.shape, np.nan)
            for k, m in np.argwhere(idx >= 0):
                r[k, m] = scene.peaks[k].ranges[m][idx[k, m]]
            return SharedWall(normal=n, offset=o, ranges=r, peaks=idx), notes
        new = all(n @ n2 < _SAME_COS or abs(o - o2) > WALL_MATCH_METRES for n2, o2 in seen)
        if new and len(notes) < _NOTES:
            seen.append((n, o))
            notes.append(_note(n, o, idx, total, checks))
    return None, notes


def _note(n: np.ndarray, o: float, idx: np.ndarray, total: int, checks: int) -> str:
    """The note on an echo set left unexplained: who heard it where, its wall, its counts."""
    heard = "; ".join(
        f"loudspeaker {k} at microphones {np.flatnonzero(row >= 0).tolist()}"
        for k, row in enumerate(idx)
        if (row >= 0).any()
    )
    return (
        f"echoes left unexplained: {heard} fit one wall (normal {np.round(n, 2).tolist()}, offset "
        f"{o:.3f} m) that cuts the room found: {total} echoes ({JOINT_WALL_RANGES} needed), "
        f"{checks} of them from loudspeakers other than the one with most ({JOINT_WALL_CHECKS} "
        "needed)"
    )


def shared_walls(
    labellings: Sequence[EchoLabelling],
    detections: Sequence[Sequence[EchoDetection]],
    mics: np.ndarray,
    room: Room,
    *,
    c: float,
    min_cut: float,
    rng: np.random.Generator,
    freed: Sequence[Sequence[int]] | None = None,
) -> SharedWalls:
    """Walls that the J loudspeakers' free echoes show jointly (module docstring).

    Args:
        labellings: J labellings, each with its source located.
        detections: J lists of M detections (the labellings' input).
        mics: (M, 3) metres. room: the room of the walls found so far. c: m/s.
        min_cut: metres; a new wall cuts ``room`` deeper than this (a plane within it of the
            room's vertices would be one of its walls). rng: Generator.
        freed: for each labelling, its columns (1..) whose peaks are free (walls left out as
            contradicted); default none.

    Returns:
        A :class:`SharedWalls`: walls with their echoes, and notes on echoes left unexplained.
    """
    pts = np.asarray(mics, dtype=float)
    scene = _Scene(
        pts=pts,
        sources=np.array([lab.source for lab in labellings], dtype=float),
        peaks=[
            _free_peaks(lab, d, pts, c, f)
            for lab, d, f in zip(
                labellings, detections, freed or [()] * len(labellings), strict=True
            )
        ],
        fit_tol=np.array([lab.fit_tolerance for lab in labellings]),
        sigma=np.array([_spread(lab) for lab in labellings]),
        tol=np.array([lab.tolerance for lab in labellings]),
        heard=np.array([lab.mask[:, 1:].any(axis=1) for lab in labellings], dtype=bool),
        room=room,
        verts=room.vertices,
        min_cut=float(min_cut),
    )
    walls: list[SharedWall] = []
    notes: list[str] = []
    for _ in range(_MAX_WALLS):
        wall, notes = _search(scene, rng)
        if wall is None:
            break
        walls.append(wall)
        scene = _with_wall(scene, wall)
        if scene is None:
            break
    return SharedWalls(walls=tuple(walls), unexplained=tuple(notes))


def _with_wall(scene: _Scene, wall: SharedWall) -> _Scene | None:
    """The scene with ``wall``'s echoes taken and the room cut by it (None when the cut room is
    degenerate)."""
    peaks = []
    for k, p in enumerate(scene.peaks):
        usable = []
        for m, r in enumerate(p.ranges):
            u = np.zeros(len(r), dtype=bool)
            u[p.lists[m][1]] = True
            if wall.peaks[k, m] >= 0:
                u[wall.peaks[k, m]] = False
            usable.append(u)
        peaks.append(Peaks(p.ranges, usable))
    try:
        room = Room(
            np.vstack([scene.room.normals, wall.normal]),
            np.append(scene.room.offsets, wall.offset),
        )
    except ValueError:
        return None
    return replace(scene, peaks=peaks, room=room, verts=room.vertices)
