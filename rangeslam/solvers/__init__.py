"""Numerical back ends shared by the estimators.

- :mod:`.sdp`: EDM completion by semidefinite programming (eq. 8, rank relaxed) and Dattorro's
  convex iteration (eq. 10) with distance bounds (eq. 11); cvxpy with Clarabel.
- :mod:`.least_squares`: least squares on the ranges of an unfolding (eq. 4 on ranges), analytic
  Jacobian.
- :mod:`.gtsam_graph`: the GTSAM range-factor graph with step-length priors and robust kernels.
"""

from __future__ import annotations

from rangeslam.solvers.gtsam_graph import ROBUST_KERNELS, STEP_PRIORS, GraphFit, refine_graph
from rangeslam.solvers.least_squares import (
    UnfoldingFit,
    refine_unfolding,
    unfolding_jacobian,
    unfolding_residuals,
)
from rangeslam.solvers.sdp import (
    RANGE_MODELS,
    EDMCompletion,
    EDMCompletionSDP,
    complete_edm,
    low_rank_direction,
    random_direction,
)

__all__ = [
    "RANGE_MODELS",
    "ROBUST_KERNELS",
    "STEP_PRIORS",
    "EDMCompletion",
    "EDMCompletionSDP",
    "GraphFit",
    "UnfoldingFit",
    "complete_edm",
    "low_rank_direction",
    "random_direction",
    "refine_graph",
    "refine_unfolding",
    "unfolding_jacobian",
    "unfolding_residuals",
]
