"""Room reconstruction from echoes with a known microphone array (paper, section 2, Problem 1).

For each loudspeaker j, column 0 of its (M, 1+K) range matrix holds the direct-path distances from
the M microphones and column k the distances to the image source of wall k (echoes matched to
walls, as the paper assumes). The pipeline:

1. every source and image source is located on its own by SR-LS multilateration (eq. 3), robustly
   if asked, which also flags wrong echo picks;
2. wall k is the perpendicular bisector of s_j and its image s_jk (the image-source formula of
   section 2 read backwards); with several loudspeakers the wall from the best-supported one starts;
3. all sources and walls are refined jointly by maximum likelihood on the ranges (Gaussian range
   noise), with every image s_jk tied to its source and wall: s_jk = s_j + 2(o_k - n_k.s_j) n_k.
   With ``robust`` this is first done with a Cauchy loss, then ranges more than 3 robust standard
   deviations off are rejected and the fit is repeated on the rest until the inlier set is stable.
   Several loudspeakers share the walls, so an echo mis-picked for one is outvoted by the others.

Walls are parametrised in the optimiser by w_k = o_k n_k in coordinates centred on the microphones
(a plane not through the origin, unoriented, d numbers); since the microphones are inside the room,
no wall passes through their centroid. Orientation is fixed at the end: normals point from the
sources to their images (outward).
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from ._validation import as_mask, as_points, as_ranges, frozen, shape_str
from .errors import DegenerateGeometryError, InvalidInputError
from .geometry import Room
from .multilateration import affine_rank, multilaterate

__all__ = ["RoomReconstruction", "reconstruct_room"]

log = logging.getLogger(__name__)

# Inlier threshold of the joint fit, in robust standard deviations of the range residual.
_JOINT_INLIER_K = 3.0


@dataclass(frozen=True)
class RoomReconstruction:
    """Result of :func:`reconstruct_room`. J loudspeakers, K walls, M microphones, d = 2 or 3.

    Attributes:
        sources: (J, d) loudspeaker positions, metres.
        image_sources: (J, K, d) first-order image sources, column k mirrored in wall k.
        wall_normals: (K, d) outward unit normals, in the order of the echo columns.
        wall_offsets: (K,) offsets, metres: wall k is {x : wall_normals[k] . x = wall_offsets[k]}.
        room: the convex room the walls bound, or None when they do not close a bounded region.
        observed: (J, M, 1+K) the mask that was given (True where a range was observed).
        inliers: (J, M, 1+K) True for the ranges used in the final fit.
        residual_rms: RMS range residual over the inliers, metres.
        converged: whether the fit converged to a consistent room (sources on the inner side of
            every wall, enough inliers); False comes with a reason in ``message``.
        message: what happened.
        iterations: function evaluations of the joint refinement.
    """

    sources: np.ndarray
    image_sources: np.ndarray
    wall_normals: np.ndarray
    wall_offsets: np.ndarray
    room: Room | None
    observed: np.ndarray
    inliers: np.ndarray
    residual_rms: float
    converged: bool
    message: str
    iterations: int

    @property
    def n_outliers(self) -> int:
        """Number of observed ranges rejected as outliers."""
        return int(self.observed.sum() - self.inliers.sum())


def _as_list(value, name: str) -> tuple[list, bool]:
    """A single (M, 1+K) matrix or a sequence of them -> list, and whether it was a sequence."""
    if isinstance(value, np.ndarray) or (
        isinstance(value, Sequence) and len(value) > 0 and np.ndim(value[0]) < 2
    ):
        return [value], False
    if isinstance(value, Sequence) and len(value) > 0:
        return list(value), True
    raise InvalidInputError(f"{name} must be an (M, 1+K) array or a non-empty list of them")


def _images(sources: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(J, K, d) mirror images of sources (J, d) in the planes w_k (K, d) (w = o n, centred coords).

    With n = w/|w| and o = |w|: s' = (I - 2 n n^T) s + 2 o n = s - 2 (w.s) w / |w|^2 + 2 w.
    """
    rho = np.einsum("kd,kd->k", walls, walls)
    q = sources @ walls.T  # (J, K)
    return (
        sources[:, None, :]
        - 2.0 * (q / rho)[:, :, None] * walls[None, :, :]
        + 2.0 * walls[None, :, :]
    )


