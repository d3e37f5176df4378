"""Echo labelling for a known microphone array: which detected peak is which image source.

Problem 1 of the paper assumes the echoes are already sorted: column k of the (M, 1+K) range
matrix holds, at every microphone, the distance to the image source of wall k. Detected peaks come
unsorted, with misses, spurious peaks and higher-order echoes among them. :func:`label_echoes`
sorts them by geometric consensus; :func:`room_from_rirs` chains detection
(:func:`rangeslam.acoustics.echoes.detect_echoes_many`), labelling and
:func:`rangeslam.localization.room_reconstruction.reconstruct_room`.

Acceptance test. Dokmanic, Parhizkar, Walther, Lu and Vetterli, "Acoustic echoes reveal room
shape", PNAS 110(30), 2013, accept a set of echoes (one per microphone) as one image source when
the microphones plus that point form a Euclidean distance matrix of embedding dimension 3: the
(M+1) x (M+1) matrix [[D_mics, r^2], [r^2^T, 0]] of squared distances must be an EDM of a point
set in R^3 (rank <= 5). With the microphone block known, that holds exactly when some point x has
||x - m_i|| = r_i for every i: when the multilateration residual is zero. With noise the rank
test becomes a bound on the residual of the best x (its s-stress is the cost of eq. (3)). So the
rank test here is multilateration: a set of echoes is one image source when the point fitted to
them predicts every one of them within the fit tolerance, for at least ``min_mics`` microphones
spanning 3-D (four would fit any four ranges; the fifth and later are the test).

Steps of :func:`label_echoes`:

1. Direct path: the detector's direct peak of each microphone (its earliest strong peak),
   located by robust multilateration (SR-LS with MSAC at ``tolerance``); at every microphone
   the peak nearest the predicted range within ``tolerance`` is then the direct path (a
   mis-picked direct peak is replaced) and the source re-fitted until the picks are stable.
   The robust spread sigma of its residuals is taken for the accuracy of the echo times;
   points are searched for with the fit tolerance clip(4 sigma, ``tolerance`` / 8,
   ``tolerance``), which keeps chance alignments of unrelated peaks out.
2. Hypotheses: for triples of microphones with large triangles (``n_triples`` a round, drawn
   with ``rng`` so as to cover every microphone), every choice of one peak per microphone
   whose ranges are compatible (differ by at most the microphones' distance) is trilaterated
   (both mirror points). Points closer to any microphone than the source are dropped: an
   image source lies beyond its wall, which has the source and every microphone on its
   other side. Each hypothesis is compared with every microphone within the uncertainty of
   its predicted range there (3 sigma propagated through the triple's geometry, plus the fit
   tolerance), kept when ``min_mics`` agree (at most 5000 a triple, the best supported), and
   moved by Gauss-Newton steps onto those peaks.
3. Consensus (RANSAC-like): the support of a hypothesis is the number of microphones with a
   peak within the fit tolerance that no point found before has, or that it predicts at least
   twice as well as the point that has it. Most supported first (then least squared error),
   a hypothesis is refined by multilateration on its echoes (least squares on the ranges,
   echoes collected again until stable) and accepted when at least ``min_mics`` microphones
   spanning 3-D agree within the fit tolerance (the EDM rank test, module docstring). Later
   rounds start hypotheses from the peaks still free, until one finds nothing new (at most 4).
   Then one peak, one point: a peak picked by several points goes to the best supported
   (most microphones), then the best fitting; points are re-fitted and those left with fewer
   than ``min_mics`` are dropped.
4. Order: nearest to the source first, a point is a higher-order image when its echoes fit
   (RMS within 3 ``tolerance``) a reflection of the source in the walls kept so far (up to
   3 reflections). Otherwise its bisector with the source is a candidate wall, kept unless it
   contradicts a kept wall: in a convex room each echo is reflected at a point of its wall
   inside all the others, and a higher-order image of walls not all found yet (or a chance
   alignment) is reflected beyond one of them. Walls confirmed by the higher-order points they
   explain come first, then the others, nearest first: the first ``n_images`` are the echo
   columns.
5. Every point collects the peak within ``tolerance`` of its predicted range at each
   microphone (conflicts as in 3).
6. Audit. A first-order image that fewer than ``min_mics`` microphones hear cleanly (its
   echoes merged with other arrivals) is missed, and a higher-order image may take its
   column: self-consistent, so it would pass. A column is left out (masked, with its reason in
   ``message``) when it is an image of the other walls, or when a wall not found, whose
   image is its reflection in another column's wall (or the source's in the bisector of the
   two images), explains the points found at least as well (more higher-order points fit the
   walls' images). Then the result is not converged when a column's wall normal has a
   standard deviation above ``max_normal_std`` (the column stays, marked doubtful in
   ``message``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._robust import MAD_TO_STD
from rangeslam._validation import (
    as_float_array,
    as_pair,
    as_points,
    as_rng,
    check_int,
    check_options_for,
    check_positive,
    frozen,
    shape_str,
)
from rangeslam.acoustics.echoes import EchoDetection, detect_echoes, detect_echoes_many
from rangeslam.acoustics.label_audit import ambiguous, classify, normal_std, wall_of
from rangeslam.acoustics.label_search import (
    Peaks,
    Triples,
    batch_refine,
    collect,
    discover,
    hypotheses,
    refine_point,
    settle,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.localization.multilateration import affine_rank, multilaterate
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room
from rangeslam.status import HasStatus, Status

__all__ = [
    "MAX_HYPOTHESES",
    "EchoLabelling",
    "RoomFromRirs",
    "detect_with_template",
    "label_echoes",
    "room_from_rirs",
]

# Points are searched for with the fit tolerance clip(_SCALE_K sigma, _MIN_FIT tolerance,
# tolerance), sigma the robust spread of the direct paths; hypotheses predicting worse than _MAX_GATE
# tolerances are dropped.
_SCALE_K = 4.0
_MIN_FIT = 0.125
_MAX_GATE = 3.0
# Rounds of hypotheses, each from n_triples new triples of microphones.
_ROUNDS = 4
#: Largest ``max_hypotheses`` accepted: ten times the default. A round holds up to n_triples times
#: this many hypotheses, each with (M,) gates and (M, 3) offsets to the microphones in float64
#: (at M = 30 and 8 triples about 3.5 GB at this limit), so larger values only exhaust memory.
MAX_HYPOTHESES = 500_000

# Measured on pyroomacoustics shoebox rooms (tests/test_echo_labelling.py: reflection order 3,
# absorption 0.1-0.3, 8-12 microphones in a 0.5 m cube or spread in the room, 30 rooms each):
# of the direct paths and first-order echoes detected within one sample and with no other
# arrival within one sample, 97.0-98.7% (16 kHz) and 99.65-99.9% (48 kHz) are labelled with the
# right image source (seeds 1 and 7). A room takes 0.1-0.3 s (compact array) or 1-2 s (spread
# array, whose wide range windows pair more peaks) for ~50 peaks per microphone. Rooms that came
# out of :func:`room_from_rirs` converged with a wrong wall (more than 5 degrees or 10 cm off),
# without step 6 -> with it (converged share in brackets): 16 kHz compact 49 of 200 (99%) ->
# 0 (65%); 16 kHz spread 7 of 100 (100%) -> 1 (94%; a third-order image with two reflections
# in the missed wall); 48 kHz compact 1 of 100 (100%) -> 0 (99%); 48 kHz spread 0 (100%) -> 0
# (100%). Step 6 adds about 0.05 s a room.
# The normal's standard deviation (max_normal_std, default 2.5 degrees), measured at 16 kHz with a
# 0.5 m array, is 0.4 degrees median, above 2.5 for a third of the rooms, and below 1.2 with 48 kHz
# or a spread array.


@dataclass(frozen=True)
class EchoLabelling(HasStatus):
    """Result of :func:`label_echoes`. M microphones, K first-order image sources found.

    Attributes:
        ranges: (M, 1+K) metres: column 0 the direct path, column k the echo of image source k;
            NaN where ``mask`` is False.
        mask: (M, 1+K) True where a detected peak was assigned.
        source: (3,) the source, multilaterated from its direct paths, metres (NaN if not found).
        images: (K, 3) first-order image sources, each multilaterated from its echoes, nearest to the
            source first (the walls are their bisector planes with ``source``).
        residuals: (M, 1+K) range residuals ||point - mic|| - range of the assigned peaks, metres;
            NaN where masked.
        peaks: (M, 1+K) index of the assigned peak in ``detections[m].times``; -1 where masked.
        normal_std: (K,) degrees: standard deviation of the normal of each column's wall (the
            bisector of the source and its image), from the range noise and the geometry of
            its microphones (see ``max_normal_std`` of :func:`label_echoes`).
        higher_order: (H, 3) further points found: higher-order image sources (reflections of the
            source in the walls found), points beyond ``n_images`` or not confirmed as walls, and
            columns left out as possible higher-order images; their peaks are not in ``ranges``.
        n_higher_order: (M,) peaks per microphone assigned to ``higher_order`` points.
        n_unassigned: (M,) peaks per microphone assigned to nothing (noise, missed images).
        tolerance: metres: the largest |range residual| of an assigned echo.
        fit_tolerance: metres: the residual within which echoes count as support when points are
            searched for (from the accuracy of the direct paths, see :func:`label_echoes`).
        status: :attr:`~rangeslam.status.Status.CONVERGED` when the source and ``n_images``
            first-order image sources (at least one when ``n_images`` is None) were found, each
            from at least ``min_mics`` microphones, none left out as a possible higher-order image
            and none with a wall normal less certain than ``max_normal_std`` (see
            :func:`label_echoes`, step 6); NOT_IDENTIFIABLE when the source or too few images were
            found or a wall normal is too uncertain; OUTLIERS when a column was left out as a
            possible higher-order image. ``converged`` is derived from it.
        message: what happened.
    """

    ranges: np.ndarray
    mask: np.ndarray
    source: np.ndarray
    images: np.ndarray
    residuals: np.ndarray
    peaks: np.ndarray
    normal_std: np.ndarray
    higher_order: np.ndarray
    n_higher_order: np.ndarray
    n_unassigned: np.ndarray
    tolerance: float
    fit_tolerance: float
    status: Status
    message: str

    @property
    def n_images(self) -> int:
        """K, the number of first-order image sources (echo columns)."""
        return int(self.images.shape[0])

    @property
    def support(self) -> np.ndarray:
        """(1+K,) microphones per column (direct path, then each image source)."""
        return self.mask.sum(axis=0)

    @property
    def has_room(self) -> bool:
        """True when the source was located and at least one echo labelled (walls to fit)."""
        return bool(self.n_images and np.all(np.isfinite(self.source)))


# ---- the labelling ------------------------------------------------------------------------------


def label_echoes(
    detections: Sequence[EchoDetection],
    mics: ArrayLike,
    *,
    c: float,
    n_images: int | None = 6,
    tolerance: float | None = None,
    min_mics: int | None = None,
    max_range: float | None = None,
    n_triples: int = 8,
    max_hypotheses: int = 50_000,
    max_normal_std: float | None = 2.5,
    rng: np.random.Generator | int | None = None,
) -> EchoLabelling:
    """Assign detected peaks to the source (direct path) and its first-order image sources.

    The steps (1. direct path, 2. hypotheses, 3. consensus, 4. order, 5. echoes collected,
    6. audit) are described in the module docstring.

    Args:
        detections: M :class:`~rangeslam.acoustics.echoes.EchoDetection`, one per microphone (empty ones for
            silent RIRs give masked rows).
        mics: (M, 3) known microphone positions, metres, not coplanar; M >= 4.
        c: speed of sound, m/s (ranges are ``times * c``).
        n_images: first-order image sources wanted (6 for a shoebox); None: as many as confirmed.
        tolerance: metres; the largest |range residual| of an assigned echo. Default one sample,
            c / fs (the lowest fs). Measured RIRs, whose echoes are less sharp than the direct
            sound, need a few centimetres.
        min_mics: microphones that must agree on a point; default max(5, ceil(M / 2)), at most M.
            Five is the fewest that checks a point in 3-D (four fit one exactly).
        max_range: metres; peaks beyond are ignored (None: all).
        n_triples: microphone triples per round of hypotheses (at most 4 rounds).
        max_hypotheses: at most this many peak triples per microphone triple (drawn with ``rng``).
        max_normal_std: degrees; not converged when the standard deviation of a column's wall
            normal (``normal_std``: range noise max(direct-path spread, the column's residual
            RMS) through its multilateration) is above it. The default 2.5 keeps a converged
            wall's normal within 5 degrees at two standard deviations. None: no such test.
        rng: random generator (or seed) for the triples and draws.

    Returns:
        An :class:`EchoLabelling`. Echoes not found are masked (NaN in ``ranges``), never zeros.
    """
    rng = as_rng(rng)
    prob = _parse_labelling(
        detections,
        mics,
        c=c,
        n_images=n_images,
        tolerance=tolerance,
        min_mics=min_mics,
        max_range=max_range,
        n_triples=n_triples,
        max_hypotheses=max_hypotheses,
        max_normal_std=max_normal_std,
    )
    src = _locate_source(prob, rng)
    if isinstance(src, str):
        nothing = _Columns(found=[], is_col=[], std={}, left_out=0)
        return _labelling(prob, _no_source(prob), nothing, Status.NOT_IDENTIFIABLE, src)
    peaks, echo = _echo_peaks(prob, src)
    found = _search_points(prob, src, peaks, echo, rng)
    cols, note = _choose_columns(prob, src, peaks, found)
    return _labelling_verdict(prob, src, cols, note)


# ---- the steps of label_echoes -------------------------------------------------------------------


@dataclass(frozen=True)
class _LabelProblem:
    """The inputs of :func:`label_echoes`, checked: M microphones, their peaks as ranges."""

    pts: np.ndarray  # (M, 3) microphones, metres
    ranges: list[np.ndarray]  # M arrays: every peak's range (time times c), metres
    in_range: list[np.ndarray]  # M boolean arrays: the peak is within max_range
    n_images: int | None
    min_mics: int
    n_triples: int
    max_hypotheses: int
    max_normal_std: float | None
    directs: list[int | None]  # M: index of each detection's direct peak, None where none
    tol: float  # metres: the largest |range residual| of an assigned echo
    cap: float  # metres: the widest gate of a hypothesis (_MAX_GATE tol)

    @property
    def n_mics(self) -> int:
        """M, the number of microphones."""
        return len(self.pts)


@dataclass(frozen=True)
class _Source:
    """Step 1: the source, its direct-path picks and the accuracy of the echo times."""

    position: np.ndarray  # (3,) metres
    picks: np.ndarray  # (M,) index of each microphone's direct peak, -1 where none
    d_src: np.ndarray  # (M,) distances from the microphones to the source, metres
    sigma: float  # metres: robust spread of the direct-path residuals (floored at fit_tol / 4)
    fit_tol: float  # metres: the fit tolerance of the point search


@dataclass(frozen=True)
class _Columns:
    """Steps 4-6: the points found [(point (3,), picks (M,))], which are echo columns, and the
    standard deviation (degrees) of each column's wall normal, by index into ``found``."""

    found: list
    is_col: list[bool]
    std: dict[int, float]
    left_out: int  # columns left out as possible higher-order images (step 6)


