"""Echo labelling, steps 4 and 6: first-order or higher-order images, and the audit of columns.

Which points found by :mod:`rangeslam.acoustics.label_search` are first-order image sources
(:func:`classify`), which echo columns a wall not found explains as well (:func:`ambiguous`), and
how well a column's echoes fix its wall's normal (:func:`normal_std`).
Internal to :mod:`rangeslam.acoustics`: nothing here is exported.
"""

from __future__ import annotations

import math

import numpy as np

from rangeslam.acoustics.label_search import Peaks
from rangeslam.geometry.room import reflect

__all__: list[str] = []

# A point is higher-order when its echoes fit (RMS) a reflection of the source in the walls found so
# far within this many tolerances.
_EXPLAIN = 3.0
# Reflections up to this order explain higher-order echoes.
_CLOSURE_ORDER = 3
# Points found that a swap of walls must explain and the walls in use do not, to count (see
# ambiguous): with fewer, nothing tells the two apart.
_MIN_EVIDENCE = 2


# ---- first-order or higher-order --------------------------------------------------------------


def _closure(source: np.ndarray, walls, order: int) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """Images of ``source`` (3,) in the walls [(normal, offset)] up to ``order`` reflections:
    (P, 3) positions and the wall sequences."""
    pts: list[np.ndarray] = []
    seqs: list[tuple[int, ...]] = []
    front = [(source, ())]
    for _ in range(order):
        new = []
        for p, seq in front:
            for k, (normal, offset) in enumerate(walls):
                if not seq or seq[-1] != k:
                    new.append((reflect(p[None], normal, offset)[0], (*seq, k)))
        pts.extend(q for q, _ in new)
        seqs.extend(w for _, w in new)
        front = new
    return np.array(pts).reshape(-1, 3), seqs


def wall_of(x, source) -> tuple[np.ndarray, float]:
    """The bisector plane of ``source`` and its image ``x``: (outward unit normal, offset)."""
    normal = (x - source) / np.linalg.norm(x - source)
    return normal, float(normal @ (x + source) / 2)


def _reflection_points(x, picks, source, mics) -> np.ndarray:
    """(P, 3) points where the echoes of image ``x`` meet its wall, for the picked microphones:
    where the segment from each microphone to ``x`` crosses the bisector of x and the source."""
    normal, offset = wall_of(x, source)
    m = mics[picks >= 0]
    t = (offset - m @ normal) / ((x - m) @ normal)
    return m + t[:, None] * (x - m)


def _beyond(points, wall, margin) -> bool:
    """Whether most of ``points`` (P, 3) lie beyond ``wall`` (normal, offset) by over ``margin``."""
    normal, offset = wall
    return bool(np.mean(points @ normal > offset + margin) > 0.5)


