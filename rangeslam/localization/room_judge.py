"""The one judge on a robust room reconstruction (:func:`rangeslam.localization.reconstruct_room`):
does another placement of a loudspeaker or a wall, made from the ranges the fit left out or
from the other side of a wall's image, fit the data as well?

A robust fit kept some ranges and dropped the rest. The question past its breakdown point is
not how many it dropped but whether the dropped ones say something else: if they cohere into
another place for the point they belong to (a loudspeaker, or an image source and so its wall),
that place may fit the data as well as the answer, or better. For each column of ranges (one
loudspeaker's direct paths, or its echoes off one wall) the generator takes every d of the
dropped ranges, the two points they fix (:func:`sphere_intersections`), and the whole model
with that loudspeaker moved there, or that wall made the bisector of the loudspeaker and that
image (:func:`bisector_walls`); the lowest of them, its point refitted to the column's ranges
within the threshold, is the column's alternative. Random wrong ranges cohere with nothing:
three of them fix a point, and a fourth rarely agrees. A second true wall hidden in the dropped
echoes does.

The second generator (:func:`mirror_alternatives`) asks each wall whether it fits as well on
the other side of its image: an image far from a nearly flat array has a mirror image through
the array's plane at almost the same ranges, and the bisector of the loudspeaker and that point
is another wall (a wall said CONVERGED 23 degrees off, its true place 2.1 noise variances above).

Every candidate is scored on one robust objective over every observed range: the truncated
quadratic (MSAC) sum of min(r^2, thr^2) / sigma^2, with ``thr`` the fit's inlier bound and
``sigma`` its noise scale. (The fit itself chooses its inliers by studentized residuals, so a
range it dropped may count as within the bound here: the objective is the same for every
candidate, the answer's included.) The subsets are all d-subsets of a column's dropped ranges:
220 at most for 12 microphones in 3-D; a large array would want them drawn. The distance is ||J (theta' - theta)||^2 / sigma^2 with J
the Jacobian of the lowest candidate's kept ranges (the microphones are known: no gauge). Then
:func:`rangeslam.verdict.judge.judge`: a lower alternative means the fit kept the wrong ranges
(OUTLIERS; a lower other side: the fit stopped on the wrong side, NO_AGREEMENT), an equal one
far off a rival (NOT_IDENTIFIABLE).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import least_squares

from rangeslam.localization.room_reconstruction import (
    JointFit,
    JointWallModel,
    RoomProblem,
    bisector_walls,
    image_points,
    sphere_intersections,
)
from rangeslam.status import Status
from rangeslam.verdict.checks import level_sigmas, mirror_point
from rangeslam.verdict.judge import LOWER, RIVAL, Alternative, cost_level, judge

__all__ = ["column_alternatives", "judge_room", "mirror_alternatives", "msac_deviance"]


def msac_deviance(model: JointWallModel, theta: np.ndarray, thr: float, sigma: float) -> float:
    """sum over the observed ranges of min(r^2, thr^2) / sigma^2 (dimensionless), r the range
    residuals of ``theta`` (scaled units, as ``thr`` and ``sigma``)."""
    res = model.all_residuals(theta)[model.use]
    return float(np.sum(np.minimum(res**2, thr**2)) / sigma**2)


def _with_point(model: JointWallModel, theta: np.ndarray, j: int, c: int, point: np.ndarray):
    """``theta`` with loudspeaker ``j`` at ``point`` (c = 0) or wall c - 1 the bisector of the
    loudspeaker and ``point`` as its image (c >= 1); None when no wall is the bisector."""
    d, out = model.d, theta.copy()
    if c == 0:
        out[j * d : (j + 1) * d] = point
        return out
    source = theta[j * d : (j + 1) * d]
    wall, ok = bisector_walls(source, point[None, :])
    if not ok[0]:
        return None
    col = (model.j_n + c - 1) * d
    out[col : col + d] = wall[0]
    return out


def _refit_point(model: JointWallModel, j: int, c: int, point: np.ndarray, thr: float):
    """``point`` refitted by least squares to column (j, c)'s observed ranges within ``thr`` of
    it (unchanged when fewer than d + 1 are)."""
    heard = model.use[j, :, c]
    mics, ranges = model.mics[heard], model.ranges[j, heard, c]
    near = np.abs(np.linalg.norm(mics - point, axis=1) - ranges) <= thr
    if near.sum() <= model.d:
        return point
    sel_m, sel_r = mics[near], ranges[near]
    return least_squares(lambda x: np.linalg.norm(sel_m - x, axis=1) - sel_r, point).x


def column_alternatives(model: JointWallModel, theta: np.ndarray, kept: np.ndarray, thr: float,
                        sigma: float):  # fmt: skip
    """Yield, for each column (loudspeaker j, column c) with at least d dropped ranges (observed
    in ``model.use``, not in ``kept``), the lowest placement its dropped ranges fix, refitted
    (module docstring), as an :class:`Alternative` (points: theta as rows)."""
    d = model.d
    for j, c in itertools.product(range(model.j_n), range(model.c_n)):
        dropped = np.flatnonzero(model.use[j, :, c] & ~kept[j, :, c])
        best = None
        for subset in itertools.combinations(dropped, d):
            idx = list(subset)
            for point in sphere_intersections(model.mics[idx], model.ranges[j, idx, c]):
                cand = _with_point(model, theta, j, c, point)
                if cand is None or not np.all(np.isfinite(cand)):
                    continue
                cost = msac_deviance(model, cand, thr, sigma)
                if best is None or cost < best[0]:
                    best = (cost, point)
        if best is None:
            continue
        refit = _with_point(model, theta, j, c, _refit_point(model, j, c, best[1], thr))
        cand = refit if refit is not None else _with_point(model, theta, j, c, best[1])
        what = (f"loudspeaker {j}: the place its direct paths the fit left out give" if c == 0
                else f"wall {c - 1}: the place loudspeaker {j}'s echoes the fit left out give")  # fmt: skip
        yield Alternative(cand.reshape(-1, d), msac_deviance(model, cand, thr, sigma), what)


def mirror_alternatives(model: JointWallModel, theta: np.ndarray, kept: np.ndarray, thr: float,
                        sigma: float):  # fmt: skip
    """Yield, for each wall and loudspeaker j whose echoes off it kept at least d + 1 ranges,
    the wall placed by the other side of j's image: the image's reflection through the plane
    of the microphones that heard it, refined on their kept ranges
    (:func:`rangeslam.verdict.mirror_point`), then refitted as a dropped ranges' place is, the
    wall the bisector of j and that point (an :class:`Alternative` with payload "mirror"). A
    far image heard by a nearly flat array fits its ranges on either side (Fig. 3-like 8
    microphones 0.6 m thick, 1 cm: a wall's other side 2.1 noise variances above the answer's,
    its normal 23 degrees away)."""
    d = model.d
    sources, walls = model.unpack(theta)
    images = image_points(sources, walls)  # (J, K, d)
    for j, k in itertools.product(range(model.j_n), range(model.c_n - 1)):
        heard = kept[j, :, 1 + k]
        if heard.sum() <= d:
            continue
        mirror = mirror_point(images[j, k], model.mics[heard], model.ranges[j, heard, 1 + k])
        if mirror is None:
            continue
        cand = _with_point(model, theta, j, 1 + k, _refit_point(model, j, 1 + k, mirror, thr))
        if cand is None or not np.all(np.isfinite(cand)):
            continue
        what = f"wall {k}: the other side of loudspeaker {j}'s image off it"
        yield Alternative(cand.reshape(-1, d), msac_deviance(model, cand, thr, sigma), what,
                          payload="mirror")  # fmt: skip


def judge_room(prob: RoomProblem, fit: JointFit, thr: float) -> list[tuple[Status, str]]:
    """(status, text) of the judgement of a robust fit's answer against the
    :func:`column_alternatives` of its dropped ranges and the :func:`mirror_alternatives` of its
    walls (module docstring); empty when it stands.
    ``thr``: the fit's inlier bound, scaled units (its noise scale is thr / level_sigmas())."""
    model = JointWallModel(prob.mics_s, prob.ranges_s, prob.observed)
    sigma = thr / level_sigmas()
    answer = Alternative(fit.theta.reshape(-1, prob.dim), msac_deviance(model, fit.theta, thr,
                                                                        sigma), "the answer")  # fmt: skip
    alternatives = [
        *column_alternatives(model, fit.theta, fit.use, thr, sigma),
        *mirror_alternatives(model, fit.theta, fit.use, thr, sigma),
    ]
    if not alternatives:
        return []

    def metric(lowest: Alternative):
        theta = lowest.points.ravel()
        kept = prob.observed & (np.abs(model.all_residuals(theta)) <= thr)
        jac = JointWallModel(prob.mics_s, prob.ranges_s, kept).jacobian(theta) / sigma

        def distance2(a: Alternative, b: Alternative, skip=()) -> float:
            step = jac @ (a.points.ravel() - b.points.ravel())
            return float(step @ step)

        return distance2

    judgement = judge(answer, alternatives, metric=metric, dof=fit.theta.size)
    own = next((c for c in judgement.comparisons if c.alternative is answer), None)
    lowest = judgement.answer.origin  # the answer is judged against the lowest candidate
    if own is not None and own.kind == LOWER:  # the answer is worse by more than the level
        status, why = (
            (Status.NO_AGREEMENT, "the fit stopped on the wrong side")
            if judgement.answer.payload == "mirror"
            else (Status.OUTLIERS, "the fit kept the wrong ranges")
        )
        return [(status, f"{lowest} fits the data better (robust cost lower by "
                 f"{own.delta_cost:.3g} noise variances): {why}; ")]  # fmt: skip
    if own is not None and own.kind == RIVAL:  # said from the answer's side
        return [(Status.NOT_IDENTIFIABLE, f"{lowest} fits the data as well (cost gap "
                 f"{own.delta_cost:.3g} <= {cost_level():.3g} noise variances) at information "
                 f"distance {own.distance2:.3g}: the data do not decide between them; ")]  # fmt: skip
    if judgement.status is not Status.CONVERGED:
        return [(judgement.status, judgement.reason + "; ")]
    return []