def _no_source(prob: _LabelProblem) -> _Source:
    """No source located: NaN position, no picks, the fit tolerance ``tol``."""
    m_n = prob.n_mics
    return _Source(
        position=np.full(3, np.nan),
        picks=np.full(m_n, -1),
        d_src=np.full(m_n, np.nan),
        sigma=math.nan,
        fit_tol=prob.tol,
    )


def _parse_labelling(
    detections,
    mics,
    *,
    c,
    n_images,
    tolerance,
    min_mics,
    max_range,
    n_triples,
    max_hypotheses,
    max_normal_std,
) -> _LabelProblem:
    """Check the inputs of :func:`label_echoes` once (messages name the argument)."""
    dets = list(detections) if isinstance(detections, Sequence) else None
    if dets is None or not dets:
        raise InvalidInputError(
            "detections must be a non-empty sequence of EchoDetection (one per microphone)"
        )
    for m, det in enumerate(dets):
        if not isinstance(det, EchoDetection):
            raise InvalidInputError(
                f"detections[{m}] must be an EchoDetection; got {type(det).__name__}"
            )
    pts = as_points(mics, "mics", dim=3)
    m_n = len(pts)
    if len(dets) != m_n:
        raise InvalidInputError(
            f"detections must hold one detection per microphone: {m_n} mics "
            f"({shape_str(pts.shape)}), {len(dets)} detections"
        )
    if m_n < 4:
        raise InvalidInputError(f"mics must hold at least 4 microphones in 3-D; got {m_n}")
    if affine_rank(pts) < 3:
        raise DegenerateGeometryError(
            "mics are coplanar (or collinear): every point has a mirror image across their plane"
        )
    c = check_positive(c, "c")
    if n_images is not None:
        n_images = check_int(n_images, "n_images", 1)
    if min_mics is None:
        min_mics = max(5, math.ceil(m_n / 2))
    min_mics = min(check_int(min_mics, "min_mics", 4), m_n)
    n_triples = check_int(n_triples, "n_triples", 1)
    max_hypotheses = check_int(max_hypotheses, "max_hypotheses", 1)
    if max_hypotheses > MAX_HYPOTHESES:
        raise InvalidInputError(
            f"max_hypotheses must be an integer in [1, {MAX_HYPOTHESES}] (each hypothesis is "
            f"held in memory); got {max_hypotheses}"
        )
    tol = (
        c / min(d.fs for d in dets) if tolerance is None else check_positive(tolerance, "tolerance")
    )
    limit = math.inf if max_range is None else check_positive(max_range, "max_range")
    if max_normal_std is not None:
        max_normal_std = check_positive(max_normal_std, "max_normal_std")
    ranges = [np.asarray(det.times, dtype=float) * c for det in dets]
    in_range = [r <= limit for r in ranges]
    return _LabelProblem(
        pts=pts,
        ranges=ranges,
        in_range=in_range,
        n_images=n_images,
        min_mics=min_mics,
        n_triples=n_triples,
        max_hypotheses=max_hypotheses,
        max_normal_std=max_normal_std,
        tol=tol,
        cap=_MAX_GATE * tol,
        directs=[d.direct for d in dets],
    )


