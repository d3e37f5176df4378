"""Echo labelling, steps 2-3 and 5: hypotheses from microphone triples and their consensus.

The search of :func:`rangeslam.acoustics.labelling.label_echoes` for points (image sources) that
``min_mics`` microphones spanning 3-D agree on: peak bookkeeping (:class:`Peaks`), hypotheses by
trilateration of peak triples (:func:`hypotheses`, :func:`batch_refine`), one point fitted to its
echoes (:func:`refine_point`, the EDM rank test with known microphones) and the RANSAC-like
consensus that keeps one point per peak (:func:`discover`, :func:`settle`, :func:`collect`).
Internal to :mod:`rangeslam.acoustics`: nothing here is exported.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from rangeslam.localization.multilateration import affine_rank

__all__: list[str] = []

# Gates, in robust standard deviations of the echo times: a hypothesis from three microphones is
# compared with the others within _GATE_K times the standard deviation of its predicted range there.
_GATE_K = 3.0
# Re-fits of one point (fit, collect its echoes again) before giving up on convergence.
_MAX_REFITS = 8
# Gauss-Newton steps of a re-fit from a nearby point.
_GN_STEPS = 5
# Largest boolean tensor (peaks_a x peaks_b x peaks_c) built at once when pairing peaks.
_CHUNK = 4_000_000
# At most this many hypotheses (the best supported) enter the consensus of a round, and at most
# this many are refined there: a bound on the time spent on dense, inconsistent peaks.
_MAX_CANDIDATES = 5000
_MAX_ATTEMPTS = 400
# A taken echo supports a hypothesis that predicts it this many times better than its owner.
_OWN_FACTOR = 2.0


# ---- peak bookkeeping ---------------------------------------------------------------------------


class Peaks:
    """Per-microphone peak ranges (ascending) and which of them may be used."""

    def __init__(self, ranges: list[np.ndarray], usable: list[np.ndarray]) -> None:
        self.ranges = ranges
        self.lists = [(r[u], np.flatnonzero(u)) for r, u in zip(ranges, usable, strict=True)]

    def nearest(self, pred: np.ndarray):
        """Nearest usable peak to each predicted range (N, M): (N, M) index (-1 if none) and
        |error| (inf if none)."""
        n, m_n = pred.shape
        idx = np.full((n, m_n), -1)
        err = np.full((n, m_n), np.inf)
        for m, (vals, where) in enumerate(self.lists):
            if not len(vals):
                continue
            p = pred[:, m]
            k = np.clip(np.searchsorted(vals, p), 1, max(len(vals) - 1, 1))
            lo = np.abs(p - vals[k - 1])
            k_hi = np.minimum(k, len(vals) - 1)
            pick = np.where(np.abs(vals[k_hi] - p) < lo, k_hi, k - 1)
            idx[:, m] = where[pick]
            err[:, m] = np.abs(vals[pick] - p)
        return idx, err

    def picked(self, picks: np.ndarray) -> np.ndarray:
        """(M,) ranges of picked peaks (picks (M,) indices, -1 = none), NaN where none."""
        return np.array([self.ranges[m][i] if i >= 0 else np.nan for m, i in enumerate(picks)])


# ---- hypotheses ---------------------------------------------------------------------------------


def _trilaterate(p: np.ndarray, r1, r2, r3, slack: float) -> np.ndarray:
    """Both intersections of three spheres centred on p (3, 3) with radii r1, r2, r3 (N,).

    Triples whose spheres miss each other by more than about ``slack`` metres (squared height
    below -2 r1 slack) are dropped; near misses are projected onto the plane of the centres.
    Returns (2 N', 3).
    """
    e1 = p[1] - p[0]
    d = float(np.linalg.norm(e1))
    ex = e1 / d
    v = p[2] - p[0]
    i = float(ex @ v)
    t = v - i * ex
    j = float(np.linalg.norm(t))
    ey = t / j
    ez = np.cross(ex, ey)
    x = (r1**2 - r2**2 + d * d) / (2 * d)
    y = (r1**2 - r3**2 + i * i + j * j) / (2 * j) - i * x / j
    z2 = r1**2 - x**2 - y**2
    ok = z2 >= -2.0 * r1 * slack
    z = np.sqrt(np.maximum(z2[ok], 0.0))
    base = p[0] + x[ok, None] * ex + y[ok, None] * ey
    return np.vstack([base + z[:, None] * ez, base - z[:, None] * ez])


class Triples:
    """Triples of usable microphones with large triangles (at least 0.3 of the largest), handed
    out in an order that covers the microphones as evenly as possible, each triple once."""

    def __init__(self, mics: np.ndarray, usable: np.ndarray, rng) -> None:
        idx = np.flatnonzero(usable)
        if math.comb(len(idx), 3) > 20_000:
            tri = np.sort(np.argsort(rng.random((20_000, len(idx))), axis=1)[:, :3], axis=1)
            tri = np.unique(idx[tri], axis=0)
        else:
            tri = np.array(list(itertools.combinations(idx.tolist(), 3)), dtype=int)
        tri = tri.reshape(-1, 3)
        a, b, c = mics[tri[:, 0]], mics[tri[:, 1]], mics[tri[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        good = np.flatnonzero(area >= 0.3 * area.max()) if len(tri) else np.zeros(0, dtype=int)
        self.tri = tri[good[rng.permutation(len(good))]]
        self.used = np.zeros(len(mics))
        self.taken = np.zeros(len(self.tri), dtype=bool)

    def next(self, n: int) -> list[np.ndarray]:
        out = []
        for _ in range(n):
            if self.taken.all():
                break
            g = int(np.argmin(self.used[self.tri].sum(axis=1) + 1e6 * self.taken))
            self.taken[g] = True
            self.used[self.tri[g]] += 1
            out.append(self.tri[g])
        return out


def hypotheses(mics, trip, gen: list, peaks: Peaks, sigma, fit_tol, cap, min_mics, max_hyp, rng):
    """Points (N, 3) from one peak per microphone of ``trip`` (3,), and their gates (N, M).

    ``gen`` lists per microphone the (ranges, indices) of the peaks that may start a hypothesis
    at the triple's first microphone; the other two use every peak of ``peaks``. Peak
    triples whose ranges differ by more than the microphones' distances (plus ``cap``) cannot
    come from one point. Each hypothesis predicts the range at microphone m with a standard
    deviation sigma ||u_m U^-1|| (U: unit vectors from the triple to the point, u_m from m), so it
    is compared with each microphone within fit_tol + _GATE_K times that (at most ``cap``); those
    that ``min_mics`` microphones do not support are dropped.
    """
    a, b, c = (int(k) for k in trip)
    ra, rb, rc = gen[a][0], peaks.lists[b][0], peaks.lists[c][0]
    empty = np.empty((0, 3)), np.empty((0, len(mics)))
    if not (len(ra) and len(rb) and len(rc)):
        return empty
    dab = np.linalg.norm(mics[a] - mics[b]) + cap
    dac = np.linalg.norm(mics[a] - mics[c]) + cap
    dbc = np.linalg.norm(mics[b] - mics[c]) + cap
    cbc = np.abs(rb[:, None] - rc[None, :]) <= dbc
    step = max(1, _CHUNK // max(len(rb) * len(rc), 1))
    found = []
    for s in range(0, len(ra), step):
        sa = ra[s : s + step]
        cab = np.abs(sa[:, None] - rb[None, :]) <= dab
        cac = np.abs(sa[:, None] - rc[None, :]) <= dac
        i, j, k = np.nonzero(cab[:, :, None] & cac[:, None, :] & cbc[None, :, :])
        found.append(np.column_stack([i + s, j, k]))
    ijk = np.vstack(found)
    if len(ijk) > max_hyp:
        ijk = ijk[rng.choice(len(ijk), max_hyp, replace=False)]
    x = _trilaterate(mics[[a, b, c]], ra[ijk[:, 0]], rb[ijk[:, 1]], rc[ijk[:, 2]], cap)
    if not len(x):
        return empty
    diff = x[:, None, :] - mics[None]
    dist = np.sqrt(np.einsum("nmi,nmi->nm", diff, diff))
    unit = diff / np.maximum(dist, 1e-12)[..., None]
    u3 = unit[:, [a, b, c], :]
    ok = np.abs(np.linalg.det(u3)) > 1e-6
    x, dist, unit, u3 = x[ok], dist[ok], unit[ok], u3[ok]
    g = np.einsum("nmi,nij->nmj", unit, np.linalg.inv(u3))
    amp = np.sqrt(np.einsum("nmj,nmj->nm", g, g))  # (N, M): |d pred_m / d r_triple|
    gate = np.minimum(fit_tol + _GATE_K * sigma * amp, cap)
    _, err = peaks.nearest(dist)
    inside = err <= gate
    support = inside.sum(axis=1)
    cost = (np.where(inside, err / gate, 1.0) ** 2).sum(axis=1)
    keep = np.flatnonzero(support >= min_mics)
    keep = keep[np.lexsort((cost[keep], -support[keep]))[:_MAX_CANDIDATES]]
    return x[keep], gate[keep]


def batch_refine(x: np.ndarray, mics: np.ndarray, peaks: Peaks, gates) -> np.ndarray:
    """Gauss-Newton steps for many points (N, 3) at once, one per gate (scalar or (N, M),
    metres), each on the peaks nearest the predicted ranges that lie within the gate."""
    for gate in gates:
        if not len(x):
            break
        diff = x[:, None, :] - mics[None]
        pred = np.sqrt(np.einsum("nmi,nmi->nm", diff, diff))
        idx, err = peaks.nearest(pred)
        use = err <= gate
        meas = np.zeros_like(pred)
        for m in range(len(mics)):
            on = idx[:, m] >= 0
            meas[on, m] = peaks.ranges[m][idx[on, m]]
        e = np.where(use, pred - meas, 0.0)
        jac = diff / np.maximum(pred, 1e-12)[..., None]
        a = np.einsum("nm,nmi,nmj->nij", use.astype(float), jac, jac) + 1e-9 * np.eye(3)
        g = np.einsum("nmi,nm->ni", jac, e)
        fit = use.sum(axis=1) >= 4
        step = np.zeros_like(x)
        step[fit] = np.linalg.solve(a[fit], g[fit][..., None])[..., 0]
        x = x - step
    return x


# ---- fitting one point to its echoes -----------------------------------------------------------


def _fit(mics, peaks: Peaks, picks: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The point fitting the picked peak of each microphone (picks (M,), -1 = none): least squares
    on the ranges (maximum likelihood for Gaussian range errors) by Gauss-Newton from ``start``,
    a nearby point (a hypothesis, or the previous fit)."""
    sel = picks >= 0
    r = peaks.picked(picks)[sel]
    x = np.asarray(start, dtype=float)
    for _ in range(_GN_STEPS):
        diff = x - mics[sel]
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        step = np.linalg.lstsq(diff / dist[:, None], dist - r, rcond=None)[0]
        x = x - step
        if np.linalg.norm(step) < 1e-9:
            break
    return x


def spans(mics, picks, min_mics) -> bool:
    sel = picks >= 0
    return bool(sel.sum() >= min_mics and affine_rank(mics[sel]) == 3)


def refine_point(x0, mics, peaks: Peaks, tol, outer, min_mics):
    """Fit a point to the peaks within ``tol`` of x0's predicted ranges (within ``outer`` if too
    few are), then repeatedly collect those within ``tol`` of the fit and re-fit. Returns (point,
    picks (M,)) or None when fewer than ``min_mics`` microphones spanning 3-D agree within
    ``tol``: the EDM rank test with known microphones (module docstring)."""
    idx, err = peaks.nearest(np.linalg.norm(mics - x0, axis=1)[None, :])
    picks = np.where(err[0] <= tol, idx[0], -1)
    if not spans(mics, picks, min_mics):
        picks = np.where(err[0] <= outer, idx[0], -1)
    seen: list[np.ndarray] = []
    x = np.asarray(x0, dtype=float)
    for _ in range(_MAX_REFITS):
        if not spans(mics, picks, 4):
            return None
        x = _fit(mics, peaks, picks, x)
        idx, err = peaks.nearest(np.linalg.norm(mics - x, axis=1)[None, :])
        new = np.where(err[0] <= tol, idx[0], -1)
        if np.array_equal(new, picks) or any(np.array_equal(new, old) for old in seen):
            picks = new
            break
        seen.append(picks)
        picks = new
    if not spans(mics, picks, min_mics):
        return None
    x = _fit(mics, peaks, picks, x)
    res = np.linalg.norm(mics - x, axis=1) - peaks.picked(picks)
    picks = np.where(np.abs(np.nan_to_num(res)) <= tol, picks, -1)
    return (x, picks) if spans(mics, picks, min_mics) else None


def settle(found, mics, peaks: Peaks, tol, min_mics):
    """One peak, one point: a peak picked by several points goes to one of them (:func:`collect`);
    points are re-fitted on what they keep; those left with fewer than ``min_mics`` microphones
    spanning 3-D are dropped (their peaks freed for the others). Until stable."""
    for _ in range(_MAX_REFITS):
        found = collect(found, mics, peaks, tol)
        kept = [(x, p) for x, p in found if spans(mics, p, min_mics)]
        refit = [(_fit(mics, peaks, p, x), p) for x, p in kept]
        stable = len(kept) == len(found) and all(
            np.allclose(x, y, atol=1e-3 * tol) for (x, _), (y, _) in zip(kept, refit, strict=True)
        )
        found = refit
        if stable:
            break
    return found


def collect(found, mics, peaks: Peaks, tol):
    """Each point takes the peak nearest its predicted range at every microphone, within ``tol``;
    a peak wanted by several points goes to the best supported (most microphones), then to the one
    that predicts it best. (Support first: a chance alignment of a few peaks fits them more
    closely than the noise allows, since the fit has three unknowns.)"""
    if not found:
        return []
    x = np.array([f[0] for f in found])
    idx, err = peaks.nearest(np.linalg.norm(x[:, None, :] - mics[None], axis=2))
    picks = np.where(err <= tol, idx, -1)
    support = (picks >= 0).sum(axis=1)
    for m in range(len(mics)):
        on = np.flatnonzero(picks[:, m] >= 0)
        best: dict[int, int] = {}
        for h in on[np.lexsort((err[on, m], -support[on]))]:
            best.setdefault(int(picks[h, m]), int(h))
        for h in on:
            if best[int(picks[h, m])] != h:
                picks[h, m] = -1
    return [(f[0], picks[h]) for h, f in enumerate(found)]


def discover(x, mics, peaks: Peaks, fit_tol, outer, min_mics, d_src, found) -> int:
    """Add to ``found`` [(point, picks)] the points that hypotheses x (N, 3) lead to.

    Each hypothesis is summarised by its echoes (the peak within ``fit_tol`` of its predicted range
    at each microphone). An echo supports it when no point found before has it, or when the
    hypothesis predicts it at least twice as well as the point that has it (so a point whose
    echoes were taken by a chance alignment is still found, while a mixture of echoes of points
    found before is not). Most supported first (then least squared error), a hypothesis is
    refined (:func:`refine_point`) and added if at least ``min_mics`` microphones spanning 3-D support
    it. Returns the number added.
    """
    if not len(x):
        return 0
    m_n = len(mics)
    owner = [np.full(len(r), np.inf) for r in peaks.ranges]  # |residual| of the point having it
    for pt, p in found:
        _own(owner, pt, p, mics, peaks)
    idx, err = peaks.nearest(np.linalg.norm(x[:, None, :] - mics[None], axis=2))
    sig = np.where(err <= fit_tol, idx, -1)
    keep = (sig >= 0).sum(axis=1) >= min_mics
    x, sig, err = x[keep], sig[keep], err[keep]
    cost = (np.where(sig >= 0, err, fit_tol) ** 2).sum(axis=1)
    best = np.lexsort((cost, -(sig >= 0).sum(axis=1)))[:_MAX_CANDIDATES]
    x, sig, err, cost = x[best], sig[best], err[best], cost[best]

    def support():
        ok = sig >= 0
        for m in range(m_n):
            on = ok[:, m]
            ok[on, m] = _OWN_FACTOR * err[on, m] < owner[m][sig[on, m]]
        return ok.sum(axis=1)

    alive = np.ones(len(x), dtype=bool)
    added = 0
    sup = support()
    for _ in range(_MAX_ATTEMPTS):
        alive &= sup >= min_mics
        if not alive.any():
            break
        cand = np.flatnonzero(alive)
        h = int(cand[np.lexsort((cost[cand], -sup[cand]))[0]])
        alive[h] = False
        out = refine_point(x[h], mics, peaks, fit_tol, outer, min_mics)
        if out is None or np.any(np.linalg.norm(mics - out[0], axis=1) < d_src - outer):
            continue
        pt, picks = out
        res = np.abs(np.linalg.norm(mics - pt, axis=1) - peaks.picked(picks))
        wins = np.array(
            [picks[m] >= 0 and _OWN_FACTOR * res[m] < owner[m][picks[m]] for m in range(m_n)]
        )
        if not spans(mics, np.where(wins, picks, -1), min_mics):
            continue
        found.append((pt, picks))
        _own(owner, pt, picks, mics, peaks)
        added += 1
        sup = support()
    return added


def _own(owner, pt, picks, mics, peaks: Peaks) -> None:
    """Record in ``owner`` (per microphone, per peak: the smallest |residual| of a point that
    has it) the echoes ``picks`` of point ``pt``."""
    res = np.abs(np.linalg.norm(mics - pt, axis=1) - peaks.picked(picks))
    for m in np.flatnonzero(picks >= 0):
        owner[m][picks[m]] = min(owner[m][picks[m]], res[m])
