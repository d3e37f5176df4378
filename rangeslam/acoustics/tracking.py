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

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linear_sum_assignment

from rangeslam._validation import as_float_array, check_int, check_positive, frozen
from rangeslam.acoustics.echoes import SPEED_OF_SOUND, EchoDetection
from rangeslam.errors import InvalidInputError

__all__ = ["EchoTracks", "track_echoes"]

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
    try:
        dets = list(detections)
    except TypeError as exc:
        raise InvalidInputError(
            f"detections must be a sequence of EchoDetection; got {type(detections).__name__}"
        ) from exc
    opts = _parse_tracking(
        dets, max_step, c, tolerance, merge_distance, max_gap, confirm, min_length
    )
    state = _Tracker(len(dets))
    for f, det in enumerate(dets):
        _track_frame(state, f, det, opts)
    return _echo_tracks(state, opts.min_len)


# ---- the steps of track_echoes -------------------------------------------------------------------


@dataclass(frozen=True)
class _TrackOptions:
    """The checked options of :func:`track_echoes` (ranges in metres)."""

    steps: np.ndarray  # (F - 1,) largest move between consecutive frames
    c: float  # speed of sound, m/s
    tol: float  # gate of a confirmed track's prediction, per frame since its last hit
    merge: float  # predictions closer than this are a crossing
    max_gap: int
    confirm: int
    min_len: int


@dataclass(eq=False)
class _Tracker:
    """The tracker's state over the frames: the direct path (F,) and the tracks so far."""

    n_frames: int
    confirmed: list[_Track] = field(default_factory=list)
    tentative: list[_Track] = field(default_factory=list)
    total: int = 0  # detections (direct paths aside) seen

    def __post_init__(self) -> None:
        self.direct = np.full(self.n_frames, np.nan)
        self.direct_amp = np.full(self.n_frames, np.nan)
        self.direct_idx = np.full(self.n_frames, -1)


def _parse_tracking(dets, max_step, c, tolerance, merge_distance, max_gap, confirm, min_length):
    """Check the inputs of :func:`track_echoes` once (messages name the argument)."""
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
    steps = as_float_array(max_step, "max_step")
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
    return _TrackOptions(steps, c, tol, merge, max_gap, confirm, min_len)


def _track_frame(state: _Tracker, f: int, det: EchoDetection, opts: _TrackOptions) -> None:
    """One frame: record the direct path, match the confirmed tracks, grow the tentative ones
    and confirm the best, and open tentative tracks on the detections left."""
    ranges = np.asarray(det.times, dtype=float) * opts.c
    amps = np.asarray(det.amplitudes, dtype=float)
    if det.direct is not None:
        state.direct[f], state.direct_amp[f], state.direct_idx[f] = (
            ranges[det.direct],
            amps[det.direct],
            det.direct,
        )
    free = [j for j in range(len(ranges)) if j != det.direct]
    state.total += len(free)
    taken: set[int] = set()
    _match_confirmed(state.confirmed, f, ranges, amps, free, taken, opts)
    grown = _grow_tentative(state.tentative, f, ranges, amps, free, taken, opts)
    _confirm_best(grown, state.confirmed, taken, opts.confirm)
    state.tentative = [
        t
        for t in grown
        if not t.confirmed and t.idx[-1] not in taken and len(t.frames) < opts.confirm
    ]
    for j in free:
        if j not in taken:
            t = _Track()
            t.add(f, ranges[j], amps[j], j)
            state.tentative.append(t)


def _match_confirmed(confirmed, f, ranges, amps, free, taken, opts: _TrackOptions) -> None:
    """Confirmed tracks: close stale ones, coast through crossings (their merged peaks belong to
    no one), match the rest (:func:`_assign`)."""
    live = [t for t in confirmed if not t.closed]
    for t in live:
        if f - t.frames[-1] > opts.max_gap + 1:
            t.closed = True
    live = [t for t in live if not t.closed]
    pred = np.array([t.predict(f) for t in live])
    crossing = np.zeros(len(live), dtype=bool)
    if len(live) > 1:
        order = np.argsort(pred)
        close = np.diff(pred[order]) < opts.merge
        crossing[order[:-1][close]] = True
        crossing[order[1:][close]] = True
    for a in np.flatnonzero(crossing):
        live[a].occluded.append(f)
        # the (merged) peaks there belong to no one
        taken.update(j for j in free if abs(ranges[j] - pred[a]) <= opts.merge)
    matchable = [a for a in range(len(live)) if not crossing[a]]
    _assign(
        [live[a] for a in matchable],
        pred[matchable],
        [opts.tol * (f - live[a].frames[-1]) for a in matchable],
        ranges,
        amps,
        free,
        taken,
        f,
    )


def _grow_tentative(tentative, f, ranges, amps, free, taken, opts: _TrackOptions) -> list:
    """Tentative tracks: extend (branching to every detection within the motion bound while the
    velocity is unknown) or drop. Returns the tracks grown."""
    grown: list[_Track] = []
    for t in tentative:
        if len(t.frames) == 1:
            reach = opts.steps[f - 1] + opts.tol
            for j in free:
                if j not in taken and abs(ranges[j] - t.ranges[-1]) <= reach:
                    b = t.branch()
                    b.add(f, ranges[j], amps[j], j)
                    grown.append(b)
        else:
            p = t.predict(f)
            near = [j for j in free if j not in taken and abs(ranges[j] - p) <= opts.tol]
            if near:
                j = min(near, key=lambda j: abs(ranges[j] - p))
                t.add(f, ranges[j], amps[j], j)
                grown.append(t)
    return grown


def _confirm_best(grown, confirmed, taken, confirm: int) -> None:
    """Confirm the smoothest of competing branches with ``confirm`` hits (they may share
    detections): each joins ``confirmed`` and takes its last detection."""
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


def _echo_tracks(state: _Tracker, min_len: int) -> EchoTracks:
    """The :class:`EchoTracks` of the direct path and the confirmed tracks with ``min_len`` hits."""
    n_frames = state.n_frames
    kept = [t for t in state.confirmed if len(t.frames) >= min_len]
    k = 1 + len(kept)
    out = np.full((n_frames, k), np.nan)
    amp = np.full((n_frames, k), np.nan)
    which = np.full((n_frames, k), -1)
    occl = np.zeros((n_frames, k), dtype=bool)
    out[:, 0], amp[:, 0], which[:, 0] = state.direct, state.direct_amp, state.direct_idx
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
        dropped_tracks=len(state.confirmed) - len(kept),
        unassigned=state.total - assigned,
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