def _locate_source(prob: _LabelProblem, rng) -> _Source | str:
    """Step 1: the source by robust multilateration of the direct peaks, re-fitted on the peaks
    within ``tol``; sigma and the fit tolerance from its residuals. A str (why) on failure."""
    pts, m_n, tol = prob.pts, prob.n_mics, prob.tol
    have = np.array(
        [d is not None and bool(prob.in_range[m][d]) for m, d in enumerate(prob.directs)]
    )
    if have.sum() < 4 or affine_rank(pts[have]) < 3:
        return (
            f"direct path found at only {int(have.sum())} of {m_n} microphones (or they are "
            "coplanar): the source cannot be located"
        )
    r0 = np.zeros(m_n)
    r0[have] = [prob.ranges[m][prob.directs[m]] for m in np.flatnonzero(have)]
    fit0 = multilaterate(pts, r0, mask=have, robust=have.sum() >= 5, inlier_threshold=tol, rng=rng)
    all_peaks = Peaks(prob.ranges, prob.in_range)
    out = refine_point(fit0.position, pts, all_peaks, tol, tol, prob.min_mics)
    if out is None:
        return (
            f"direct path: fewer than min_mics = {prob.min_mics} microphones agree within "
            f"{tol:.3g} m on one source (or they are coplanar)"
        )
    source, src_picks = out
    d_src = np.linalg.norm(pts - source, axis=1)
    res = np.linalg.norm(pts - source, axis=1) - all_peaks.picked(src_picks)
    res = res[src_picks >= 0]
    dof = max(len(res) - 3, 1)
    sigma = MAD_TO_STD * float(np.median(np.abs(res))) * math.sqrt(len(res) / dof)
    fit_tol = float(np.clip(_SCALE_K * sigma, _MIN_FIT * tol, tol))
    sigma = max(sigma, fit_tol / _SCALE_K)
    return _Source(position=source, picks=src_picks, d_src=d_src, sigma=sigma, fit_tol=fit_tol)


