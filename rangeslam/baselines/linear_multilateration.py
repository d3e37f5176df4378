"""The classical linear least-squares multilateration, the usual baseline for SR-LS.

Treating t = ||x||^2 as a free unknown turns ||x - a_m||^2 = r_m^2 into the linear system
[-2 a_m^T, 1] [x; t] = r_m^2 - ||a_m||^2, solved by ordinary least squares. It ignores the
constraint t = ||x||^2, so it needs d + 2 anchors for an overdetermined fit and degrades badly
when the anchors are nearly coplanar or the point is far from them (Beck, Stoica and Li 2008,
section II); SR-LS solves the constrained problem exactly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_points, as_ranges
from rangeslam.errors import DegenerateGeometryError, InvalidInputError

__all__ = ["linear_multilaterate"]


def linear_multilaterate(anchors: ArrayLike, ranges: ArrayLike) -> np.ndarray:
    """Unconstrained linear LS estimate (d,) from anchors (M, d), M >= d + 1, and ranges (M,)."""
    a = as_points(anchors, "anchors")
    m, d = a.shape
    r = as_ranges(ranges, "ranges", shape=(m,))
    if m < d + 1:
        raise InvalidInputError(f"anchors must hold at least {d + 1} points; got {m}")
    centre = a.mean(axis=0)
    ac = a - centre
    a_mat = np.column_stack([-2.0 * ac, np.ones(m)])
    b = r**2 - np.einsum("nd,nd->n", ac, ac)
    y, _, rank, _ = np.linalg.lstsq(a_mat, b, rcond=None)
    if rank < d + 1:
        raise DegenerateGeometryError("anchors must affinely span R^d for linear multilateration")
    return centre + y[:d]