def _points_and_jacobian(sources: np.ndarray, walls: np.ndarray):
    """Points P (J, 1+K, d) and dP/d(sources) (J, 1+K, d, d), dP/d(walls) (J, K, d, d)."""
    j_n, d = sources.shape
    k_n = walls.shape[0]
    eye = np.eye(d)
    rho = np.einsum("kd,kd->k", walls, walls)
    q = sources @ walls.T
    pts = np.concatenate([sources[:, None, :], _images(sources, walls)], axis=1)
    d_src = np.empty((j_n, 1 + k_n, d, d))
    d_src[:, 0] = eye
    householder = eye[None] - 2.0 * np.einsum("ka,kb->kab", walls, walls) / rho[:, None, None]
    d_src[:, 1:] = householder[None]
    # d s'/d w = 2 I - 2 [ (w s^T + q I) / rho - 2 q w w^T / rho^2 ]
    ws = np.einsum("ka,jb->jkab", walls, sources)
    ww = np.einsum("ka,kb->kab", walls, walls)
    d_wall = (
        2.0 * eye
        - 2.0 * (ws + q[:, :, None, None] * eye) / rho[None, :, None, None]
        + 4.0 * q[:, :, None, None] * ww[None] / (rho**2)[None, :, None, None]
    )
    return pts, d_src, d_wall


class _JointModel:
    """Range residuals of all loudspeakers given (sources, walls), and their analytic Jacobian."""

    def __init__(self, mics: np.ndarray, ranges: np.ndarray, use: np.ndarray) -> None:
        self.mics = mics  # (M, d)
        self.ranges = ranges  # (J, M, 1+K)
        self.use = use  # (J, M, 1+K) bool
        self.j_n, self.m_n, self.c_n = ranges.shape
        self.d = mics.shape[1]

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = theta[: self.j_n * self.d].reshape(self.j_n, self.d)
        w = theta[self.j_n * self.d :].reshape(self.c_n - 1, self.d)
        return s, w

    def all_residuals(self, theta: np.ndarray) -> np.ndarray:
        s, w = self.unpack(theta)
        pts = np.concatenate([s[:, None, :], _images(s, w)], axis=1)
        dist = np.linalg.norm(self.mics[None, :, None, :] - pts[:, None, :, :], axis=3)
        return dist - self.ranges

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        return self.all_residuals(theta)[self.use]

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        s, w = self.unpack(theta)
        d, j_n, k_n = self.d, self.j_n, self.c_n - 1
        pts, d_src, d_wall = _points_and_jacobian(s, w)
        diff = pts[:, None, :, :] - self.mics[None, :, None, :]  # (J, M, 1+K, d)
        u = diff / np.maximum(np.linalg.norm(diff, axis=3, keepdims=True), 1e-300)
        jac = np.zeros((j_n, self.m_n, 1 + k_n, (j_n + k_n) * d))
        for j in range(j_n):
            jac[j, :, :, j * d : (j + 1) * d] = np.einsum("mca,cab->mcb", u[j], d_src[j])
            for k in range(k_n):
                col = (j_n + k) * d
                jac[j, :, 1 + k, col : col + d] = u[j, :, 1 + k] @ d_wall[j, k]
        return jac[self.use]


