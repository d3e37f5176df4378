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
* Range model: as :func:`rangeslam.beacons.slam.beacon_slam`'s, measured range = (1 + s) |p - l|
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

Measured on Plaza1 (about 0.4 s for 9,657 predictions and 3,529 ranges; with the defaults the
beacons are initialised at poses 435-450, about 90 s in); position error after rigid alignment,
mean / median / max, and the beacons' distances from the truth:

- defaults (affine, shared): 0.29 / 0.21 / 1.59 m; beacons 0.21-0.39 m off; scale 1.0641 (fitted
  against the ground truth, range on true distance with intercept: 1.0694, intercept 0.03 m),
  b = -0.06 m; all ranges used. ``calibration_sigma`` (0.05, 10), (1, 10) and (0.2, 5) give the
  same 0.29 m mean.
- "scale", shared: 0.28 / 0.21 / 1.48 m; beacons 0.15-0.31 m off; scale 1.0643.
- None: 1.12 / 1.11 / 2.47 m; beacons 2.4-2.9 m off (pushed out by the unmodelled scale).
- "offset", shared: 1.12 / 1.11 / 2.49 m; beacons 2.9-3.4 m off; b = -0.47 m.
- "offset", ``per_beacon`` (a constant bias per beacon, this baseline's former model): 1.31 /
  1.23 / 4.41 m, barely better than odometry alone (1.34 / 1.30 / 4.33 m); beacons 1.2-7.9 m off;
  biases 1.4, -4.9, -2.0 and 1.7 m, not the 2.6-2.9 m of ``data.range_bias()``: Plaza1's range
  error is a scale (range minus true distance is about 0.07 times the distance, per-beacon
  intercepts -0.02 to 0.10 m), which a constant bias can only trade against the beacon's distance.
- "affine", ``per_beacon``: 0.57 / 0.48 / 2.57 m; beacons 0.9-3.4 m off; scales 1.05-1.07 and
  offsets -2.3 to 3.9 m (each pair from one beacon's ranges alone).

The defaults ``odometry_sigma`` are a little above the per-step odometry errors measured on Plaza1
(about 0.015 m along and across the track per 0.2 s step).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.stats import chi2

from rangeslam._validation import frozen
from rangeslam.baselines.odometry_only import resolve_start_pose
from rangeslam.beacons.slam import RANGE_CALIBRATIONS, BeaconSlamResult
from rangeslam.datasets import PlazaDataset
from rangeslam.errors import InvalidInputError

__all__ = ["ekf_range_odometry"]

log = logging.getLogger(__name__)


class _Filter(ExtendedKalmanFilter):
    """filterpy's EKF with the odometry motion (move, then turn) as its state prediction."""

    def predict_x(self, u=0):
        d, dtheta = u
        theta = self.x[2]
        self.x[0] += d * math.cos(theta)
        self.x[1] += d * math.sin(theta)
        self.x[2] += dtheta


def ekf_range_odometry(
    data: PlazaDataset,
    *,
    start_pose: ArrayLike | None = None,
    range_sigma: float = 1.0,
    odometry_sigma: tuple[float, float] = (0.02, 0.005),
    gate_probability: float = 0.99,
    init_ranges: int = 30,
    init_spread: float = 2.0,
    range_calibration: str | None = "affine",
    per_beacon: bool = False,
    calibration_sigma: tuple[float, float] = (0.2, 10.0),
    n_starts: int = 8,
    rng: np.random.Generator | int | None = None,
) -> BeaconSlamResult:
    """Poses (N + 1, 3), beacons (B, 2) and the range calibration by EKF SLAM (module notes).

    Args:
        data: a CMU Plaza data set (:func:`rangeslam.datasets.plaza`) or one built like it.
        start_pose: (3,) x, y [m], heading [rad] of pose 0, taken as exact; default
            ``data.truth[0]`` (the only use of ground truth, to fix the gauge).
        range_sigma: range noise standard deviation [m].
        odometry_sigma: (distance, heading change) noise standard deviation per step [m, rad].
        gate_probability: ranges whose squared innovation over its variance exceeds this quantile
            of chi-square with 1 degree of freedom are rejected (0.99: 6.63).
        init_ranges: ranges a beacon needs before it is initialised.
        init_spread: RMS spread [m] of the buffered positions across their principal direction
            needed before a beacon is initialised.
        range_calibration: the range model, as :func:`rangeslam.beacons.slam.beacon_slam`'s
            (:data:`rangeslam.beacons.slam.RANGE_CALIBRATIONS`): measured range = (1 + s) *
            distance + b with s and b estimated ("affine", the default), s alone ("scale"), b
            alone ("offset") or neither (None: ranges taken as distances).
        per_beacon: one calibration per beacon instead of one shared by all.
        calibration_sigma: standard deviations of the zero-mean priors on s and on b [m].
        n_starts: starts of each beacon's initialisation fit.
        rng: Generator or seed for the offset of those starts.

    Returns:
        :class:`BeaconSlamResult` with method "ekf": the filtered pose at each pose time
        (headings not wrapped), beacons in ``data.beacons``' row order (NaN if never
        initialised), ``range_scale`` (B,) 1 + s when s is estimated and ``range_bias`` (B,) b
        when b is estimated, else None (a shared value repeated; NaN for a beacon never
        initialised), ``range_inlier`` (R,) (False for ranges gated out, outside the gate of
        their beacon's initialisation fit, or to a beacon never initialised), ``seconds``.
        ``converged`` is False when the state or covariance becomes non-finite or the
        covariance loses positive semi-definiteness; the poses after that are NaN.

    Raises InvalidInputError (naming the argument) for a ``data`` that is not a PlazaDataset, a
    ``start_pose`` that is not a finite (3,) pose, non-positive or non-finite sigmas or spread,
    ``odometry_sigma`` or ``calibration_sigma`` not of length 2, ``gate_probability`` outside
    (0, 1), ``range_calibration`` not in RANGE_CALIBRATIONS, ``per_beacon`` not a bool, or
    ``init_ranges`` or ``n_starts`` not positive integers (``init_ranges`` at least 3).
    """
    t0 = time.perf_counter()
    start = resolve_start_pose(data, start_pose)
    range_sigma = _positive(range_sigma, "range_sigma")
    init_spread = _positive(init_spread, "init_spread")
    odo_sigma = _two_positive(odometry_sigma, "odometry_sigma", "distance [m], heading [rad]")
    cal_sigma = _two_positive(calibration_sigma, "calibration_sigma", "s, b [m]")
    if not (range_calibration is None or isinstance(range_calibration, str)) or (
        range_calibration not in RANGE_CALIBRATIONS
    ):
        raise InvalidInputError(
            f"range_calibration must be one of {RANGE_CALIBRATIONS}; got {range_calibration!r}"
        )
    if not isinstance(per_beacon, bool | np.bool_):
        raise InvalidInputError(f"per_beacon must be a bool; got {per_beacon!r}")
    if not (isinstance(gate_probability, float | int) and 0 < gate_probability < 1):
        raise InvalidInputError(f"gate_probability must be in (0, 1); got {gate_probability!r}")
    for name, value, least in (("init_ranges", init_ranges, 3), ("n_starts", n_starts, 1)):
        if isinstance(value, bool) or not (isinstance(value, int | np.integer) and value >= least):
            raise InvalidInputError(f"{name} must be an integer >= {least}; got {value!r}")
    rng = np.random.default_rng(rng)
    gate = float(chi2.ppf(gate_probability, 1))
    var_r = range_sigma**2
    q_odo = odo_sigma**2
    model = range_calibration
    has_s = model in ("scale", "affine")
    has_b = model in ("offset", "affine")
    n_cal = int(has_s) + int(has_b)
    prior_sd = cal_sigma[[has_s, has_b]]  # the estimated parameters' prior SDs, (s, b) order

    n_poses = len(data.pose_time)
    n_beacons = len(data.beacon_ids)
    odometry = np.asarray(data.odometry, dtype=float)
    ranges = np.asarray(data.ranges, dtype=float)
    beacon_row = np.asarray(data.range_beacon_index)
    range_pose = np.asarray(data.range_pose)
    order = np.argsort(range_pose, kind="stable")
    first = np.searchsorted(range_pose[order], np.arange(n_poses + 1), side="left")

    ekf = _new_filter(start, np.zeros((3, 3)))
    offset = np.full(n_beacons, -1)  # state index of each beacon, -1 until initialised
    cal_at = np.full(n_beacons, -1)  # state index of each beacon's calibration block
    shared_at = -1  # state index of the shared calibration block, -1 until in the state
    buf_pos: list[list[np.ndarray]] = [[] for _ in range(n_beacons)]
    buf_idx: list[list[int]] = [[] for _ in range(n_beacons)]
    inlier = np.zeros(len(ranges), dtype=bool)
    poses = np.full((n_poses, 3), np.nan)
    r_mat = np.array([[var_r]])
    diverged_at = None
    n_gated = 0

    for k in range(n_poses):
        if k > 0:
            d, dtheta = odometry[k - 1]
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
        for r in order[first[k] : first[k + 1]]:
            j = beacon_row[r]
            if offset[j] < 0:
                buf_pos[j].append(ekf.x[:2].copy())
                buf_idx[j].append(int(r))
                if len(buf_idx[j]) >= init_ranges:
                    # Joint fit of the calibration unless it is shared and already estimated.
                    joint = n_cal > 0 and (per_beacon or shared_at < 0)
                    fixed = _calibration(ekf.x, shared_at, has_s, has_b)
                    fit = _initial_beacon(
                        np.array(buf_pos[j]),
                        ranges[buf_idx[j]],
                        range_sigma,
                        init_spread,
                        gate,
                        (has_s, has_b),
                        prior_sd if joint else None,
                        fixed,
                        n_starts,
                        rng,
                    )
                    if fit is not None:
                        mean, cov, ok, g = fit
                        inlier[buf_idx[j]] = ok
                        offset[j] = len(ekf.x)
                        if joint:
                            cal_at[j] = offset[j] + 2
                            if not per_beacon:
                                shared_at = cal_at[j]
                            ekf = _augment(ekf, mean, cov)
                        else:
                            cal_at[j] = shared_at
                            ekf = _augment(ekf, mean, cov, g, shared_at)
                        log.info(
                            "beacon %d initialised at pose %d from %d ranges: %s",
                            data.beacon_ids[j],
                            k,
                            len(buf_idx[j]),
                            np.round(mean, 3),
                        )
                        buf_pos[j], buf_idx[j] = [], []
                continue
            o, oc = offset[j], cal_at[j]
            x = ekf.x
            dx, dy = x[0] - x[o], x[1] - x[o + 1]
            dist = math.hypot(dx, dy)
            if dist < 1e-9:  # on top of the beacon: no direction to linearise along
                continue
            sc, bc = _calibration(x, oc, has_s, has_b)
            ux, uy = (1.0 + sc) * dx / dist, (1.0 + sc) * dy / dist
            h = np.zeros((1, len(x)))
            h[0, 0], h[0, 1] = ux, uy
            h[0, o], h[0, o + 1] = -ux, -uy
            if has_s:
                h[0, oc] = dist
            if has_b:
                h[0, oc + int(has_s)] = 1.0
            pred = (1.0 + sc) * dist + bc
            nz = np.flatnonzero(h[0])
            hs = h[0, nz]
            s_var = float(hs @ ekf.P[np.ix_(nz, nz)] @ hs) + var_r
            innov = ranges[r] - pred
            if not (math.isfinite(innov) and math.isfinite(s_var) and s_var > 0):
                diverged_at = k
                break
            if innov * innov > gate * s_var:
                n_gated += 1
                continue
            hx = np.array([pred])
            ekf.update(
                np.array([ranges[r]]),
                lambda _x, h=h: h,
                lambda _x, hx=hx: hx,
                R=r_mat,
            )
            ekf.P = 0.5 * (ekf.P + ekf.P.T)
            inlier[r] = True
            if not _healthy(ekf):
                diverged_at = k
                break
        if diverged_at is None and not np.all(np.isfinite(ekf.x)):  # e.g. from the odometry
            diverged_at = k
        if diverged_at is not None:
            break
        poses[k] = ekf.x[:3]

    beacons = np.full((n_beacons, 2), np.nan)
    scale = np.full(n_beacons, np.nan)
    bias = np.full(n_beacons, np.nan)
    for j in np.flatnonzero(offset >= 0):
        beacons[j] = ekf.x[offset[j] : offset[j] + 2]
        sc, bias[j] = _calibration(ekf.x, cal_at[j], has_s, has_b)
        scale[j] = 1.0 + sc
    if diverged_at is None and not _healthy(ekf):
        diverged_at = n_poses - 1
    missing = [int(data.beacon_ids[j]) for j in np.flatnonzero(offset < 0)]
    notes = [
        f"{int(inlier.sum())} of {len(ranges)} ranges used, {n_gated} gated out",
    ]
    if missing:
        notes.append(f"beacons never initialised: {missing}")
    if diverged_at is not None:
        notes.insert(
            0,
            f"the filter diverged at pose {diverged_at}: non-finite or indefinite",
        )
    return BeaconSlamResult(
        method="ekf",
        pose_time=frozen(np.array(data.pose_time, dtype=float)),
        poses=frozen(poses),
        beacons=frozen(beacons),
        range_bias=frozen(bias) if has_b else None,
        range_inlier=frozen(inlier),
        converged=diverged_at is None,
        message="; ".join(notes),
        range_scale=frozen(scale) if has_s else None,
        seconds=time.perf_counter() - t0,
    )


def _positive(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}") from exc
    if not (math.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return v


def _two_positive(value, name: str, what: str) -> np.ndarray:
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


def _initial_beacon(pos, r, sigma, min_spread, gate, estimated, prior_sd, fixed, n_starts, rng):
    """(mean, cov, inlier, g) of a beacon from positions (m, 2) and ranges (m,); None while the
    positions span too little or the fit is singular (see the module notes).

    ``estimated``: (has_s, has_b), the calibration parameters of the range model. ``prior_sd``
    None: the calibration is held at ``fixed`` (s, b), mean is (x, y) and g (2, c) the derivative
    of the fitted (x, y) with respect to the c estimated calibration parameters; else prior_sd
    (c,) holds the zero-mean priors of the calibration fitted jointly, mean is (x, y, *cal) and g
    None."""
    m = len(r)
    centre = pos.mean(axis=0)
    spread = np.linalg.svd(pos - centre, compute_uv=False)[-1] / math.sqrt(m)
    if spread < min_spread:
        return None
    has_s, has_b = estimated
    joint = prior_sd is not None
    n_cal = len(prior_sd) if joint else 0
    n_par = 2 + n_cal
    i_b = 2 + int(has_s)  # index of b in a jointly fitted z

    def unpack(z):
        if not joint:
            return fixed
        return (z[2] if has_s else 0.0), (z[i_b] if has_b else 0.0)

    def residuals(z):  # ranges, then the calibration priors, whitened
        s, b = unpack(z)
        res = ((1.0 + s) * np.linalg.norm(pos - z[:2], axis=1) + b - r) / sigma
        return np.concatenate([res, z[2:] / prior_sd]) if joint else res

    def cal_jacobian(z):  # (m, 2): d residual / d (s, b)
        dist = np.linalg.norm(pos - z[:2], axis=1)
        return np.column_stack([dist, np.ones(m)]) / sigma

    def jacobian(z):
        s, _ = unpack(z)
        diff = z[:2] - pos
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-12)
        jac = np.zeros((m + n_cal, n_par))
        jac[:m, :2] = (1.0 + s) * diff / (sigma * dist[:, None])
        if joint:
            jac[:m, 2:] = cal_jacobian(z)[:, [has_s, has_b]]
            jac[m:, 2:] = np.diag(1.0 / prior_sd)
        return jac

    s0, b0 = fixed
    radius = max(float(np.median((r - b0) / (1.0 + s0))), 0.0)
    phase = rng.uniform(0.0, 2 * np.pi / n_starts)
    best = None
    for a in phase + 2 * np.pi * np.arange(n_starts) / n_starts:
        z0 = np.zeros(n_par)
        z0[:2] = centre + radius * np.array([math.cos(a), math.sin(a)])
        sol = least_squares(residuals, z0, jac=jacobian, loss="soft_l1")
        if np.all(np.isfinite(sol.x)) and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        return None
    res = residuals(best.x)
    ok = res[:m] ** 2 <= gate
    n_ok = int(ok.sum())
    if n_ok <= n_par:
        return None
    keep = np.append(ok, np.ones(n_cal, dtype=bool))
    jac = jacobian(best.x)[keep]
    jtj = jac.T @ jac
    if np.linalg.matrix_rank(jtj) < n_par:
        return None
    inv = np.linalg.solve(jtj, np.eye(n_par))
    scale = max(1.0, float(res[keep] @ res[keep]) / (n_ok - 2))
    cov = scale * inv
    g = None
    if not joint:
        g = -inv @ jac.T @ cal_jacobian(best.x)[ok][:, [has_s, has_b]]
    return best.x, 0.5 * (cov + cov.T), ok, g
