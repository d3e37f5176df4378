"""A planar walk fitted in its plane: the nested model of :func:`rangeslam.mdu.slam`'s answer.

A robot on a floor (Fig. 5's lemniscate at one height) walks in a plane. Fitted in 3-D, the
walk bends out of its plane to fit the range noise, and each landmark fits as well on either side
of the plane: every combination of sides is a local minimum, a few noise variances apart. The
lowest of them is a selection on fitted noise, and its covariance is optimistic (on Fig. 5's
walks: benchmarks/README.md, "a planar walk fitted in 3-D").

The nested model holds the receivers in one plane (each step's offset across it: M unknowns
fewer, less the plane's own three, a translation and two tilts that the rigid motion already
leaves free) with the landmarks free. Refitted from the answer projected into its best plane, on
the same graph at the same range sigma, it is kept when the likelihood-ratio test does not reject
it: the deviance gap (-2 log likelihood ratio, :func:`rangeslam.mdu.slam_graph.graph_deviance`)
within the chi-square(M - 3) quantile at :data:`rangeslam.verdict.thresholds.CHI2_LEVEL`, the
test :func:`rangeslam.mdu.planarity.flat_fit_check` makes of a whole configuration. Then the
landmarks' sides are an exact discrete gauge (reported as ``ambiguous_landmarks``), not minima to
choose between, and the trajectory's covariance has rank 2 M - 3. Only a converged 3-D answer
is refitted, and the verdict stays the 3-D model's (:func:`rangeslam.mdu.slam.judged_answer`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import chi2

from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.slam_graph import graph_deviance, graph_fit, stacked
from rangeslam.mdu.slam_verdict import SlamProblem, SlamRun
from rangeslam.verdict.judge import CheckRecord
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = ["PLANAR_CHECK", "best_plane", "planar_answer", "planar_fit"]

#: The name of the check record the nested test leaves in :attr:`SlamResult.checks`.
PLANAR_CHECK = "the walk in its plane"


def best_plane(receivers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), unit normal (3,)): the least-squares plane of the trajectory (M, 3), the
    normal its direction of least spread (the last right singular vector)."""
    centre = receivers.mean(axis=0)
    return centre, np.linalg.svd(receivers - centre)[2][-1]


def planar_fit(problem: SlamProblem, answer: np.ndarray, sigma: float, normal: np.ndarray):
    """The nested model's fit from ``answer`` (M + K, 3), the receivers held in the plane across
    ``normal`` (3,), with covariances. A robust graph: GTSAM's LM. A Gaussian graph: MINPACK to
    its minimum (:mod:`rangeslam.solvers.graph_minpack`), then GTSAM's covariances there without
    iterating (its status MINPACK's). GTSAM's LM creeps along the landmarks' flat valleys here
    (15-2000 iterations against MINPACK's 30-180 Jacobians; on 12 walks of 8 steps 2.9 s
    against 0.9 s: benchmarks/README.md, "slam's random starts by MINPACK"), and where it
    stopped depended on the last bits of its start: a Fig. 5 walk's NEES differed in the
    fifth digit from run to run of one process when GTSAM iterated from MINPACK's end."""
    if problem.robust is not None:
        return graph_fit(problem, answer, sigma, covariances=True, plane=normal)
    near = graph_fit(problem, answer, sigma, plane=normal, minpack=True)
    at = graph_fit(problem, stacked(near), sigma, covariances=True, plane=normal, max_iterations=0)
    return dataclasses.replace(at, status=near.status, message=near.message)


def planar_answer(problem: SlamProblem, best: SlamRun) -> tuple[SlamRun, CheckRecord | None]:
    """``best`` (a refined 3-D run), or its refit in the trajectory's plane (module docstring)
    when the likelihood-ratio test keeps the plane, with covariances; and the test's record
    (statistic: the deviance gap; level: the chi-square(M - 3) quantile; passed: the refit ran),
    None where the test does not apply (2-D, fewer than 4 steps, no GTSAM fit). Both models are
    minimised and scored on the graph of ``best``'s own range sigma (its covariances' too;
    :func:`planar_fit`). A refit that fails leaves ``best``, with the failure as the record's
    reason."""
    m, sigma = problem.ranges.shape[0], best.sigma
    if problem.dim != 3 or m < 4 or best.fit is None or not sigma:
        return best, None
    level = float(chi2.ppf(CHI2_LEVEL, m - 3))
    answer = np.vstack([best.receivers, best.sources])
    normal = best_plane(best.receivers)[1]
    try:  # from the receivers projected onto the plane (planar_fit)
        fit = planar_fit(problem, answer, sigma, normal)
    except (SolverError, InvalidInputError, RuntimeError) as exc:
        return best, CheckRecord(PLANAR_CHECK, float("nan"), level, False, f"refit failed: {exc}")
    gap = graph_deviance(problem, stacked(fit), sigma) - graph_deviance(problem, answer, sigma)
    if not (fit.converged and gap <= level):
        return best, CheckRecord(PLANAR_CHECK, gap, level, True)
    res = range_matrix(fit.receivers, fit.sources) - problem.ranges
    run = dataclasses.replace(
        best,
        ssr=float(np.sum(res[problem.observed] ** 2)),
        receivers=fit.receivers,
        sources=fit.sources,
        fit=fit,
        residuals=res,
        key=fit.error,
        planar=True,
    )
    return run, CheckRecord(PLANAR_CHECK, gap, level, True)
