"""Unknown emission times: every range of one acoustic event carries the same unknown offset.

When the emission time of an event is known only up to an error tau (seconds), each range measured
from it is r = ||x - a|| + b with one constant offset b = c tau (metres) for the whole event: the
direct path and every echo (the paper's "future work"). Here b is estimated jointly with the
geometry.

Known microphones (Problem 1)
    :func:`multilaterate_with_offset` (in :mod:`.pseudorange`, re-exported here) locates one
    point and b from M >= d + 2 ranges (pseudoranges, as in GPS). Squaring
    (r - b)^2 = ||x - a||^2 gives

        r_m^2 - ||a_m||^2 = -2 a_m.x + 2 r_m b + (||x||^2 - b^2)                       (E1)

    linear in (x, b, t = ||x||^2 - b^2). The starts are its unconstrained least-squares solution
    and Bancroft's (Bancroft, "An algebraic solution of the GPS equations", IEEE Trans. AES 21(1),
    1985): (x, b) = p + t q from the d + 1 columns of (E1) without t, and t from the quadratic
    t = ||x(t)||^2 - b(t)^2. Each start is refined by Gauss-Newton (Levenberg-Marquardt) on the
    range residuals ||x - a_m|| + b - r_m (the Gaussian ML) and the lowest cost is kept.

    :func:`reconstruct_room_unknown_emission`: the source and its K first-order image sources share
    the event's offset. b is estimated by a joint least squares over the K + 1 points as free points
    and one b; then the ranges minus b go to :func:`rangeslam.reconstruct_room`. With one image per
    wall, (source, images) and (source, walls) are two parametrisations of the same points (wall k
    is the bisector of s and its image), so this two-step estimate is the joint ML of (b, source,
    walls): no information is lost by fixing b first.

    The price of the unknown time is one more unknown per event: the Cramer-Rao bounds of the
    source and of the walls grow (the source's most, the normals' least), and the estimates
    attain them. The unknown-time result is the known-time one plus the offset error propagated
    through the geometry (tests/test_emission.py).

Unknown microphones (Problem 2)
    :func:`calibrate_unknown_emission`: multidimensional unfolding with one unknown offset per
    event (a group of columns, e.g. a loudspeaker and its image sources). The offsets start from
    a rank test (:func:`offsets_from_rank`: the double-centred squared corrected ranges have rank
    d), the points from the SDP of :func:`rangeslam.calibrate` on the corrected ranges; then
    points and offsets are refined jointly by least squares on the ranges. The SDP's own offset
    model (``range_model="offset"``) does not serve as a start here: with every pair an offset
    range, its relaxation lets the offsets absorb most of the ranges.

Identifiability. An offset is told from geometry only by the curvature of the wavefronts. For one
point the Jacobian rows are [u_m, 1] (u_m the unit vector from anchor m), singular when the u_m
lie on a cone, u_m . n = const (anchors on a cone around the point; in the far field all u_m
nearly coincide and b trades off against the distance). In MDU, the ranges must number at least
(M + K) d - d (d + 1) / 2 + G (G offsets), and then generic configurations are locally
identifiable, even with ONE offset shared by all ranges: ||x - y|| + b is not a Euclidean
distance for b != 0 (no scaling or motion of the points adds a constant to every distance). The
Jacobian of (points, offsets) was measured to have full rank up to the rigid motions for random
points, one or per-column offsets, and for sources with their images, whenever the count allows
(e.g. 5 receivers and 5 sources in 3-D with one offset: 25 ranges, 25 unknowns). Not
identifiable: d = 1 with receivers on one side of the sources, and the far field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from rangeslam._robust import robust_mode
from rangeslam._validation import (
    as_float_array,
    as_mask,
    as_points,
    as_rng,
    as_speed,
    frozen,
    shape_str,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.localization.multilateration import affine_rank, check_spanning, multilaterate
from rangeslam.localization.pseudorange import (
    OffsetMultilaterationResult,
    multilaterate_with_offset,
    pseudoranges,
)
from rangeslam.localization.robust_start import check_robust_options
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room
from rangeslam.status import HasStatus, Status
from rangeslam.verdict.thresholds import RANK_RTOL

__all__ = [
    "OffsetMultilaterationResult",
    "UnknownEmissionRoom",
    "multilaterate_with_offset",
    "reconstruct_room_unknown_emission",
]

# --- one event heard through its direct path and first-order echoes (Problem 1) -----------------


@dataclass(frozen=True)
class UnknownEmissionRoom(HasStatus):
    """Result of :func:`reconstruct_room_unknown_emission`.

    Attributes:
        offset: range offset b of the event, metres (measured range = distance + b).
        offset_time: b / c, seconds (the emission time error: the event was emitted that much
            later than assumed); NaN when no speed of sound was given.
        offset_std: standard deviation of b from the joint fit, metres (the residual noise level
            times the square root of the offset's diagonal entry of (J^T J)^-1); 0 for exact data.
        corrected_ranges: (M, 1+K) the ranges minus b (0 where not observed): the input of the
            room reconstruction.
        reconstruction: the :class:`rangeslam.RoomReconstruction` from the corrected ranges (one
            loudspeaker: ``sources`` is (1, d)).
        points: (1+K, d) the source and image sources of the joint offset fit (free points).
        residual_rms: RMS range residual of the joint offset fit over the ranges it used, metres.
        status: :class:`rangeslam.status.Status` (``converged`` is ``status is CONVERGED``): the
            offset fit's NOT_IDENTIFIABLE (no redundancy, rank-deficient) or SOLVER_FAILED, else
            the reconstruction's status.
        message: what happened.
    """

    offset: float
    offset_time: float
    offset_std: float
    corrected_ranges: np.ndarray
    reconstruction: RoomReconstruction
    points: np.ndarray
    residual_rms: float
    status: Status
    message: str

    @property
    def room(self):
        """The reconstructed room (or None), as ``reconstruction.room``."""
        return self.reconstruction.room


class _SharedOffsetModel:
    """Residuals ||m - p_c|| + b - r_mc of free points p_c (C, d) sharing one offset b.

    theta = [p_0, ..., p_{C-1}, b]; the Jacobian is analytic: d/dp_c = (p_c - m) / ||p_c - m||,
    d/db = 1.
    """

    def __init__(self, mics: np.ndarray, ranges: np.ndarray, use: np.ndarray) -> None:
        self.mics = mics
        self.d = mics.shape[1]
        self.n_points = ranges.shape[1]
        self.pairs = np.argwhere(use)  # (P, 2): (mic, column)
        self.r = ranges[use]

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        pts = theta[:-1].reshape(self.n_points, self.d)
        m, c = self.pairs[:, 0], self.pairs[:, 1]
        return np.linalg.norm(pts[c] - self.mics[m], axis=1) + theta[-1] - self.r

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        pts = theta[:-1].reshape(self.n_points, self.d)
        m, c = self.pairs[:, 0], self.pairs[:, 1]
        diff = pts[c] - self.mics[m]
        u = diff / np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-300)
        jac = np.zeros((len(self.pairs), theta.size))
        rows = np.arange(len(self.pairs))[:, None]
        jac[rows, c[:, None] * self.d + np.arange(self.d)[None, :]] = u
        jac[:, -1] = 1.0
        return jac


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


#: Column fits that give no start: the robust search failed, or least squares did.
_NO_START = (Status.OUTLIERS, Status.SOLVER_FAILED)


def _offset_start(mics, r, observed, robust, inlier_threshold, max_hypotheses, rng):
    """Offset and points (C, d) to start the joint fit, from each column on its own.

    Every column with d + 2 observed ranges from microphones spanning R^d is located with its own
    offset (:func:`multilaterate_with_offset`); the start is their median weighted by 1 / dop_b^2
    (the direct path, surrounded by microphones, usually dominates; a mis-picked column is
    outvoted). Columns without their own estimate get a point by SR-LS from the ranges minus b.
    """
    c_n = r.shape[1]
    d = mics.shape[1]
    pts = np.full((c_n, d), np.nan)
    offsets, inv_var = [], []
    for c in range(c_n):
        obs = observed[:, c]
        if obs.sum() < d + 2 or affine_rank(mics[obs]) < d:
            continue
        try:
            res = multilaterate_with_offset(
                mics,
                r[:, c],
                mask=obs,
                robust=robust,
                inlier_threshold=inlier_threshold,
                max_hypotheses=max_hypotheses,
                rng=rng,
            )
        except DegenerateGeometryError:
            continue
        # A start needs a fit, not a verdict: a column weakly determined on its own (an image
        # source far from the array) still votes, weighted by its offset's precision.
        if res.status not in _NO_START and np.all(np.isfinite(res.dop)):
            pts[c] = res.position
            offsets.append(res.offset)
            inv_var.append(1.0 / res.dop[-1] ** 2)
    if not offsets:
        raise InvalidInputError(
            f"no column of ranges has {d + 2} observed ranges from microphones spanning {d}-D: "
            "an unknown offset needs one more range per point than multilateration"
        )
    b0 = _weighted_median(np.array(offsets), np.array(inv_var))
    for c in range(c_n):
        obs = observed[:, c]
        if np.all(np.isfinite(pts[c])) or obs.sum() < d + 1 or affine_rank(mics[obs]) < d:
            continue
        pts[c] = multilaterate(mics, np.maximum(r[:, c] - b0, 0.0), mask=obs).position
    return b0, pts


@dataclass(frozen=True)
class SharedOffsetFit:
    """The joint least squares of points (C, d) and their shared offset b, scaled units.

    Attributes:
        offset: b; points: (C, d) (NaN for columns left out); rms: RMS range residual;
        offset_std: standard deviation of b (inf when rank-deficient, NaN without redundancy);
        failure: (status, message) when the fit cannot be trusted, None otherwise.
    """

    offset: float
    points: np.ndarray
    rms: float
    offset_std: float
    failure: tuple[Status, str] | None


def _with_free(theta0: np.ndarray, free: np.ndarray, t: np.ndarray) -> np.ndarray:
    """theta0 with its ``free`` entries replaced by t."""
    full = theta0.copy()
    full[free] = t
    return full


def _joint_offset_fit(mics, r, use, b0, pts0) -> SharedOffsetFit:
    """Least squares of (points, b) on the ranges in ``use`` (columns with finite pts0 only)."""
    cols = np.all(np.isfinite(pts0), axis=1)
    use = use & cols[None, :]
    model = _SharedOffsetModel(mics, r, use)
    theta0 = np.r_[np.where(cols[:, None], pts0, 0.0).ravel(), b0]
    # Columns left out keep their (zero) parameters: their Jacobian columns are zero, so drop
    # them from the optimisation by fitting only the parameters of the columns used.
    free = np.r_[np.repeat(cols, mics.shape[1]), True]
    n_res, n_par = int(use.sum()), int(free.sum())
    if n_res <= n_par:
        text = (
            f"{n_res} ranges for {n_par} unknowns (points and offset): no redundancy to tell the "
            "offset; "
        )
        nan = float("nan")
        return SharedOffsetFit(b0, pts0, nan, nan, (Status.NOT_IDENTIFIABLE, text))
    fit = least_squares(
        lambda t: model.residuals(_with_free(theta0, free, t)),
        theta0[free],
        jac=lambda t: model.jacobian(_with_free(theta0, free, t))[:, free],
        method="lm",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    theta = _with_free(theta0, free, fit.x)
    pts = np.where(cols[:, None], theta[:-1].reshape(-1, mics.shape[1]), np.nan)
    sv = np.linalg.svd(fit.jac, compute_uv=False)
    ssr = float(fit.fun @ fit.fun)
    rms = math.sqrt(ssr / n_res)
    message = "" if fit.status > 0 else f"offset fit: least squares failed: {fit.message}; "
    failed = Status.SOLVER_FAILED if message else None
    if sv[-1] <= RANK_RTOL * sv[0]:
        text = message + "the offset cannot be told from the geometry (rank-deficient joint fit); "
        return SharedOffsetFit(
            theta[-1], pts, rms, float("inf"), (failed or Status.NOT_IDENTIFIABLE, text)
        )
    _, s, vt = np.linalg.svd(fit.jac, full_matrices=False)
    var_b = float(np.sum((vt[:, -1] / s) ** 2))  # (J^T J)^-1 entry of b
    std_b = math.sqrt(ssr / (n_res - n_par) * var_b)
    return SharedOffsetFit(
        float(theta[-1]), pts, rms, std_b, None if failed is None else (failed, message)
    )


@dataclass(frozen=True)
class EventProblem:
    """The inputs of :func:`reconstruct_room_unknown_emission`, parsed once.

    Attributes:
        mics: (M, d) metres; ranges: (M, 1+K) metres (0 where unobserved); observed: (M, 1+K).
        centre, scale: the microphones' centroid (d,) and RMS radius, metres.
        mics_s, ranges_s: centred and divided by ``scale`` (b scales with the ranges).
    """

    mics: np.ndarray
    ranges: np.ndarray
    observed: np.ndarray
    centre: np.ndarray
    scale: float
    mics_s: np.ndarray
    ranges_s: np.ndarray


@dataclass(frozen=True)
class EventFit:
    """One round: the joint offset fit (scaled units), the ranges minus b (M, 1+K), metres, and
    the room reconstructed from them."""

    offset_fit: SharedOffsetFit
    corrected: np.ndarray
    room: RoomReconstruction


def _parse_event(mics, ranges, mask, c) -> EventProblem:
    """Validate mics (M, d), M >= d + 2 spanning R^d, ranges (M, 1+K), mask and c once; scale."""
    m_pts = as_points(mics, "mics")
    m_n, d = m_pts.shape
    if m_n < d + 2:
        raise InvalidInputError(
            f"mics must hold at least d + 2 = {d + 2} microphones in {d}-D with an unknown "
            f"emission time; got {shape_str(m_pts.shape)}"
        )
    check_spanning(m_pts, d, "mics", "the image sources are ambiguous")
    shape = as_float_array(ranges, "ranges").shape
    if len(shape) != 2 or shape[0] != m_n or shape[1] < 2:
        raise InvalidInputError(
            f"ranges must have shape ({m_n}, 1+K) with K >= 1 echo columns; got {shape_str(shape)}"
        )
    observed = as_mask(mask, "mask", shape=shape)
    r = pseudoranges(ranges, "ranges", shape, observed)
    c = as_speed(c)
    # Centre on the microphones and scale to unit size (b scales with the ranges).
    centre = m_pts.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m_pts - centre) ** 2, axis=1))))
    return EventProblem(m_pts, r, observed, centre, scale, (m_pts - centre) / scale, r / scale)


@dataclass(frozen=True)
class RoomOptions:
    """The robust settings passed on to :func:`rangeslam.reconstruct_room`."""

    robust: bool
    inlier_threshold: float | None
    max_hypotheses: int


def _event_round(prob: EventProblem, use, b_s, pts, options: RoomOptions, rng) -> EventFit:
    """Fit b jointly over the points on the ranges in ``use``, then the room on the ranges minus b.

    ``options``: robust, inlier_threshold and max_hypotheses of :func:`reconstruct_room`.
    """
    fit = _joint_offset_fit(prob.mics_s, prob.ranges_s, use, b_s, pts)
    observed, b = prob.observed, fit.offset * prob.scale
    corrected = np.where(observed, prob.ranges - b, 0.0)
    if np.any(corrected[observed] < 0):
        bad = tuple(int(i) for i in np.argwhere(observed & (corrected < 0))[0])
        raise InvalidInputError(
            f"ranges minus the estimated offset {b:.4g} m are negative (entry {bad}): "
            "the ranges are inconsistent with one offset per event"
        )
    room = reconstruct_room(
        prob.mics,
        corrected,
        mask=observed,
        robust=options.robust,
        inlier_threshold=options.inlier_threshold,
        max_hypotheses=options.max_hypotheses,
        rng=rng,
    )
    return EventFit(fit, corrected, room)


def _event_result(prob: EventProblem, last: EventFit, c) -> UnknownEmissionRoom:
    """The verdict: the offset fit's failure first, else the room's status; caller's units."""
    fit, room, scale = last.offset_fit, last.room, prob.scale
    message = "" if fit.failure is None else fit.failure[1]
    status = room.status if fit.failure is None else fit.failure[0]
    if not room.converged:
        message += f"room reconstruction: {room.message}; "
    b = float(fit.offset * scale)
    if status is Status.CONVERGED:
        message = f"offset {b:.4g} m; {room.message}"
    return UnknownEmissionRoom(
        offset=b,
        offset_time=float("nan") if c is None else b / float(c),
        offset_std=float(fit.offset_std * scale),
        corrected_ranges=frozen(last.corrected),
        reconstruction=room,
        points=frozen(prob.centre + scale * fit.points),
        residual_rms=float(fit.rms * scale),
        status=status,
        message=message.strip().rstrip(";"),
    )


def reconstruct_room_unknown_emission(
    mics: ArrayLike,
    ranges: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    c: float | None = None,
    robust: bool = True,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 500,
    rng: np.random.Generator | int | None = None,
) -> UnknownEmissionRoom:
    """Room, source and emission time error of one event heard by a known microphone array.

    Args:
        mics: (M, d) known microphone positions, metres, affinely spanning R^d; at least d + 2.
        ranges: (M, 1+K) ranges from each microphone to the source (column 0) and to its K
            first-order image sources (column k for wall k), all with the same unknown offset b:
            r = distance + b, e.g. c times (arrival time - assumed emission time).
        mask: (M, 1+K) boolean, True where the echo was observed.
        c: speed of sound in m/s, to report b in seconds (``offset_time``); optional.
        robust, inlier_threshold, max_hypotheses: as :func:`rangeslam.reconstruct_room`. With
            ``robust`` the start of b is a weighted median of per-column robust estimates, and b is
            re-estimated on the ranges the reconstruction keeps, until they are stable.
        rng: random generator (or seed) for the robust searches.

    Returns:
        :class:`UnknownEmissionRoom`. b is estimated jointly over the source and every image
        source (one least squares, (1+K) d + 1 unknowns), then the walls by
        :func:`rangeslam.reconstruct_room` on the ranges minus b (the joint ML of b and the room,
        see the module docstring).
    """
    rng = as_rng(rng)
    robust = robust_mode(robust, ("on",)) is not None  # True: on; None or False: off
    inlier_threshold, max_hypotheses = check_robust_options(inlier_threshold, max_hypotheses)
    prob = _parse_event(mics, ranges, mask, c)
    thr_s = None if inlier_threshold is None else inlier_threshold / prob.scale
    b_s, pts = _offset_start(
        prob.mics_s, prob.ranges_s, prob.observed, robust, thr_s, max_hypotheses, rng
    )
    options = RoomOptions(robust, inlier_threshold, max_hypotheses)
    use = prob.observed.copy()
    last = _event_round(prob, use, b_s, pts, options, rng)
    for _ in range(4 if robust else 0):
        # Re-estimate b on the ranges the reconstruction kept, from its points.
        room = last.room
        if np.array_equal(room.inliers[0], use):
            break
        use = room.inliers[0]
        pts = (np.vstack([room.sources, room.image_sources[0]]) - prob.centre) / prob.scale
        last = _event_round(prob, use, last.offset_fit.offset, pts, options, rng)
    return _event_result(prob, last, c)
