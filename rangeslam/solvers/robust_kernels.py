"""The robust kernels of every GTSAM graph in the package, in one table.

The constants give 95% asymptotic efficiency on Gaussian residuals (Huber 1.345, Cauchy 2.3849,
Tukey 4.6851; Zhang, "Parameter estimation techniques: a tutorial with application to conic
fitting", Image and Vision Computing 15(1), 1997), in units of the residual's sigma.
"""

from __future__ import annotations

from rangeslam._robust import ROBUST_KERNEL_CONSTANTS, ROBUST_KERNELS, ROBUST_VALUES, robust_mode

__all__ = [
    "ROBUST_KERNELS",
    "ROBUST_KERNEL_CONSTANTS",
    "ROBUST_VALUES",
    "robust_mode",
    "robust_noise_model",
]


def robust_noise_model(gtsam, base, kind: str | None, constant: float | None = None):
    """``base`` wrapped in GTSAM's M-estimator ``kind`` (None: ``base`` itself).

    ``constant`` is the kernel's threshold in units of ``base``'s sigma (default: the table's).
    ``gtsam`` is the imported module (passed in so that this table imports no back end).
    """
    if kind is None:
        return base
    estimators = {
        "huber": gtsam.noiseModel.mEstimator.Huber,
        "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
        "tukey": gtsam.noiseModel.mEstimator.Tukey,
    }
    c = ROBUST_KERNEL_CONSTANTS[kind] if constant is None else float(constant)
    return gtsam.noiseModel.Robust.Create(estimators[kind].Create(c), base)
