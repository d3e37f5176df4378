"""Euclidean distance matrices (paper, section 3.1, eqs. 5-7). Pure numpy.

``edm`` always means a matrix of *squared* distances, D = [d_ij^2]. Points are rows (N, d).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, as_scalar, shape_str
from rangeslam.errors import InvalidInputError

__all__ = ["centring_matrix", "classical_mds", "edm", "edm_to_gram", "gram_to_edm", "is_edm"]


def _as_square(value: ArrayLike, name: str) -> np.ndarray:
    arr = as_float_array(value, name)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] < 1:
        raise InvalidInputError(
            f"{name} must be a square (N, N) matrix; got {shape_str(arr.shape)}"
        )
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be finite")
    return arr


def edm(points: ArrayLike) -> np.ndarray:
    """(N, N) squared distances between points (N, d), eq. (5). Any finite coordinates (no
    limit in metres: estimators apply it to their own answers)."""
    x = as_points(points, "points", metres=False)
    sq = np.einsum("nd,nd->n", x, x)
    d = sq[:, None] + sq[None, :] - 2.0 * x @ x.T
    np.fill_diagonal(d, 0.0)
    return np.maximum(d, 0.0)  # round-off can make tiny entries negative


def gram_to_edm(gram: ArrayLike) -> np.ndarray:
    """K(G) = diag(G) 1^T + 1 diag(G)^T - 2 G, eq. (6)."""
    g = _as_square(gram, "gram")
    dg = np.diag(g)
    return dg[:, None] + dg[None, :] - 2.0 * g


def centring_matrix(n: int) -> np.ndarray:
    """J = I - 11^T / n, the geometric centring matrix."""
    return np.eye(n) - np.full((n, n), 1.0 / n)


def edm_to_gram(edm_matrix: ArrayLike) -> np.ndarray:
    """G = -1/2 J D J, eq. (7): the Gram matrix of the centred point set."""
    d = _as_square(edm_matrix, "edm_matrix")
    j = centring_matrix(d.shape[0])
    g = -0.5 * j @ d @ j
    return 0.5 * (g + g.T)


def is_edm(edm_matrix: ArrayLike, *, dim: int | None = None, rtol: float = 1e-9) -> bool:
    """Gower's test: D is an EDM iff it is symmetric, hollow, and -1/2 J D J is PSD.

    With ``dim``, also requires embedding dimension <= dim (at most ``dim`` eigenvalues of the Gram
    matrix above ``rtol`` times the largest). Tolerances are relative to the largest entry.
    ``dim``: None or a positive integer; ``rtol``: a real number in [0, 1).
    """
    d = _as_square(edm_matrix, "edm_matrix")
    dim = as_scalar(dim, "dim", low=1, integer=True, allow_none=True)
    rtol = as_scalar(rtol, "rtol", low=0.0, high=1.0, high_open=True)
    scale = max(float(np.abs(d).max()), np.finfo(float).tiny)
    if not np.allclose(d, d.T, atol=rtol * scale, rtol=0):
        return False
    if np.any(np.abs(np.diag(d)) > rtol * scale) or np.any(d < -rtol * scale):
        return False
    eig = np.linalg.eigvalsh(edm_to_gram(d))
    if eig[0] < -rtol * scale * d.shape[0]:
        return False
    if dim is not None:
        return int(np.sum(eig > rtol * max(eig[-1], scale))) <= dim
    return True


def classical_mds(edm_matrix: ArrayLike, dim: int) -> np.ndarray:
    """Points (N, dim), centred, whose EDM best fits D (Torgerson's classical MDS).

    Double centring (eq. 7), ``eigh``, the ``dim`` largest eigenvalues with negatives clipped to 0.
    The result is unique up to rotation and reflection.
    """
    dim = as_scalar(dim, "dim", low=1, integer=True, expected="a positive integer")
    g = edm_to_gram(edm_matrix)
    if dim > g.shape[0]:
        raise InvalidInputError(f"dim must be <= the number of points {g.shape[0]}; got {dim}")
    eigval, eigvec = np.linalg.eigh(g)
    top = np.argsort(eigval)[::-1][:dim]
    return eigvec[:, top] * np.sqrt(np.maximum(eigval[top], 0.0))[None, :]


def range_matrix(receivers: ArrayLike, sources: ArrayLike) -> np.ndarray:
    """(M, K) distances between receivers (M, d) and sources (K, d). Any finite coordinates (no
    limit in metres: estimators apply it to their own answers, which may have diverged)."""
    r = as_points(receivers, "receivers", metres=False)
    s = as_points(sources, "sources", dim=r.shape[1], metres=False)
    return np.linalg.norm(r[:, None, :] - s[None, :, :], axis=2)
