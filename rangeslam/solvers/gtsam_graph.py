"""GTSAM back end: a range-factor graph over receivers and sources, with step-length priors.

The design of this project: the EDM solution (convex iteration) initialises a factor graph that
GTSAM refines by Levenberg-Marquardt; the covariances come from GTSAM's linearisation of the graph
at the answer (see ``_covariance`` for why not ``gtsam.Marginals``).

- every observed range r_mk: a point-to-point ``RangeFactor3`` (``RangeFactor2`` in 2-D) between
  receiver m and source k, Gaussian with ``noise_std``, or wrapped in a robust kernel (Huber,
  Cauchy, Tukey) against wrong echoes;
- step-length bounds lower_i <= |x_{i+1} - x_i| <= upper_i (eq. 11 of the paper, here as a prior):
  a range factor with measured (lower + upper) / 2 and an L2-with-dead-zone kernel of half-width
  (upper - lower) / 2, so it costs nothing inside the bounds and grows quadratically (scale
  ``step_sigma``) outside. With ``step_prior="uniform"`` (the default) a second factor reads the
  bounds as what they say of the step, a length uniform on [lower, upper]: a Gaussian range factor
  with that distribution's mean (lower + upper) / 2 and standard deviation (upper - lower) / sqrt(12)
  (moment matching). The dead zone alone ("dead_zone") is the MAP of a flat prior: where the ranges
  leave a direction free (few steps, a planar path) it runs to a corner of the bounds;
- odometry-style priors: step lengths or step vectors with a sigma (range or between factors);
- the gauge (a rigid motion, unobservable from ranges) is fixed by priors on 6 coordinates of three
  well-spread points (3 in 2-D) at their initial values: the first point entirely, the second in
  the 2 coordinates across the line to it, the third along the normal of their plane. These pin
  only unobservable directions (to first order), so they do not bias the estimate.

Covariances are returned in the *receiver gauge* (the rigid motion fitted to the receivers
removed, as for :func:`rangeslam.mdu_crlb`), so they are comparable with errors taken after
aligning the receivers to the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import (
    MAX_METRES,
    as_flag,
    as_float_array,
    as_mask,
    as_points,
    as_ranges,
    as_scalar,
    frozen,
    shape_str,
)
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import receiver_gauge_projection
from rangeslam.solvers.robust_kernels import (
    ROBUST_KERNEL_CONSTANTS,
    ROBUST_KERNELS,
    robust_mode,
    robust_noise_model,
)
from rangeslam.solvers.step_bounds import KNOWN_STEP_WIDTH, StepBounds
from rangeslam.status import HasStatus, Status

__all__ = [
    "GAUGE_TIGHT",
    "STEP_PRIORS",
    "GraphFit",
    "LMOptions",
    "dead_zone_bounds",
    "partial_prior",
    "refine_graph",
]

#: Readings of step bounds in the graph (see the module docstring).
STEP_PRIORS = ("uniform", "dead_zone")
#: Largest cost decrease (noise variances) a Gauss-Newton step may still predict when LM stops at
#: its iteration limit for the fit to stand: within one standard deviation of the minimum along
#: every direction. (A 6-step walk with bounds stopped at 5000 iterations 0.21 variances short,
#: 7.8 mm off against a 6.1 cm bound; 1116 more iterations reached the predicted cost.)
STATIONARY_CHI2 = 1.0
#: Sigma of the gauge priors (and of a receivers' plane) relative to noise_std. The pinned
#: directions are unobservable, so how tight does not change the estimate; 1e-2 keeps the
#: factorisation well conditioned. The other coordinates of the gauge points get no prior
#: information at all (zero rows of the square-root information), so nothing observable is pulled.
GAUGE_TIGHT = 1e-2
# The least damping of Levenberg-Marquardt (see run_levenberg_marquardt): round-off against the
# whitened information, whose diagonal is at least of order 1 (ranges over their sigma).
_LAMBDA_FLOOR = 1e-16


@dataclass(frozen=True)
class GraphFit(HasStatus):
    """Result of :func:`refine_graph`. M receivers, K sources, d = 2 or 3.

    Attributes:
        receivers: (M, d) refined receivers (positions along the trajectory), metres.
        sources: (K, d) refined sources (landmarks), metres.
        receiver_cov: (M, d, d) marginal covariances in the receiver gauge, m^2 (None when not
            computed).
        source_cov: (K, d, d) the same for the sources.
        joint_cov: ((M + K) d, (M + K) d) joint covariance of the stacked points in the receiver
            gauge (None when not computed).
        residuals: (M, K) fitted minus measured range, metres; NaN where not observed.
        error: final value of the graph's cost (GTSAM's error: half the weighted squared sum).
        initial_error: the cost at the starting point.
        iterations: Levenberg-Marquardt iterations.
        status: CONVERGED when LM finished within its iteration limit with a finite cost no
            larger than the start's, else SOLVER_FAILED (``converged`` is derived from it).
        message: why not, when not converged; empty otherwise.
    """

    receivers: np.ndarray
    sources: np.ndarray
    receiver_cov: np.ndarray | None
    source_cov: np.ndarray | None
    joint_cov: np.ndarray | None
    residuals: np.ndarray
    error: float
    initial_error: float
    iterations: int
    status: Status
    message: str


@dataclass(frozen=True)
class LMOptions:
    """Levenberg-Marquardt settings of :func:`refine_graph` (as GTSAM's LevenbergMarquardtParams).

    Attributes:
        max_iterations: iteration limit; 0 evaluates the graph without moving the points.
        lambda_upper_bound: LM stops when its damping exceeds this (GTSAM's default is 1e5; see
            :func:`run_levenberg_marquardt` for why the default here is 1e12).
    """

    # Planar trajectories leave a slow valley: from the truth, 80 iterations are typical at 1 cm
    # noise, hence a limit well above that.

    max_iterations: int = 500
    lambda_upper_bound: float = 1e12


@dataclass(frozen=True)
class StepPrior:
    """Step bounds read as a prior (module docstring): ``kind`` in STEP_PRIORS, ``sigma`` the
    scale outside the bounds, metres."""

    bounds: StepBounds
    sigma: float
    kind: str


@dataclass(frozen=True)
class Odometry:
    """Odometry factors: step lengths (M - 1,) and/or step vectors (M - 1, d), metres, each
    Gaussian with ``sigma``."""

    lengths: np.ndarray | None
    vectors: np.ndarray | None
    sigma: float | None


@dataclass(frozen=True)
class GraphProblem:
    """The validated inputs of :func:`refine_graph`: start points, ranges and factor settings."""

    receivers: np.ndarray  # (M, d) start
    sources: np.ndarray  # (K, d) start
    ranges: np.ndarray  # (M, K) metres
    observed: np.ndarray  # (M, K) bool
    noise_std: float
    robust: str | None
    robust_constant: float | None  # kernel threshold in units of noise_std
    step_prior: StepPrior | None
    odometry: Odometry
    lm: LMOptions
    plane: np.ndarray | None = None  # (d,) unit normal of the receivers' plane, or None


def check_lm_options(max_iterations, lambda_upper_bound) -> LMOptions:
    """The LM settings, refused (InvalidInputError naming the setting) unless max_iterations is an
    integer >= 0 and lambda_upper_bound a finite number > 0."""
    # GTSAM takes a C int: at most 2^31 - 1 iterations.
    iterations = as_scalar(max_iterations, "max_iterations", low=0, high=2**31 - 1, integer=True)
    bound = as_scalar(
        lambda_upper_bound,
        "lambda_upper_bound",
        low=0.0,
        low_open=True,
        expected="positive and finite",
    )
    return LMOptions(int(iterations), float(bound))


def robust_constant(robust: str | None, robust_scale, noise_std: float) -> float | None:
    """The kernel's threshold in sigmas: robust_scale / noise_std, or the table's constant."""
    if robust is None:
        return None
    scale = as_scalar(
        robust_scale, "robust_scale", low=0.0, low_open=True, allow_none=True,
        expected="positive (metres) or None",
    )  # fmt: skip
    c = ROBUST_KERNEL_CONSTANTS[robust] if scale is None else scale / noise_std
    if not (np.isfinite(c) and c > 0):
        raise InvalidInputError(f"robust_scale must be positive; got {robust_scale!r}")
    return float(c)


def parse_step_prior(
    step_bounds, step_sigma, kind: str, m: int, noise_std: float, scale: float
) -> StepPrior | None:
    """The step prior from ``step_bounds`` (None without them); sigma defaults to the noise.

    lower = upper is a known step length: such an interval is widened to
    ``KNOWN_STEP_WIDTH * scale`` (``scale`` the median observed range, metres) about its
    midpoint, as :func:`rangeslam.slam` does, because the dead zone needs a positive width.
    """
    if step_bounds is None:
        return None
    bounds = StepBounds.parse(step_bounds, m - 1).widened(KNOWN_STEP_WIDTH * scale)
    sig = as_scalar(
        step_sigma, "step_sigma", low=0.0, low_open=True, allow_none=True,
        expected="positive (metres) or None",
    )  # fmt: skip
    return StepPrior(bounds, noise_std if sig is None else sig, kind)


def parse_odometry(step_lengths, step_vectors, odometry_sigma, m: int, d: int) -> Odometry:
    """Odometry lengths (M - 1,) and vectors (M - 1, d), checked."""
    lengths = vectors = None
    if step_lengths is not None:
        lengths = as_float_array(step_lengths, "step_lengths")
        if lengths.shape != (m - 1,) or not np.all(np.isfinite(lengths)) or np.any(lengths < 0):
            raise InvalidInputError(
                f"step_lengths must be ({m - 1},) finite non-negative; got {shape_str(lengths.shape)}"
            )
    if step_vectors is not None:
        vectors = as_points(step_vectors, "step_vectors", dim=d)
        if vectors.shape != (m - 1, d):
            raise InvalidInputError(
                f"step_vectors must have shape ({m - 1}, {d}); got {shape_str(vectors.shape)}"
            )
    return Odometry(lengths, vectors, odometry_sigma)


def _gauge_points(points: np.ndarray) -> list[int]:
    """Indices of d well-spread points: the first, the farthest from it, the farthest from their
    line (3-D)."""
    a = 0
    b = int(np.argmax(np.linalg.norm(points - points[a], axis=1)))
    if points.shape[1] == 2:
        return [a, b]
    u = (points[b] - points[a]) / np.linalg.norm(points[b] - points[a])
    rel = points - points[a]
    off_line = rel - np.outer(rel @ u, u)
    c = int(np.argmax(np.linalg.norm(off_line, axis=1)))
    return [a, b, c]


def _gauge_frame(points: np.ndarray, idx: list[int]) -> np.ndarray:
    """Orthonormal (d, d) frame: columns along a->b, then across, then normal (3-D)."""
    d = points.shape[1]
    e1 = points[idx[1]] - points[idx[0]]
    e1 /= np.linalg.norm(e1)
    if d == 2:
        return np.column_stack([e1, [-e1[1], e1[0]]])
    v = points[idx[2]] - points[idx[0]]
    e2 = v - (v @ e1) * e1
    e2 /= np.linalg.norm(e2)
    return np.column_stack([e1, e2, np.cross(e1, e2)])


def partial_prior(gtsam, key: int, at: np.ndarray, rows: np.ndarray, noise_std: float):
    """Factor pinning the components rows @ (p - at) of one point (rows: (n, d)), and no other:
    the gauge prior that leaves every observable direction to the measurements. A point is a
    vector space, so the linear factor rows (p - at) held at ``at`` is exact (a native
    LinearContainerFactor: no Python call per linearisation)."""
    lin = gtsam.Values()
    lin.insert(key, np.asarray(at, dtype=float).copy())
    model = gtsam.noiseModel.Isotropic.Sigma(len(rows), GAUGE_TIGHT * noise_std)
    factor = gtsam.JacobianFactor(key, np.ascontiguousarray(rows), np.zeros(len(rows)), model)
    return gtsam.LinearContainerFactor(factor, lin)


def _covariance(gtsam, graph, values, keys: list[int], n_gauge: int) -> np.ndarray:
    """Covariance of the stacked points from GTSAM's linearisation of the measurement factors at
    ``values`` (noise models, robust weights and step priors baked in): the pseudo-inverse of the
    information through the SVD of the whitened Jacobian, the gauge's ``n_gauge`` null
    directions dropped (the rigid motions; in a plane's graph the motions in the plane).

    GTSAM's own Marginals need the gauge priors, and with them the elimination was reported
    indeterminate on a few well-posed lemniscate scenes; the SVD of A does not square the
    condition number. Raises SolverError when more than the gauge is unobservable.
    """
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    jac, _ = graph.linearize(values).jacobian(ordering)
    if not np.all(np.isfinite(jac)):  # |p - l| has no derivative where p and l coincide
        raise SolverError(
            "covariances undefined: the range factors have no derivative at the estimate (a "
            "receiver and a source coincide)",
            status="non-finite Jacobian",
        )
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    keep = sv > 1e-9 * sv[0]
    if int(np.sum(~keep)) + (jac.shape[1] - len(sv)) > n_gauge:
        raise SolverError(
            "covariances undefined: the graph leaves directions beyond the gauge unobservable",
            status=f"{int(np.sum(~keep)) + jac.shape[1] - len(sv)} null directions, "
            f"{n_gauge} expected",
        )
    v = vt[keep].T / sv[keep]
    return v @ v.T


def graph_keys(gtsam, m: int, k: int) -> list[int]:
    """GTSAM symbol keys X(i) of the M receivers, then L(j) of the K sources."""
    return [gtsam.symbol("x", i) for i in range(m)] + [gtsam.symbol("l", j) for j in range(k)]


def add_range_factors(gtsam, graph, problem: GraphProblem, keys: list[int]) -> None:
    """One range factor per observed r_mk, Gaussian with noise_std or in the robust kernel."""
    m, d = problem.receivers.shape
    range_factor = gtsam.RangeFactor3 if d == 3 else gtsam.RangeFactor2
    base = gtsam.noiseModel.Isotropic.Sigma(1, problem.noise_std)
    noise = robust_noise_model(gtsam, base, problem.robust, problem.robust_constant)
    r = problem.ranges
    for i, j in np.argwhere(problem.observed):
        graph.add(range_factor(keys[int(i)], keys[m + int(j)], float(r[i, j]), noise))


def dead_zone_bounds(prior: StepPrior) -> StepBounds:
    """The bounds the step prior's factors use: ``prior.bounds``, where a known step length
    (lower = upper) survived refine_graph's door (built without it, or widened by less than a
    unit in the last place) widened as parse_step_prior does (scale: the steps or the sigma): the
    dead zone needs a positive width."""
    bounds = prior.bounds
    if np.any(bounds.upper <= bounds.lower):
        scale = max(float(np.median(bounds.midpoints)), prior.sigma)
        bounds = bounds.widened(KNOWN_STEP_WIDTH * scale)
    return bounds


def add_step_priors(gtsam, graph, prior: StepPrior, keys: list[int], d: int) -> None:
    """Per step, a dead-zone range factor of half-width (upper - lower) / 2 at the midpoint, and
    with "uniform" the moment-matched Gaussian of U(lower, upper) (never below sigma)."""
    range_factor = gtsam.RangeFactor3 if d == 3 else gtsam.RangeFactor2
    sig = prior.sigma
    bounds = dead_zone_bounds(prior)
    lower, upper = bounds.lower, bounds.upper
    for i in range(prior.bounds.n_steps):
        half = 0.5 * (upper[i] - lower[i])
        model = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.L2WithDeadZone(half / sig),
            gtsam.noiseModel.Isotropic.Sigma(1, sig),
        )
        graph.add(range_factor(keys[i], keys[i + 1], float(lower[i] + half), model))
        if prior.kind == "uniform":  # mean and variance of U(lower, upper); never below sig
            spread = max(2 * half / np.sqrt(12), sig)
            model = gtsam.noiseModel.Isotropic.Sigma(1, spread)
            graph.add(range_factor(keys[i], keys[i + 1], float(lower[i] + half), model))


def add_odometry_factors(gtsam, graph, odometry: Odometry, keys: list[int], d: int) -> None:
    """Gaussian step-length (range) and step-vector (between) factors with odometry.sigma."""
    range_factor = gtsam.RangeFactor3 if d == 3 else gtsam.RangeFactor2
    between_factor = gtsam.BetweenFactorPoint3 if d == 3 else gtsam.BetweenFactorPoint2
    if odometry.lengths is not None:
        model = gtsam.noiseModel.Isotropic.Sigma(1, odometry.sigma)
        for i, length in enumerate(odometry.lengths):
            graph.add(range_factor(keys[i], keys[i + 1], float(length), model))
    if odometry.vectors is not None:
        model = gtsam.noiseModel.Isotropic.Sigma(d, odometry.sigma)
        for i, step in enumerate(odometry.vectors):
            graph.add(between_factor(keys[i], keys[i + 1], step, model))


def add_gauge_priors(gtsam, graph, points: np.ndarray, keys: list[int], problem: GraphProblem):
    """Priors on the unobservable rigid motion only: 6 coordinates (3 in 2-D) of three spread
    points; with step vectors (which fix the orientation), the first point's translation."""
    d = points.shape[1]
    if problem.plane is not None:
        add_in_plane_gauge_priors(gtsam, graph, problem, keys)
        return
    if problem.odometry.vectors is not None:
        prior_factor = gtsam.PriorFactorPoint3 if d == 3 else gtsam.PriorFactorPoint2
        noise = gtsam.noiseModel.Isotropic.Sigma(d, GAUGE_TIGHT * problem.noise_std)
        graph.add(prior_factor(keys[0], points[0], noise))
        return
    idx = _gauge_points(points)
    frame = _gauge_frame(points, idx)
    axes = [list(range(d)), list(range(1, d))]  # a: all; b: across the line ab
    if d == 3:
        axes.append([2])  # c: along the normal of the plane abc
    for p, pinned in zip(idx, axes, strict=True):
        graph.add(partial_prior(gtsam, keys[p], points[p], frame[:, pinned].T, problem.noise_std))


def add_in_plane_gauge_priors(gtsam, graph, problem: GraphProblem, keys: list[int]) -> None:
    """The gauge left once the plane priors hold the receivers (a motion in the plane: 2
    translations and the turn about the normal): the first receiver's two coordinates in the
    plane, and the farthest receiver from it across their line in the plane; nothing observable
    pinned."""
    x, normal = problem.receivers, problem.plane
    far = int(np.argmax(np.linalg.norm(x - x[0], axis=1)))
    along = (x[far] - x[0]) - ((x[far] - x[0]) @ normal) * normal
    along /= np.linalg.norm(along)
    across = np.cross(normal, along)
    sigma = problem.noise_std
    graph.add(partial_prior(gtsam, keys[0], x[0], np.vstack([along, across]), sigma))
    graph.add(partial_prior(gtsam, keys[far], x[far], across[None, :], sigma))


def add_plane_priors(gtsam, graph, problem: GraphProblem, keys: list[int]) -> None:
    """Each receiver's offset along ``problem.plane`` (a unit normal) pinned where the start (on
    the plane: :func:`parse_graph_problem` projected it) has it, as the gauge priors pin theirs
    (sigma 1e-2 noise_std): the receivers held in one plane; the covariances then have (almost)
    no variance across it."""
    row = problem.plane[None, :]
    for i, key in enumerate(keys[: len(problem.receivers)]):
        graph.add(partial_prior(gtsam, key, problem.receivers[i], row, problem.noise_std))


@dataclass(frozen=True)
class LMRun:
    """What Levenberg-Marquardt returned: GTSAM's values, the estimate (N, d) metres, the
    iterations made, the graph's cost at the start and at the end, and, when LM stopped at its
    iteration limit, the decrease of the cost (in noise variances, i.e. chi-square units) that a
    Gauss-Newton step from the end still predicts (:func:`predicted_decrease`; 0 otherwise)."""

    values: object
    estimate: np.ndarray
    iterations: int
    initial_error: float
    error: float
    remaining: float = 0.0


def run_levenberg_marquardt(
    gtsam, graph, points: np.ndarray, keys: list[int], lm: LMOptions
) -> LMRun:
    """LM from ``points`` (N, d). Raises SolverError on a non-finite cost."""
    initial = gtsam.Values()
    for key, p in zip(keys, points, strict=True):
        initial.insert(key, p)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(lm.max_iterations))
    params.setRelativeErrorTol(1e-9)
    params.setAbsoluteErrorTol(1e-12)
    # GTSAM stops once the damping passes lambdaUpperBound (1e5 by default). In the curved, flat
    # valleys of few-step SLAM (sigma = 1 mm, M = 5) that stopped it 5-8 cm from the minimum,
    # which a bound of 1e12 reaches (measured: mean trajectory error 7 -> 1.7 cm).
    params.setlambdaUpperBound(float(lm.lambda_upper_bound))
    # GTSAM's lower bound on the damping is 0: after some 320 accepted steps in a row (LM creeping
    # along a flat valley, as a planar walk's refit without one landmark does) the damping
    # underflows to 0, and the next rejected step multiplies 0 by the factor forever: LM never
    # returns. A floor at the round-off of whitened (unit) information leaves every step as it
    # was and lets the damping grow again.
    params.setlambdaLowerBound(_LAMBDA_FLOOR)
    initial_error = float(graph.error(initial))
    result, iterations = initial, 0
    if lm.max_iterations > 0:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        result = optimizer.optimize()
        iterations = int(optimizer.iterations())
    error = float(graph.error(result))
    if not np.isfinite(error):
        raise SolverError("GTSAM Levenberg-Marquardt diverged", status=f"error {error}")
    at = result.atPoint3 if points.shape[1] == 3 else result.atPoint2
    est = np.array([at(key) for key in keys])
    hit_limit = 0 < lm.max_iterations <= iterations
    remaining = predicted_decrease(gtsam, graph, result) if hit_limit else 0.0
    return LMRun(result, est, iterations, initial_error, error, remaining)