def classify(found, source, mics, peaks: Peaks, tol, n_images) -> list[bool]:
    """Which points are first-order image sources (True) rather than higher-order or unconfirmed.

    Nearest to the source first, a point is explained when its echoes fit (RMS within _EXPLAIN
    ``tol``) a reflection of the source in the walls kept so far, up to _CLOSURE_ORDER
    reflections. Otherwise its bisector with the source is a candidate wall, kept unless it
    contradicts a kept wall: in a convex room every echo of a wall is reflected at a point inside
    all the other walls, so the echoes of one of the two would have to be reflected beyond the other
    (a higher-order image of walls not all found yet, or a chance alignment, does that). Of two
    contradicting walls, one confirmed by the higher-order points it explains stays, else the one
    with more echoes. Confirmed walls come first, then the others, nearest first, up to
    ``n_images`` (None: the confirmed ones, or all if none is confirmed).
    """
    kept: list[int] = []  # indices into found, in the order kept
    walls: dict[int, tuple[np.ndarray, float]] = {}
    refl: dict[int, np.ndarray] = {}
    children: dict[int, int] = {}
    closure, seqs = np.empty((0, 3)), []
    margin = _EXPLAIN * tol
    support = [int((p >= 0).sum()) for _, p in found]
    for h, (x, picks) in enumerate(found):
        sel = picks >= 0
        if len(closure):
            pred = np.linalg.norm(closure[:, None, :] - mics[None, sel], axis=2)
            rms = np.sqrt(np.mean((pred - peaks.picked(picks)[sel]) ** 2, axis=1))
            best = int(np.argmin(rms))
            if rms[best] <= _EXPLAIN * tol:
                for k in {kept[i] for i in seqs[best]}:
                    children[k] += 1
                continue
        wall = wall_of(x, source)
        pts_h = _reflection_points(x, picks, source, mics)
        clash = [
            k for k in kept if _beyond(pts_h, walls[k], margin) or _beyond(refl[k], wall, margin)
        ]
        # a confirmed wall stays; an unconfirmed one gives way to a better-supported candidate
        if any(children[k] > 0 or support[k] >= support[h] for k in clash):
            continue
        kept = [k for k in kept if k not in clash]
        kept.append(h)
        walls[h], refl[h], children[h] = wall, pts_h, 0
        closure, seqs = _closure(source, [walls[k] for k in kept], _CLOSURE_ORDER)
    confirmed = [k for k in kept if children[k] > 0]
    others = [k for k in kept if children[k] == 0]
    if n_images is None:
        chosen = confirmed if confirmed else others
    else:
        chosen = (confirmed + others)[:n_images]
    cols = set(chosen)
    return [h in cols for h in range(len(found))]


def _images_upto(source: np.ndarray, walls, order: int) -> np.ndarray:
    """(P, 3) images of ``source`` (3,) in ``walls`` [(normal, offset)], 1 to ``order``
    reflections (no wall twice in a row): the points of :func:`_closure`, vectorised."""
    if not walls:
        return np.empty((0, 3))
    normals = np.array([n for n, _ in walls])
    offsets = np.array([o for _, o in walls])
    front, last, out = source[None].astype(float), np.array([-1]), []
    for _ in range(order):
        # (F, K, 3): every front point reflected in every wall; drop the wall it was last in
        new = front[:, None] + 2.0 * (offsets - front @ normals.T)[..., None] * normals[None]
        keep = last[:, None] != np.arange(len(walls))[None]
        front, last = new[keep], np.broadcast_to(np.arange(len(walls)), keep.shape)[keep]
        out.append(front)
    return np.vstack(out)


def _explained(meas: np.ndarray, walls, source, mics, tol) -> np.ndarray:
    """(H,) whether each point whose echoes are ``meas`` (H, M) metres (NaN: none) fits (RMS within
    _EXPLAIN ``tol``) an image of ``source`` in ``walls``, up to _CLOSURE_ORDER reflections."""
    closure = _images_upto(source, walls, _CLOSURE_ORDER)
    if not len(meas) or not len(closure):
        return np.zeros(len(meas), dtype=bool)
    pred = np.linalg.norm(closure[:, None, :] - mics[None], axis=2)  # (P, M)
    seen = ~np.isnan(meas)
    sq = np.where(seen[:, None, :], (pred[None] - np.nan_to_num(meas)[:, None]) ** 2, 0.0)
    rms = np.sqrt(sq.sum(axis=2) / np.maximum(seen.sum(axis=1), 1)[:, None])
    return rms.min(axis=1) <= _EXPLAIN * tol