def _echo_peaks(prob: _LabelProblem, src: _Source) -> tuple[Peaks, list[np.ndarray]]:
    """The echo peaks: in range, not a direct path, not before the direct path at their
    microphone. Returns them as :class:`Peaks` and the (M,) boolean arrays of which they are."""
    echo = []
    for m in range(prob.n_mics):
        u = prob.in_range[m] & (prob.ranges[m] >= src.d_src[m] - prob.tol)
        if src.picks[m] >= 0:
            u[src.picks[m]] = False
        echo.append(u)
    return Peaks(prob.ranges, echo), echo


def _search_points(prob: _LabelProblem, src: _Source, peaks: Peaks, echo, rng) -> list:
    """Steps 2-3: hypotheses and consensus in rounds (at most _ROUNDS, until one adds nothing),
    then one peak, one point. Returns [(point (3,), picks (M,))]."""
    usable = np.array([u.any() for u in echo])
    found: list[tuple[np.ndarray, np.ndarray]] = []
    if usable.sum() < 3 or affine_rank(prob.pts[usable]) < 2:
        return found
    triples = Triples(prob.pts, usable, rng)
    for rnd in range(_ROUNDS):
        gen = peaks.lists if rnd == 0 else _free_peaks(prob, echo, found)
        x = _round_hypotheses(prob, src, peaks, gen, triples, rng)
        if x is None:
            break
        added = discover(x, prob.pts, peaks, src.fit_tol, prob.tol, prob.min_mics, src.d_src, found)
        if rnd > 0 and not added:
            break
    return settle(found, prob.pts, peaks, src.fit_tol, prob.min_mics)


