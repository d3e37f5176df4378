"""Range-only EKF SLAM with odometry and radio beacons: the filtering baseline on CMU Plaza data.

The data are J. Djugash, B. Hamner and S. Roth, "Navigating with ranging radios: five data sets
with ground truth", Journal of Field Robotics 26(9), 2009 (:func:`rangeslam.datasets.plaza`).
The filter is filterpy's ``ExtendedKalmanFilter``; the equations are those of Bar-Shalom, Li and
Kirubarajan, "Estimation with Applications to Tracking and Navigation", 2001, ch. 10.

* State: the robot pose (x, y, theta), then for every beacon initialised so far its position
  (x, y), and the range calibration (below). Beacons and calibration are static.
* Prediction: each odometry step (d, dtheta) moves, then turns (as ``data.dead_reckoning`` and
  GTSAM's Plaza examples): x += d cos(theta), y += d sin(theta), theta += dtheta. Its noise is
  per step, independent on the distance and the heading change (``odometry_sigma``), mapped
  through the motion's Jacobian.
* Pose 0 is ``start_pose`` with zero covariance: it fixes the gauge (as the true start does in
  GTSAM's RangeISAMExample_plaza2).
* Range model: as :func:`rangeslam.beacons.beacon_slam`'s, measured range = (1 + s) |p - l|
  + b with s and b estimated (``range_calibration`` "affine", the default), s alone ("scale"), b
  alone ("offset") or neither (None), under zero-mean Gaussian priors (``calibration_sigma``:
  SD 0.2 on s and 10 m on b by default, as beacon_slam's). With ``per_beacon`` False (the default)
  one calibration block, (s, b) or the one estimated, is shared by all beacons. It joins the
  state with the first beacon initialised, right after that beacon's (x, y): before then no
  range reaches the filter, so a block present from the start would only carry its prior,
  uncorrelated with the rest, which is what the first beacon's fit (below) uses anyway. With
  ``per_beacon`` every beacon's (x, y) is followed by its own block.
* Ranges: a range joins at the first pose at or after its time (``data.range_pose``); to an
  initialised beacon l it is h = (1 + s)|p - l| + b with Jacobian (1 + s) u^T on p, -(1 + s) u^T
  on l, |p - l| on s and 1 on b (u = (p - l) / |p - l|), a scalar update with variance
  ``range_sigma``^2 after a Mahalanobis gate: y^2 / S above the chi-square(1) quantile
  ``gate_probability`` is rejected as an outlier (``range_inlier`` False). filterpy's update
  uses the Joseph form.

Beacon initialisation (delayed). A range says nothing about the beacon's direction, so each unseen
beacon's ranges are buffered with the filter's position at their time until there are at least
``init_ranges`` of them from positions that span a 2-D region: the smaller singular value of the
centred positions over sqrt(count), i.e. their RMS spread across the principal direction, at least
``init_spread`` metres (a straight drive leaves a mirror image of the beacon across it; Kantor and
Singh, ICRA 2002, and Djugash et al., ICRA 2006, likewise wait until the robot has moved enough).
Then the beacon is fitted to the buffered ranges by robust least squares (scipy's
``least_squares``, soft-L1 loss, residuals (1 + s)|p_i - l| + b - r_i in units of
``range_sigma``) from ``n_starts`` starts on a circle of the median calibrated range
(r - b) / (1 + s) around the positions' centroid, evenly spaced at a random offset; the lowest
cost wins, which settles the mirror ambiguity. What is fitted depends on the calibration:

- No calibration block in the state yet (``per_beacon``, or the first beacon of a shared
  calibration): (x, y) and the calibration jointly, the priors as extra residuals. They are
  needed: seen from a short stretch of path a far beacon's distance and the calibration trade off
  almost exactly (they differ only through the curvature of the range field). On Plaza1 with
  priors of SD 1e6 the first shared fit put b at -99 m, and three of the four per-beacon offset
  fits ran off to -93 m, -5.8 km and -20 km (the filter then diverged at pose 473). With the
  defaults Plaza1's first fit gives s = -0.018, b = -0.20 m, near the priors; the scale is
  learnt by the filter afterwards.
- A shared block already in the state: (x, y) alone, with the calibration held at the filter's
  estimate c^ (as if the buffered ranges were corrected to (r - b) / (1 + s)). The fitted
  position moves with the calibration by G = -(J_l^T J_l)^-1 J_l^T J_c (J_l, J_c: the fit's
  whitened Jacobians on l and on the calibration, inliers only), so the beacon joins as
  l^ + G (c - c^): cross-covariance G P_c. with the whole state (P_c. the calibration's rows of
  the covariance P) and covariance C + G P_cc G^T.
  This coupling matters: with zero cross-covariance instead, Plaza1 gave 0.55 m mean error,
  beacons 2.7-3.5 m off, scale 1.054 and b = -2.2 m.

The fit is accepted when its Jacobian has full rank; its block (the beacon's (x, y), and its
calibration when fitted jointly) has covariance C = k (J^T J)^-1 (whitened Jacobian of the fit's
inliers, |residual| within the gate, and the priors; k the larger of 1 and their chi-square per
degree of freedom) and, apart from the coupling above, zero cross-covariance with the robot and
the other beacons (the buffered positions' own errors are neglected: a filter that keeps no past
poses has no correlation to give). The buffered ranges are used by the fit only (not again as
updates); those within the gate count as inliers.

The figures behind the defaults, measured on Plaza1, are in a comment below the imports.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.stats import chi2

from rangeslam._validation import as_rng, frozen
from rangeslam.baselines.odometry_only import BaselineData, baseline_data
from rangeslam.beacons.data import RangeOdometry
from rangeslam.beacons.known import check_known_positions
from rangeslam.beacons.options import RANGE_CALIBRATIONS
from rangeslam.beacons.result import BeaconSlamResult, as_calibration
from rangeslam.datasets import PlazaDataset
from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.problem import RangeAidedProblem
from rangeslam.status import Status
from rangeslam.verdict.checks import consistency_check
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = ["EkfRangeOptions", "ekf_range_odometry"]

log = logging.getLogger(__name__)

# Measured on Plaza1 (about 0.4 s for 9,657 predictions and 3,529 ranges; with the defaults the
# beacons are initialised at poses 435-450, about 90 s in); position error after rigid alignment,
# mean / median / max, and the beacons' distances from the truth. They justify the defaults
# (affine calibration shared by all beacons):
# - defaults (affine, shared): 0.29 / 0.21 / 1.59 m; beacons 0.21-0.39 m off; scale 1.0641 (fitted
#   against the ground truth, range on true distance with intercept: 1.0694, intercept 0.03 m),
#   b = -0.06 m; all ranges used. calibration_sigma (0.05, 10), (1, 10) and (0.2, 5) give the
#   same 0.29 m mean.
# - "scale", shared: 0.28 / 0.21 / 1.48 m; beacons 0.15-0.31 m off; scale 1.0643.
# - None: 1.12 / 1.11 / 2.47 m; beacons 2.4-2.9 m off (pushed out by the unmodelled scale).
# - "offset", shared: 1.12 / 1.11 / 2.49 m; beacons 2.9-3.4 m off; b = -0.47 m.
# - "offset", per_beacon (a constant bias per beacon, this baseline's former model): 1.31 /
#   1.23 / 4.41 m, barely better than odometry alone (1.34 / 1.30 / 4.33 m); beacons 1.2-7.9 m
#   off; biases 1.4, -4.9, -2.0 and 1.7 m, not the 2.6-2.9 m of data.range_bias(): Plaza1's range
#   error is a scale (range minus true distance is about 0.07 times the distance, per-beacon
#   intercepts -0.02 to 0.10 m), which a constant bias can only trade against the distance.
# - "affine", per_beacon: 0.57 / 0.48 / 2.57 m; beacons 0.9-3.4 m off; scales 1.05-1.07 and
#   offsets -2.3 to 3.9 m (each pair from one beacon's ranges alone).
# The default odometry_sigma is a little above the per-step odometry errors measured on Plaza1
# (about 0.015 m along and across the track per 0.2 s step).


# Defaults derived from the data (a 3 m room and a 300 m field alike), each set so that
# Plaza1 keeps the figures above: range_sigma twice the ranges' own noise (a filter keeps no past
# pose to relinearise, so its ranges carry the linearisation error too; Plaza1 1.1 m, formerly a
# fixed 1 m), init_spread twice range_sigma (2.2 m, formerly 2 m: a beacon's mirror across the
# path differs in range by about twice the spread), odometry a tenth of the median step along
# (0.020 m, formerly 0.02 m) and 0.005 rad per step.
RANGE_SIGMAS = 2.0
INIT_SPREAD_SIGMAS = 2.0
ODOMETRY_STEP_FRACTION = 0.1
ODOMETRY_HEADING_SIGMA = 0.005


class _Filter(ExtendedKalmanFilter):
    """filterpy's EKF with the odometry motion (move, then turn) as its state prediction."""

    def predict_x(self, u=0):
        """x += d cos(theta), y += d sin(theta), theta += dtheta for u = (d, dtheta)."""
        d, dtheta = u
        theta = self.x[2]
        self.x[0] += d * math.cos(theta)
        self.x[1] += d * math.sin(theta)
        self.x[2] += dtheta