def ambiguous(found, is_col, source, mics, peaks: Peaks, tol, d_src) -> dict:
    """Echo columns that may be higher-order images: {column: image of the wall not found that
    explains them, or None for an image of the other walls}.

    The image x_k of column k may be a second-order image of the wall of another column b and of
    a wall not found, whose image y (farther from every microphone than the source, as an image
    is) was missed, its echoes heard cleanly at too few microphones: y = R_b(x_k) (y's wall, then
    b) or y = R_w(source) with w the bisector of x_k and b's image x_b (b, then y's wall). Then the
    walls with y's in place of k's explain the data as well. Each set of walls predicts the points
    found (its images up to _CLOSURE_ORDER reflections); the swap that explains the most of them,
    if at least as many as the walls in use and at least _MIN_EVIDENCE that these do not, marks
    column k ambiguous, and y's wall replaces k's for the next swap; a column then explained by
    the other walls (an image of them up to _CLOSURE_ORDER reflections, within ``tol``; of
    several, the farthest from the source) is left out too; until nothing changes.
    Measured on shoebox rooms (tests/test_echo_labelling.py, 16 and 48 kHz): the best swap of a
    right column explains 2 to 14 points fewer, that of a wrong one 0 to 15 more.
    """
    meas = np.array([peaks.picked(p) for _, p in found])
    walls = {h: wall_of(found[h][0], source) for h, col in enumerate(is_col) if col}
    out: dict[int, np.ndarray | None] = {}
    while sum(h not in out for h in walls) > 1:
        # once walls were swapped in, a column that is their image is not a wall: fitting (RMS)
        # within tol / _EXPLAIN, not by chance (the closure is dense in the ranges of a compact array)
        echo = [
            k
            for k in walls
            if out
            and k not in out
            and _explained(
                meas[k : k + 1],
                [w for h, w in walls.items() if h != k],
                source,
                mics,
                tol / _EXPLAIN,
            )[0]
        ]
        if echo:  # the farthest: of two images of each other, the higher-order one
            k = max(echo, key=lambda h: float(np.linalg.norm(found[h][0] - source)))
            out[k] = None
            del walls[k]
            continue
        base = _explained(meas, list(walls.values()), source, mics, tol)
        best = (-1, -1, None)
        for k in walls:
            if k in out:
                continue
            rest = [w for h, w in walls.items() if h != k]
            ys = []
            for b in walls:
                if b == k or b in out:
                    continue
                x_b = reflect(source[None], *walls[b])[0]
                ys.append(reflect(found[k][0][None], *walls[b])[0])  # x_k = R_b(y): y, then b
                ys.append(reflect(source[None], *wall_of(found[k][0], x_b))[0])  # b, then y
            for y in ys:
                if np.any(np.linalg.norm(mics - y, axis=1) < d_src - tol):
                    continue
                swap = _explained(meas, [*rest, wall_of(y, source)], source, mics, tol)
                gain = int(swap.sum()) - int(base.sum())
                if gain >= 0 and gain > best[0] and np.sum(swap & ~base) >= _MIN_EVIDENCE:
                    best = (gain, k, y)
        if best[2] is None:
            break
        _, k, y = best
        out[k] = y
        walls[k] = wall_of(y, source)
    return out


def normal_std(x, picks, source, mics, peaks: Peaks, sigma) -> float:
    """Standard deviation, degrees, of the normal of the wall of image ``x`` (3,) multilaterated
    from its echoes ``picks`` (M,): range noise max(``sigma``, RMS residual of these echoes with
    3 degrees of freedom removed) propagated through the fit (covariance s^2 (J^T J)^-1, J the
    unit vectors from the microphones to x) onto the directions across x - source."""
    sel = picks >= 0
    diff = x - mics[sel]
    dist = np.linalg.norm(diff, axis=1)
    jac = diff / dist[:, None]
    res = dist - peaks.picked(picks)[sel]
    s = max(sigma, math.sqrt(float(res @ res) / max(len(res) - 3, 1)))
    cov = s * s * np.linalg.pinv(jac.T @ jac)
    axis = x - source
    length = float(np.linalg.norm(axis))
    across = np.eye(3) - np.outer(axis, axis) / length**2
    return math.degrees(math.sqrt(max(float(np.trace(across @ cov @ across)), 0.0)) / length)