def _free_peaks(prob: _LabelProblem, echo, found) -> list:
    """The (ranges, indices) lists of the echo peaks no point of ``found`` has taken: later
    rounds start hypotheses from these only."""
    taken = [np.zeros(len(r), dtype=bool) for r in prob.ranges]
    for _, p in found:
        for m in np.flatnonzero(p >= 0):
            taken[m][p[m]] = True
    return Peaks(prob.ranges, [e & ~t for e, t in zip(echo, taken, strict=True)]).lists


def _round_hypotheses(prob: _LabelProblem, src: _Source, peaks: Peaks, gen, triples, rng):
    """Step 2, one round: the hypotheses (N, 3) of ``n_triples`` new microphone triples, beyond
    the source from every microphone, moved onto their peaks; None when there are none."""
    pts, m_n = prob.pts, prob.n_mics
    xs, gates = [np.empty((0, 3))], [np.empty((0, m_n))]
    for trip in triples.next(prob.n_triples):
        x, g = hypotheses(
            pts,
            trip,
            gen,
            peaks,
            src.sigma,
            src.fit_tol,
            prob.cap,
            prob.min_mics,
            prob.max_hypotheses,
            rng,
        )
        xs.append(x)
        gates.append(g)
    x, g = np.vstack(xs), np.vstack(gates)
    if not len(x):
        return None
    # an image source is farther from every microphone than the source (its wall between)
    ok = np.all(np.linalg.norm(x[:, None, :] - pts[None], axis=2) >= src.d_src - prob.tol, axis=1)
    return batch_refine(x[ok], pts, peaks, (g[ok], src.fit_tol))