@dataclass(frozen=True, eq=False)  # arrays
class EkfRangeOptions:
    """The settings of :func:`ekf_range_odometry` (see its arguments), validated on
    construction, with the quantities the filter derives from them."""

    range_sigma: float
    odometry_sigma: np.ndarray
    gate_probability: float
    init_ranges: int
    init_spread: float
    range_calibration: str | None
    per_beacon: bool
    calibration_sigma: np.ndarray
    n_starts: int

    def __post_init__(self) -> None:
        """Validate; InvalidInputError names the first bad argument."""
        object.__setattr__(self, "range_sigma", _positive(self.range_sigma, "range_sigma"))
        object.__setattr__(self, "init_spread", _positive(self.init_spread, "init_spread"))
        odo = _two_positive(self.odometry_sigma, "odometry_sigma", "distance [m], heading [rad]")
        object.__setattr__(self, "odometry_sigma", odo)
        cal = _two_positive(self.calibration_sigma, "calibration_sigma", "s, b [m]")
        object.__setattr__(self, "calibration_sigma", cal)
        model = self.range_calibration
        if not (model is None or isinstance(model, str)) or model not in RANGE_CALIBRATIONS:
            raise InvalidInputError(
                f"range_calibration must be one of {RANGE_CALIBRATIONS}; got {model!r}"
            )
        if not isinstance(self.per_beacon, bool | np.bool_):
            raise InvalidInputError(f"per_beacon must be a bool; got {self.per_beacon!r}")
        p = self.gate_probability
        if not (isinstance(p, float | int) and 0 < p < 1):
            raise InvalidInputError(f"gate_probability must be in (0, 1); got {p!r}")
        for name, least in (("init_ranges", 3), ("n_starts", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | np.integer) and value >= least
            ):
                raise InvalidInputError(f"{name} must be an integer >= {least}; got {value!r}")

    @property
    def gate(self) -> float:
        """The chi-square(1) quantile of ``gate_probability``."""
        return float(chi2.ppf(self.gate_probability, 1))

    @property
    def has_s(self) -> bool:
        """The range scale error s is estimated."""
        return self.range_calibration in ("scale", "affine")

    @property
    def has_b(self) -> bool:
        """The range offset b is estimated."""
        return self.range_calibration in ("offset", "affine")

    @property
    def n_cal(self) -> int:
        """Length of a calibration block (0, 1 or 2)."""
        return int(self.has_s) + int(self.has_b)

    @property
    def prior_sd(self) -> np.ndarray:
        """The estimated calibration parameters' prior SDs, (s, b) order."""
        return self.calibration_sigma[[self.has_s, self.has_b]]


