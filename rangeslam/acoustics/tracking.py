"""Echo tracking for a moving microphone: follow each echo from RIR to RIR (the curves of the
paper's Fig. 4C) so that one column of the range matrix is one image source.

Every image source, of any order, is a fixed point, so a track needs no wall label for SLAM: it
must be one point throughout. Data association, frame by frame (one RIR a frame):

- The direct path (``EchoDetection.direct``) is column 0.
- A confirmed track predicts its next range by a parabola fitted to its last six hits (a line
  to fewer than five) and takes the detection nearest the prediction within its gate (``tolerance``, growing with
  the frames since its last hit); tracks and detections are matched by least total distance
  (Hungarian algorithm, ``scipy.optimize.linear_sum_assignment``), confirmed tracks first.
- Crossings: where the predictions of two confirmed tracks come within ``merge_distance`` (the
  detector resolves two arrivals only that far apart), neither takes a detection: both coast on
  their predictions, with masked entries, until they part, and then each takes the detection its
  own curve predicts. A merged peak is thus never given to either echo.
- New tracks: a detection no track takes opens a tentative track; with one hit its velocity is
  unknown, so it branches to every detection of the next frame within the motion bound (the
  range of a fixed point changes by at most the distance moved, eq. 11's upper bound); a
  tentative track is confirmed after ``confirm`` consecutive hits on a smooth curve and dropped at
  its first miss. A tentative track never takes a detection a confirmed track took.

Ranges change by up to a step length per frame, so with one RIR per 30 cm step of the paper's
Fig. 5 walk (echoes of orders 1 to 3 are mostly within 15 cm of one another) no curve can be
followed: record RIRs more densely than the SLAM steps (``keyframes``) and track on all of them.
Entries a track does not cover are masked (``mask`` False, ``ranges`` NaN), never zeros.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares, linear_sum_assignment

from rangeslam._robust import mad_sigma
from rangeslam._validation import check_int, check_positive, frozen
from rangeslam.acoustics.echoes import SPEED_OF_SOUND, EchoDetection, detect_echoes_many
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.mdu.core import canonical_frame, residual_verdict, rotated_covariances
from rangeslam.mdu.slam import SlamResult, slam
from rangeslam.solvers.gtsam_graph import check_step_bounds, refine_graph

__all__ = ["EchoTracks", "WalkFromRirs", "track_echoes", "walk_from_rirs"]

# Hits the prediction is fitted to: a parabola through up to six (a line through fewer than five;
# a parabola through few noisy hits extrapolates their noise, a line misses the curvature).
_FIT_POINTS = 6


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class EchoTracks:
    """Echoes followed along a walk: F frames (RIRs), K tracks (column 0: the direct path).

    Attributes:
        ranges: (F, K) ranges [m] (arrival time x c); NaN where ``mask`` is False.
        mask: (F, K) True where the track has a detection at that frame.
        amplitudes: (F, K) the detections' amplitudes (NaN where masked).
        detection: (F, K) index of the detection in that frame's ``EchoDetection`` (-1: none).
        occluded: (F, K) True where the track coasted through a crossing (masked on purpose).
        dropped_tracks: confirmed tracks with fewer than ``min_length`` hits, left out.
        unassigned: detections (direct paths aside) in no kept track, over all frames.
    """

    ranges: np.ndarray
    mask: np.ndarray
    amplitudes: np.ndarray
    detection: np.ndarray
    occluded: np.ndarray
    dropped_tracks: int
    unassigned: int

    @property
    def n_tracks(self) -> int:
        """K, the direct path included."""
        return self.ranges.shape[1]

    def rows(self, frames: ArrayLike) -> EchoTracks:
        """The same tracks at the given frames only (e.g. the SLAM steps among the RIRs)."""
        idx = np.asarray(frames, dtype=int)
        return EchoTracks(
            ranges=frozen(self.ranges[idx]),
            mask=frozen(self.mask[idx]),
            amplitudes=frozen(self.amplitudes[idx]),
            detection=frozen(self.detection[idx]),
            occluded=frozen(self.occluded[idx]),
            dropped_tracks=self.dropped_tracks,
            unassigned=self.unassigned,
        )


@dataclass(eq=False)
class _Track:
    frames: list[int] = field(default_factory=list)
    ranges: list[float] = field(default_factory=list)
    amps: list[float] = field(default_factory=list)
    idx: list[int] = field(default_factory=list)
    occluded: list[int] = field(default_factory=list)
    confirmed: bool = False
    closed: bool = False

    def add(self, f: int, r: float, a: float, j: int) -> None:
        self.frames.append(f)
        self.ranges.append(r)
        self.amps.append(a)
        self.idx.append(j)

    def branch(self) -> _Track:
        return _Track(
            list(self.frames), list(self.ranges), list(self.amps), list(self.idx), [], False
        )

    def predict(self, f: int) -> float:
        n = min(_FIT_POINTS, len(self.frames))
        if n == 1:
            return self.ranges[-1]
        t = np.asarray(self.frames[-n:], dtype=float)
        coef = np.polyfit(t - t[-1], np.asarray(self.ranges[-n:]), 2 if n >= 5 else 1)
        return float(np.polyval(coef, f - t[-1]))


def track_echoes(
    detections: Sequence[EchoDetection],
    max_step: float | ArrayLike,
    *,
    c: float = SPEED_OF_SOUND,
    tolerance: float | None = None,
    merge_distance: float | None = None,
    max_gap: int = 8,
    confirm: int = 4,
    min_length: int | None = None,
) -> EchoTracks:
    """Follow the echoes across the F RIRs of a walk (detections in the order recorded).

    Args:
        detections: F :class:`~rangeslam.acoustics.echoes.EchoDetection`, one per frame (RIR).
        max_step: the largest distance moved between consecutive frames [m], one number or
            (F - 1,): gates tracks whose velocity is not known yet.
        c: speed of sound [m/s].
        tolerance: largest distance of a detection from a confirmed track's prediction [m]
            (default: 0.3 sample, 0.3 c / fs), times the frames since its last hit.
        merge_distance: predictions closer than this are a crossing [m] (default: two samples,
            the detector's default ``min_separation``).
        max_gap: frames a confirmed track may go without a hit (coasting included) before it is
            closed.
        confirm: consecutive hits that confirm a new track.
        min_length: fewest hits of a kept track (default: a third of the frames, at least
            ``confirm``).

    Returns:
        :class:`EchoTracks` over all F frames (``rows`` picks the SLAM steps).

    Raises InvalidInputError for fewer than 2 detections, detections with different sampling
    rates, or bad options.
    """
    dets = list(detections)
    n_frames = len(dets)
    if n_frames < 2 or not all(isinstance(d, EchoDetection) for d in dets):
        raise InvalidInputError(
            f"detections must be a sequence of at least 2 EchoDetection; got {n_frames} items"
        )
    fs = dets[0].fs
    if any(d.fs != fs for d in dets):
        bad = next(i for i, d in enumerate(dets) if d.fs != fs)
        raise InvalidInputError(
            f"detections must share one sampling rate; detections[{bad}] has {dets[bad].fs} Hz, "
            f"detections[0] {fs} Hz"
        )
    steps = np.asarray(max_step, dtype=float)
    if steps.ndim > 1 or (steps.ndim == 1 and steps.shape != (n_frames - 1,)):
        raise InvalidInputError(
            f"max_step must be one number or ({n_frames - 1},), one per pair of frames; got "
            f"shape {steps.shape}"
        )
    steps = np.broadcast_to(steps, (n_frames - 1,))
    if not (np.all(np.isfinite(steps)) and np.all(steps > 0)):
        raise InvalidInputError(f"max_step must be positive and finite; got {max_step!r}")
    c = check_positive(c, "c")
    tol = 0.3 * c / fs if tolerance is None else check_positive(tolerance, "tolerance")
    merge = (
        2 * c / fs if merge_distance is None else check_positive(merge_distance, "merge_distance")
    )
    max_gap = check_int(max_gap, "max_gap", 0)
    confirm = check_int(confirm, "confirm", 2)
    min_len = max(confirm, n_frames // 3) if min_length is None else min_length
    min_len = check_int(min_len, "min_length", 1)

    direct = np.full(n_frames, np.nan)
    direct_amp = np.full(n_frames, np.nan)
    direct_idx = np.full(n_frames, -1)
    confirmed: list[_Track] = []
    tentative: list[_Track] = []
    total = 0
    for f, det in enumerate(dets):
        ranges = np.asarray(det.times, dtype=float) * c
        amps = np.asarray(det.amplitudes, dtype=float)
        if det.direct is not None:
            direct[f], direct_amp[f], direct_idx[f] = (
                ranges[det.direct],
                amps[det.direct],
                det.direct,
            )
        free = [j for j in range(len(ranges)) if j != det.direct]
        total += len(free)
        taken: set[int] = set()

        # Confirmed tracks: close stale ones, coast through crossings, match the rest.
        live = [t for t in confirmed if not t.closed]
        for t in live:
            if f - t.frames[-1] > max_gap + 1:
                t.closed = True
        live = [t for t in live if not t.closed]
        pred = np.array([t.predict(f) for t in live])
        crossing = np.zeros(len(live), dtype=bool)
        if len(live) > 1:
            order = np.argsort(pred)
            close = np.diff(pred[order]) < merge
            crossing[order[:-1][close]] = True
            crossing[order[1:][close]] = True
        for a in np.flatnonzero(crossing):
            live[a].occluded.append(f)
            # the (merged) peaks there belong to no one
            taken.update(j for j in free if abs(ranges[j] - pred[a]) <= merge)
        matchable = [a for a in range(len(live)) if not crossing[a]]
        _assign(
            [live[a] for a in matchable],
            pred[matchable],
            [tol * (f - live[a].frames[-1]) for a in matchable],
            ranges,
            amps,
            free,
            taken,
            f,
        )

        # Tentative tracks: extend (branching while the velocity is unknown) or drop.
        grown: list[_Track] = []
        for t in tentative:
            if len(t.frames) == 1:
                reach = steps[f - 1] + tol
                for j in free:
                    if j not in taken and abs(ranges[j] - t.ranges[-1]) <= reach:
                        b = t.branch()
                        b.add(f, ranges[j], amps[j], j)
                        grown.append(b)
            else:
                p = t.predict(f)
                near = [j for j in free if j not in taken and abs(ranges[j] - p) <= tol]
                if near:
                    j = min(near, key=lambda j: abs(ranges[j] - p))
                    t.add(f, ranges[j], amps[j], j)
                    grown.append(t)
        # confirm the best of competing branches (they may share detections)
        ready = [t for t in grown if len(t.frames) >= confirm]
        ready.sort(key=_roughness)
        used: set[tuple[int, int]] = set()
        for t in ready:
            hits = set(zip(t.frames, t.idx, strict=True))
            if hits & used:
                continue
            used |= hits
            t.confirmed = True
            confirmed.append(t)
            taken.add(t.idx[-1])
        tentative = [
            t
            for t in grown
            if not t.confirmed and t.idx[-1] not in taken and len(t.frames) < confirm
        ]
        for j in free:
            if j not in taken:
                t = _Track()
                t.add(f, ranges[j], amps[j], j)
                tentative.append(t)

    kept = [t for t in confirmed if len(t.frames) >= min_len]
    k = 1 + len(kept)
    out = np.full((n_frames, k), np.nan)
    amp = np.full((n_frames, k), np.nan)
    which = np.full((n_frames, k), -1)
    occl = np.zeros((n_frames, k), dtype=bool)
    out[:, 0], amp[:, 0], which[:, 0] = direct, direct_amp, direct_idx
    for col, t in enumerate(kept, start=1):
        out[t.frames, col] = t.ranges
        amp[t.frames, col] = t.amps
        which[t.frames, col] = t.idx
        occl[t.occluded, col] = True
    assigned = int(sum(len(t.frames) for t in kept))
    return EchoTracks(
        ranges=frozen(out),
        mask=frozen(np.isfinite(out)),
        amplitudes=frozen(amp),
        detection=frozen(which),
        occluded=frozen(occl),
        dropped_tracks=len(confirmed) - len(kept),
        unassigned=total - assigned,
    )


def _roughness(t: _Track) -> float:
    """Sum of |second differences| of a track's ranges (smooth curves first)."""
    r = np.asarray(t.ranges)
    return float(np.sum(np.abs(np.diff(r, 2)))) if len(r) > 2 else 0.0


def _assign(tracks, pred, gates, ranges, amps, free, taken, f) -> None:
    """Match tracks to free detections (Hungarian, cost = distance to the prediction) within each
    track's gate; extend the matched tracks and mark their detections taken."""
    cand = [j for j in free if j not in taken]
    if not tracks or not cand:
        return
    r = ranges[cand]
    cost = np.abs(r[None, :] - np.asarray(pred)[:, None])
    ok = cost <= np.asarray(gates)[:, None]
    if not ok.any():
        return
    rows, cols = linear_sum_assignment(np.where(ok, cost, 1e6))
    for a, b in zip(rows, cols, strict=True):
        if ok[a, b]:
            j = cand[b]
            rivals = np.sort(cost[a][ok[a]])
            if len(rivals) > 1 and rivals[1] < 2 * rivals[0] + 0.1 * gates[a]:
                tracks[a].closed = True  # two detections fit: end the track rather than guess
                continue
            tracks[a].add(f, ranges[j], amps[j], j)
            taken.add(j)


# ---- the walk: tracks -> SLAM ------------------------------------------------------------------

# Rounds of "drop the entries beyond the gate, refine again" on the start set and on the answer.
_PRUNE_ROUNDS = 3
# Gate on range residuals, in robust standard deviations, and its floor in samples (c / fs): an
# entry further than this from its landmark's fit is taken for a wrong or merged echo.
_GATE_K = 4.0
_GATE_FLOOR = 0.1
# More than this share of the steps on a bound: the bounds decide the answer, not converged (a
# 10-step walk given bounds 1.3x too long was 17 cm off with a 2 mm residual; helper review).
_MAX_PINNED = 0.5
# Kernel of the last GTSAM run, from the gated Huber answer: Tukey's, which gives no weight to the
# few ranges biased by millimetres (merged arrivals) that Huber's still follows (Fig. 5 walks 9 and
# 10 of benchmarks/bench_walk_rirs.py: 3.41 and 3.20 mm with Huber, 2.30 and 1.20 mm with Tukey;
# Tukey in the gating rounds too made walk 10 worse, 5.1 mm).
_FINAL_KERNEL = "tukey"


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class WalkFromRirs:
    """Result of :func:`walk_from_rirs`. F frames (RIRs), M steps (keyframes), K landmarks.

    Attributes:
        detections: the F echo detections.
        tracks: the :class:`EchoTracks` over the F frames (fragments of echo curves).
        keyframes: (M,) the frame of each SLAM step.
        ranges: (M, K) ranges to the landmarks (column 0: the loudspeaker, by the direct path),
            metres; NaN where ``mask`` is False.
        mask: (M, K) True where used (entries the fit rejected are False).
        columns: K tuples, the columns of ``tracks`` joined into each landmark.
        start_columns: the columns of ``tracks`` the EDM start was solved on.
        slam: the answer as a :class:`~rangeslam.mdu.slam.SlamResult` (``receivers`` (M, d) the
            trajectory, ``sources`` (K, d) the landmarks, covariances), or None when there is none.
        gate: the residual gate used to reject entries, metres.
        converged: a trajectory was found and passed the residual test.
        message: what happened.
    """

    detections: tuple[EchoDetection, ...]
    tracks: EchoTracks
    keyframes: np.ndarray
    ranges: np.ndarray | None
    mask: np.ndarray | None
    columns: tuple[tuple[int, ...], ...]
    start_columns: tuple[int, ...]
    slam: SlamResult | None
    gate: float
    converged: bool
    message: str

    @property
    def trajectory(self) -> np.ndarray | None:
        """(M, d) the positions of the steps, or None."""
        return None if self.slam is None else self.slam.receivers

    @property
    def landmarks(self) -> np.ndarray | None:
        """(K, d) the loudspeaker (row 0) and the image sources, or None."""
        return None if self.slam is None else self.slam.sources


def _keyframes(keyframes, n_frames: int) -> np.ndarray:
    if keyframes is None:
        return np.arange(n_frames)
    k = np.asarray(keyframes)
    if k.ndim != 1 or k.size < 3 or not np.issubdtype(k.dtype, np.integer):
        raise InvalidInputError(
            f"keyframes must be at least 3 frame indices (integers); got {keyframes!r}"
        )
    if k[0] < 0 or k[-1] >= n_frames or np.any(np.diff(k) <= 0):
        raise InvalidInputError(
            f"keyframes must increase strictly within [0, {n_frames}) (one RIR per frame); "
            f"got {k.tolist()}"
        )
    return k.astype(int)


def _frame_steps(upper: np.ndarray, keyframes: np.ndarray, n_frames: int) -> np.ndarray:
    """(F - 1,) the largest move between consecutive frames: twice a step's upper bound shared
    among the frames recorded during it (frames before the first step or after the last take
    the nearest step's)."""
    per = np.maximum(2.0 * upper / np.diff(keyframes), 1e-6)  # a step bounded by 0: standing
    step_of = np.clip(
        np.searchsorted(keyframes, np.arange(n_frames - 1), side="right") - 1, 0, len(per) - 1
    )
    return per[step_of]


def _subspace(trajectory: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal basis (M, p) of the vectors rho^2 - |r|^2 a fixed point p can give along the
    trajectory r (centred): rho^2 - |r|^2 = -2 r.p + |p|^2 is affine in r, so the vector lies in
    the span of [r, 1] (p = d + 1, or 3 for a planar walk in 3-D): the EDM rank test with the
    trajectory known. Also returns (M,) |r|^2."""
    r = trajectory - trajectory.mean(axis=0)
    a = np.column_stack([-2.0 * r, np.ones(len(r))])
    u, sv, _ = np.linalg.svd(a, full_matrices=False)
    return u[:, sv > 1e-6 * sv[0]], np.sum(r**2, axis=1)


def _predict(basis: np.ndarray, ref: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(M,) the ranges of the point whose rho^2 - ``ref`` fits the observed ``r`` best in the
    basis (:func:`_subspace`)."""
    coef, *_ = np.linalg.lstsq(basis[ok], r[ok] ** 2 - ref[ok], rcond=None)
    return np.sqrt(np.maximum(ref + basis @ coef, 0.0))


def _link(ranges, mask, columns, basis, ref, gate, min_hits):
    """Join track columns into landmarks: longest first, a column joins the first landmark whose
    ranges it agrees with where both are observed and whose fit (``_predict``) keeps every range
    within ``gate``; otherwise it starts a landmark if it fits one point itself. Returns
    [(columns, ranges (M,), observed (M,))] with at least ``min_hits`` observed each."""
    p = basis.shape[1]
    groups: list[tuple[list[int], np.ndarray, np.ndarray]] = []
    for c in sorted(columns, key=lambda c: -int(mask[:, c].sum())):
        ok_c = mask[:, c]
        if ok_c.sum() <= p:  # p hits fit any point: no test
            continue
        for cols, r, ok in groups:
            both = ok & ok_c
            if np.any(np.abs(r[both] - ranges[both, c]) > gate):
                continue
            r2 = np.where(ok_c, ranges[:, c], r)
            ok2 = ok | ok_c
            if np.max(np.abs(_predict(basis, ref, r2, ok2) - r2)[ok2]) <= gate:
                cols.append(c)
                r[:] = r2
                ok[:] = ok2
                break
        else:
            r = np.where(ok_c, ranges[:, c], np.nan)
            if np.max(np.abs(_predict(basis, ref, r, ok_c) - r)[ok_c]) <= gate:
                groups.append(([c], r, ok_c.copy()))
    return [(tuple(cols), r, ok) for cols, r, ok in groups if ok.sum() >= min_hits]


def _locate(trajectory: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The point at ranges ``r`` (observed where ``ok``) from the trajectory: least squares from
    starts on both sides of the trajectory's best-fit plane (a planar walk hears a point and its
    mirror image alike; either will do)."""
    centre = trajectory.mean(axis=0)
    _, _, vt = np.linalg.svd(trajectory - centre)
    normal = vt[-1]
    spread = float(np.nanmax(r[ok]))
    best = None
    for sign in (1.0, -1.0):
        x0 = centre + sign * 0.5 * spread * normal
        fit = least_squares(
            lambda x: np.linalg.norm(trajectory[ok] - x, axis=1) - r[ok], x0, method="lm"
        )
        if best is None or fit.cost < best.cost:
            best = fit
    return best.x


def _steps_on_bounds(traj: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> int:
    """Steps of ``traj`` within 2 % of the bounds' width of either bound (bounds of zero width
    not counted)."""
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    width = upper - lower
    near = (steps <= lower + 0.02 * width) | (steps >= upper - 0.02 * width)
    return int(np.sum(near & (width > 0)))


def _gated_refine(traj, pts, r, mask, bounds, sigma, gate_floor):
    """GTSAM (Huber) on the ranges, then rounds of masking the entries beyond the gate
    (``_GATE_K`` robust sigmas, at least ``gate_floor``) and refining again. Returns
    (fit, mask, gate, sigma)."""
    mask = mask.copy()
    r = np.nan_to_num(r)

    gate = gate_floor
    fit = None
    for _ in range(_PRUNE_ROUNDS):
        fit = refine_graph(
            traj,
            pts,
            r,
            noise_std=sigma,
            mask=mask,
            step_bounds=bounds,
            robust="huber",
            covariances=False,
        )
        traj, pts = fit.receivers, fit.sources
        res = np.abs(np.nan_to_num(fit.residuals))
        sigma = max(mad_sigma(np.where(mask, res, np.nan)), 0.25 * gate_floor / _GATE_K)
        gate = max(_GATE_K * sigma, gate_floor)
        drop = mask & (res > gate)
        if not drop.any():
            break
        mask &= ~drop
    return fit, mask, gate, sigma


def walk_from_rirs(
    rirs: ArrayLike,
    fs: float,
    *,
    step_bounds: tuple[ArrayLike, ArrayLike],
    keyframes: ArrayLike | None = None,
    c: float = SPEED_OF_SOUND,
    dim: int = 3,
    n_start: int = 8,
    min_hits: int | None = None,
    isolation: float = 3.0,
    rng: np.random.Generator | int | None = None,
    detect_options: dict[str, Any] | None = None,
    track_options: dict[str, Any] | None = None,
    slam_options: dict[str, Any] | None = None,
) -> WalkFromRirs:
    """Trajectory and landmarks of a moving microphone from its RIRs and bounds on its steps.

    1. :func:`rangeslam.acoustics.echoes.detect_echoes_many` on every RIR (frame).
    2. :func:`track_echoes` over all frames, with the largest move between frames twice a
       step's upper bound shared among the frames recorded during it.
    3. At the M keyframes (the SLAM steps), the ``n_start`` tracks with the most hits (at least
       ``min_hits``; more where a step would hear fewer than d + 1 of them) and the direct path: :func:`rangeslam.mdu.slam` (EDM completion with the step
       bounds of eq. 11, then GTSAM, Huber kernel), each track a landmark of its own.
    4. Entries beyond a gate (4 robust sigmas of the range residuals, at least 0.1 sample) are
       masked and GTSAM run again (at most 3 rounds).
    5. Linking: a fixed point's squared ranges minus the loudspeaker's are affine in the
       position, so they lie in a (d + 1)-dimensional space known from the trajectory (the EDM
       rank test); tracks whose ranges fit one point within the gate are one landmark.
    6. GTSAM on all landmarks (each started by least squares from the trajectory), gated as in 4;
       landmarks left with d or fewer ranges dropped; a last run with Tukey's kernel.

    Args:
        rirs: (F, L) RIRs, t = 0 at the emission, one per frame. fs: Hz.
        step_bounds: (lower, upper), each (M - 1,): bounds on the steps between keyframes [m].
        keyframes: (M,) increasing frame indices of the SLAM steps (default: every frame). Record
            more RIRs than steps where steps are long: echoes are followed frame to frame.
        c: speed of sound, m/s. dim: 2 or 3.
        n_start: tracks the EDM start is solved on (besides the direct path).
        min_hits: fewest keyframes a landmark is heard at (default max(dim + 3, M // 3), at most M).
        isolation: samples; an arrival nearer than this to another in its RIR is left out (two
            arrivals that close bias each other's times). 0 keeps them all.
        rng: random generator (or seed) for the SDP's restarts.
        detect_options, track_options, slam_options: keyword arguments of
            :func:`rangeslam.acoustics.echoes.detect_echoes_many`, :func:`track_echoes` and
            :func:`rangeslam.mdu.slam` (e.g. ``noise_std``).

    Returns:
        A :class:`WalkFromRirs`; ``converged`` False, with the reason, when too few echoes were
        tracked, the SDP failed, or the answer failed its residual test.
    """
    rng = np.random.default_rng(rng)
    dets = tuple(detect_echoes_many(rirs, fs, **(detect_options or {})))
    n_frames = len(dets)
    if n_frames < 3:
        raise InvalidInputError(f"rirs must hold at least 3 RIRs (frames); got {n_frames}")
    keys = _keyframes(keyframes, n_frames)
    m = len(keys)
    lower, upper = check_step_bounds(step_bounds, m)
    bounds = (lower, upper)
    if dim not in (2, 3):
        raise InvalidInputError(f"dim must be 2 or 3; got {dim!r}")
    if not (isinstance(n_start, int | np.integer) and n_start >= dim + 1):
        raise InvalidInputError(
            f"n_start must be an integer >= dim + 1 = {dim + 1}; got {n_start!r}"
        )
    if m < dim + 2:
        raise InvalidInputError(
            f"keyframes must give at least dim + 2 = {dim + 2} steps (RIRs, when keyframes is "
            f"None); got {m}"
        )
    min_hits = min(max(dim + 3, m // 3), m) if min_hits is None else min_hits
    if not (isinstance(min_hits, int | np.integer) and dim + 2 <= min_hits <= m):
        raise InvalidInputError(
            f"min_hits must be an integer in [dim + 2, M] = [{dim + 2}, {m}]; got {min_hits!r}"
        )
    if not (isinstance(isolation, int | float | np.number) and 0 <= isolation < np.inf):
        raise InvalidInputError(f"isolation must be a number of samples >= 0; got {isolation!r}")
    topts = dict(track_options or {})
    topts.setdefault("c", c)
    tracks = track_echoes(dets, topts.pop("max_step", _frame_steps(upper, keys, n_frames)), **topts)
    sample = c / dets[0].fs
    gate_floor = _GATE_FLOOR * sample
    key = tracks.rows(keys)
    ranges, mask = key.ranges, key.mask.copy()
    if isolation > 0:  # arrivals near another are biased by it: leave them out
        for i, f in enumerate(keys):
            t = dets[f].times * dets[f].fs
            if len(t) > 1:
                gap = np.abs(t[:, None] - t[None, :]) + np.diag(np.full(len(t), np.inf))
                crowded = np.flatnonzero(gap.min(axis=1) < isolation)
                mask[i] &= ~np.isin(key.detection[i], crowded)
    hits = mask.sum(axis=0)
    candidates = [j for j in range(1, key.n_tracks) if hits[j] >= min_hits]
    amp = np.where(mask, np.abs(np.nan_to_num(key.amplitudes)), 0.0).sum(axis=0) / np.maximum(
        hits, 1
    )
    ranked = sorted(candidates, key=lambda j: (-hits[j], -amp[j]))
    start_cols = ranked[:n_start]
    # every step must hear dim + 1 landmarks of the start: add the tracks that fill the gaps most
    for _ in range(n_start):
        short = mask[:, [0, *start_cols]].sum(axis=1) < dim + 1
        rest = [j for j in ranked if j not in start_cols]
        if not short.any() or not rest:
            break
        best = max(rest, key=lambda j: int(np.sum(mask[short, j])))
        if not mask[short, best].any():
            break
        start_cols.append(best)

    def result(ranges=None, mask=None, columns=(), answer=None, gate=gate_floor, ok=False, msg=""):
        return WalkFromRirs(
            detections=dets,
            tracks=tracks,
            keyframes=frozen(keys),
            ranges=None if ranges is None else frozen(np.where(mask, ranges, np.nan)),
            mask=None if mask is None else frozen(mask),
            columns=tuple(columns),
            start_columns=tuple(start_cols),
            slam=answer,
            gate=float(gate),
            converged=bool(ok),
            message=msg,
        )

    if hits[0] < min_hits:
        return result(
            msg=f"the direct path was found clear of other arrivals at {hits[0]} of {m} steps "
            f"(< {min_hits})"
        )
    if len(start_cols) < dim + 1:
        return result(
            msg=f"{len(start_cols)} echoes were tracked over at least {min_hits} of the {m} "
            f"steps; at least {dim + 1} are needed"
        )
    cols0 = [0, *start_cols]
    sopts = {"robust": "huber", **(slam_options or {})}
    try:
        start = slam(
            np.nan_to_num(ranges[:, cols0]),
            mask=mask[:, cols0],
            step_bounds=bounds,
            dim=dim,
            rng=rng,
            **sopts,
        )
    except SolverError as exc:
        return result(msg=f"the EDM start failed: {exc}")
    except InvalidInputError as exc:  # e.g. the tracks leave the unfolding under-determined
        return result(msg=f"the EDM start refused the tracked ranges: {exc}")
    sigma0 = max(start.residual_rms, gate_floor / _GATE_K)
    try:
        fit0, _, gate, _ = _gated_refine(
            start.receivers,
            start.sources,
            ranges[:, cols0],
            mask[:, cols0],
            bounds,
            sigma0,
            gate_floor,
        )
    except SolverError as exc:
        return result(msg=f"GTSAM from the EDM start failed: {exc}")
    traj = fit0.receivers
    direct = np.where(mask[:, 0], ranges[:, 0], np.nan)
    basis, ref = _subspace(traj)
    groups = _link(ranges, mask, candidates, basis, ref, gate, min_hits)
    if len(groups) < dim + 1:
        return result(msg=f"{len(groups)} landmarks were linked; at least {dim + 1} are needed")
    r_all = np.column_stack([direct] + [g[1] for g in groups])
    m_all = np.column_stack([mask[:, 0]] + [g[2] for g in groups])
    pts = np.vstack([fit0.sources[0]] + [_locate(traj, g[1], g[2]) for g in groups])
    cols_all = [(0,), *[g[0] for g in groups]]
    n_linked = int(m_all.sum())
    try:
        fit, m_all, gate, sigma = _gated_refine(
            traj,
            pts,
            r_all,
            m_all,
            bounds,
            sigma0,
            gate_floor,
        )
    except SolverError as exc:
        return result(msg=f"GTSAM on the linked landmarks failed: {exc}")
    # a landmark the gate left with d or fewer ranges is not determined: leave it out
    keep = m_all.sum(axis=0) > dim
    if not keep[0]:
        return result(
            msg=f"the direct path kept {int(m_all[:, 0].sum())} ranges through the gate of "
            f"{gate:.2g} m: the loudspeaker is not determined"
        )
    if keep.sum() < dim + 2:
        return result(msg=f"{int(keep.sum()) - 1} echo landmarks kept ranges through the gate")
    r_all, m_all = r_all[:, keep], m_all[:, keep]
    cols_all = [c for c, k in zip(cols_all, keep, strict=True) if k]
    try:
        fit = refine_graph(
            fit.receivers,
            fit.sources[keep],
            np.nan_to_num(r_all),
            noise_std=sigma,
            mask=m_all,
            step_bounds=bounds,
            robust=_FINAL_KERNEL,
            covariances=True,
        )
    except SolverError as exc:
        return result(msg=f"GTSAM on the linked landmarks failed: {exc}")
    res = np.where(m_all, fit.residuals, np.nan)
    ssr = float(np.nansum(res**2))
    noise = sopts.get("noise_std")
    ok, why = residual_verdict(
        ssr,
        m_all,
        dim,
        noise,
        float(np.median(r_all[m_all])),
        chi_square=noise is not None,
        bounded=True,
    )
    msg = why
    if not start.converged:
        ok = False
        msg += f"the EDM start did not converge ({start.message}); "
    if not fit.converged:
        ok = False
        msg += f"GTSAM: {fit.message}; "
    pinned = _steps_on_bounds(fit.receivers, lower, upper)
    if pinned > _MAX_PINNED * (m - 1):
        ok = False
        msg += (
            f"{pinned} of the {m - 1} steps sit on a step bound: the bounds, not the ranges, "
            "decide the trajectory (are they right?); "
        )
    rec, src, rot = canonical_frame(fit.receivers, fit.sources)
    cov_r, cov_s, cov_traj = rotated_covariances(fit, rot)
    answer = SlamResult(
        receivers=frozen(rec),
        sources=frozen(src),
        receiver_cov=frozen(cov_r),
        source_cov=frozen(cov_s),
        trajectory_cov=frozen(cov_traj),
        residuals=frozen(res),
        edm_receivers=start.edm_receivers,
        edm_sources=None,
        residual_rms=float(np.sqrt(ssr / m_all.sum())),
        converged=bool(ok),
        message=msg.rstrip("; "),
        attempts=start.attempts,
        start="edm",
        eigen_gap=start.eigen_gap,
    )
    n_masked = n_linked - int(m_all.sum())
    summary = (
        f"{len(cols_all) - 1} echo landmarks from {sum(len(c) for c in cols_all[1:])} of "
        f"{key.n_tracks - 1} tracks, {int(m_all.sum())} ranges used, {n_masked} left out by the "
        f"gate of {gate:.2g} m"
    )
    return result(
        r_all,
        m_all,
        cols_all,
        answer,
        gate,
        ok,
        f"{summary}; {msg.rstrip('; ')}" if msg else summary,
    )