def _choose_columns(prob: _LabelProblem, src: _Source, peaks: Peaks, found) -> tuple[_Columns, str]:
    """Steps 4-6: order the points, classify them (first-order or not), let each collect its
    echoes within ``tol``, and audit the columns. Returns the columns and the notes for
    ``message`` on the columns left out or doubtful."""
    pts, tol, source = prob.pts, prob.tol, src.position
    # 4. first-order or higher-order
    found.sort(key=lambda f: float(np.linalg.norm(f[0] - source)))
    is_col = classify(found, source, pts, peaks, tol, prob.n_images)
    # 5. every point collects its echoes within ``tolerance``
    found = collect(found, pts, peaks, tol)
    is_col = [col and (p >= 0).sum() >= 4 for col, (_, p) in zip(is_col, found, strict=True)]
    # 6. columns that a wall not found explains as well, or whose wall the echoes do not
    # determine, are left out (ambiguous, normal_std)
    amb = ambiguous(found, is_col, source, pts, peaks, tol, src.d_src) if sum(is_col) > 1 else {}
    is_col = [col and h not in amb for h, col in enumerate(is_col)]
    std = {
        h: normal_std(found[h][0], found[h][1], source, pts, peaks, src.sigma)
        for h, col in enumerate(is_col)
        if col
    }
    cols = _Columns(found=found, is_col=is_col, std=std, left_out=len(amb))
    return cols, _left_out_notes(found, source, amb) + _doubtful_notes(prob, source, cols)


def _left_out_notes(found, source, amb: dict) -> str:
    """``message`` notes on the columns left out as possible higher-order images (step 6)."""
    return "".join(
        f"; left out the image at {np.linalg.norm(found[h][0] - source):.3g} m from the source "
        f"(wall normal {np.round(wall_of(found[h][0], source)[0], 2).tolist()}): "
        + (
            "an image of the other walls"
            if y is None
            else f"a wall not found (image at {np.round(y, 2).tolist()}) explains the points "
            "found as well"
        )
        for h, y in amb.items()
    )


def _vague(prob: _LabelProblem, cols: _Columns) -> list[int]:
    """Indices (into ``found``) of the columns whose wall normal is less certain than
    ``max_normal_std`` degrees."""
    limit = prob.max_normal_std
    return [h for h, v in cols.std.items() if limit is not None and v > limit]


def _doubtful_notes(prob: _LabelProblem, source, cols: _Columns) -> str:
    """``message`` notes on the columns whose wall normal is too uncertain (step 6)."""
    found, std = cols.found, cols.std
    return "".join(
        f"; column {1 + sorted(std).index(h)} (image at {np.linalg.norm(found[h][0] - source):.3g} "
        f"m from the source, wall normal {np.round(wall_of(found[h][0], source)[0], 2).tolist()}) "
        f"is doubtful: its echoes fix the wall's normal to {std[h]:.2g} degrees (standard "
        f"deviation), more than max_normal_std = {prob.max_normal_std:g}"
        for h in _vague(prob, cols)
    )


def _labelling_verdict(prob: _LabelProblem, src: _Source, cols: _Columns, note: str):
    """The verdict: enough first-order images (NOT_IDENTIFIABLE if not), none left out as a
    possible higher-order image (OUTLIERS), every wall normal certain enough (NOT_IDENTIFIABLE)."""
    found, is_col = cols.found, cols.is_col
    k_n = int(sum(is_col))
    counts = ", ".join(
        str(int((p >= 0).sum())) for (_, p), col in zip(found, is_col, strict=True) if col
    )
    if prob.n_images is not None and k_n < prob.n_images:
        msg = (
            f"found {k_n} of the {prob.n_images} first-order image sources asked for (from "
            f"{counts or 'no'} microphones; each needs {prob.min_mics} agreeing within "
            f"{src.fit_tol:.3g} m){note}"
        )
        return _labelling(prob, src, cols, Status.NOT_IDENTIFIABLE, msg)
    if k_n == 0:
        msg = (
            f"no image source found: no echoes agree at {prob.min_mics} microphones within "
            f"{src.fit_tol:.3g} m{note}"
        )
        return _labelling(prob, src, cols, Status.NOT_IDENTIFIABLE, msg)
    if cols.left_out:
        status = Status.OUTLIERS
    elif _vague(prob, cols):
        status = Status.NOT_IDENTIFIABLE
    else:
        status = Status.CONVERGED
    msg = (
        f"source from {int((src.picks >= 0).sum())} of {prob.n_mics} microphones, {k_n} "
        f"first-order image sources from {counts} microphones, {len(found) - k_n} other "
        f"points{note}"
    )
    return _labelling(prob, src, cols, status, msg)