class _EkfState:
    """The filter and its bookkeeping over one run: state indices of the beacons and calibration
    blocks, the ranges buffered for beacons not yet initialised, inliers, counts."""

    def __init__(self, start: np.ndarray, n_beacons: int, n_ranges: int):
        """A filter at ``start`` (3,) with zero covariance (the gauge), no beacon yet."""
        self.ekf = _new_filter(start, np.zeros((3, 3)))
        self.offset = np.full(n_beacons, -1)  # state index of each beacon, -1 until initialised
        self.cal_at = np.full(n_beacons, -1)  # state index of each beacon's calibration block
        self.shared_at = -1  # state index of the shared calibration block, -1 until in the state
        self.buf_pos: list[list[np.ndarray]] = [[] for _ in range(n_beacons)]
        self.buf_idx: list[list[int]] = [[] for _ in range(n_beacons)]
        self.inlier = np.zeros(n_ranges, dtype=bool)
        self.n_gated = 0
        self.diverged_at: int | None = None


def ekf_range_odometry(
    data: RangeOdometry | PlazaDataset | RangeAidedProblem,
    *,
    start_pose: ArrayLike | None = None,
    range_sigma: float | None = None,
    odometry_sigma: tuple[float, float] | None = None,
    gate_probability: float = 0.99,
    init_ranges: int = 30,
    init_spread: float | None = None,
    range_calibration: str | None = "affine",
    per_beacon: bool = False,
    calibration_sigma: tuple[float, float] = (0.2, 10.0),
    n_starts: int = 8,
    rng: np.random.Generator | int | None = None,
    beacons: ArrayLike | None = None,
    beacon_sigma: float | None = None,
) -> BeaconSlamResult:
    """Poses (N + 1, 3), beacons (B, 2) and the range calibration by EKF SLAM (module notes).

    Args:
        data: the odometry and ranges as :func:`rangeslam.beacons.beacon_slam` takes them
            (:class:`~rangeslam.beacons.RangeOdometry`), a range-aided problem that is a beacon
            log (:class:`~rangeslam.rangeaided.RangeAidedProblem`, e.g. a PyFG file: one robot
            in 2-D; InvalidInputError naming why where it is not), or a CMU Plaza data set
            (:func:`rangeslam.datasets.plaza`) or one built like it.
        start_pose: (3,) x, y [m], heading [rad] of pose 0, taken as exact; default
            ``data.truth[0]`` for a Plaza set (the only use of ground truth, to fix the gauge),
            the origin facing +x for a RangeOdometry.
        range_sigma: range noise standard deviation [m]; None (default): :data:`RANGE_SIGMAS`
            times the ranges' own noise (:func:`rangeslam.beacons.defaults.range_noise`).
        odometry_sigma: (distance, heading change) noise standard deviation per step [m, rad];
            None (default): :data:`ODOMETRY_STEP_FRACTION` of the median step, and
            :data:`ODOMETRY_HEADING_SIGMA`.
        gate_probability: ranges whose squared innovation over its variance exceeds this quantile
            of chi-square with 1 degree of freedom are rejected (0.99: 6.63).
        init_ranges: ranges a beacon needs before it is initialised.
        init_spread: RMS spread [m] of the buffered positions across their principal direction
            needed before a beacon is initialised; None (default): :data:`INIT_SPREAD_SIGMAS`
            range sigmas.
        range_calibration: the range model, as :func:`rangeslam.beacons.beacon_slam`'s
            (:data:`rangeslam.beacons.RANGE_CALIBRATIONS`): measured range = (1 + s) *
            distance + b with s and b estimated ("affine", the default), s alone ("scale"), b
            alone ("offset") or neither (None: ranges taken as distances).
        per_beacon: one calibration per beacon instead of one shared by all.
        calibration_sigma: standard deviations of the zero-mean priors on s and on b [m].
        n_starts: starts of each beacon's initialisation fit.
        rng: Generator or seed for the offset of those starts.
        beacons, beacon_sigma: known beacons as beacon_slam takes them, in the state from
            the start (:func:`_add_known`); ``start_pose`` is then in their frame.

    Returns:
        :class:`BeaconSlamResult` with method "ekf": the filtered pose at each pose time
        (headings not wrapped), beacons in ``data.beacons``' row order (NaN if never
        initialised), ``range_scale`` (B,) 1 + s when s is estimated and ``range_bias`` (B,) b
        when b is estimated, else None (a shared value repeated; NaN for a beacon never
        initialised), ``range_inlier`` (R,) (False for ranges gated out, outside the gate of
        their beacon's initialisation fit, or to a beacon never initialised), ``seconds``.
        The status is SOLVER_FAILED when the state or covariance becomes non-finite or the
        covariance loses positive semi-definiteness; the poses after that are NaN.

    Raises InvalidInputError naming the argument out of the ranges above.
    """
    t0 = time.perf_counter()
    data = baseline_data(data, start_pose)  # the fields read below, from either kind of data
    range_sigma, odometry_sigma, init_spread = _from_the_data(
        data, range_sigma, odometry_sigma, init_spread
    )
    opts = EkfRangeOptions(
        range_sigma=range_sigma, odometry_sigma=odometry_sigma, gate_probability=gate_probability,
        init_ranges=init_ranges, init_spread=init_spread, range_calibration=range_calibration,
        per_beacon=per_beacon, calibration_sigma=calibration_sigma, n_starts=n_starts,
    )  # fmt: skip
    st = _EkfState(data.start, len(data.beacon_ids), len(data.ranges))
    _add_known(st, check_known_positions(beacons, beacon_sigma, len(data.beacon_ids)), opts)
    poses = _run_filter(st, data, opts, as_rng(rng))
    return _verdict(st, data, opts, poses, time.perf_counter() - t0)