def predicted_decrease(gtsam, graph, values) -> float:
    """The decrease of the graph's cost a Gauss-Newton step from ``values`` predicts, in noise
    variances (twice GTSAM's error: chi-square units): that of the linearised graph from the zero
    step to its minimiser (robust and dead-zone factors enter reweighted, as LM sees them; their
    nonlinear error is not the model's value at zero). inf when the linearised system cannot be
    solved. Under 1 the point is within one standard deviation of the minimum along every
    direction (a quadratic cost), however flat the valley LM was creeping along."""
    try:
        linear = graph.linearize(values)
        delta = linear.optimize()
    except RuntimeError:  # gtsam: an indeterminant linear system
        return float("inf")
    return float(2.0 * (linear.error(gtsam.VectorValues.Zero(delta)) - linear.error(delta)))


def build_graph(gtsam, problem: GraphProblem, keys: list[int]):
    """The factor graph: ranges, step priors, odometry, then the gauge priors. Returns (graph,
    the measurement factors alone (for the covariances), the start points (M + K, d))."""
    d = problem.receivers.shape[1]
    graph = gtsam.NonlinearFactorGraph()
    add_range_factors(gtsam, graph, problem, keys)
    if problem.step_prior is not None:
        add_step_priors(gtsam, graph, problem.step_prior, keys, d)
    add_odometry_factors(gtsam, graph, problem.odometry, keys, d)
    if problem.plane is not None:  # part of the model: the covariances see it
        add_plane_priors(gtsam, graph, problem, keys)
    measurements = graph.clone()  # without the gauge priors: the covariances come from these
    points = np.vstack([problem.receivers, problem.sources])
    add_gauge_priors(gtsam, graph, points, keys, problem)
    return graph, measurements, points