def _labelling(prob: _LabelProblem, src: _Source, cols: _Columns, status, message):
    """The :class:`EchoLabelling` of the source and the columns (the others: higher order)."""
    m_n, pts = prob.n_mics, prob.pts
    found, is_col = cols.found, cols.is_col
    chosen = [f for f, col in zip(found, is_col, strict=True) if col]
    col_std = [cols.std.get(h, np.nan) for h, col in enumerate(is_col) if col]
    higher = [f for f, col in zip(found, is_col, strict=True) if not col]
    k_n = len(chosen)
    r_out = np.full((m_n, 1 + k_n), np.nan)
    res_out = np.full((m_n, 1 + k_n), np.nan)
    pk_out = np.full((m_n, 1 + k_n), -1, dtype=int)
    for k, (x, picks) in enumerate([(src.position, src.picks), *chosen]):
        sel = picks >= 0
        pk_out[sel, k] = picks[sel]
        r_out[sel, k] = [prob.ranges[m][picks[m]] for m in np.flatnonzero(sel)]
        res_out[sel, k] = np.linalg.norm(pts[sel] - x, axis=1) - r_out[sel, k]
    n_high = np.zeros(m_n, dtype=int)
    for _, picks in higher:
        n_high += picks >= 0
    n_peaks = np.array([int(u.sum()) for u in prob.in_range])
    return EchoLabelling(
        ranges=frozen(r_out),
        mask=frozen(pk_out >= 0),
        source=frozen(np.asarray(src.position, dtype=float).copy()),
        images=frozen(np.array([x for x, _ in chosen], dtype=float).reshape(k_n, 3)),
        residuals=frozen(res_out),
        peaks=frozen(pk_out),
        normal_std=frozen(np.array(col_std, dtype=float)),
        higher_order=frozen(np.array([x for x, _ in higher], dtype=float).reshape(-1, 3)),
        n_higher_order=frozen(n_high),
        n_unassigned=frozen(n_peaks - (pk_out >= 0).sum(axis=1) - n_high),
        tolerance=prob.tol,
        fit_tolerance=src.fit_tol,
        status=Status(status),
        message=message,
    )


# ---- end to end -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class RoomFromRirs(HasStatus):
    """Result of :func:`room_from_rirs`.

    Attributes:
        detections: the M echo detections.
        labelling: the :class:`EchoLabelling` of their peaks.
        reconstruction: the :class:`~rangeslam.localization.room_reconstruction.RoomReconstruction` from the
            labelled ranges (also when the labelling did not converge: what it found), or None
            when no source or no image source was labelled.
        status: :attr:`~rangeslam.status.Status.CONVERGED` when labelling and reconstruction
            both converged and the walls bound a room; else the labelling's status, the
            reconstruction's, or OUT_OF_RANGE when the walls found do not bound a room.
            ``converged`` is derived from it.
        message: what happened.
    """

    detections: tuple[EchoDetection, ...]
    labelling: EchoLabelling
    reconstruction: RoomReconstruction | None
    status: Status
    message: str


