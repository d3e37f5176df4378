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

from rangeslam._validation import as_mask, as_points, as_ranges, frozen, shape_str
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import receiver_gauge_projection

__all__ = ["ROBUST_KERNELS", "STEP_PRIORS", "GraphFit", "refine_graph"]

ROBUST_KERNELS = ("huber", "cauchy", "tukey")
#: Readings of step bounds in the graph (see the module docstring).
STEP_PRIORS = ("uniform", "dead_zone")
# Sigma of the gauge priors relative to noise_std. The pinned directions are unobservable, so how
# tight does not change the estimate; 1e-2 keeps the factorisation well conditioned. The other
# coordinates of the gauge points get no prior information at all (zero rows of the square-root
# information), so nothing observable is pulled.
_GAUGE_TIGHT = 1e-2


@dataclass(frozen=True)
class GraphFit:
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
        converged: LM finished within its iteration limit with a finite cost no larger than the
            start's.
        message: why not, when ``converged`` is False; empty otherwise.
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
    converged: bool
    message: str


def check_step_bounds(step_bounds, m: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        lower, upper = (np.array(b, dtype=float, copy=True) for b in step_bounds)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            "step_bounds must be a pair (lower, upper) of arrays of step lengths"
        ) from exc
    for name, b in (("lower", lower), ("upper", upper)):
        if b.shape != (m - 1,):
            raise InvalidInputError(
                f"step_bounds {name} must have shape ({m - 1},) (one per step between the {m} "
                f"receivers); got {shape_str(b.shape)}"
            )
        if not np.all(np.isfinite(b)):
            raise InvalidInputError(f"step_bounds {name} must be finite")
    if np.any(lower < 0):
        i = int(np.argmax(lower < 0))
        raise InvalidInputError(f"step_bounds lower must be >= 0; step {i} has {lower[i]}")
    if np.any(lower > upper):
        i = int(np.argmax(lower > upper))
        raise InvalidInputError(
            f"step_bounds must have lower <= upper; step {i} has [{lower[i]}, {upper[i]}]"
        )
    return lower, upper


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


def _partial_prior(gtsam, key: int, at: np.ndarray, rows: np.ndarray, noise_std: float):
    """CustomFactor pinning the components rows @ (p - at) of one point (rows: (n, d)), and no
    other: the gauge prior that leaves every observable direction to the measurements."""
    at = at.copy()
    rows = np.ascontiguousarray(rows)
    getter = "atPoint3" if len(at) == 3 else "atPoint2"

    def error(this, values, jacobians):
        p = getattr(values, getter)(this.keys()[0])
        if jacobians is not None:
            jacobians[0] = rows
        return rows @ (p - at)

    model = gtsam.noiseModel.Isotropic.Sigma(len(rows), _GAUGE_TIGHT * noise_std)
    return gtsam.CustomFactor(model, [key], error)


def _covariance(gtsam, graph, values, keys: list[int], d: int, *, gauge_free: bool) -> np.ndarray:
    """Covariance of the stacked points from GTSAM's linearisation of the measurement factors at
    ``values`` (noise models, robust weights and step priors baked in): the pseudo-inverse of the
    information through the SVD of the whitened Jacobian, the rigid-motion null space dropped.

    GTSAM's own Marginals need the gauge priors, and with them the elimination was reported
    indeterminate on a few well-posed lemniscate scenes; the SVD of A does not square the
    condition number. Raises SolverError when more than the rigid motions are unobservable.
    """
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    jac, _ = graph.linearize(values).jacobian(ordering)
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    n_gauge = d * (d + 1) // 2 if gauge_free else d
    keep = sv > 1e-9 * sv[0]
    if int(np.sum(~keep)) + (jac.shape[1] - len(sv)) > n_gauge:
        raise SolverError(
            "covariances undefined: the graph leaves directions beyond the gauge unobservable",
            status=f"{int(np.sum(~keep)) + jac.shape[1] - len(sv)} null directions, "
            f"{n_gauge} expected",
        )
    v = vt[keep].T / sv[keep]
    return v @ v.T