def lm_verdict(lm: LMOptions, run: LMRun) -> tuple[Status, str]:
    """(status, message): SOLVER_FAILED when the cost went up, or when LM hit its iteration
    limit short of the minimum: a Gauss-Newton step would still lower the cost by more than
    :data:`STATIONARY_CHI2` noise variances (run.remaining). Within that, LM was creeping along
    a flat valley inside the estimate's own uncertainty, and the fit stands, with a note."""
    limit = 0 < lm.max_iterations <= run.iterations
    short = limit and run.remaining > STATIONARY_CHI2
    went_up = run.error > run.initial_error * (1 + 1e-9) + 1e-12
    parts = []
    if limit:
        parts.append(
            f"Levenberg-Marquardt hit the limit of {lm.max_iterations} iterations"
            + (" short of the minimum" if short else "")
            + f" (a Gauss-Newton step predicts a decrease of {run.remaining:.3g} noise variances)"
        )
    if went_up:
        parts.append("the cost went up")
    if short or went_up:
        return Status.SOLVER_FAILED, "; ".join(parts)
    return Status.CONVERGED, "; ".join(f"noted: {p}" for p in parts)


def graph_covariances(gtsam, measurements, values, keys, est: np.ndarray, problem: GraphProblem):
    """(receiver (M, d, d), source (K, d, d), joint) covariances at the estimate ``est``
    (M + K, d), in the receiver gauge unless step vectors fixed the orientation."""
    m, d = problem.receivers.shape
    gauge_free = problem.odometry.vectors is None
    n_gauge = 3 if problem.plane is not None else d * (d + 1) // 2 if gauge_free else d
    full = _covariance(gtsam, measurements, values, keys, n_gauge)
    if gauge_free:
        proj = receiver_gauge_projection(est[:m], est[m:])
        full = proj @ full @ proj.T
    blocks = np.array([full[i * d : (i + 1) * d, i * d : (i + 1) * d] for i in range(len(est))])
    return frozen(blocks[:m]), frozen(blocks[m:]), frozen(full)