def room_from_rirs(
    rirs: ArrayLike,
    fs: float,
    mics: ArrayLike,
    *,
    c: float,
    rng: np.random.Generator | int | None = None,
    direct_template: tuple[float, float] | None = None,
    detect_options: dict[str, Any] | None = None,
    label_options: dict[str, Any] | None = None,
    reconstruct_options: dict[str, Any] | None = None,
) -> RoomFromRirs:
    """Room from M RIRs of one source and the known microphones: detect, label, reconstruct.

    :func:`rangeslam.acoustics.echoes.detect_echoes_many` -> :func:`label_echoes` ->
    :func:`rangeslam.localization.room_reconstruction.reconstruct_room` on the labelled ranges with their mask.

    Args:
        rirs: (M, L) RIRs, t = 0 at the emission. fs: Hz. mics: (M, 3) metres. c: m/s.
        rng: random generator (or seed) for labelling and reconstruction.
        direct_template: (before, after) seconds: matched-filter the RIRs with the direct sound of
            the RIR with the strongest direct path, from ``before`` its peak to ``after`` it, and
            time the echoes at the template's peak. For measured RIRs, whose loudspeaker and
            microphones make every arrival a long, ringing pulse rather than the band-limited impulse
            the detector models (each of its lobes would be taken for an echo). None: the RIRs as
            they are (simulation).
        detect_options: keyword arguments of :func:`rangeslam.acoustics.echoes.detect_echoes_many`.
        label_options: keyword arguments of :func:`label_echoes` (n_images, tolerance...).
        reconstruct_options: keyword arguments of
            :func:`rangeslam.localization.room_reconstruction.reconstruct_room` (default: ``inlier_threshold``
            of twice the labelling tolerance, since every labelled echo fits its own point within
            one tolerance).

    Returns:
        A :class:`RoomFromRirs`. When the labelling did not converge (too few echoes labelled),
        ``converged`` is False with the reason in ``message``, and ``reconstruction`` holds the
        walls it did find (None when it found no image source or no source); when the walls
        found do not bound a room, ``converged`` is False as well.
    """
    rng = as_rng(rng)
    c = check_positive(c, "c")
    as_points(mics, "mics", dim=3)  # checked before the (slow) detection; label_echoes converts
    opts = check_options_for(detect_options, "detect_options", detect_echoes, passed=("rir", "fs"))
    lopts = check_options_for(
        label_options, "label_options", label_echoes, passed=("detections", "mics", "c", "rng")
    )
    ropts = check_options_for(
        reconstruct_options, "reconstruct_options", reconstruct_room,
        passed=("mics", "ranges", "mask", "rng"),
    )  # fmt: skip
    dets = detect_with_template(rirs, fs, direct_template=direct_template, detect_options=opts)
    lab = label_echoes(dets, mics, c=c, rng=rng, **lopts)
    if not lab.has_room:
        status = lab.status if not lab.converged else Status.NOT_IDENTIFIABLE
        msg = f"echo labelling did not converge: {lab.message}"
        return RoomFromRirs(dets, lab, None, status, msg)
    ropts = {"inlier_threshold": 2.0 * lab.tolerance, **ropts}
    rec = reconstruct_room(mics, lab.ranges, mask=lab.mask, rng=rng, **ropts)
    if not lab.converged:  # the walls it found are kept and reported; the verdict is its own
        msg = f"echo labelling did not converge: {lab.message}; its walls: {rec.message}"
        return RoomFromRirs(dets, lab, rec, lab.status, msg)
    msg = f"labelling: {lab.message}; reconstruction: {rec.message}"
    if not rec.converged:
        # the reconstruction's own status once it has one (INCONSISTENT: its residual test)
        status = Status(getattr(rec, "status", Status.INCONSISTENT))
    elif rec.room is None:
        status = Status.OUT_OF_RANGE
        msg += f"; the {lab.n_images} walls found do not bound a room"
    else:
        status = Status.CONVERGED
    return RoomFromRirs(dets, lab, rec, status, msg)


def detect_with_template(
    rirs: ArrayLike,
    fs: float,
    *,
    direct_template: tuple[float, float] | None,
    detect_options: dict[str, Any],
) -> tuple[EchoDetection, ...]:
    """The M detections of :func:`room_from_rirs`: ``detect_echoes_many`` with
    ``detect_options`` (checked), matched-filtered with the direct sound of the strongest RIR
    when ``direct_template`` (before, after) seconds is given, the times then at the template's
    peak. Raises InvalidInputError for a bad template or one with an ``excitation``."""
    opts = dict(detect_options)
    shift = 0.0
    if direct_template is not None:
        if "excitation" in opts:
            raise InvalidInputError("pass either direct_template or an excitation, not both")
        opts["excitation"], shift = _direct_template(rirs, fs, direct_template)
    dets = tuple(detect_echoes_many(rirs, fs, **opts))
    if shift:  # times of the template's peak, not of its start
        dets = tuple(replace(d, times=frozen(d.times + shift)) for d in dets)
    return dets


def _direct_template(rirs, fs, direct_template) -> tuple[np.ndarray, float]:
    """The matched filter of ``room_from_rirs``: the direct sound of the RIR with the strongest
    direct path, from ``before`` its peak to ``after`` it (seconds), and the time (seconds) from
    the template's start to its peak."""
    what = "(before >= 0, after > 0) seconds, at least one sample after the direct peak"
    before, after = as_pair(direct_template, "direct_template", expected=what)
    x = as_float_array(rirs, "rirs")
    if x.ndim != 2 or not np.all(np.isfinite(x)) or not np.any(x):
        raise InvalidInputError(
            f"rirs must be a finite, non-silent (M, L) array to take a direct template from; "
            f"got shape {shape_str(x.shape)}"
        )
    fs_ = check_positive(fs, "fs")
    # a window that ends at the peak (or before it: a reversed window) is no matched filter
    if not (before >= 0 and after > 0 and math.isfinite(before + after)) or after * fs_ < 0.5:
        raise InvalidInputError(f"direct_template must be {what}; got {direct_template!r:.80}")
    m0 = int(np.argmax(np.abs(x).max(axis=1)))
    n0 = int(np.argmax(np.abs(x[m0])))
    start = max(n0 - round(before * fs_), 0)
    return x[m0, start : n0 + round(after * fs_) + 1], (n0 - start) / fs_
