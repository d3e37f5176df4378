"""Cramer-Rao lower bounds for range measurements with i.i.d. Gaussian noise. Pure numpy.

The information of the models the estimators solve: the verdicts judge precision with it (so it
sits below the estimators, beside the checks) and the benchmarks use it as a yardstick
(re-exported by :mod:`rangeslam.evaluation`).

For a point x observed through ranges r_m = ||x - a_m|| + e_m, e_m ~ N(0, sigma_m^2), the Fisher
information is F = sum_m u_m u_m^T / sigma_m^2 with u_m = (x - a_m) / ||x - a_m||, and any
unbiased estimator has covariance >= F^-1. The bound on the RMSE is sqrt(trace F^-1): compare it
with the RMS error over trials (sqrt of the mean squared error), not with a median, and with the
RMS of the per-trial bounds (sqrt(mean(bound^2))) when the configuration changes between trials.

:func:`mdu_crlb` also takes the priors of :func:`rangeslam.mdu.slam` (step bounds, odometry step
lengths): their information is added to J^T J / sigma^2, so that a method that uses them is
compared with the bound of the information it uses. A bound is a lower bound only where the
estimator is in its asymptotic regime: the benchmarks quote it only where the oracle (the
estimator's cost minimised from the truth) attains it (:func:`rangeslam.evaluation.rms_against_bound`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import (
    as_float_array,
    as_mask,
    as_point,
    as_points,
    check_metres,
    real_scalar,
    shape_str,
)
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.geometry.rigid_motion import receiver_gauge_projection, rigid_motion_basis
from rangeslam.solvers.step_bounds import StepBounds

#: How an estimator reads step bounds (as ``step_prior`` of :func:`rangeslam.mdu.slam`).
STEP_PRIOR_KINDS = ("uniform", "dead_zone")

__all__ = ["STEP_PRIOR_KINDS", "MDUBound", "mdu_crlb", "multilateration_crlb", "wall_crlb"]


def _check_sigma(sigma: float) -> float:
    """A range noise standard deviation must be positive (at 0 the information is infinite)."""
    value = real_scalar(sigma, "sigma", "a positive number of metres")
    # sigma^2 and 1 / sigma^2 must stay finite floats (1e-100 m is no noise level anyway).
    if not (1e-100 <= value <= 1e100):
        raise InvalidInputError(f"sigma must be in [1e-100, 1e100] metres; got {sigma!r}")
    return float(value)


def multilateration_crlb(
    anchors: ArrayLike,
    point: ArrayLike,
    sigma: float | ArrayLike,
    *,
    mask: ArrayLike | None = None,
) -> np.ndarray:
    """(d, d) CRLB covariance of a point located from ranges to known anchors (M, d).

    ``sigma`` is the range noise standard deviation in metres, a scalar or one per anchor (M,).
    ``sqrt(trace(result))`` bounds the RMSE of any unbiased estimator.
    """
    a = as_points(anchors, "anchors")
    m, d = a.shape
    x = as_point(point, "point", dim=d)
    observed = as_mask(mask, "mask", shape=(m,))
    s = as_float_array(sigma, "sigma")
    s = np.broadcast_to(s, (m,)) if s.ndim == 0 else s
    if s.shape != (m,):
        raise InvalidInputError(
            f"sigma must be a scalar or have shape ({m},); got {shape_str(s.shape)}"
        )
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InvalidInputError(
            "sigma must be positive and finite (the bound is infinite information at 0)"
        )
    if np.any(s < 1e-100) or np.any(s > 1e100):  # as _check_sigma: 1 / sigma^2 stays finite
        raise InvalidInputError(f"sigma must be in [1e-100, 1e100] metres; got {sigma!r:.80}")
    diff = x - a[observed]
    dist = np.linalg.norm(diff, axis=1)
    if np.any(dist == 0):
        raise DegenerateGeometryError(
            "point coincides with an anchor: the range gradient is undefined there"
        )
    u = diff / dist[:, None] / s[observed][:, None]
    fisher = u.T @ u
    eig = np.linalg.eigvalsh(fisher)
    if eig[0] <= 1e-12 * eig[-1]:
        raise DegenerateGeometryError(
            "the Fisher information is singular: the anchors' directions from the point do not span R^d"
        )
    return np.linalg.solve(fisher, np.eye(d))


def wall_crlb(
    mics: ArrayLike,
    sources: ArrayLike,
    normals: ArrayLike,
    offsets: ArrayLike,
    sigma: float,
    *,
    points: ArrayLike | None = None,
    mask: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """CRLB of the walls reconstructed from first-order echoes heard by known microphones.

    The unknowns are the J loudspeakers (J, d) and the K walls, each image source tied to its
    source and wall (the joint model of :func:`rangeslam.reconstruct_room`); the ranges are
    i.i.d. N(0, sigma^2) in metres, ``mask`` (J, M, 1+K) True where observed.

    Returns:
        offset_std: (K,) bound on the standard deviation of each wall plane's offset measured at
            ``points[k]`` (a point on wall k, such as its centroid; by default the foot of the
            perpendicular from the first source), metres.
        normal_std: (K,) bound on the standard deviation of each wall normal's angle, radians.
    """
    from rangeslam.localization.room_reconstruction import JointWallModel

    m = as_points(mics, "mics")
    d = m.shape[1]
    s = as_points(sources, "sources", dim=d)
    n = as_points(normals, "normals", dim=d)
    o = as_float_array(offsets, "offsets")
    k_n, j_n = len(n), len(s)
    if o.shape != (k_n,):
        raise InvalidInputError(f"offsets must have shape ({k_n},); got {shape_str(o.shape)}")
    if not np.all(np.isfinite(o)):
        raise InvalidInputError(f"offsets must be finite; got {o}")
    check_metres(o, "offsets", "wall offsets", min_scale=False)
    sigma = _check_sigma(sigma)
    if points is None:
        p = s[0] + (o - n @ s[0])[:, None] * n
    else:
        p = as_points(points, "points", dim=d)
        if p.shape != (k_n, d):
            raise InvalidInputError(
                f"points must have shape ({k_n}, {d}); got {shape_str(p.shape)}"
            )
    observed = as_mask(mask, "mask", shape=(j_n, len(m), 1 + k_n))
    # Centre on the sources' mean, inside the room, so that no wall passes through the origin.
    c = s.mean(axis=0)
    w = n * (o - n @ c)[:, None]
    theta = np.concatenate([(s - c).ravel(), w.ravel()])
    model = JointWallModel(m - c, np.zeros((j_n, len(m), 1 + k_n)), observed)
    jac = model.jacobian(theta) / sigma
    fisher = jac.T @ jac
    eig = np.linalg.eigvalsh(fisher)
    if eig[0] <= 1e-12 * eig[-1]:
        raise DegenerateGeometryError(
            "the Fisher information of the walls is singular: too few echoes"
        )
    cov = np.linalg.solve(fisher, np.eye(len(theta)))
    offset_std = np.empty(k_n)
    normal_std = np.empty(k_n)
    for k in range(k_n):
        sl = slice((j_n + k) * d, (j_n + k + 1) * d)
        cw = cov[sl, sl]
        nk, rho = w[k] / np.linalg.norm(w[k]), np.linalg.norm(w[k])
        proj = np.eye(d) - np.outer(nk, nk)
        # offset at p: e = n.(p - c) - |w|, de/dw = (I - n n^T)(p - c)/|w| - n  (n = w/|w|)
        grad = proj @ (p[k] - c) / rho - nk
        offset_std[k] = np.sqrt(grad @ cw @ grad)
        normal_std[k] = np.sqrt(np.trace(proj @ cw @ proj)) / rho
    return offset_std, normal_std


def _gauge_free_covariance(jac: np.ndarray, basis: np.ndarray, sigma: float):
    """F^+ of F = J^T J / sigma^2 (J (R, n)) whose null space holds the rigid motions ``basis``
    (n, r), and the null space's dimension.

    The gauge is removed analytically: J is restricted to the orthogonal complement Q of the
    rigid motions, and the rank of J Q is judged from its own singular values (numpy's
    ``matrix_rank`` tolerance, max(shape) eps s_max, relative to J's spectrum; singular values,
    not the eigenvalues of J^T J, so a well-posed but ill-conditioned problem keeps its finite
    bound). Then F^+ = Q V diag(sigma^2 / s^2) V^T Q^T. Raises DegenerateGeometryError when
    more than the rigid motions are unobservable.
    """
    n_rigid = basis.shape[1]
    full, _, _ = np.linalg.svd(basis, full_matrices=True)
    q = full[:, n_rigid:]
    _, sv, vt = np.linalg.svd(jac @ q, full_matrices=False)
    tol = (max(jac.shape[0], q.shape[1]) * np.finfo(float).eps * sv[0]) if sv.size else 0.0
    rank = int(np.sum(sv > tol))
    null_dim = n_rigid + q.shape[1] - rank
    if null_dim > n_rigid:
        raise DegenerateGeometryError(
            f"{null_dim} unobservable directions, more than the {n_rigid} rigid motions: "
            "too few ranges (or a degenerate configuration) for unique unfolding"
        )
    half = q @ (vt.T / sv) * sigma  # no explicit inverse: F^+ = half half^T
    return half @ half.T, null_dim


@dataclass(frozen=True)
class MDUBound:
    """Anchor-free CRLB of multidimensional unfolding (M receivers, K sources, all unknown).

    Attributes:
        receiver_cov: (M, d, d) bound on each receiver's error covariance, in the chosen gauge.
        source_cov: (K, d, d) the same for the sources.
        receiver_rmse: sqrt(mean over receivers of trace(receiver_cov)), metres.
        source_rmse: the same over the sources, metres.
        gauge: "receivers" (errors after rigidly aligning the receivers alone) or "all".
        null_dimension: dimension of the Fisher information's null space (d(d+1)/2 when only
            rigid motions are unobservable: 3 in 2-D, 6 in 3-D).
    """

    receiver_cov: np.ndarray
    source_cov: np.ndarray
    receiver_rmse: float
    source_rmse: float
    gauge: str
    null_dimension: int


def _step_prior_sigmas(step_bounds, step_prior, step_sigma, odometry_sigma, m, sigma):
    """(M - 1,) standard deviations of the Gaussian step-length factors the estimator adds per
    step, metres (one array per factor kind; empty list without priors), checked at the door."""
    if not isinstance(step_prior, str) or step_prior not in STEP_PRIOR_KINDS:
        raise InvalidInputError(f"step_prior must be one of {STEP_PRIOR_KINDS}; got {step_prior!r}")
    spreads = []
    if step_bounds is not None:
        if m < 2:
            raise InvalidInputError(f"step_bounds need at least 2 receivers; got {m}")
        bounds = StepBounds.parse(step_bounds, m - 1)
        floor = sigma if step_sigma is None else _positive(step_sigma, "step_sigma")
        if step_prior == "uniform":
            # the moment-matched Gaussian of U(lower, upper), never below step_sigma (as
            # rangeslam.solvers.gtsam_graph.add_step_priors); the dead zone adds nothing inside
            width = bounds.upper - bounds.lower
            spreads.append(np.maximum(width / np.sqrt(12.0), floor))
    elif step_sigma is not None:
        raise InvalidInputError(
            "step_sigma is only meaningful with step_bounds; got step_bounds=None"
        )
    if odometry_sigma is not None:
        if m < 2:
            raise InvalidInputError(f"odometry_sigma needs at least 2 receivers; got {m}")
        spreads.append(np.full(m - 1, _positive(odometry_sigma, "odometry_sigma")))
    return spreads


def _positive(value, name: str) -> float:
    """A positive finite number of metres, or InvalidInputError naming ``name``."""
    x = real_scalar(value, name, "a positive number of metres")
    if not (np.isfinite(x) and x > 0):
        raise InvalidInputError(f"{name} must be a positive finite number of metres; got {value!r}")
    return float(x)


def _range_rows(first: np.ndarray, second: np.ndarray, i_idx, j_idx, n: int, what: str):
    """Jacobian rows (R, n d) of the distances ||first_r - second_r|| of points i_idx[r] and
    j_idx[r] of the stacked vector of n points; ``what`` names a coincident pair."""
    d = first.shape[1]
    diff = first - second
    dist = np.linalg.norm(diff, axis=1)
    if np.any(dist == 0):
        raise DegenerateGeometryError(f"{what}: the range gradient is undefined")
    u = diff / dist[:, None]
    jac = np.zeros((len(u), n * d))
    for row, (i, j, uu) in enumerate(zip(i_idx, j_idx, u, strict=True)):
        jac[row, i * d : (i + 1) * d] = uu
        jac[row, j * d : (j + 1) * d] = -uu
    return jac


def _whitened_jacobian(x, s, observed, spreads, sigma: float) -> np.ndarray:
    """Rows (R, (M + K) d) of the ranges of receivers ``x`` (M, d) and sources ``s`` (K, d) in
    ``observed``, then one block of step-length rows per prior in ``spreads`` (each (M - 1,),
    metres), whitened so that F = J^T J / sigma^2."""
    m, k = len(x), len(s)
    pairs = np.argwhere(observed)
    jac = _range_rows(
        x[pairs[:, 0]],
        s[pairs[:, 1]],
        pairs[:, 0],
        m + pairs[:, 1],
        m + k,
        "a receiver coincides with a source",
    )
    if spreads:
        steps = np.arange(m - 1)
        step_jac = _range_rows(
            x[1:], x[:-1], steps + 1, steps, m + k, "a receiver coincides with the next one"
        )
        # whitened to the range noise: F = [J; W J_step]^T [J; W J_step] / sigma^2
        jac = np.vstack([jac] + [step_jac * (sigma / sp)[:, None] for sp in spreads])
    return jac


def mdu_crlb(
    receivers: ArrayLike,
    sources: ArrayLike,
    sigma: float,
    *,
    mask: ArrayLike | None = None,
    gauge: str = "receivers",
    step_bounds: StepBounds | tuple[ArrayLike, ArrayLike] | None = None,
    step_prior: str = "uniform",
    step_sigma: float | None = None,
    odometry_sigma: float | None = None,
) -> MDUBound:
    """CRLB of receivers (M, d) and sources (K, d) located from their ranges (eq. 9 setting) and
    the step priors the estimator uses (:func:`rangeslam.mdu.slam`).

    Ranges r_mk = ||x_m - s_k|| + N(0, sigma^2) for the pairs in ``mask`` (M, K) (True = observed).
    The Fisher information F = J^T J / sigma^2 + sum_i u_i u_i^T / spread_i^2 (on the difference
    x_{i+1} - x_i, u_i its unit direction) is singular along the rigid motions (priors on step
    lengths do not fix them), so the bound depends on how the estimate is aligned before its
    error is taken:

    - ``gauge="all"``: errors after aligning all points: the pseudo-inverse F^+;
    - ``gauge="receivers"``: errors after aligning the receivers alone (as in Fig. 3): P F^+ P^T
      with P = I - T (T_r^T T_r)^-1 T_r^T S_r, which removes the rigid motion (basis T) fitted to
      the receiver rows (T_r, selected by S_r) of the error. This differs from F^+.

    The gauge is removed analytically and the rank judged relative to the information's own
    spectrum, so the bound is finite wherever F is regular beyond the rigid motions.

    Priors (the receivers are then a trajectory, consecutive rows one step apart):

    - ``step_bounds`` (lower, upper), each (M - 1,), metres, read as ``step_prior`` says:
      "uniform" (the default of :func:`rangeslam.mdu.slam`): the information of the Gaussian
      factor the estimator adds, mean (lower + upper) / 2 and spread max((upper - lower) /
      sqrt(12), step_sigma) (U(lower, upper)'s moments; the bound is that of the estimator that
      uses this Gaussian, which for a step length truly uniform in the bounds is the bound of
      the best linear use of its first two moments); "dead_zone": no information at all, since
      the dead-zone factor is flat inside the bounds (a true step strictly inside them);
    - ``step_sigma``: the floor of that spread, metres (default ``sigma``, as the estimator);
    - ``odometry_sigma``: step lengths measured with N(0, odometry_sigma^2) noise (odometry range
      factors); the information does not depend on the measured values. (Step vectors, which
      also fix the orientation, are not covered.)

    Raises InvalidInputError for bad input (naming the argument) and DegenerateGeometryError when
    more than the rigid motions are unobservable.
    """
    x = as_points(receivers, "receivers")
    d = x.shape[1]
    s = as_points(sources, "sources", dim=d)
    m, k = len(x), len(s)
    observed = as_mask(mask, "mask", shape=(m, k))
    if not isinstance(gauge, str) or gauge not in ("receivers", "all"):
        raise InvalidInputError(f"gauge must be 'receivers' or 'all'; got {gauge!r}")
    sigma = _check_sigma(sigma)
    spreads = _step_prior_sigmas(step_bounds, step_prior, step_sigma, odometry_sigma, m, sigma)
    jac = _whitened_jacobian(x, s, observed, spreads, sigma)
    cov, null_dim = _gauge_free_covariance(jac, rigid_motion_basis(np.vstack([x, s])), sigma)
    if gauge == "receivers":
        proj = receiver_gauge_projection(x, s)
        cov = proj @ cov @ proj.T
    blocks = np.array([cov[i * d : (i + 1) * d, i * d : (i + 1) * d] for i in range(m + k)])
    rec, src = blocks[:m], blocks[m:]
    return MDUBound(
        receiver_cov=rec,
        source_cov=src,
        receiver_rmse=float(np.sqrt(np.mean(np.trace(rec, axis1=1, axis2=2)))),
        source_rmse=float(np.sqrt(np.mean(np.trace(src, axis1=1, axis2=2)))),
        gauge=gauge,
        null_dimension=null_dim,
    )
