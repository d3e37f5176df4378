"""Residual diagnostics shared by the robust fits (room reconstruction, calibration)."""

from __future__ import annotations

import numpy as np

__all__ = ["MAD_TO_STD", "mad_sigma", "studentized"]

#: The median absolute deviation times this is the standard deviation of Gaussian data
#: (1 / Phi^-1(3/4)).
MAD_TO_STD = 1.4826


def studentized(abs_res: np.ndarray, jac: np.ndarray, in_fit: np.ndarray) -> np.ndarray:
    """|Residuals| divided by their standard deviation in units of the noise sigma.

    ``jac`` (N, p) holds the Jacobian rows of all N residuals, ``in_fit`` (N,) marks those the
    least-squares fit used. With the leverage h = x (J^T J)^+ x^T (J the in-fit rows), a residual in
    the fit has variance sigma^2 (1 - h), one outside it sigma^2 (1 + h) (the deleted-residual
    test). Exactly fitted residuals (h ~ 1) say nothing and cannot be tested: they get NaN.
    """
    _, sv, vt = np.linalg.svd(jac[in_fit], full_matrices=False)
    keep = sv > 1e-10 * max(float(sv[0]) if sv.size else 0.0, 1e-300)
    proj = (jac @ vt[keep].T) / sv[keep]  # rows: x V S^-1, so h = ||row||^2
    lev = np.sum(proj**2, axis=1)
    var = np.where(in_fit, 1.0 - lev, 1.0 + lev)
    out = np.full(abs_res.shape, np.nan)
    ok = var > 1e-6
    out[ok] = abs_res[ok] / np.sqrt(var[ok])
    return out


def mad_sigma(stud: np.ndarray) -> float:
    """1.4826 times the median of the finite studentized |residuals| (floored at 1e-9)."""
    finite = stud[np.isfinite(stud)]
    return max(MAD_TO_STD * float(np.median(finite)), 1e-9) if finite.size else 1e-9