def _add_known(st: _EkfState, known, opts: EkfRangeOptions) -> None:
    """The known beacons (None: none) into the state at pose 0, each followed by a calibration
    block under its priors when per beacon, the first only when shared; covariance zero when
    fixed (as pose 0's: no update moves them), else their prior's ``beacon_sigma``^2."""
    if known is None:
        return
    var = 0.0 if known.sigma is None else known.sigma**2
    for j in np.flatnonzero(known.known):
        joint = opts.n_cal > 0 and (opts.per_beacon or st.shared_at < 0)
        mean, cov = known.positions[j], np.full(2, var)
        if joint:
            mean = np.concatenate([mean, np.zeros(opts.n_cal)])
            cov = np.concatenate([cov, opts.prior_sd**2])
        _enter_beacon(st, j, mean, np.diag(cov), joint=joint, per_beacon=opts.per_beacon)


def _enter_beacon(
    st: _EkfState,
    j: int,
    mean: np.ndarray,
    cov: np.ndarray,
    *,
    joint: bool,
    per_beacon: bool,
    g: np.ndarray | None = None,
) -> None:
    """Beacon ``j`` (mean, cov) appended to the state (:func:`_augment`). ``joint``: its own
    calibration block follows it (the shared one when not ``per_beacon``); else it uses the
    shared block, through ``g`` (None: no cross-covariance)."""
    st.offset[j] = len(st.ekf.x)
    if joint:
        st.cal_at[j] = st.offset[j] + 2
        if not per_beacon:
            st.shared_at = st.cal_at[j]
        st.ekf = _augment(st.ekf, mean, cov)
    else:
        st.cal_at[j] = st.shared_at
        st.ekf = _augment(st.ekf, mean, cov, g, st.shared_at)