def refine_graph(
    receivers: ArrayLike,
    sources: ArrayLike,
    ranges: ArrayLike,
    *,
    noise_std: float,
    mask: ArrayLike | None = None,
    step_bounds: tuple[ArrayLike, ArrayLike] | None = None,
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
) -> GraphFit:
    """Refine receivers (M, d) and sources (K, d) on their ranges (M, K) with GTSAM.

    Args:
        receivers, sources: the starting point (e.g. :func:`rangeslam.calibrate`'s answer).
        ranges: (M, K) metres; entries outside ``mask`` are ignored.
        noise_std: standard deviation of the range noise, metres (> 0).
        mask: (M, K) boolean, True where observed.
        step_bounds: (lower, upper), each (M - 1,), bounds on |x_{i+1} - x_i| in metres: a
            step prior as ``step_prior`` says.
        step_sigma: scale of the step prior outside the bounds, metres (default ``noise_std``).
        step_prior: "uniform" (dead zone plus the moment-matched Gaussian of a length uniform
            within the bounds) or "dead_zone" (no cost inside the bounds at all).
        step_lengths: (M - 1,) measured step lengths (odometry), Gaussian with ``odometry_sigma``.
        step_vectors: (M - 1, d) measured steps x_{i+1} - x_i in the map frame (odometry), each
            coordinate Gaussian with ``odometry_sigma``. They fix the frame's orientation, so no
            gauge priors are added with them.
        robust: None (Gaussian), "huber", "cauchy" or "tukey" on the range factors.
        robust_scale: the kernel's scale in metres; default 1.345, 1 and 4.685 ``noise_std`` for
            Huber, Cauchy and Tukey (the usual constants).
        covariances: compute the marginal covariances (GTSAM Marginals).
        max_iterations: Levenberg-Marquardt iteration limit (planar trajectories leave a slow
            valley: from the truth, 80 iterations are typical at 1 cm noise); 0 evaluates the
            graph's cost (and covariances) at the given points without moving them.
        lambda_upper_bound: LM stops when its damping exceeds this (GTSAM's default is 1e5;
            see the comment in the code for why the default here is 1e12).

    Returns a :class:`GraphFit`. Raises SolverError when LM returns a non-finite cost or the
    covariances are undefined (an unobservable direction beyond the gauge).
    """
    import gtsam  # the back end is imported on use, so `import rangeslam` stays light

    x = as_points(receivers, "receivers")
    m, d = x.shape
    s = as_points(sources, "sources", dim=d)
    k = len(s)
    observed = as_mask(mask, "mask", shape=(m, k))
    r = as_ranges(ranges, "ranges", shape=(m, k), observed=observed)
    if not (np.isfinite(noise_std) and noise_std > 0):
        raise InvalidInputError(f"noise_std must be positive and finite; got {noise_std!r}")
    if robust is not None and robust not in ROBUST_KERNELS:
        raise InvalidInputError(f"robust must be None or one of {ROBUST_KERNELS}; got {robust!r}")
    if not (isinstance(max_iterations, int | np.integer) and max_iterations >= 0):
        raise InvalidInputError(f"max_iterations must be an integer >= 0; got {max_iterations!r}")
    if step_prior not in STEP_PRIORS:
        raise InvalidInputError(f"step_prior must be one of {STEP_PRIORS}; got {step_prior!r}")
    odometry = step_lengths is not None or step_vectors is not None
    if odometry and not (odometry_sigma is not None and odometry_sigma > 0):
        raise InvalidInputError("odometry_sigma (> 0) is required with step_lengths/step_vectors")

    point3 = d == 3
    range_factor = gtsam.RangeFactor3 if point3 else gtsam.RangeFactor2
    prior_factor = gtsam.PriorFactorPoint3 if point3 else gtsam.PriorFactorPoint2
    between_factor = gtsam.BetweenFactorPoint3 if point3 else gtsam.BetweenFactorPoint2

    def key_x(i: int) -> int:
        return gtsam.symbol("x", i)

    def key_l(j: int) -> int:
        return gtsam.symbol("l", j)

    graph = gtsam.NonlinearFactorGraph()
    base = gtsam.noiseModel.Isotropic.Sigma(1, noise_std)
    if robust is None:
        range_noise = base
    else:
        default = {"huber": 1.345, "cauchy": 1.0, "tukey": 4.685}[robust]
        c = default if robust_scale is None else robust_scale / noise_std
        if not (np.isfinite(c) and c > 0):
            raise InvalidInputError(f"robust_scale must be positive; got {robust_scale!r}")
        kernel = {
            "huber": gtsam.noiseModel.mEstimator.Huber,
            "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
            "tukey": gtsam.noiseModel.mEstimator.Tukey,
        }[robust](c)
        range_noise = gtsam.noiseModel.Robust.Create(kernel, base)
    for i, j in np.argwhere(observed):
        graph.add(range_factor(key_x(int(i)), key_l(int(j)), float(r[i, j]), range_noise))

    if step_bounds is not None:
        lower, upper = check_step_bounds(step_bounds, m)
        sig = noise_std if step_sigma is None else float(step_sigma)
        if not (np.isfinite(sig) and sig > 0):
            raise InvalidInputError(f"step_sigma must be positive; got {step_sigma!r}")
        for i in range(m - 1):
            half = 0.5 * (upper[i] - lower[i])
            model = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.L2WithDeadZone(half / sig),
                gtsam.noiseModel.Isotropic.Sigma(1, sig),
            )
            graph.add(range_factor(key_x(i), key_x(i + 1), float(lower[i] + half), model))
            if step_prior == "uniform":  # mean and variance of U(lower, upper); never below sig
                spread = max(2 * half / np.sqrt(12), sig)
                model = gtsam.noiseModel.Isotropic.Sigma(1, spread)
                graph.add(range_factor(key_x(i), key_x(i + 1), float(lower[i] + half), model))
    if step_lengths is not None:
        lengths = np.asarray(step_lengths, dtype=float)
        if lengths.shape != (m - 1,) or not np.all(np.isfinite(lengths)) or np.any(lengths < 0):
            raise InvalidInputError(
                f"step_lengths must be ({m - 1},) finite non-negative; got {shape_str(lengths.shape)}"
            )
        model = gtsam.noiseModel.Isotropic.Sigma(1, odometry_sigma)
        for i in range(m - 1):
            graph.add(range_factor(key_x(i), key_x(i + 1), float(lengths[i]), model))
    if step_vectors is not None:
        steps = as_points(step_vectors, "step_vectors", dim=d)
        if steps.shape != (m - 1, d):
            raise InvalidInputError(
                f"step_vectors must have shape ({m - 1}, {d}); got {shape_str(steps.shape)}"
            )
        model = gtsam.noiseModel.Isotropic.Sigma(d, odometry_sigma)
        for i in range(m - 1):
            graph.add(between_factor(key_x(i), key_x(i + 1), steps[i], model))

    measurements = graph.clone()  # without the gauge priors: the covariances come from these
    points = np.vstack([x, s])
    keys = [key_x(i) for i in range(m)] + [key_l(j) for j in range(k)]
    if step_vectors is None:
        # Gauge: priors on the unobservable rigid motion only, in a frame of 3 spread points.
        idx = _gauge_points(points)
        frame = _gauge_frame(points, idx)
        axes = [list(range(d)), list(range(1, d))]  # a: all; b: across the line ab
        if d == 3:
            axes.append([2])  # c: along the normal of the plane abc
        for p, pinned in zip(idx, axes, strict=True):
            graph.add(_partial_prior(gtsam, keys[p], points[p], frame[:, pinned].T, noise_std))
    else:  # odometry vectors fix the orientation; only the translation is free
        graph.add(
            prior_factor(
                keys[0], points[0], gtsam.noiseModel.Isotropic.Sigma(d, _GAUGE_TIGHT * noise_std)
            )
        )

    initial = gtsam.Values()
    for key, p in zip(keys, points, strict=True):
        initial.insert(key, p)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(1e-9)
    params.setAbsoluteErrorTol(1e-12)
    # GTSAM stops once the damping passes lambdaUpperBound (1e5 by default). In the curved, flat
    # valleys of few-step SLAM (sigma = 1 mm, M = 5) that stopped it 5-8 cm from the minimum,
    # which a bound of 1e12 reaches (measured: mean trajectory error 7 -> 1.7 cm).
    if not (lambda_upper_bound > 0):
        raise InvalidInputError(f"lambda_upper_bound must be positive; got {lambda_upper_bound!r}")
    params.setlambdaUpperBound(float(lambda_upper_bound))
    initial_error = float(graph.error(initial))
    result, iterations = initial, 0
    if max_iterations > 0:
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        result = optimizer.optimize()
        iterations = int(optimizer.iterations())
    error = float(graph.error(result))
    if not np.isfinite(error):
        raise SolverError("GTSAM Levenberg-Marquardt diverged", status=f"error {error}")
    at = result.atPoint3 if point3 else result.atPoint2
    est = np.array([at(key) for key in keys])
    message = ""
    if 0 < max_iterations <= iterations:
        message += f"Levenberg-Marquardt hit the limit of {max_iterations} iterations; "
    if error > initial_error * (1 + 1e-9) + 1e-12:
        message += "the cost went up; "

    rec_cov = src_cov = joint = None
    if covariances:
        full = _covariance(gtsam, measurements, result, keys, d, gauge_free=step_vectors is None)
        if step_vectors is None:
            proj = receiver_gauge_projection(est[:m], est[m:])
            full = proj @ full @ proj.T
        blocks = np.array([full[i * d : (i + 1) * d, i * d : (i + 1) * d] for i in range(m + k)])
        rec_cov, src_cov = frozen(blocks[:m]), frozen(blocks[m:])
        joint = frozen(full)

    residuals = np.where(observed, range_matrix(est[:m], est[m:]) - r, np.nan)
    return GraphFit(
        receivers=frozen(est[:m]),
        sources=frozen(est[m:]),
        receiver_cov=rec_cov,
        source_cov=src_cov,
        joint_cov=joint,
        residuals=frozen(residuals),
        error=error,
        initial_error=initial_error,
        iterations=iterations,
        converged=not message,
        message=message.rstrip("; "),
    )
