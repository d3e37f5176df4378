"""Levenberg-Marquardt on a GTSAM graph with the outer loop in Python (GTSAM's algorithm)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam._validation import as_scalar, check_int
from rangeslam.status import HasStatus, Status

__all__ = ["MAX_LM_ITERATIONS", "LMReport", "levenberg_marquardt"]

#: The message of a stop at a stationary point whose cost no step lowers beyond round-off.
ROUND_OFF_MESSAGE = "converged to round-off: no decrease at the largest damping, none predicted"

# The relative-decrease test counts as convergence only at damping up to this (a unit-free
# lambda on whitened residuals: at 1e-2 the step is within about 1% of Gauss-Newton's).
LM_CONVERGED_LAMBDA = 1e-2


@dataclass(frozen=True)
class LMReport(HasStatus):
    """How a :func:`levenberg_marquardt` run ended: iterations, initial and final cost (GTSAM's
    ``graph.error``: half the sum of squared whitened residuals), status (CONVERGED or
    SOLVER_FAILED) and a message."""

    iterations: int
    initial_cost: float
    cost: float
    status: Status
    message: str


def damped_system(linear, dims: dict[int, int], models: dict, lam: float):
    """``linear`` plus lambda I as unit prior factors on every variable (keys and dimensions in
    ``dims``; ``models`` the unit noise model of each dimension)."""
    import gtsam

    damped = linear.clone()
    root = np.sqrt(lam)
    blocks = {d: (root * np.eye(d), np.zeros(d)) for d in models}  # the factors copy them
    for key, d in dims.items():
        damped.add(gtsam.JacobianFactor(key, *blocks[d], models[d]))
    return damped


def damped_trial(graph, linear, values, dims: dict[int, int], models: dict, lam: float):
    """One damped step: solve :func:`damped_system`, retract; returns (trial values, their
    cost), the cost infinite when the linear solve fails."""
    damped = damped_system(linear, dims, models, lam)
    try:
        delta = damped.optimize()
        trial = values.retract(delta)
        return trial, graph.error(trial)
    except RuntimeError:  # e.g. an indeterminant system: as GTSAM, a failed step
        return values, np.inf


def predicted_decrease(linear, dims: dict[int, int], models: dict, lam: float) -> float:
    """Decrease of the linearised cost ``linear`` predicted by its (lightly damped, ``lam``)
    Gauss-Newton step: 0 (to round-off) at a stationary point; inf if the solve fails."""
    import gtsam

    try:
        delta = damped_system(linear, dims, models, lam).optimize()
    except RuntimeError:  # an indeterminant system: no verdict of a minimum from it
        return np.inf
    return float(linear.error(gtsam.VectorValues.Zero(delta)) - linear.error(delta))


def stall_report(
    iteration: int, initial: float, cost: float, predicted: float, rel_tol: float
) -> LMReport:
    """No step decreased the cost up to the largest damping: CONVERGED when the Gauss-Newton
    step predicts at most ``rel_tol`` of the cost (round-off), else a stall (SOLVER_FAILED)."""
    if predicted <= rel_tol * max(cost, 1e-300):
        return LMReport(iteration, initial, cost, Status.CONVERGED, ROUND_OFF_MESSAGE)
    return LMReport(
        iteration,
        initial,
        cost,
        Status.SOLVER_FAILED,
        "stalled: no decrease at the largest damping",
    )


#: The most Levenberg-Marquardt iterations a caller may ask for: Plaza converges in tens; a
#: larger count only makes a run that does not converge run for hours before it says so.
MAX_LM_ITERATIONS = 100_000


def check_lm_settings(max_iterations, rel_tol, lambda_initial, lambda_max):
    """The settings of :func:`levenberg_marquardt` checked at its door: max_iterations an integer
    in [1, MAX_LM_ITERATIONS], rel_tol in (0, 1), 0 < lambda_initial < lambda_max (finite); InvalidInputError naming
    the setting otherwise. Returns them as (int, float, float, float)."""
    iterations = check_int(max_iterations, "max_iterations", 1, MAX_LM_ITERATIONS)
    tol = as_scalar(rel_tol, "rel_tol", low=0.0, high=1.0, low_open=True, high_open=True)
    lam0 = as_scalar(lambda_initial, "lambda_initial", low=0.0, low_open=True)
    lam_max = as_scalar(lambda_max, "lambda_max", low=lam0, low_open=True)
    return iterations, tol, lam0, lam_max


def levenberg_marquardt(
    graph,
    values,
    dims: dict[int, int],
    *,
    max_iterations: int = 100,
    rel_tol: float = 1e-6,
    lambda_initial: float = 1e-5,
    lambda_max: float = 1e10,
):
    """Levenberg-Marquardt on a GTSAM graph, the outer loop in Python (GTSAM's algorithm: damping
    lambda I added as prior factors on every variable, Cholesky on the damped system).

    Why not gtsam.LevenbergMarquardtOptimizer: it linearises in TBB worker threads, and every
    CustomFactor callback from a worker thread takes the GIL afresh, which makes linearising a
    graph of thousands of CustomFactors many times slower than ``graph.linearize`` from Python.

    Converged: an accepted step decreased the cost by at most ``rel_tol`` of it, with the damping
    low enough that the step was close to Gauss-Newton's; or no step decreases the cost up to
    ``lambda_max`` while the Gauss-Newton step of the linearised cost predicts a decrease of at
    most ``rel_tol`` of it (a stationary point: the trial costs differ from the cost by round-off
    only, e.g. on exact data with tiny sigmas). Not converged (SOLVER_FAILED): the iteration
    limit, a non-finite initial cost, or no decrease up to ``lambda_max`` although one was
    predicted (a stall: a wrong Jacobian, or a point that is not a minimum of the model). Failed
    linear solves count as rejected steps.

    Returns the optimised values and an :class:`LMReport`.
    """
    import gtsam

    max_iterations, rel_tol, lambda_initial, lambda_max = check_lm_settings(
        max_iterations, rel_tol, lambda_initial, lambda_max
    )
    models = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    cost = initial = graph.error(values)
    if not np.isfinite(cost):
        return values, LMReport(
            0, initial, cost, Status.SOLVER_FAILED, "the initial cost is not finite"
        )
    lam = lambda_initial
    for iteration in range(1, max_iterations + 1):
        linear = graph.linearize(values)
        while True:
            trial, trial_cost = damped_trial(graph, linear, values, dims, models, lam)
            if np.isfinite(trial_cost) and trial_cost <= cost:
                break
            lam *= 10.0
            if lam > lambda_max:
                predicted = predicted_decrease(linear, dims, models, lambda_initial)
                return values, stall_report(iteration, initial, cost, predicted, rel_tol)
        decrease = cost - trial_cost
        values, cost = trial, trial_cost
        # A tiny decrease under heavy damping is a short step, not a minimum: keep going.
        if decrease <= rel_tol * max(cost, 1e-300) and lam <= LM_CONVERGED_LAMBDA:
            return values, LMReport(
                iteration, initial, cost, Status.CONVERGED, "relative decrease below tol"
            )
        lam = max(lam / 10.0, 1e-12)
    return values, LMReport(
        max_iterations,
        initial,
        cost,
        Status.SOLVER_FAILED,
        f"not converged in {max_iterations} iterations",
    )