def _from_the_data(data: BaselineData, range_sigma, odometry_sigma, init_spread):
    """(range_sigma, odometry_sigma, init_spread) with those left at None derived from the data's
    range noise and median step (the constants above the filter)."""
    from rangeslam.beacons.defaults import range_noise

    if range_sigma is None:
        range_sigma = RANGE_SIGMAS * range_noise(data)
    if odometry_sigma is None:
        moved = np.abs(np.asarray(data.odometry, dtype=float)[:, 0])
        moved = moved[np.isfinite(moved) & (moved > 0)]
        step = float(np.median(moved)) if moved.size else 1e-6 * float(np.median(data.ranges))
        odometry_sigma = (ODOMETRY_STEP_FRACTION * step, ODOMETRY_HEADING_SIGMA)
    if init_spread is None and isinstance(range_sigma, float | int | np.number) and range_sigma > 0:
        init_spread = INIT_SPREAD_SIGMAS * float(range_sigma)
    return range_sigma, odometry_sigma, init_spread


def _run_filter(st: _EkfState, data: BaselineData, opts: EkfRangeOptions, rng) -> np.ndarray:
    """Predict at each pose, then process its ranges in time order; stops at divergence.
    Returns the filtered poses (N + 1, 3) (NaN from the divergence on)."""
    n_poses = len(data.pose_time)
    odometry = np.asarray(data.odometry, dtype=float)
    ranges = np.asarray(data.ranges, dtype=float)
    beacon_row = np.asarray(data.range_beacon)
    range_pose = np.asarray(data.range_pose)
    order = np.argsort(range_pose, kind="stable")
    first = np.searchsorted(range_pose[order], np.arange(n_poses + 1), side="left")
    poses = np.full((n_poses, 3), np.nan)
    q_odo = opts.odometry_sigma**2
    for k in range(n_poses):
        if k > 0:
            _predict(st.ekf, odometry[k - 1], q_odo)
        for r in order[first[k] : first[k + 1]]:
            j = beacon_row[r]
            if st.offset[j] < 0:
                _buffer_range(st, data, int(j), int(r), k, opts, rng)
            elif not _update_range(st, int(j), int(r), float(ranges[r]), opts):
                st.diverged_at = k
                break
        if st.diverged_at is None and not np.all(np.isfinite(st.ekf.x)):  # e.g. from odometry
            st.diverged_at = k
        if st.diverged_at is not None:
            break
        poses[k] = st.ekf.x[:3]
    return poses


def _predict(ekf: _Filter, step: np.ndarray, q_odo: np.ndarray) -> None:
    """Prediction by one odometry step (d, dtheta): F's heading column, Q = G diag(q_odo) G^T
    for the motion's Jacobian G on (d, dtheta)."""
    d, dtheta = step
    theta = ekf.x[2]
    c, s = math.cos(theta), math.sin(theta)
    ekf.F[0, 2] = -d * s
    ekf.F[1, 2] = d * c
    q = ekf.Q
    q[0, 0] = q_odo[0] * c * c
    q[0, 1] = q[1, 0] = q_odo[0] * c * s
    q[1, 1] = q_odo[0] * s * s
    q[2, 2] = q_odo[1]
    ekf.predict(u=(d, dtheta))


def _buffer_range(
    st: _EkfState, data: BaselineData, j: int, r: int, k: int, opts: EkfRangeOptions, rng
) -> None:
    """Buffer range ``r`` to beacon ``j`` (not yet initialised) with the filter's position; once
    ``init_ranges`` are buffered, try to initialise the beacon (module notes)."""
    st.buf_pos[j].append(st.ekf.x[:2].copy())
    st.buf_idx[j].append(r)
    if len(st.buf_idx[j]) < opts.init_ranges:
        return
    # Joint fit of the calibration unless it is shared and already estimated.
    joint = opts.n_cal > 0 and (opts.per_beacon or st.shared_at < 0)
    fit = _initial_beacon(
        np.array(st.buf_pos[j]),
        np.asarray(data.ranges, dtype=float)[st.buf_idx[j]],
        opts,
        opts.prior_sd if joint else None,
        _calibration(st.ekf.x, st.shared_at, opts.has_s, opts.has_b),
        rng,
    )
    if fit is None:
        return
    st.inlier[st.buf_idx[j]] = fit.inlier
    _enter_beacon(st, j, fit.mean, fit.cov, joint=joint, per_beacon=opts.per_beacon, g=fit.g)
    log.info(
        "beacon %d initialised at pose %d from %d ranges: %s",
        data.beacon_ids[j],
        k,
        len(st.buf_idx[j]),
        np.round(fit.mean, 3),
    )
    st.buf_pos[j], st.buf_idx[j] = [], []