def check_reached(observed: np.ndarray, stepped: bool) -> None:
    """Refuse a mask that leaves a source without a range (nothing places it), or, without step
    bounds or odometry, a receiver without one: InvalidInputError naming the column or row."""
    for axis, what, side in ((0, "column", "source"), (1, "row", "receiver")):
        if axis == 1 and stepped:
            continue
        empty = np.flatnonzero(~observed.any(axis=axis))
        if empty.size:
            j = int(empty[0])
            raise InvalidInputError(
                f"mask {what} {j} has no observed range: {side} {j} is unobservable"
                + ("" if axis == 0 else " (without step bounds or odometry)")
            )


def parse_graph_problem(
    receivers, sources, ranges, *, noise_std, mask, step_bounds, step_sigma, step_prior,
    step_lengths, step_vectors, odometry_sigma, robust, robust_scale, max_iterations,
    lambda_upper_bound, receiver_plane=None,
) -> GraphProblem:  # fmt: skip
    """The front door of :func:`refine_graph`: every input checked once, in the order of the
    messages users know."""
    x = as_points(receivers, "receivers")
    m, d = x.shape
    s = as_points(sources, "sources", dim=d)
    observed = as_mask(mask, "mask", shape=(m, len(s)))
    stepped = step_bounds is not None or step_lengths is not None or step_vectors is not None
    check_reached(observed, stepped)
    r = as_ranges(ranges, "ranges", shape=(m, len(s)), observed=observed)
    noise_std = as_scalar(
        noise_std,
        "noise_std",
        low=0.0,
        low_open=True,
        high=MAX_METRES,
        expected="positive, at most 1e12 m",
    )
    robust = robust_mode(robust, ROBUST_KERNELS, default_kernel="huber")
    lm = check_lm_options(max_iterations, lambda_upper_bound)
    if not isinstance(step_prior, str) or step_prior not in STEP_PRIORS:
        raise InvalidInputError(f"step_prior must be one of {STEP_PRIORS}; got {step_prior!r:.80}")
    odometry = step_lengths is not None or step_vectors is not None
    odometry_sigma = as_scalar(
        odometry_sigma, "odometry_sigma", low=0.0, low_open=True, allow_none=True,
        expected="positive (metres) or None",
    )  # fmt: skip
    if odometry and odometry_sigma is None:
        raise InvalidInputError("odometry_sigma (> 0) is required with step_lengths/step_vectors")
    c = robust_constant(robust, robust_scale, noise_std)
    scale = float(np.median(r[observed])) if observed.any() else 1.0
    prior = parse_step_prior(step_bounds, step_sigma, step_prior, m, noise_std, max(scale, 1e-300))
    odo = parse_odometry(step_lengths, step_vectors, odometry_sigma, m, d)
    plane = parse_receiver_plane(receiver_plane, x)
    if plane is not None:  # the start projected onto the plane (the gauge priors hold it there)
        x = x - np.outer((x - x.mean(axis=0)) @ plane, plane)
    return GraphProblem(x, s, r, observed, noise_std, robust, c, prior, odo, lm, plane)


