"""Range-only SLAM with an extended Kalman filter: the baseline "from the filtering world".

One microphone moves along an unknown trajectory r_1..r_M and measures its ranges to K static
landmarks at unknown positions (a loudspeaker and its image sources). There is no odometry
direction and no compass, only (optionally) bounds on each step length, so the answer is defined
up to a rigid motion and a reflection. :func:`rangeslam.mdu.slam` solves the problem in batch (EDM
completion with eq. 11 step bounds, then GTSAM); :func:`ekf_slam` is the recursive alternative it
is compared against.

Filter (filterpy's ``ExtendedKalmanFilter``; the equations are those of Bar-Shalom, Li and
Kirubarajan, "Estimation with Applications to Tracking and Navigation", 2001, ch. 10):

* State: the current position p_i, the last step v_i = p_i - p_(i-1), every landmark l_1..l_K, and
  stochastic clones of the positions of the initialisation window (see below; Roumeliotis and
  Burdick, "Stochastic cloning", ICRA 2002), so that what is learnt later also corrects them.
* Motion: p_(i+1) = p_i + a v_i + w_i, v_(i+1) = a v_i + w_i, landmarks and clones static. With
  ``motion="constant_velocity"`` (a = 1, the default) the next step repeats the last one up to w_i;
  with ``motion="random_walk"`` (a = 0) it is drawn afresh. The process noise w_i carries the
  step-length information the batch methods get: from ``step_bounds`` the nominal step is the
  midpoint s_i = (lower_i + upper_i) / 2 and its spread the standard deviation of a uniform law
  on the interval, sd_i = (upper_i - lower_i) / sqrt(12). Constant velocity:
  Cov(w_i) = ((turn_std s_i)^2 + sd_i^2) I (a turn of turn_std radians per step changes the step
  vector by about turn_std s_i); random walk: Cov(w_i) = (s_i^2 + sd_i^2) / d I. A Gaussian
  process noise cannot say "the length is s_i": that is imposed by a pseudo-measurement
  |v_i| = s_i with variance sd_i^2 after each step's ranges (the pseudo-measurement method for
  state constraints; Simon, "Kalman filtering with state constraints: a survey of linear and
  nonlinear algorithms", IET Control Theory Appl. 4(8), 2010).
  Without ``step_bounds`` they are derived from the data: by the triangle inequality a step is
  at least lower_i = max_k |r_(i+1)k - r_ik| long (over the landmarks heard at both steps), and
  upper_i = lower_i + median_i(lower_i) is taken as the documented default upper bound.
* Measurements: h_k(x) = |p - l_k| with Jacobian u^T on p and -u^T on l_k, u = (p - l_k) / |p - l_k|.
  The K ranges of a step are processed one by one (scalar updates, relinearised after each, so
  filterpy's inverse of S is a division by a positive scalar); unobserved ones (``mask`` False) are
  skipped. filterpy's ``update`` already uses the Joseph form
  P = (I - KH) P (I - KH)^T + K R K^T (it stays symmetric positive semi-definite even for a
  slightly wrong gain); P is symmetrised after every update against round-off.

Landmark initialisation (delayed, batch on a short window). A single range to an unknown landmark
from an unknown position says nothing about its direction, and with no odometry direction the
filter's own positions before any landmark is known follow the motion model alone, a straight line
along the gauge's x axis: multilateration from collinear anchors leaves every landmark a mirror
image (2-D) or a circle (3-D) of solutions. So, as in delayed initialisation for partially
observed landmarks (Bailey, "Constrained initialisation for bearing-only SLAM", ICRA 2003; in
range-only SLAM Kantor and Singh, ICRA 2002, and Djugash et al., ICRA 2006, who keep the ranges
until the robot has moved enough), the ranges of the first W steps are kept and, once there are
enough of them, the window's positions and all the landmarks are estimated jointly by a small
Gauss-Newton (Levenberg-Marquardt) fit of the ranges and the same step-length priors, from
``n_starts`` random-walk starts (landmarks started by SR-LS, :func:`rangeslam.multilaterate`, from
the start positions). The window grows one step at a time, from the smallest W that leaves
d redundant equations (and W >= d + 2), until for every landmark the second-order range error of
its uncertainty, delta^2 / (2 r) with delta its largest standard deviation in the fit
((J^T J)^-1, within the span of the window's positions) and r its nearest range, is at most
``init_tol`` times the range noise, so that the filter's linearisation error is below the noise;
or until W = M (then no step is left to filter and the answer is the window fit). This is a
linearisation test in the spirit of Bailey's (who waits until the landmark's distribution is close
enough to Gaussian), not his exact test. The filter starts at step W - 1 with the
fit's mean and covariance. A weak prior N(0, (3 max range)^2 I) on each landmark keeps the fit's
information matrix invertible when a landmark lies in the plane of a planar trajectory (its offset
from that plane is then unobservable to first order).

Gauge: p_1 = 0, the first step along +x and (3-D) the third position in the xy-plane; these
coordinates are fixed in the window fit and have zero variance. The result is returned in the
frame of :func:`rangeslam.mdu.slam` (the trajectory's centroid at 0, its principal axes), and the
covariances are rotated with it; they still describe the uncertainty in the gauge above.

Smoothing (``smooth=True``): a Rauch-Tung-Striebel pass over the filtered steps W .. M - 1 of
the whole state, with the stored priors, posteriors and transition matrices (the motion model is
linear, so F is exact; the measurement linearisations are those of the forward pass). The
positions and their covariances are the smoothed ones; the landmarks and window clones are static
states, whose smoothed estimate is the final filtered one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from numpy.typing import ArrayLike
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares

from rangeslam._validation import MAX_METRES, as_flag, as_rng, as_scalar, check_int, frozen
from rangeslam.baselines.filter_verdict import filter_check
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.localization.multilateration import multilaterate
from rangeslam.mdu.core import (
    SIGMA_FLOOR,
    canonical_frame,
    least_steps,
    residual_status,
    unknowns_up_to_rigid_motion,
    validated_ranges,
)
from rangeslam.mdu.slam import SlamResult
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import Status

__all__ = ["ekf_slam"]

log = logging.getLogger(__name__)

# The floor of the range noise the filter is told is slam's SIGMA_FLOOR (relative to the median
# range): exact data would otherwise give R = 0, and the first updates with a poor linearisation
# would be trusted fully.
# Without noise_std, the window fit is first weighted with this guess (times the median range),
# then refitted with the noise estimated from its residuals.
_SIGMA_GUESS = 5e-3
# Standard deviation of the weak landmark prior, in units of the largest observed range.
_LANDMARK_PRIOR = 3.0
_MOTIONS = ("constant_velocity", "random_walk")
#: Most random starts of each window fit ``n_starts`` takes (each start is a least-squares fit;
#: without a limit, n_starts=10**400 never returned).
MAX_STARTS = 1000
#: Largest ``turn_std``, radians per step: a full turn (2 pi); beyond it the process noise says
#: nothing more, and at 1e308 it overflowed the filter's covariance.
MAX_TURN_STD = 2 * np.pi


@dataclass(frozen=True)
class EkfOptions:
    """Filter settings of :func:`ekf_slam` (see its docstring)."""

    smooth: bool = False
    motion: str = "constant_velocity"
    turn_std: float = 0.5
    init_tol: float = 1.0
    init_steps: int | None = None
    n_starts: int = 10


@dataclass(frozen=True)
class StepModel:
    """Nominal step lengths (M - 1,) and their spread (M - 1,), metres (module notes)."""

    nominal: np.ndarray
    spread: np.ndarray


@dataclass(frozen=True)
class EkfAnswer:
    """Positions (M, d), landmarks (K, d), their covariances (M, d, d), (K, d, d), whether the
    filter diverged, and notes for the message."""

    receivers: np.ndarray
    sources: np.ndarray
    receiver_cov: np.ndarray
    source_cov: np.ndarray
    diverged: bool
    message: str


def check_ekf_options(options: EkfOptions, m: int) -> EkfOptions:
    """The options checked and converted (InvalidInputError naming the option otherwise):
    ``smooth`` a boolean, ``motion`` one of the models, ``turn_std`` in (0, 2 pi], ``init_tol``
    a finite real number > 0, ``n_starts`` an integer in [1, :data:`MAX_STARTS`], ``init_steps`` None
    or an integer in [3, m] (booleans are not integers)."""
    smooth = as_flag(options.smooth, "smooth")
    if not isinstance(options.motion, str) or options.motion not in _MOTIONS:
        raise InvalidInputError(f"motion must be one of {_MOTIONS}; got {options.motion!r:.80}")
    turn_std = as_scalar(
        options.turn_std, "turn_std", low=0.0, low_open=True, high=MAX_TURN_STD,
        expected=f"a real number > 0 and <= {MAX_TURN_STD:.4g} (radians per step)",
    )  # fmt: skip
    init_tol = as_scalar(
        options.init_tol, "init_tol", low=0.0, low_open=True, expected="a finite real number > 0"
    )
    n_starts = check_int(options.n_starts, "n_starts", 1, MAX_STARTS)
    init_steps = options.init_steps
    if init_steps is not None:
        init_steps = check_int(init_steps, "init_steps", 3, m)
    return EkfOptions(smooth, options.motion, turn_std, init_tol, init_steps, n_starts)


def step_model(bounds: StepBounds | None, r, observed, scale: float) -> StepModel:
    """Nominal steps (the bounds' midpoints) and the spread of a uniform law on the bounds,
    (upper - lower) / sqrt(12), floored so exact bounds keep R > 0; bounds from the ranges
    (:func:`_bounds_from_ranges`) when none are given."""
    lower, upper = _bounds_from_ranges(r, observed) if bounds is None else bounds
    nominal = 0.5 * (lower + upper)
    spread = np.maximum((upper - lower) / np.sqrt(12.0), 1e-6 * max(scale, 1e-12))
    return StepModel(nominal, spread)


def filtered_answer(r, observed, dim, window: _Window, steps: StepModel, options: EkfOptions):
    """Filter (and smooth) steps W .. M - 1 after the window; the window's clones, the
    filtered positions and the final landmarks as an :class:`EkfAnswer`."""
    k = r.shape[1]
    w_len = window.positions.shape[0]
    message = ""
    run = _run_filter(
        r, observed, dim, window, steps.nominal, steps.spread, window.sigma,
        motion=options.motion, turn_std=options.turn_std,
    )  # fmt: skip
    diverged = run.diverged
    if diverged:
        message += f"the filter diverged at step {run.last_step + 1}; "
    positions, pos_cov = run.positions, run.position_cov
    if options.smooth and not diverged:
        try:
            positions, pos_cov = _rts_positions(run)
        except np.linalg.LinAlgError:
            message += "smoothing failed (singular predicted covariance): filtered positions; "
    lay = run.layout
    x_end, p_end = run.x_post[-1], run.p_post[-1]
    clones = x_end[lay.clones].reshape(-1, dim)
    clone_cov = _blocks(p_end, lay.clones.start, w_len - 1, dim)
    rec = np.vstack([np.zeros((1, dim)), clones, positions])
    rec_cov = np.concatenate([np.zeros((1, dim, dim)), clone_cov, pos_cov])
    src = x_end[lay.landmarks].reshape(k, dim)
    src_cov = _blocks(p_end, lay.landmarks.start, k, dim)
    if not diverged:
        # Positive semi-definite, not definite: with one filtered step p - v is exactly the
        # last clone, a structural zero direction of P.
        eig = np.linalg.eigvalsh(p_end[np.ix_(lay.free, lay.free)])
        if not (np.all(np.isfinite(eig)) and eig[0] >= -1e-9 * max(eig[-1], 0.0)):
            diverged = True
            message += "the final covariance is not positive semi-definite; "
    return EkfAnswer(rec, src, rec_cov, src_cov, diverged, message)


def ekf_result(answer: EkfAnswer, r, observed, dim, noise_std, scale, bounds, rng):
    """The :class:`SlamResult`: residual status (:func:`residual_status`), then ``slam``'s
    verdict on the trajectory (:func:`filter_check`), SOLVER_FAILED when the filter diverged;
    the answer in the canonical frame with its covariances rotated."""
    rec, src, rec_cov, src_cov = (answer.receivers, answer.sources, answer.receiver_cov,
                                  answer.source_cov)  # fmt: skip
    finite = bool(np.all(np.isfinite(rec)) and np.all(np.isfinite(src)))
    diverged = answer.diverged or not finite
    res = (
        np.where(observed, range_matrix(rec, src) - r, np.nan)
        if finite
        else np.full_like(r, np.nan)
    )
    ssr = float(np.nansum(res**2)) if finite else float("inf")
    rms = float(np.sqrt(ssr / int(observed.sum())))
    status, why = residual_status(
        ssr, observed, dim, noise_std, scale, chi_square=noise_std is not None,
        bounded=bounds is not None,
    )  # fmt: skip
    if status is Status.CONVERGED and finite:
        check = filter_check(rec, src, r, observed, noise_std, scale, bounds, rng)
        status, why = check.status, why + (check.reason + "; " if check.reason else "")
    if diverged:
        status = Status.SOLVER_FAILED
    if finite:
        rec, src, rot = canonical_frame(rec, src)
        rec_cov = np.einsum("ji,njk,kl->nil", rot, rec_cov, rot)
        src_cov = np.einsum("ji,njk,kl->nil", rot, src_cov, rot)
    return SlamResult(
        receivers=frozen(np.array(rec, dtype=float)),
        sources=frozen(np.array(src, dtype=float)),
        receiver_cov=frozen(np.array(rec_cov, dtype=float)),
        source_cov=frozen(np.array(src_cov, dtype=float)),
        # A filter keeps no joint covariance of the positions it has left behind (only of the
        # window clones), so there is no honest (M d, M d) covariance of the whole trajectory.
        trajectory_cov=None,
        residuals=frozen(res),
        edm_receivers=None,  # there is no EDM step
        edm_sources=None,
        residual_rms=rms,
        status=status,
        message=(answer.message + why).rstrip("; "),
        start="filter",
        attempts=1,
        eigen_gap=float("nan"),
    )


def ekf_slam(
    ranges: ArrayLike,
    *,
    step_bounds: StepBounds | tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    dim: int = 3,
    noise_std: float | None = None,
    smooth: bool = False,
    motion: str = "constant_velocity",
    turn_std: float = 0.5,
    init_tol: float = 1.0,
    init_steps: int | None = None,
    n_starts: int = 10,
    rng: np.random.Generator | int | None = None,
) -> SlamResult:
    """Trajectory (M, d) and landmarks (K, d) from ranges (M, K) by an EKF (see the module notes).

    Args:
        ranges: (M, K) range from step i to landmark k, metres.
        step_bounds: a :class:`~rangeslam.solvers.step_bounds.StepBounds` or (lower, upper), each
            (M - 1,), bounds on |r_(i+1) - r_i| in metres: the nominal step and its spread in the
            process noise and the step pseudo-measurements. None: lower bounds from the triangle
            inequality on the ranges (module notes).
        mask: (M, K) boolean, True where observed; unobserved entries are skipped.
        dim: 2 or 3.
        noise_std: range noise standard deviation, metres (R of the filter, and the residual
            test), at most :data:`rangeslam._validation.MAX_METRES`. None: estimated from the
            residuals of the initialisation window.
        smooth: return Rauch-Tung-Striebel smoothed positions instead of filtered ones.
        motion: ``"constant_velocity"`` or ``"random_walk"`` (module notes).
        turn_std: with constant velocity, the expected change of direction per step, radians,
            in (0, 2 pi] (:data:`MAX_TURN_STD`).
        init_tol: the initialisation window grows until, for every landmark, the second-order
            range error delta^2 / (2 r) of its standard deviation delta (within the span of the
            window's positions) is at most init_tol times the range noise: the error the filter's
            linearisation neglects is then no larger than the noise.
        init_steps: a fixed window length W (an integer in [3, M]) instead of the ``init_tol``
            rule.
        n_starts: random starts of each window fit, an integer in [1, 1000]
            (:data:`MAX_STARTS`).
        rng: Generator or seed for those starts.

    Returns:
        :class:`rangeslam.mdu.slam.SlamResult` with ``attempts=1`` and ``eigen_gap`` NaN (there is no
        SDP); ``status`` is the residual test of :func:`rangeslam.mdu.slam` on the final answer,
        and SOLVER_FAILED when the filter diverged.

    Raises InvalidInputError for bad input (named in the message): ranges not (M, K), negative or
    non-finite where observed; a mask of the wrong shape, not boolean or leaving the problem
    under-determined; step bounds of the wrong length, negative, non-finite or lower > upper;
    an unknown motion model or bad tuning values (strings, None, complex numbers or arrays for
    numbers, booleans for integers, anything but True or False for ``smooth``).
    """
    r, observed, scale = validated_ranges(ranges, mask, dim, noise_std)
    noise_std = as_scalar(noise_std, "noise_std", low=0.0, high=MAX_METRES, allow_none=True)
    m = r.shape[0]
    if m < 3:
        raise InvalidInputError(f"ranges must have at least 3 rows (steps); got {m}")
    bounds = None if step_bounds is None else StepBounds.parse(step_bounds, m - 1)
    options = check_ekf_options(
        EkfOptions(smooth, motion, turn_std, init_tol, init_steps, n_starts), m
    )
    rng = as_rng(rng)
    steps = step_model(bounds, r, observed, scale)
    sigma = max(noise_std, SIGMA_FLOOR * scale) if noise_std is not None else None
    window = _initial_window(
        r, observed, dim, steps.nominal, steps.spread, sigma, float(np.max(r[observed])),
        init_tol=options.init_tol, init_steps=options.init_steps, n_starts=options.n_starts,
        rng=rng,
    )  # fmt: skip
    if window.positions.shape[0] == m:
        answer = EkfAnswer(
            window.positions, window.landmarks, window.position_cov, window.landmark_cov, False,
            f"the initialisation window covered all {m} steps: no step was filtered; ",
        )  # fmt: skip
    else:
        answer = filtered_answer(r, observed, dim, window, steps, options)
    return ekf_result(answer, r, observed, dim, noise_std, scale, bounds, rng)


# ----------------------------------------------------------------------------------------------
# step-length information


def _bounds_from_ranges(r: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Default step bounds without step_bounds: lower_i = max_k |r_(i+1)k - r_ik| over the
    landmarks heard at both steps (triangle inequality), upper_i = lower_i + median(lower)."""
    lower = least_steps(r, observed)
    return lower, lower + float(np.median(lower))


# ----------------------------------------------------------------------------------------------
# delayed initialisation: a batch fit on the first W steps


class _Window:
    """The window fit: positions (W, d), landmarks (K, d), the covariance of all their
    coordinates (W d + K d square, zero on the gauge-fixed ones), its blocks, and sigma used."""

    def __init__(self, positions, landmarks, cov, sigma):
        w, d = positions.shape
        self.positions = positions
        self.landmarks = landmarks
        self.cov = cov
        self.sigma = sigma
        self.position_cov = _blocks(cov, 0, w, d)
        self.landmark_cov = _blocks(cov, w * d, landmarks.shape[0], d)


def _free_coordinates(w: int, k: int, d: int) -> np.ndarray:
    """Boolean over the (W + K) d coordinates: False on the gauge (p_1 = 0, p_2 on +x, and in
    3-D p_3 in the xy-plane)."""
    free = np.ones((w + k, d), dtype=bool)
    free[0] = False
    free[1, 1:] = False
    if d == 3:
        free[2, 2] = False
    return free.ravel()


def _window_residuals(z, free, base, r, obs, nominal, spread, sigma, prior_std, w, k, d):
    """Residuals and Jacobian of the window fit (ranges / sigma, steps / spread, landmark prior)."""
    full = base.copy()
    full[free] = z
    pts = full.reshape(w + k, d)
    p, lm = pts[:w], pts[w:]
    ii, kk = np.nonzero(obs)
    diff = p[ii] - lm[kk]
    dist = np.linalg.norm(diff, axis=1)
    u = diff / np.maximum(dist, 1e-12)[:, None]
    step = p[1:] - p[:-1]
    slen = np.linalg.norm(step, axis=1)
    sv = step / np.maximum(slen, 1e-12)[:, None]
    n_r, n_s = len(ii), w - 1
    res = np.concatenate(
        [(dist - r[ii, kk]) / sigma, (slen - nominal) / spread, (lm / prior_std).ravel()]
    )
    jac = np.zeros((n_r + n_s + k * d, (w + k) * d))
    rows = np.arange(n_r)
    for c in range(d):
        jac[rows, ii * d + c] = u[:, c] / sigma
        jac[rows, (w + kk) * d + c] = -u[:, c] / sigma
    srows = n_r + np.arange(n_s)
    for c in range(d):
        jac[srows, (np.arange(1, w)) * d + c] = sv[:, c] / spread
        jac[srows, (np.arange(w - 1)) * d + c] = -sv[:, c] / spread
    jac[n_r + n_s :, w * d :] = np.eye(k * d) / prior_std
    return res, jac[:, free], n_r


def _to_gauge(p: np.ndarray) -> np.ndarray:
    """Rigidly move positions (W, d) so that p_1 = 0, p_2 on +x and (3-D) p_3 in the xy-plane."""
    q = p - p[0]
    d = p.shape[1]
    e1 = q[1] / np.linalg.norm(q[1]) if np.linalg.norm(q[1]) > 1e-12 else np.eye(d)[0]
    if d == 2:
        return q @ np.column_stack([e1, [-e1[1], e1[0]]])
    e2 = q[2] - (q[2] @ e1) * e1
    if np.linalg.norm(e2) < 1e-12:  # p_3 on the first step's line: any perpendicular
        e2 = np.eye(3)[int(np.argmin(np.abs(e1)))]
        e2 = e2 - (e2 @ e1) * e1
    e2 /= np.linalg.norm(e2)
    return q @ np.column_stack([e1, e2, np.cross(e1, e2)])


def random_start(w, k, d, r, obs, nominal, rng):
    steps = rng.standard_normal((w - 1, d))
    steps *= (nominal[: w - 1] / np.linalg.norm(steps, axis=1))[:, None]
    p = _to_gauge(np.vstack([np.zeros(d), np.cumsum(steps, axis=0)]))
    return p, _landmarks_from(p, r, obs, rng)


def _landmarks_from(p, r, obs, rng):
    """SR-LS landmarks from positions p (W, d); random points at the right range where that fails."""
    w, d = p.shape
    lm = np.empty((r.shape[1], d))
    for kk in range(r.shape[1]):
        try:
            lm[kk] = multilaterate(p, r[:w, kk], mask=obs[:, kk]).position
        except (DegenerateGeometryError, InvalidInputError, SolverError):
            i = int(np.argmax(obs[:, kk])) if obs[:, kk].any() else 0
            u = rng.standard_normal(d)
            lm[kk] = p[i] + r[i, kk] * u / np.linalg.norm(u)
    return lm


@dataclass(frozen=True)
class WindowStartFit:
    """The Levenberg-Marquardt fit of the window from one start: its cost, the full coordinates
    ((W + K) d, gauge ones included), the free ones and the start's gauge-fixed base."""

    cost: float
    full: np.ndarray
    z: np.ndarray
    base: np.ndarray


class WindowObjective:
    """Residuals and Jacobian of :func:`_window_residuals` for least_squares, computed once per
    point z (the last one is cached, as scipy asks for both at the same z)."""

    def __init__(self, free, base, r, obs, nominal, spread, sigma, prior_std, w, k, d) -> None:
        self.args = (free, base, r, obs, nominal, spread, sigma, prior_std, w, k, d)
        self.cache: dict = {}

    def both(self, z):
        """(residuals, Jacobian, number of range rows) at z."""
        key = z.tobytes()
        if key not in self.cache:
            self.cache.clear()
            self.cache[key] = _window_residuals(z, *self.args)
        return self.cache[key]

    def residuals(self, z):
        """Whitened residuals at z."""
        return self.both(z)[0]

    def jacobian(self, z):
        """Their Jacobian at z (free coordinates only)."""
        return self.both(z)[1]


def _fit_window(starts, r, obs, nominal, spread, sigma, prior_std, d):
    """Best Levenberg-Marquardt fit of the window from the given starts: positions (W, d),
    landmarks (K, d), covariance of all coordinates (zero on the gauge) and the range ssr."""
    w, k = obs.shape
    free = _free_coordinates(w, k, d)
    best = None
    for p0, l0 in starts:
        base = np.vstack([_to_gauge(p0), l0]).ravel()
        z0 = base[free]
        objective = WindowObjective(free, base, r, obs, nominal, spread, sigma, prior_std, w, k, d)
        sol = least_squares(
            objective.residuals, z0, jac=objective.jacobian, method="lm", max_nfev=50 * len(z0)
        )
        if not np.all(np.isfinite(sol.x)):
            continue
        if best is None or sol.cost < best.cost:
            full = base.copy()
            full[free] = sol.x
            best = WindowStartFit(sol.cost, full, sol.x, base)
    if best is None:
        raise SolverError("EKF initialisation: every window fit failed")
    res, jac_m, n_r = _window_residuals(
        best.z, free, best.base, r, obs, nominal, spread, sigma, prior_std, w, k, d
    )
    info = jac_m.T @ jac_m
    try:
        factor = cho_factor(info)
    except np.linalg.LinAlgError as exc:  # e.g. a noise_std of 1e8 m against 1 mm step priors
        raise SolverError(
            "EKF initialisation: the window fit's information matrix is not positive definite "
            "(range noise and step spreads too far apart in scale)"
        ) from exc
    cov_free = cho_solve(factor, np.eye(info.shape[0]))
    cov = np.zeros((best.full.size, best.full.size))
    cov[np.ix_(free, free)] = 0.5 * (cov_free + cov_free.T)
    pts = best.full.reshape(w + k, d)
    ssr_ranges = float(np.sum((res[:n_r] * sigma) ** 2))
    return pts[:w], pts[w:], cov, ssr_ranges


def _initial_window(
    r, observed, d, nominal, spread, sigma, max_range, *, init_tol, init_steps, n_starts, rng
) -> _Window:
    m, k = r.shape
    scale = float(np.median(r[observed]))
    prior_std = _LANDMARK_PRIOR * max_range
    if init_steps is not None:
        w_min = w_max = int(init_steps)
    else:
        w_min = max(d + 2, 3)
        while w_min < m:
            eqs = int(observed[:w_min].sum()) + (w_min - 1)
            if eqs - unknowns_up_to_rigid_motion(w_min + k, d) >= d:
                break
            w_min += 1
        w_max = m
    previous = None
    for w in range(w_min, w_max + 1):
        obs = observed[:w]
        if previous is None:
            starts = [random_start(w, k, d, r, obs, nominal, rng) for _ in range(n_starts)]
        else:  # warm start: the last window extended by its last step, and a few random ones
            p_prev, l_prev = previous
            starts = [(np.vstack([p_prev, 2 * p_prev[-1] - p_prev[-2]]), l_prev)]
            starts += [
                random_start(w, k, d, r, obs, nominal, rng) for _ in range(max(1, n_starts // 5))
            ]
        s = sigma if sigma is not None else _SIGMA_GUESS * scale
        p, lm, cov, ssr = _fit_window(
            starts, r[:w], obs, nominal[: w - 1], spread[: w - 1], s, prior_std, d
        )
        if sigma is None:  # estimate the noise from the window's residuals, then refit
            redundancy = int(obs.sum()) + (w - 1) - unknowns_up_to_rigid_motion(w + k, d)
            s = max(np.sqrt(ssr / max(redundancy, 1)), SIGMA_FLOOR * scale)
            p, lm, cov, ssr = _fit_window(
                [(p, lm)], r[:w], obs, nominal[: w - 1], spread[: w - 1], s, prior_std, d
            )
        previous = (p, lm)
        window = _Window(p, lm, cov, s)
        worst = _linearisation_error(window, r[:w], obs)
        log.debug("EKF init window W=%d: linearisation error %.3g sigma", w, worst / s)
        if worst <= init_tol * s:
            break
    return window


def _linearisation_error(window: _Window, r: np.ndarray, obs: np.ndarray) -> float:
    """Largest over landmarks of delta^2 / (2 r_min): the second-order error of a range r to a
    landmark displaced by delta perpendicular to the line of sight (|l + delta - p| is
    r + u^T delta + |delta_perp|^2 / (2 r) + ...), the error the filter's linearisation ignores.

    delta is the landmark's largest standard deviation within the span of the window's positions.
    The out-of-span directions are left out: a landmark in the plane of a planar trajectory has an
    offset from that plane that is unobservable to first order, so its covariance there never
    shrinks however long the window, while the trajectory does not depend on it."""
    p, lm = window.positions, window.landmarks
    centred = p - p.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    basis = vt[sv > 1e-2 * sv[0]].T  # (d, s)
    worst = 0.0
    for kk, c in enumerate(window.landmark_cov):
        rows = np.flatnonzero(obs[:, kk])
        if rows.size == 0:
            return np.inf
        r_min = float(np.min(np.linalg.norm(p[rows] - lm[kk], axis=1)))
        var = float(np.linalg.eigvalsh(basis.T @ c @ basis)[-1])
        worst = max(worst, max(var, 0.0) / (2.0 * max(r_min, 1e-12)))
    return worst


# ----------------------------------------------------------------------------------------------
# the filter


class _Layout:
    """Slices of the state: p, v, landmarks (K d), window clones p_2..p_W ((W - 1) d)."""

    def __init__(self, d, k, w):
        self.p = slice(0, d)
        self.v = slice(d, 2 * d)
        self.landmarks = slice(2 * d, 2 * d + k * d)
        self.clones = slice(2 * d + k * d, 2 * d + k * d + (w - 1) * d)
        self.n = self.clones.stop
        # the clones' gauge-fixed coordinates are constants (zero variance): the smoother and the
        # positive-definiteness check work on the other coordinates
        self.free = np.ones(self.n, dtype=bool)
        self.free[self.clones] = _free_coordinates(w, 0, d)[d:]


class _Run:
    def __init__(self, layout, x_post, p_post, x_prior, p_prior, f, positions, cov, diverged, last):
        self.layout = layout
        self.x_post, self.p_post = x_post, p_post
        self.x_prior, self.p_prior = x_prior, p_prior
        self.f = f
        self.positions, self.position_cov = positions, cov
        self.diverged, self.last_step = diverged, last


def _range_h(x, sl_p, sl_l):
    return np.array([np.linalg.norm(x[sl_p] - x[sl_l])])


def _range_jacobian(x, sl_p, sl_l, n):
    diff = x[sl_p] - x[sl_l]
    u = diff / max(float(np.linalg.norm(diff)), 1e-12)
    h = np.zeros((1, n))
    h[0, sl_p] = u
    h[0, sl_l] = -u
    return h


def _step_h(x, sl_v):
    return np.array([np.linalg.norm(x[sl_v])])


def _step_jacobian(x, sl_v, n):
    v = x[sl_v]
    h = np.zeros((1, n))
    h[0, sl_v] = v / np.linalg.norm(v)
    return h


def initial_state(window: _Window, lay: _Layout, d: int, k: int):
    """State x (n,) and covariance P (n, n) at step W - 1 from the window fit, through the
    linear map A of the fit's coordinates: p = p_W, v = p_W - p_(W-1), landmarks, clones."""
    w = window.positions.shape[0]
    n_fit = (w + k) * d
    a_map = np.zeros((lay.n, n_fit))
    eye = np.eye(d)
    a_map[lay.p, (w - 1) * d : w * d] = eye
    a_map[lay.v, (w - 1) * d : w * d] = eye
    a_map[lay.v, (w - 2) * d : (w - 1) * d] = -eye
    a_map[lay.landmarks, w * d :] = np.eye(k * d)
    a_map[lay.clones, d : w * d] = np.eye((w - 1) * d)
    fit_mean = np.vstack([window.positions, window.landmarks]).ravel()
    p0 = a_map @ window.cov @ a_map.T
    return a_map @ fit_mean, 0.5 * (p0 + p0.T)


def transition(lay: _Layout, d: int, motion: str):
    """F (n, n) of p_(i+1) = p_i + a v_i, v_(i+1) = a v_i (a = 1 constant velocity, 0 random
    walk), and G (n, d): the step noise w_i enters p and v alike."""
    eye = np.eye(d)
    a = 1.0 if motion == "constant_velocity" else 0.0
    f = np.eye(lay.n)
    f[lay.p, lay.v] = a * eye
    f[lay.v, lay.v] = a * eye
    g = np.zeros((lay.n, d))
    g[lay.p] = eye
    g[lay.v] = eye
    return f, g


def process_variance(nominal: float, spread: float, d: int, motion: str, turn_std: float):
    """Per-coordinate variance of w_i (module notes): ((turn_std s)^2 + sd^2) for constant
    velocity, (s^2 + sd^2) / d for a random walk, m^2."""
    if motion == "constant_velocity":
        return (turn_std * nominal) ** 2 + spread**2
    return (nominal**2 + spread**2) / d


def update_step(ekf, r_i, obs_i, lay: _Layout, d: int, r_noise, nominal: float, spread: float):
    """The scalar range updates of one step (observed landmarks only), then the step-length
    pseudo-measurement |v| = nominal (variance spread^2); P symmetrised after each."""
    n = lay.n
    for kk in np.flatnonzero(obs_i):
        sl_l = slice(lay.landmarks.start + kk * d, lay.landmarks.start + (kk + 1) * d)
        ekf.update(
            np.array([r_i[kk]]),
            _range_jacobian,
            _range_h,
            R=r_noise,
            args=(lay.p, sl_l, n),
            hx_args=(lay.p, sl_l),
        )
        ekf.P = 0.5 * (ekf.P + ekf.P.T)
    if np.linalg.norm(ekf.x[lay.v]) > 1e-9 * max(nominal, 1e-12):
        ekf.update(
            np.array([nominal]),
            _step_jacobian,
            _step_h,
            R=np.array([[spread**2]]),
            args=(lay.v, n),
            hx_args=(lay.v,),
        )
        ekf.P = 0.5 * (ekf.P + ekf.P.T)


def _run_filter(r, observed, d, window, nominal, spread, sigma, *, motion, turn_std) -> _Run:
    """Predict and update steps W .. M - 1 from the window's state; stops where it diverges
    (non-finite state or a negative variance), the remaining steps NaN."""
    m, k = r.shape
    w = window.positions.shape[0]
    lay = _Layout(d, k, w)
    n = lay.n
    ekf = ExtendedKalmanFilter(dim_x=n, dim_z=1)
    ekf.x, ekf.P = initial_state(window, lay, d, k)
    r_noise = np.array([[sigma**2]])
    f, g = transition(lay, d, motion)
    ekf.F = f
    x_post, p_post = [ekf.x.copy()], [ekf.P.copy()]
    x_prior, p_prior = [ekf.x.copy()], [ekf.P.copy()]
    positions, cov = [], []
    diverged, last = False, w - 1
    for i in range(w, m):
        j = i - 1  # the step from i - 1 to i
        ekf.Q = process_variance(nominal[j], spread[j], d, motion, turn_std) * (g @ g.T)
        ekf.predict()
        x_prior.append(ekf.x.copy())
        p_prior.append(ekf.P.copy())
        update_step(ekf, r[i], observed[i], lay, d, r_noise, nominal[j], spread[j])
        if not (np.all(np.isfinite(ekf.x)) and np.all(np.isfinite(ekf.P))) or np.any(
            np.diag(ekf.P) < 0
        ):
            diverged, last = True, i
            break
        x_post.append(ekf.x.copy())
        p_post.append(ekf.P.copy())
        positions.append(ekf.x[lay.p].copy())
        cov.append(ekf.P[lay.p, lay.p].copy())
    if diverged:  # keep the shapes: the remaining steps are NaN
        missing = m - w - len(positions)
        positions += [np.full(d, np.nan)] * missing
        cov += [np.full((d, d), np.nan)] * missing
        x_post.append(np.full(n, np.nan))
        p_post.append(np.full((n, n), np.nan))
    return _Run(
        lay, x_post, p_post, x_prior, p_prior, f,
        np.array(positions).reshape(m - w, d), np.array(cov).reshape(m - w, d, d), diverged, last,
    )  # fmt: skip


def _rts_positions(run: _Run) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoother over the filtered steps W .. M - 1 (stored index 1 .. M - W):
    C_i = P_i F^T (P_(i+1)^-)^-1, by a solve with the symmetric P_(i+1)^-;
    x_i^s = x_i + C_i (x_(i+1)^s - x_(i+1)^-), P_i^s = P_i + C_i (P_(i+1)^s - P_(i+1)^-) C_i^T.

    Index 0 (the initial state at step W - 1) is not smoothed: its position is the clone of
    p_W, and the first prior is singular (p - v equals that clone exactly)."""
    lay = run.layout
    fr = lay.free
    f = run.f[np.ix_(fr, fr)]
    p_idx = np.flatnonzero(fr)[: lay.p.stop]  # p comes first and is free
    xs, ps = run.x_post[-1][fr], run.p_post[-1][np.ix_(fr, fr)]
    out_x, out_p = [xs[p_idx].copy()], [ps[np.ix_(p_idx, p_idx)].copy()]
    for i in range(len(run.x_post) - 2, 0, -1):
        p_prior = run.p_prior[i + 1][np.ix_(fr, fr)]
        p_post = run.p_post[i][np.ix_(fr, fr)]
        gain = np.linalg.solve(p_prior, f @ p_post).T
        xs = run.x_post[i][fr] + gain @ (xs - run.x_prior[i + 1][fr])
        ps = p_post + gain @ (ps - p_prior) @ gain.T
        ps = 0.5 * (ps + ps.T)
        out_x.append(xs[p_idx].copy())
        out_p.append(ps[np.ix_(p_idx, p_idx)].copy())
    return np.array(out_x[::-1]), np.array(out_p[::-1])


def _blocks(cov: np.ndarray, start: int, count: int, d: int) -> np.ndarray:
    """The (count, d, d) diagonal blocks of cov from index start."""
    return np.array(
        [
            cov[start + i * d : start + (i + 1) * d, start + i * d : start + (i + 1) * d]
            for i in range(count)
        ]
    ).reshape(count, d, d)