def _update_range(st: _EkfState, j: int, r: int, measured: float, opts: EkfRangeOptions) -> bool:
    """The scalar update by range ``r`` to initialised beacon ``j`` (h = (1 + s)|p - l| + b),
    after the Mahalanobis gate; False when the filter diverges (non-finite or indefinite)."""
    ekf = st.ekf
    o, oc = st.offset[j], st.cal_at[j]
    x = ekf.x
    dx, dy = x[0] - x[o], x[1] - x[o + 1]
    dist = math.hypot(dx, dy)
    if dist < 1e-9:  # on top of the beacon: no direction to linearise along
        return True
    sc, bc = _calibration(x, oc, opts.has_s, opts.has_b)
    ux, uy = (1.0 + sc) * dx / dist, (1.0 + sc) * dy / dist
    h = np.zeros((1, len(x)))
    h[0, 0], h[0, 1] = ux, uy
    h[0, o], h[0, o + 1] = -ux, -uy
    if opts.has_s:
        h[0, oc] = dist
    if opts.has_b:
        h[0, oc + int(opts.has_s)] = 1.0
    pred = (1.0 + sc) * dist + bc
    nz = np.flatnonzero(h[0])
    hs = h[0, nz]
    var_r = opts.range_sigma**2
    s_var = float(hs @ ekf.P[np.ix_(nz, nz)] @ hs) + var_r
    innov = measured - pred
    if not (math.isfinite(innov) and math.isfinite(s_var) and s_var > 0):
        return False
    if innov * innov > opts.gate * s_var:
        st.n_gated += 1
        return True
    hx = np.array([pred])
    ekf.update(np.array([measured]), lambda _x, h=h: h, lambda _x, hx=hx: hx, R=np.array([[var_r]]))
    ekf.P = 0.5 * (ekf.P + ekf.P.T)
    st.inlier[r] = True
    return _healthy(ekf)


def _verdict(
    st: _EkfState, data: BaselineData, opts: EkfRangeOptions, poses: np.ndarray, seconds: float
) -> BeaconSlamResult:
    """The result: beacons and calibration from the final state; SOLVER_FAILED when the filter
    diverged; NOT_IDENTIFIABLE when it used no range or left a beacon it heard uninitialised
    (its ranges never reached the filter: nothing places it); else CONVERGED."""
    n_beacons = len(data.beacon_ids)
    beacons = np.full((n_beacons, 2), np.nan)
    scale = np.full(n_beacons, np.nan)
    bias = np.full(n_beacons, np.nan)
    for j in np.flatnonzero(st.offset >= 0):
        beacons[j] = st.ekf.x[st.offset[j] : st.offset[j] + 2]
        sc, bias[j] = _calibration(st.ekf.x, st.cal_at[j], opts.has_s, opts.has_b)
        scale[j] = 1.0 + sc
    if st.diverged_at is None and not _healthy(st.ekf):
        st.diverged_at = len(data.pose_time) - 1
    missing = [int(data.beacon_ids[j]) for j in np.flatnonzero(st.offset < 0)]
    heard = np.isin(np.arange(n_beacons), data.range_beacon)
    unplaced = [int(data.beacon_ids[j]) for j in np.flatnonzero(heard & (st.offset < 0))]
    notes = [f"{int(st.inlier.sum())} of {len(data.ranges)} ranges used, {st.n_gated} gated out"]
    if missing:
        notes.append(f"beacons never initialised: {missing}")
    status = Status.CONVERGED
    misfit = _kept_ranges_misfit(
        data, poses, beacons, scale if opts.has_s else None, bias if opts.has_b else None,
        st.inlier, opts.range_sigma,
    )  # fmt: skip
    if st.diverged_at is not None:
        status = Status.SOLVER_FAILED
        notes.insert(0, f"the filter diverged at pose {st.diverged_at}: non-finite or indefinite")
    elif misfit:
        status = Status.INCONSISTENT
        notes.insert(0, misfit)
    elif unplaced or not st.inlier.any():
        status = Status.NOT_IDENTIFIABLE
        notes.insert(
            0,
            f"beacons heard but never initialised: {unplaced} (fewer than init_ranges = "
            f"{opts.init_ranges} ranges from positions spread init_spread = "
            f"{opts.init_spread:.3g} m across their line)"
            if unplaced
            else "no range was used",
        )
    return BeaconSlamResult(
        method="ekf",
        pose_time=frozen(np.array(data.pose_time, dtype=float)),
        poses=frozen(poses),
        beacons=frozen(beacons),
        range_bias=as_calibration(bias, opts.per_beacon) if opts.has_b else None,
        range_inlier=frozen(st.inlier),
        status=status,
        message="; ".join(notes),
        range_scale=as_calibration(scale, opts.per_beacon) if opts.has_s else None,
        seconds=seconds,
    )