def parse_receiver_plane(receiver_plane, receivers: np.ndarray) -> np.ndarray | None:
    """The unit normal (d,) of ``receiver_plane`` (a normal vector, any length), checked: 3-D
    only, finite and nonzero. None when not given."""
    if receiver_plane is None:
        return None
    d = receivers.shape[1]
    normal = as_float_array(receiver_plane, "receiver_plane")
    if d != 3 or normal.shape != (3,):
        raise InvalidInputError(
            f"receiver_plane must be a normal vector of shape (3,) with 3-D points; got "
            f"{shape_str(normal.shape)} with {d}-D points"
        )
    size = float(np.linalg.norm(normal))
    if not np.isfinite(size) or size == 0:
        raise InvalidInputError(f"receiver_plane must be finite and nonzero; got {normal}")
    return normal / size


def refine_graph(
    receivers: ArrayLike,
    sources: ArrayLike,
    ranges: ArrayLike,
    *,
    noise_std: float,
    mask: ArrayLike | None = None,
    step_bounds: StepBounds | tuple[ArrayLike, ArrayLike] | None = None,
    step_sigma: float | None = None,
    step_prior: str = "uniform",
    step_lengths: ArrayLike | None = None,
    step_vectors: ArrayLike | None = None,
    odometry_sigma: float | None = None,
    robust: str | None = None,
    robust_scale: float | None = None,
    covariances: bool = True,
    max_iterations: int = 500,
    lambda_upper_bound: float = 1e12,
    receiver_plane: ArrayLike | None = None,
) -> GraphFit:
    """Refine receivers (M, d) and sources (K, d) on their ranges (M, K) with GTSAM.

    Args:
        receivers, sources: the starting point (e.g. :func:`rangeslam.calibrate`'s answer).
        ranges: (M, K) metres; entries outside ``mask`` are ignored.
        noise_std: standard deviation of the range noise, metres (> 0).
        mask: (M, K) boolean, True where observed.
        step_bounds: a :class:`StepBounds` or (lower, upper), each (M - 1,), bounds on
            |x_{i+1} - x_i| in metres: a step prior as ``step_prior`` says.
        step_sigma: scale of the step prior outside the bounds, metres (default ``noise_std``).
        step_prior: "uniform" (dead zone plus the moment-matched Gaussian of a length uniform
            within the bounds) or "dead_zone" (no cost inside the bounds at all).
        step_lengths: (M - 1,) measured step lengths (odometry), Gaussian with ``odometry_sigma``.
        step_vectors: (M - 1, d) measured steps x_{i+1} - x_i in the map frame (odometry), each
            coordinate Gaussian with ``odometry_sigma``. They fix the frame's orientation, so no
            gauge priors are added with them.
        robust: None (Gaussian), "huber", "cauchy" or "tukey" on the range factors.
        robust_scale: the kernel's scale in metres; default the 95%-efficiency constants of
            :data:`rangeslam.solvers.robust_kernels.ROBUST_KERNEL_CONSTANTS` times ``noise_std``.
        covariances: compute the marginal covariances (GTSAM Marginals).
        max_iterations, lambda_upper_bound: Levenberg-Marquardt settings (:class:`LMOptions`);
            max_iterations=0 evaluates the graph's cost (and covariances) at the given points.
        receiver_plane: (3,) a normal: the receivers held in the plane across it through their
            start's centroid, started on it (:func:`add_plane_priors`; used by
            :mod:`rangeslam.mdu.planar_walk`).

    Returns a :class:`GraphFit`. Raises SolverError when LM returns a non-finite cost or the
    covariances are undefined (an unobservable direction beyond the gauge).
    """
    import gtsam  # the back end is imported on use, so `import rangeslam` stays light

    covariances = as_flag(covariances, "covariances")
    problem = parse_graph_problem(
        receivers, sources, ranges, noise_std=noise_std, mask=mask, step_bounds=step_bounds,
        step_sigma=step_sigma, step_prior=step_prior, step_lengths=step_lengths,
        step_vectors=step_vectors, odometry_sigma=odometry_sigma, robust=robust,
        robust_scale=robust_scale, max_iterations=max_iterations,
        lambda_upper_bound=lambda_upper_bound, receiver_plane=receiver_plane,
    )  # fmt: skip
    m = len(problem.receivers)
    keys = graph_keys(gtsam, m, len(problem.sources))
    graph, measurements, points = build_graph(gtsam, problem, keys)
    run = run_levenberg_marquardt(gtsam, graph, points, keys, problem.lm)
    status, message = lm_verdict(problem.lm, run)
    covs = (None, None, None)
    if covariances:
        covs = graph_covariances(gtsam, measurements, run.values, keys, run.estimate, problem)
    return fit_result(problem, run, covs, status, message)


def fit_result(problem: GraphProblem, run: LMRun, covs, status: Status, message: str) -> GraphFit:
    """The :class:`GraphFit` of an LM ``run`` on ``problem``, with ``covs`` (receiver, source,
    joint covariances, or Nones) and its verdict."""
    m, est = len(problem.receivers), run.estimate
    residuals = np.where(problem.observed, range_matrix(est[:m], est[m:]) - problem.ranges, np.nan)
    return GraphFit(
        receivers=frozen(est[:m]),
        sources=frozen(est[m:]),
        receiver_cov=covs[0],
        source_cov=covs[1],
        joint_cov=covs[2],
        residuals=frozen(residuals),
        error=run.error,
        initial_error=run.initial_error,
        iterations=run.iterations,
        status=status,
        message=message,
    )