def _mixture_fit(
    res: np.ndarray, valid: np.ndarray, nu: float, sigma_floor: float, iterations: int = 30
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit residuals as inliers N(0, sigma^2) plus outliers uniform on [-nu, nu], by EM (MLESAC).

    ``res`` and ``valid`` are (H, N): H hypotheses, N residuals each (``valid`` False = ignore).
    Returns sigma (H,) (never below ``sigma_floor``), the inlier fraction gamma (H,), the
    log-likelihood (H,) and the inlier posterior (H, N) (Torr and Zisserman, "MLESAC", CVIU 2000).
    """
    r2 = np.where(valid, res**2, 0.0)
    n = np.maximum(valid.sum(axis=1), 1)
    med = np.array(
        [np.median(np.abs(row[v])) if v.any() else 0.0 for row, v in zip(res, valid, strict=True)]
    )
    sigma = np.maximum(1.4826 * med, sigma_floor)
    gamma = np.full(len(res), 0.5)
    p_out = 1.0 / (2.0 * nu)
    for _ in range(iterations):
        p_in = np.exp(-0.5 * r2 / sigma[:, None] ** 2) / (math.sqrt(2.0 * math.pi) * sigma[:, None])
        num = gamma[:, None] * p_in
        post = np.where(valid, num / (num + (1.0 - gamma[:, None]) * p_out), 0.0)
        wsum = np.maximum(post.sum(axis=1), 1e-12)
        sigma = np.maximum(np.sqrt((post * r2).sum(axis=1) / wsum), sigma_floor)
        gamma = np.clip(wsum / n, 1e-3, 1.0 - 1e-3)
    p_in = np.exp(-0.5 * r2 / sigma[:, None] ** 2) / (math.sqrt(2.0 * math.pi) * sigma[:, None])
    mix = gamma[:, None] * p_in + (1.0 - gamma[:, None]) * p_out
    loglik = np.where(valid, np.log(mix), 0.0).sum(axis=1)
    post = np.where(valid, gamma[:, None] * p_in / mix, 0.0)
    return sigma, gamma, loglik, post


def _wall_hypotheses(
    mics: np.ndarray,
    ranges: np.ndarray,
    observed: np.ndarray,
    sources: np.ndarray,
    per_source: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Candidate walls (H, d), as w = o n, for one echo column of every loudspeaker.

    For loudspeaker j, each subset of d+1 microphones that heard the echo gives the image source by
    the exact linear solution of A y = b (y = [x, ||x||^2]) and the wall as the bisector of s_j and
    that image. ``per_source`` random subsets are drawn per loudspeaker (all of them when there are
    fewer); the SR-LS solution from all of the loudspeaker's echoes is always a candidate too, and
    with ``per_source == 0`` the only one.
    """
    d = mics.shape[1]
    walls: list[np.ndarray] = []
    for j in range(ranges.shape[0]):
        idx = np.flatnonzero(observed[j])
        if len(idx) < d + 1 or affine_rank(mics[idx]) < d:
            continue
        images = [multilaterate(mics, ranges[j], mask=observed[j]).position[None, :]]
        if per_source > 0 and len(idx) > d + 1:
            if math.comb(len(idx), d + 1) <= per_source:
                subsets = np.array(list(itertools.combinations(idx, d + 1)))
            else:
                subsets = idx[np.argsort(rng.random((per_source, len(idx))), axis=1)[:, : d + 1]]
            a_sub = np.concatenate(
                [-2.0 * mics[subsets], np.ones((len(subsets), d + 1, 1))], axis=2
            )
            b_sub = ranges[j][subsets] ** 2 - np.einsum("hpd,hpd->hp", mics[subsets], mics[subsets])
            sv = np.linalg.svd(a_sub, compute_uv=False)
            ok = sv[:, -1] > 1e-8 * sv[:, 0]
            if np.any(ok):
                images.append(np.linalg.solve(a_sub[ok], b_sub[ok][..., None])[..., 0][:, :d])
        img = np.vstack(images)
        normal = img - sources[j]
        length = np.linalg.norm(normal, axis=1)
        keep = length > 1e-9
        normal = normal[keep] / length[keep, None]
        offset = np.einsum("hd,hd->h", normal, (img[keep] + sources[j]) / 2.0)
        keep2 = np.abs(offset) > 1e-9  # a plane through the microphones' centroid cannot be a wall
        walls.append(normal[keep2] * offset[keep2, None])
    return np.vstack(walls) if walls else np.empty((0, d))


def reconstruct_room(
    mics: ArrayLike,
    ranges: ArrayLike | Sequence[ArrayLike],
    *,
    mask: ArrayLike | Sequence[ArrayLike] | None = None,
    robust: bool = True,
    inlier_threshold: float | None = None,
    max_hypotheses: int = 500,
    rng: np.random.Generator | int | None = None,
) -> RoomReconstruction:
    """Sources, image sources and walls from echoes heard by a known microphone array.

    Args:
        mics: (M, d) known microphone positions, metres, affinely spanning R^d (M >= d + 1).
        ranges: (M, 1+K) distances from each microphone to the source (column 0) and to its K
            first-order image sources (columns 1..K, one per wall, matched across microphones);
            or a list of J such matrices, one per loudspeaker, with the same walls in the same
            column order, whose walls are then estimated jointly.
        mask: boolean array(s) of the shape of ``ranges``, True where the echo was observed.
        robust: reject wrong echo picks (LMedS per source, then a robust joint fit). Without it
            every observed range is used in a plain least-squares fit.
        rng: random generator (or seed) for the robust subset search.

    Returns:
        :class:`RoomReconstruction`; ``sources`` is (J, d) even for one loudspeaker.
    """
    rng = np.random.default_rng(rng)
    m_pts = as_points(mics, "mics")
    m_n, d = m_pts.shape
    if m_n < d + 1:
        raise InvalidInputError(
            f"mics must hold at least d + 1 = {d + 1} microphones in {d}-D; got {shape_str(m_pts.shape)}"
        )
    if affine_rank(m_pts) < d:
        kind = {0: "coincident", 1: "collinear", 2: "coplanar"}[affine_rank(m_pts)]
        raise DegenerateGeometryError(
            f"mics are {kind}: in {d}-D they must not all lie in one {'plane' if d == 3 else 'line'}, "
            "or the image sources are ambiguous (mirror images across it)"
        )
    range_list, _ = _as_list(ranges, "ranges")
    if mask is None:
        mask_list = [None] * len(range_list)
    else:
        mask_list, _ = _as_list(mask, "mask")
        if len(mask_list) != len(range_list):
            raise InvalidInputError(
                f"mask must give one mask per range matrix; got {len(mask_list)} for {len(range_list)}"
            )
    first = np.asarray(range_list[0])
    if first.ndim != 2 or first.shape[1] < 2:
        raise InvalidInputError(
            f"ranges must have shape (M, 1+K) with K >= 1 echo columns; got {shape_str(first.shape)}"
        )
    c_n = first.shape[1]
    k_n = c_n - 1
    j_n = len(range_list)
    observed = np.empty((j_n, m_n, c_n), dtype=bool)
    r_all = np.empty((j_n, m_n, c_n))
    for j, (r, mk) in enumerate(zip(range_list, mask_list, strict=True)):
        name = "ranges" if j_n == 1 else f"ranges[{j}]"
        observed[j] = as_mask(mk, "mask" if j_n == 1 else f"mask[{j}]", shape=(m_n, c_n))
        r_all[j] = as_ranges(r, name, shape=(m_n, c_n), observed=observed[j])

    # Work centred on the microphones and scaled to unit size (results do not depend on units).
    centre = m_pts.mean(axis=0)
    scale = float(np.median(r_all[observed])) if observed.any() else 1.0
    scale = scale if scale > 0 else 1.0
    mics_s = (m_pts - centre) / scale
    r_s = r_all / scale

    # 1. Each loudspeaker from its direct path (eq. 3), robustly if asked.
    sources0 = np.empty((j_n, d))
    direct_resid: list[np.ndarray] = []
    for j in range(j_n):
        obs = observed[j, :, 0]
        if obs.sum() < d + 1 or affine_rank(mics_s[obs]) < d:
            raise InvalidInputError(
                f"loudspeaker {j}: the direct path (column 0) needs at least {d + 1} observed "
                f"ranges from microphones spanning {d}-D; got {int(obs.sum())}"
            )
        res = multilaterate(mics_s, r_s[j, :, 0], mask=obs, robust=robust, rng=rng)
        if not res.converged:
            raise InvalidInputError(
                f"loudspeaker {j}: the direct path could not be located: {res.message}"
            )
        sources0[j] = res.position
        direct_resid.append(res.residuals[res.inliers])
    # Echoes cannot be located more precisely than the direct sound: the noise scale of the direct
    # paths is the floor of every column's noise scale below.
    pooled = np.concatenate(direct_resid)
    sigma_floor = max(math.sqrt(float(pooled @ pooled) / max(pooled.size - j_n * d, 1)), 1e-9)
    # Outliers are spread over the span of the measured ranges (MLESAC's uniform component).
    nu = float(r_s[observed].max())
    fixed_thr = None if inlier_threshold is None else float(inlier_threshold) / scale

    def classify(res_col: np.ndarray, obs_col: np.ndarray) -> np.ndarray:
        """Inliers of one column's residuals (J, M): fixed threshold, or the mixture posterior."""
        if fixed_thr is not None:
            return obs_col & (np.abs(res_col) <= fixed_thr)
        _, _, _, post = _mixture_fit(
            res_col.reshape(1, -1), obs_col.reshape(1, -1), nu, sigma_floor
        )
        return obs_col & (post.reshape(res_col.shape) > 0.5)

    # 2. Each wall by consensus over all loudspeakers (bisector of s_j and its image, section 2).
    walls0 = np.empty((k_n, d))
    for k in range(k_n):
        cands = _wall_hypotheses(
            mics_s,
            r_s[:, :, 1 + k],
            observed[:, :, 1 + k],
            sources0,
            max_hypotheses if robust else 0,
            rng,
        )
        if len(cands) == 0:
            raise InvalidInputError(
                f"wall {k} (column {1 + k}): no loudspeaker has {d + 1} observed echoes from "
                f"microphones spanning {d}-D to locate it"
            )
        imgs = _images(sources0, cands.reshape(-1, d)).transpose(1, 0, 2)  # (H, J, d)
        dist = np.linalg.norm(mics_s[None, None, :, :] - imgs[:, :, None, :], axis=3)
        res = (dist - r_s[None, :, :, 1 + k]).reshape(len(cands), -1)
        valid = np.broadcast_to(observed[None, :, :, 1 + k], dist.shape).reshape(len(cands), -1)
        if fixed_thr is not None:  # MSAC: truncated squared residuals over every loudspeaker
            score = np.where(valid, np.minimum(res**2, fixed_thr**2), 0.0).sum(axis=1)
        else:  # MLESAC: negative log-likelihood of the inlier/outlier mixture
            score = -_mixture_fit(res, valid, nu, sigma_floor)[2]
        walls0[k] = cands[int(np.argmin(score))]

    # 3. Joint maximum-likelihood refinement with every image tied to its source and wall.
    theta = np.concatenate([sources0.ravel(), walls0.ravel()])
    n_params = theta.size
    nfev = 0
    model = _JointModel(mics_s, r_s, observed)

    def classify_all(theta: np.ndarray) -> np.ndarray:
        res_all = model.all_residuals(theta)
        return np.stack([classify(res_all[:, :, c], observed[:, :, c]) for c in range(c_n)], axis=2)

    use = classify_all(theta) if robust else observed.copy()
    converged = True
    message = ""
    for _ in range(20):
        if use.sum() < n_params:
            converged, message = (
                False,
                f"only {int(use.sum())} inlier ranges for {n_params} unknowns",
            )
            break
        inlier_model = _JointModel(mics_s, r_s, use)
        fit = least_squares(
            inlier_model.residuals,
            theta,
            jac=inlier_model.jacobian,
            method="trf",
            x_scale="jac",
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
        )
        theta, nfev = fit.x, nfev + fit.nfev
        if not robust:
            break
        new = classify_all(theta)
        if np.array_equal(new, use):
            break
        use = new
    else:
        message = "inlier set still changing after 20 re-fits; "

    s_s, w_s = _JointModel(mics_s, r_s, use).unpack(theta)
    offsets_s = np.linalg.norm(w_s, axis=1)
    normals = w_s / offsets_s[:, None]
    images_s = _images(s_s, w_s)
    # Orientation: outward normals point from the sources to their images.
    side = np.einsum("jkd,kd->jk", images_s - s_s[:, None, :], normals)
    if np.any(side <= 0):
        bad = sorted({int(k) for k in np.argwhere(side <= 0)[:, 1]})
        converged = False
        message += f"walls {bad} do not separate the microphones' centroid from the sources; "
    sources = centre + scale * s_s
    image_sources = centre + scale * images_s
    wall_offsets = scale * offsets_s + normals @ centre
    res_final = _JointModel(mics_s, r_s, use).residuals(theta) * scale
    rms = float(np.sqrt(np.mean(res_final**2))) if res_final.size else float("nan")

    room = None
    try:
        room = Room(normals, wall_offsets)
    except (DegenerateGeometryError, InvalidInputError) as exc:
        message += f"the walls do not bound a room ({exc}); "
    if room is not None:
        tol = 1e-6 * room.size
        if not np.all(room.contains(sources, margin=-tol)):
            converged = False
            message += "a source lies outside the reconstructed room; "
    if converged:
        message += f"converged: {int(use.sum())} of {int(observed.sum())} ranges used, RMS residual {rms:.3g} m"
    return RoomReconstruction(
        sources=frozen(sources),
        image_sources=frozen(image_sources),
        wall_normals=frozen(normals),
        wall_offsets=frozen(wall_offsets),
        room=room,
        observed=frozen(observed),
        inliers=frozen(use),
        residual_rms=rms,
        converged=converged,
        message=message.strip().rstrip(";"),
        iterations=int(nfev),
    )