def _kept_ranges_misfit(
    data: BaselineData, poses: np.ndarray, beacons: np.ndarray, scale, bias, inlier, sigma: float
) -> str:
    """Why the ranges the filter kept do not fit its answer ('' when they do): their residuals
    against the final beacons and calibration, at the filtered poses, fail the chi-square test
    of :func:`~rangeslam.verdict.checks.consistency_check` (their sum of squares above
    ``sigma``^2 times the upper :data:`CHI2_LEVEL` quantile, one degree of freedom per range).
    The gate alone lets a wrong state keep ranges up to its edge: with known beacons and a start
    0.3 m off their frame (simulated rooms, seeds 11-13) the kept ranges' RMS was 2.9-3.4 range
    noises, where a right answer's was 0.96-0.99 (and 1.00-1.03 with 5 % wrong picks gated)."""
    kept = np.flatnonzero(inlier & np.all(np.isfinite(beacons[data.range_beacon]), axis=1))
    if len(kept) == 0:
        return ""
    j = data.range_beacon[kept]
    dist = np.linalg.norm(poses[data.range_pose[kept], :2] - beacons[j], axis=1)
    model = dist * (1.0 if scale is None else scale[j]) + (0.0 if bias is None else bias[j])
    residuals = data.ranges[kept] - model
    if consistency_check(residuals, None, len(kept), sigma, 1.0, 0.0, tail=False).passed:
        return ""
    rms = float(np.sqrt(np.mean(residuals**2)))
    return (
        f"the {len(kept)} ranges kept fit the answer to {rms:.3g} m RMS, above "
        f"the {sigma:.3g} m range noise (chi-square at {CHI2_LEVEL}): the state and its ranges "
        "disagree (a start_pose outside the known beacons' frame, or a range model that does not "
        "fit)"
    )


def _positive(value, name: str) -> float:
    """``value`` as a finite float > 0; InvalidInputError naming ``name`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}") from exc
    if not (math.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return v


def _two_positive(value, name: str, what: str) -> np.ndarray:
    """``value`` as two finite floats > 0 (``what`` they are); InvalidInputError otherwise."""
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be two positive numbers; got {value!r}") from exc
    if v.shape != (2,) or not np.all(np.isfinite(v) & (v > 0)):
        raise InvalidInputError(f"{name} must be two positive numbers ({what}); got {value!r}")
    return v


def _calibration(x: np.ndarray, at: int, has_s: bool, has_b: bool) -> tuple[float, float]:
    """(s, b) from the calibration block at state index ``at`` (0 for what is not estimated)."""
    if at < 0:
        return 0.0, 0.0
    s = float(x[at]) if has_s else 0.0
    b = float(x[at + int(has_s)]) if has_b else 0.0
    return s, b


def _new_filter(x: np.ndarray, p: np.ndarray) -> _Filter:
    """A filter with state x (n,), covariance p (n, n), F the identity, Q zero."""
    n = len(x)
    ekf = _Filter(dim_x=n, dim_z=1)
    ekf.x = np.array(x, dtype=float)
    ekf.P = np.array(p, dtype=float)
    ekf.F = np.eye(n)
    ekf.Q = np.zeros((n, n))
    return ekf


def _augment(
    ekf: _Filter, mean: np.ndarray, cov: np.ndarray, g: np.ndarray | None = None, at: int = -1
) -> _Filter:
    """The filter with a beacon (mean, cov) appended to the state. Without ``g`` its
    cross-covariance with the state is zero; with ``g`` (m, c) the new block is mean + g (c -
    c_hat) for the c-vector at state index ``at`` (the shared calibration the fit held fixed),
    so it inherits that block's covariance and correlations: cross-covariance G P, covariance
    cov + G P G^T, G being g at ``at``'s columns."""
    n, m = len(ekf.x), len(mean)
    p = np.zeros((n + m, n + m))
    p[:n, :n] = ekf.P
    p[n:, n:] = cov
    if g is not None and g.size:
        cols = slice(at, at + g.shape[1])
        cross = g @ ekf.P[cols, :]  # (m, n)
        p[n:, :n] = cross
        p[:n, n:] = cross.T
        p[n:, n:] += cross[:, cols] @ g.T
    return _new_filter(np.concatenate([ekf.x, mean]), p)


def _healthy(ekf: _Filter) -> bool:
    """Finite state and covariance, the covariance positive semi-definite (to round-off)."""
    if not (np.all(np.isfinite(ekf.x)) and np.all(np.isfinite(ekf.P))):
        return False
    eig = np.linalg.eigvalsh(ekf.P)
    return bool(eig[0] >= -1e-9 * max(eig[-1], 1.0))


