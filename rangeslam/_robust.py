"""Residual diagnostics shared by the robust fits (room reconstruction, calibration), and the one
set of values every estimator's ``robust=`` takes (:func:`robust_mode`)."""

from __future__ import annotations

import numpy as np

from rangeslam.errors import InvalidInputError

__all__ = [
    "MAD_TO_STD",
    "ROBUST_KERNELS",
    "ROBUST_KERNEL_CONSTANTS",
    "ROBUST_VALUES",
    "mad_sigma",
    "robust_mode",
    "studentized",
]

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


#: Kernel name -> tuning constant in sigmas (95% efficiency).
ROBUST_KERNEL_CONSTANTS: dict[str, float] = {"huber": 1.345, "cauchy": 2.3849, "tukey": 4.6851}
#: The kernel names accepted by every ``robust=`` option backed by GTSAM.
ROBUST_KERNELS: tuple[str, ...] = tuple(ROBUST_KERNEL_CONSTANTS)


#: The one set of values every estimator's ``robust=`` takes: None or False (off), True (on, the
#: estimator's own robust method), "auto" (decided from the data), or a kernel name (the
#: M-estimator of the fit). An estimator refuses the values it cannot honour, naming those it can.
ROBUST_VALUES: tuple = (None, False, True, "auto", *ROBUST_KERNELS)


def robust_mode(value, supported: tuple[str, ...], *, default_kernel: str | None = None,
                name: str = "robust") -> str | None:  # fmt: skip
    """``robust=`` read once, the same way by every estimator: None (off), "auto", "on" or a
    kernel name.

    ``value``: one of :data:`ROBUST_VALUES` (a numpy bool counts as a bool); ``supported``: the
    modes this estimator has ("on", "auto" and kernel names; off is always there); True is
    ``default_kernel`` when the estimator's robust method is a kernel, else "on". Raises
    InvalidInputError naming the argument for any other value or one the estimator lacks."""
    if isinstance(value, np.bool_):
        value = bool(value)
    known = (
        value is None
        or isinstance(value, bool)
        or (isinstance(value, str) and value in ROBUST_VALUES)
    )
    if not known:
        raise InvalidInputError(
            f"{name} must be one of None, False, True, 'auto', "
            f"{', '.join(repr(k) for k in ROBUST_KERNELS)}; got {value!r:.80}"
        )
    if value is None or value is False:
        return None
    mode = (default_kernel or "on") if value is True else value
    if mode not in supported:
        takes = ", ".join(["None", "False", "True", *(repr(m) for m in supported if m != "on")])
        raise InvalidInputError(f"{name}={value!r} is not available here; it takes {takes}")
    return mode
