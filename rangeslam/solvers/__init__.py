"""Numerical back ends shared by the estimators.

- :mod:`.sdp`: EDM completion by semidefinite programming (eq. 8, rank relaxed) and Dattorro's
  convex iteration (eq. 10) with distance bounds (eq. 11); cvxpy with Clarabel.
- :mod:`.least_squares`: least squares on the ranges of an unfolding (eq. 4 on ranges), analytic
  Jacobian.
- :mod:`.gtsam_graph`: the GTSAM range-factor graph with step-length priors and robust kernels.
- :mod:`.robust_kernels`: the one table of robust kernels (Huber, Cauchy, Tukey) of every graph.
- :mod:`.step_bounds`: :class:`StepBounds`, bounds on a walk's step lengths (eq. 11), parsed once.
"""

from __future__ import annotations

from rangeslam.solvers.gtsam_graph import STEP_PRIORS, GraphFit, LMOptions, refine_graph
from rangeslam.solvers.least_squares import (
    UnfoldingFit,
    refine_unfolding,
    unfolding_jacobian,
    unfolding_residuals,
)
from rangeslam.solvers.robust_kernels import (
    ROBUST_KERNEL_CONSTANTS,
    ROBUST_KERNELS,
    robust_noise_model,
)
from rangeslam.solvers.sdp import (
    RANGE_MODELS,
    EDMCompletion,
    EDMCompletionSDP,
    complete_edm,
    low_rank_direction,
    random_direction,
)
from rangeslam.solvers.step_bounds import StepBounds

__all__ = [
    "RANGE_MODELS",
    "ROBUST_KERNELS",
    "ROBUST_KERNEL_CONSTANTS",
    "STEP_PRIORS",
    "EDMCompletion",
    "EDMCompletionSDP",
    "GraphFit",
    "LMOptions",
    "StepBounds",
    "UnfoldingFit",
    "complete_edm",
    "low_rank_direction",
    "random_direction",
    "refine_graph",
    "refine_unfolding",
    "robust_noise_model",
    "unfolding_jacobian",
    "unfolding_residuals",
]