@dataclass(frozen=True, eq=False)
class _BeaconFit:
    """The robust least-squares fit of one beacon to buffered positions ``pos`` (m, 2) and
    ranges ``r`` (m,): residuals (1 + s)|p_i - l| + b - r_i over ``sigma``, then (when
    ``prior_sd`` (c,) is given: the calibration fitted jointly) the whitened priors. Without
    ``prior_sd`` the calibration is held at ``fixed`` (s, b)."""

    pos: np.ndarray
    r: np.ndarray
    sigma: float
    has_s: bool
    has_b: bool
    prior_sd: np.ndarray | None
    fixed: tuple[float, float]

    @property
    def joint(self) -> bool:
        """The calibration is fitted with the beacon."""
        return self.prior_sd is not None

    @property
    def n_cal(self) -> int:
        """Calibration parameters fitted (0 unless joint)."""
        return len(self.prior_sd) if self.joint else 0

    def unpack(self, z: np.ndarray) -> tuple[float, float]:
        """(s, b) at parameters z = (x, y[, s][, b])."""
        if not self.joint:
            return self.fixed
        i_b = 2 + int(self.has_s)
        return (z[2] if self.has_s else 0.0), (z[i_b] if self.has_b else 0.0)

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """(m [+ c],) whitened residuals: ranges, then the calibration priors."""
        s, b = self.unpack(z)
        res = ((1.0 + s) * np.linalg.norm(self.pos - z[:2], axis=1) + b - self.r) / self.sigma
        return np.concatenate([res, z[2:] / self.prior_sd]) if self.joint else res

    def cal_jacobian(self, z: np.ndarray) -> np.ndarray:
        """(m, 2): d residual / d (s, b)."""
        dist = np.linalg.norm(self.pos - z[:2], axis=1)
        return np.column_stack([dist, np.ones(len(self.r))]) / self.sigma

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """(m [+ c], 2 + c) Jacobian of :meth:`residuals`."""
        m, n_cal = len(self.r), self.n_cal
        s, _ = self.unpack(z)
        diff = z[:2] - self.pos
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        jac = np.zeros((m + n_cal, 2 + n_cal))
        jac[:m, :2] = (1.0 + s) * diff / (self.sigma * dist[:, None])
        if self.joint:
            jac[:m, 2:] = self.cal_jacobian(z)[:, [self.has_s, self.has_b]]
            jac[m:, 2:] = np.diag(1.0 / self.prior_sd)
        return jac


@dataclass(frozen=True, eq=False)
class _BeaconInit:
    """A beacon's initialisation: ``mean`` (x, y[, cal]), its covariance ``cov``, ``inlier``
    (m,) of the buffered ranges, and ``g`` (2, c) the derivative of (x, y) with respect to the
    calibration held fixed (None when fitted jointly)."""

    mean: np.ndarray
    cov: np.ndarray
    inlier: np.ndarray
    g: np.ndarray | None


def _best_start(fit: _BeaconFit, n_starts: int, rng):
    """The lowest-cost soft-L1 solution from ``n_starts`` starts on a circle of the median
    calibrated range around the positions' centroid, at a random phase (None if none finite)."""
    s0, b0 = fit.fixed
    centre = fit.pos.mean(axis=0)
    radius = max(float(np.median((fit.r - b0) / (1.0 + s0))), 0.0)
    phase = rng.uniform(0.0, 2 * np.pi / n_starts)
    best = None
    for a in phase + 2 * np.pi * np.arange(n_starts) / n_starts:
        z0 = np.zeros(2 + fit.n_cal)
        z0[:2] = centre + radius * np.array([math.cos(a), math.sin(a)])
        sol = least_squares(fit.residuals, z0, jac=fit.jacobian, loss="soft_l1")
        if np.all(np.isfinite(sol.x)) and (best is None or sol.cost < best.cost):
            best = sol
    return best


def _initial_beacon(pos, r, opts: EkfRangeOptions, prior_sd, fixed, rng) -> _BeaconInit | None:
    """A beacon from positions (m, 2) and ranges (m,); None while the positions span too little
    or the fit is singular (see the module notes). ``prior_sd`` None: the calibration is held at
    ``fixed`` (s, b); else prior_sd (c,) holds the zero-mean priors of the calibration fitted
    jointly."""
    m = len(r)
    spread = np.linalg.svd(pos - pos.mean(axis=0), compute_uv=False)[-1] / math.sqrt(m)
    if spread < opts.init_spread:
        return None
    fit = _BeaconFit(pos, r, opts.range_sigma, opts.has_s, opts.has_b, prior_sd, fixed)
    n_par = 2 + fit.n_cal
    best = _best_start(fit, opts.n_starts, rng)
    if best is None:
        return None
    res = fit.residuals(best.x)
    ok = res[:m] ** 2 <= opts.gate
    n_ok = int(ok.sum())
    if n_ok <= n_par:
        return None
    keep = np.append(ok, np.ones(fit.n_cal, dtype=bool))
    jac = fit.jacobian(best.x)[keep]
    jtj = jac.T @ jac
    if np.linalg.matrix_rank(jtj) < n_par:
        return None
    inv = np.linalg.solve(jtj, np.eye(n_par))
    scale = max(1.0, float(res[keep] @ res[keep]) / (n_ok - 2))
    cov = scale * inv
    g = None
    if not fit.joint:
        g = -inv @ jac.T @ fit.cal_jacobian(best.x)[ok][:, [opts.has_s, opts.has_b]]
    return _BeaconInit(best.x, 0.5 * (cov + cov.T), ok, g)
