"""One judge for every alternative answer: is there another answer that fits as well?

An estimator's search makes candidates (its own starts and the alternatives of
:mod:`rangeslam.verdict.alternatives`' generators); the judge compares each with the answer on
the SAME objective over ALL the data, in the units of the likelihood:

- ``Delta = deviance(theta') - deviance(theta)``: the cost gap, -2 log likelihood ratio (for
  Gaussian ranges the sum of squared residuals over sigma^2; for a robust kernel, twice its cost
  over every range, not over the ranges each one kept);
- ``delta^2 = (theta' - theta)^T F (theta' - theta)``: how far theta' lies from theta in the
  metric of the answer's information F = J^T J (J whitened: rows divided by their sigma), theta'
  first brought to theta by the model's gauge (a rigid motion, with reflection for ranges alone).

One level decides both (:data:`rangeslam.verdict.thresholds.CHI2_LEVEL`): two answers cannot be
told apart by the data when ``Delta`` is within the chi-square(1) quantile (a likelihood ratio
test of two point hypotheses), and theta' is another answer when ``delta^2`` is beyond the
chi-square(dof) quantile (outside the answer's confidence region). Hence, with the answer the
lowest candidate (a lower one replaces it):

| delta^2 <= q(dof), or Delta <= q(1) and every point within its precision | the same answer:
  it confirms it (a start that reached it) |
| Delta <= q(1), far | a rival: NOT_IDENTIFIABLE; or, when the alternative is a named discrete
  gauge of the geometry (a source's side of coplanar receivers), an ambiguity of those points |
| Delta > q(1), far | a worse minimum: ruled out by the data |

"Within its precision" (where the estimator gives :func:`judge` its ``precision``): each point
of theta' within sqrt(q(1)) standard deviations of theta's, its variance the smaller of the two
candidates' (:func:`precision_spread`): minima closer than the precision the result states are
one answer at that precision, where the quadratic model at the lowest does not describe the
valley between them.

How long to search is a separate rule (:func:`unseen_minima`, Boender and Rinnooy Kan 1987):
from how many random starts reached how many distinct minima, the posterior expected number of
minima; the search of random starts stops once it does not exceed those seen by a half.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.stats import chi2

from rangeslam.geometry.alignment import align
from rangeslam.status import Status
from rangeslam.verdict.thresholds import CHI2_LEVEL, RANK_RTOL

__all__ = [
    "AMBIGUITY",
    "DRAWS_BUDGET",
    "LOWER",
    "RANDOM_STARTS_LIMIT",
    "RIVAL",
    "SAME",
    "WORSE",
    "Alternative",
    "CheckRecord",
    "Comparison",
    "JudgedSearch",
    "Judgement",
    "ReachedLowest",
    "cost_level",
    "distance_level",
    "indistinguishable",
    "information_distance",
    "jacobian_point_variances",
    "judge",
    "marginal_precision",
    "point_columns",
    "precision_spread",
    "random_search",
    "same_answer",
    "search_complete",
    "starts_to_complete",
    "unseen_minima",
]

SAME, LOWER, RIVAL, AMBIGUITY, WORSE = "same", "lower", "rival", "ambiguity", "worse"


@dataclass(frozen=True)
class Alternative:
    """A candidate answer of the model: ``points`` (N, d) (receivers above sources, or the
    model's rows), ``extra`` (q,) further unknowns (offsets; empty when none), ``deviance``
    (-2 log likelihood over all data, dimensionless: sum of squared whitened residuals, or the
    robust kernel's equivalent), ``origin`` (the generator that made it: "answer", "random
    start 3", "without source 5", "mirror", ...). ``ambiguous`` (row indices) and ``ambiguity``
    (words) name a discrete gauge of the geometry the alternative differs by: those rows' places
    are then an ambiguity of those points, not a rival of the whole answer."""

    points: np.ndarray
    deviance: float
    origin: str
    extra: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ambiguous: tuple[int, ...] = ()
    ambiguity: str = ""
    payload: object = None  # the estimator's own record of this candidate (its fit)
    #: The cost gap (noise variances) this alternative shows on the data the answer predicts
    #: (noise-free): the noncentrality of the likelihood ratio of the two answers, the gap the
    #: data could be expected to show. None when not made.
    expected_gap: float | None = None


@dataclass(frozen=True)
class Comparison:
    """One alternative against the answer: the cost gap ``delta_cost`` (Delta, in deviance
    units, >= 0 against the lowest), the information distance ``distance2`` (delta^2), and the
    ``kind`` the one test gives it (SAME, RIVAL, AMBIGUITY, WORSE; LOWER for a replaced answer)."""

    alternative: Alternative
    delta_cost: float
    distance2: float
    kind: str


@dataclass(frozen=True)
class CheckRecord:
    """One check a verdict ran: its ``name``, the ``statistic``, the ``level`` it was held
    against, whether it ``passed``, and the ``reason`` in words when it did not."""

    name: str
    statistic: float
    level: float
    passed: bool
    reason: str = ""


@dataclass(frozen=True)
class Judgement:
    """The judge's outcome: the ``answer`` (the lowest candidate), every ``comparisons`` made, its
    ``check`` record, the ``status`` it implies (CONVERGED, or NOT_IDENTIFIABLE for a rival), the
    ``reason`` in words, and counts: ``reached`` (candidates of ``counted`` origins that reached
    the answer, itself included) and ``minima`` (distinct minima among those)."""

    answer: Alternative
    comparisons: tuple[Comparison, ...]
    check: CheckRecord
    status: Status
    reason: str
    reached: int
    minima: int
    replaced: Alternative | None = None

    @property
    def rivals(self) -> tuple[Comparison, ...]:
        """The comparisons that found a rival minimum."""
        return tuple(c for c in self.comparisons if c.kind == RIVAL)

    @property
    def replacement(self) -> Comparison | None:
        """The comparison of the replaced answer against the lowest (None when the answer is
        the lowest): its kind says whether the lowest is the same answer, a rival or lower."""
        return next((c for c in self.comparisons if c.alternative is self.replaced), None)

    @property
    def ambiguities(self) -> tuple[Comparison, ...]:
        """The comparisons that found a named ambiguity of some points."""
        return tuple(c for c in self.comparisons if c.kind == AMBIGUITY)


#: The budget of a search of random starts, in words: SEARCH_BUDGET draws.
DRAWS_BUDGET = "the budget (SEARCH_BUDGET)"
#: ... and when an estimator's ``random_starts`` caps the draws.
RANDOM_STARTS_LIMIT = "the random_starts limit"


@dataclass(frozen=True)
class JudgedSearch:
    """A judgement and the search behind it: ``starts`` (the search's own and random ones, the
    answer's included), ``complete`` whether the stopping rule ended them (else the budget did),
    ``expected`` minima by the rule (:func:`unseen_minima`), ``failures`` the fits that failed
    or were cut short (in words), ``draws`` the random starts drawn (failed fits included)."""

    judgement: Judgement
    starts: int
    complete: bool
    expected: float
    failures: tuple[str, ...] = ()
    budget: str = DRAWS_BUDGET  # the budget that ends the search when the rule does not, in words
    draws: int = 0

    @classmethod
    def of(cls, judgement: Judgement, starts: int, failures=(), budget: str = DRAWS_BUDGET,
           draws: int = 0) -> JudgedSearch:  # fmt: skip
        """The record of ``judgement`` after ``starts`` starts, the rule asked once more;
        ``budget``: the search's budget in words; ``draws``: the random starts drawn."""
        complete = search_complete(starts, judgement.minima)
        expected = unseen_minima(starts, judgement.minima)
        return cls(judgement, starts, complete, expected, tuple(failures), budget, draws)

    def record(self) -> CheckRecord:
        """The stopping rule as a check: the expected number of minima against those seen plus
        a half (passed when the rule, not the budget, ended the random starts)."""
        seen = self.judgement.minima
        return CheckRecord("search complete", self.expected, seen + 0.5, self.complete,
                           "" if self.complete else self.words())  # fmt: skip

    def words(self) -> str:
        """The search in words, for the message."""
        j = self.judgement
        rule = "the stopping rule" if self.complete else self.budget
        return (
            f"{len(j.comparisons)} alternatives judged; {self.starts} starts reached "
            f"{j.minima} distinct minima ({j.reached} the answer; expected {self.expected:.3g} "
            f"minima in all), stopped by {rule}"
        )


@lru_cache(maxsize=64)  # scipy's quantile costs 0.3 ms; a judge asks it on every call
def cost_level(level: float = CHI2_LEVEL) -> float:
    """The cost gap (deviance units) within which two answers cannot be told apart: the
    ``level`` quantile of chi-square with one degree of freedom."""
    return float(chi2.ppf(level, 1))


@lru_cache(maxsize=256)
def distance_level(dof: int, level: float = CHI2_LEVEL) -> float:
    """The information distance delta^2 beyond which an alternative lies outside the answer's
    confidence region of ``dof`` unknowns (beyond the gauge): the ``level`` quantile of
    chi-square with ``dof`` degrees of freedom."""
    return float(chi2.ppf(level, max(int(dof), 1)))


def point_columns(rows: np.ndarray, d: int) -> np.ndarray:
    """The columns (len(rows) d,) of the points ``rows`` among unknowns stored d per point,
    row-major."""
    return (np.asarray(rows)[:, None] * d + np.arange(d)[None, :]).ravel()


def information_distance(
    jacobian: np.ndarray, *, reflection: bool = True, interest: Sequence[int] | None = None
) -> Callable[[Alternative, Alternative, Sequence[int]], float]:
    """delta^2 between two candidates in the metric of ``jacobian`` (R, N d + q), the whitened
    Jacobian of the model at the answer (points row-major, then the extra unknowns):
    ``distance2(a, b, skip)`` moves b's points onto a's by the best rigid motion (with
    reflection when ``reflection``: the gauge of ranges alone) and measures the step. Rows in
    ``skip`` (a named ambiguity's points) are left out of the alignment and of the step.

    ``interest``: the rows (points) the estimate is of (a calibration's receivers, a walk's
    steps); the others and the extra unknowns are then nuisance, profiled out: the step of the
    points of interest is measured in their marginal information (the Schur complement of the
    nuisance block, J_i^T (I - P_n) J_i with P_n the projection on the nuisance columns), after
    the rigid motion that best aligns those points alone."""
    n_cols = jacobian.shape[1]

    def distance2(a: Alternative, b: Alternative, skip: Sequence[int] = ()) -> float:
        ref, pts = np.asarray(a.points, dtype=float), np.asarray(b.points, dtype=float)
        d = ref.shape[1]
        rows = np.arange(len(ref)) if interest is None else np.asarray(interest, dtype=int)
        keep = np.setdiff1d(rows, np.asarray(skip, dtype=int))
        moved = align(pts[keep], ref[keep], reflection=reflection)
        step = np.zeros(n_cols)
        step[point_columns(keep, d)] = (moved.aligned - ref[keep]).ravel()
        if interest is None:
            step[ref.size :] = np.asarray(b.extra) - np.asarray(a.extra)
            return float(np.sum((jacobian @ step) ** 2))
        nuisance = np.setdiff1d(np.arange(n_cols), point_columns(rows, d))
        moved_rows = jacobian @ step
        fitted = (
            jacobian[:, nuisance]
            @ np.linalg.lstsq(jacobian[:, nuisance], moved_rows, rcond=None)[0]
        )
        return float(np.sum((moved_rows - fitted) ** 2))

    return distance2


def precision_spread(
    point_variances: Callable[[Alternative], np.ndarray],
    step: Callable[[Alternative, Alternative], np.ndarray],
    rms_limit: float = np.inf,
) -> Callable[[Alternative, Alternative], float]:
    """``spread2(a, b)`` for :func:`judge`'s ``precision``: the largest over the points of
    interest of b's squared distance from a (``step(a, b)``: b's points moved onto a's by the
    gauge, minus a's, (n d,) metres) over that point's variance (``point_variances``: (n,) m^2,
    the trace of the point's d x d covariance that a candidate's information implies), the
    smaller of a's and b's. Each point must lie within its own stated precision, so a weak point
    does not excuse a move of well-determined ones; either candidate may be the truth, so an
    imprecise minimum does not make a precise one near. ``rms_limit`` (metres): the precision
    test's limit on the RMS standard deviation per point (PRECISION_FRACTION of the scene); at a
    candidate beyond it the data state no useful precision, and spread2 is infinite (the
    precision must hold wherever the truth may lie, as :func:`rangeslam.verdict.weak_moves`
    probes it)."""

    def spread2(a: Alternative, b: Alternative) -> float:
        at_a, at_b = point_variances(a), point_variances(b)
        if max(np.mean(at_a), np.mean(at_b)) > rms_limit**2:
            return float("inf")
        variances = np.minimum(at_a, at_b)
        moved = np.sum(step(a, b).reshape(len(variances), -1) ** 2, axis=1)
        return float(np.max(moved / np.maximum(variances, np.finfo(float).tiny)))

    return spread2


def jacobian_point_variances(jac: np.ndarray, rows: np.ndarray, d: int) -> np.ndarray:
    """(len(rows),) the variance of each of the points ``rows`` (d columns each, row-major) under
    the whitened Jacobian ``jac`` (R, p), the other columns profiled out (projected away, as
    :func:`information_distance` profiles them): singular values under RANK_RTOL of the largest
    (the gauge's) left out."""
    cols = point_columns(rows, d)
    nuisance = np.setdiff1d(np.arange(jac.shape[1]), cols)
    j_i = jac[:, cols]
    if nuisance.size:
        u, s_n, _ = np.linalg.svd(jac[:, nuisance], full_matrices=False)
        u = u[:, s_n > RANK_RTOL * s_n[0]]
        j_i = j_i - u @ (u.T @ j_i)
    _, singular, vt = np.linalg.svd(j_i, full_matrices=False)
    keep = singular > RANK_RTOL * max(singular[0], np.finfo(float).tiny)
    diagonal = (vt[keep] ** 2).T @ (1.0 / singular[keep] ** 2)
    return diagonal.reshape(-1, d).sum(axis=1)


def marginal_precision(
    jacobian_at: Callable[[Alternative], np.ndarray],
    interest: Sequence[int],
    *,
    reflection: bool = True,
    rms_limit: float = np.inf,
) -> Callable[[Alternative, Alternative], float]:
    """:func:`judge`'s ``precision`` for a model whose whitened Jacobian (R, N d + q) at a
    candidate is ``jacobian_at(candidate)`` (points row-major, then extra unknowns): the spread
    (:func:`precision_spread`) of the points ``interest`` (their step after the best rigid
    motion, with reflection when ``reflection``) in their marginal variances at each candidate
    (:func:`jacobian_point_variances`, kept per candidate), ``rms_limit`` as there (metres)."""
    rows = np.asarray(interest, dtype=int)
    kept: dict[int, tuple[Alternative, np.ndarray]] = {}

    def variances(candidate: Alternative) -> np.ndarray:
        hit = kept.get(id(candidate))
        if hit is None or hit[0] is not candidate:
            d = np.asarray(candidate.points).shape[1]
            hit = (candidate, jacobian_point_variances(jacobian_at(candidate), rows, d))
            kept[id(candidate)] = hit
        return hit[1]

    def step(a: Alternative, b: Alternative) -> np.ndarray:
        ref, pts = np.asarray(a.points)[rows], np.asarray(b.points)[rows]
        return (align(pts, ref, reflection=reflection).aligned - ref).ravel()

    return precision_spread(variances, step, rms_limit)


def same_answer(
    distance2: Callable[[Alternative, Alternative, Sequence[int]], float],
    answer: Alternative,
    dof: int,
    level: float = CHI2_LEVEL,
) -> Callable[[Alternative], bool]:
    """The judge's first row alone, for a search that counts the starts reaching its answer:
    a predicate, true for a candidate whose information distance delta^2 from ``answer``
    (``distance2`` of :func:`information_distance` in the information at ``answer``) is within
    :func:`distance_level` of ``dof`` unknowns, i.e. inside the answer's confidence region: the
    same answer, whatever its cost. (The judge's precision test needs both costs: the
    searches' counts do not make it.)"""
    q_far = distance_level(dof, level)
    return lambda alt: distance2(answer, alt, ()) <= q_far


def judge(
    answer: Alternative,
    alternatives: Sequence[Alternative],
    *,
    metric: Callable[[Alternative], Callable[[Alternative, Alternative, Sequence[int]], float]],
    dof: int,
    counted: Callable[[Alternative], bool] = lambda alt: True,
    level: float = CHI2_LEVEL,
    precision: Callable[[Alternative, Alternative], float] | None = None,
) -> Judgement:
    """Every alternative against the lowest candidate, by the one test (module docstring).

    Args:
        answer: the estimator's answer.
        alternatives: the candidates the search and the generators made (scored on the same
            objective over all data as ``answer``).
        metric: ``metric(lowest)`` gives the delta^2 function of :func:`information_distance`
            in the information at ``lowest`` (called once, for the lowest candidate).
        dof: unknowns beyond the gauge (the distance level's degrees of freedom).
        counted: which candidates count as starts for ``reached`` and ``minima`` (random starts;
            refits of part of the data do not sample the basins).
        level: the chi-square level (default CHI2_LEVEL).
        precision: ``spread2(a, b)`` (:func:`precision_spread`: the largest over the points of
            b's squared step from a, after the gauge, over that point's variance, the smaller of
            a's and b's). An alternative within the cost level of the lowest whose spread2 is
            also within it lies within the estimate's precision
            at the level (each point within :func:`rangeslam.verdict.level_sigmas` standard
            deviations of it): the same answer at that precision, even outside the confidence
            region (a valley the quadratic model at the lowest does not describe). None: the
            confidence region alone.
    """
    pool = [answer, *alternatives]
    q_cost, q_far = cost_level(level), distance_level(dof, level)
    lowest = min(pool, key=lambda a: a.deviance)  # the answer judged: the most likely
    distance2 = metric(lowest)
    # the expected gaps are the answer's: they count while the lowest is the answer itself
    answer_lowest = lowest is answer or distance2(lowest, answer, ()) <= q_far
    comparisons = []

    def near(a: Alternative, b: Alternative, distance: float) -> bool:
        # within the confidence region; or as likely (the cost level) and within the precision
        as_likely = abs(a.deviance - b.deviance) <= q_cost
        return distance <= q_far or (
            precision is not None and as_likely and precision(a, b) <= q_cost
        )

    for alt in pool:
        if alt is lowest:
            continue
        gap = float(alt.deviance - lowest.deviance)
        far = distance2(lowest, alt, ())
        kind = (
            SAME
            if near(lowest, alt, far)
            else (WORSE if _told_apart(gap, alt, answer_lowest, q_cost) else RIVAL)
        )
        if kind == RIVAL and alt.ambiguous and distance2(lowest, alt, alt.ambiguous) <= q_far:
            kind = AMBIGUITY
        if alt is answer and kind != SAME:
            kind = LOWER if kind == WORSE else kind
        comparisons.append(Comparison(alt, gap, far, kind))
    minima = _distinct_minima(
        lowest, comparisons, counted, lambda a, b: near(a, b, distance2(a, b, ()))
    )
    return _judgement(answer, lowest, comparisons, counted, minima, q_cost, q_far)


@dataclass
class ReachedLowest:
    """A search's lowest candidate so far and how many of its candidates reached it (``hits``,
    the lowest's own counted), by the judge's same-answer test: ``same_at(best)`` gives the
    predicate of another candidate at ``best`` (e.g. :func:`same_answer` in the information at
    it, made once per lowest), ``key`` a candidate's cost. A lower candidate that reached the
    lowest before it carries its hits on. ``confirmed``: a second candidate reached the lowest."""

    same_at: Callable[[object], Callable[[object], bool]]
    key: Callable[[object], float]
    best: object = None
    hits: int = 0
    test: Callable[[object], bool] | None = None

    def add(self, cand: object) -> bool:
        """Count ``cand``; whether it reached the lowest before it."""
        same = self.best is not None and self.same_as_best(cand)
        if self.best is None or self.key(cand) < self.key(self.best):
            self.best, self.test = cand, None
            self.hits = self.hits + 1 if same else 1
        elif same:
            self.hits += 1
        return same

    def same_as_best(self, cand: object) -> bool:
        """The same-answer test of ``cand`` at the lowest."""
        if self.test is None:
            self.test = self.same_at(self.best)
        return self.test(cand)

    @property
    def confirmed(self) -> bool:
        """Whether a second candidate reached the lowest."""
        return self.hits >= 2


def indistinguishable(gap: float, expected_gap: float | None, q_cost: float | None = None) -> bool:
    """Whether the data cannot tell an alternative from the answer: its cost ``gap`` over the
    answer (deviance units, noise variances for Gaussian ranges) is within ``q_cost`` (default
    :func:`cost_level`), or its ``expected_gap`` (the gap on the data the answer predicts,
    noise-free: the noncentrality of the likelihood ratio; None when not made) is. An expected
    gap within the level means the test's power is under a half: an observed gap beyond it is
    the noise's luck, not the data's evidence (a point whose mirror through nearly coplanar
    anchors the noise-free ranges do not resolve)."""
    q = cost_level() if q_cost is None else q_cost
    return gap <= q or (expected_gap is not None and expected_gap <= q)


def _told_apart(gap: float, alt: Alternative, answer_lowest: bool, q_cost: float) -> bool:
    """Whether ``alt``'s cost ``gap`` over the lowest candidate rules it out
    (:func:`indistinguishable` fails), its expected gap counted only while the answer is the
    lowest (``answer_lowest``: it, or the same answer): the expected gap is the answer's."""
    expected = alt.expected_gap if answer_lowest else None
    return not indistinguishable(gap, expected, q_cost)


def _judgement(answer, lowest, comparisons, counted, minima, q_cost, q_far) -> Judgement:
    """The :class:`Judgement` of the comparisons against ``lowest``."""
    rivals = [c for c in comparisons if c.kind == RIVAL]
    starts = [c for c in comparisons if counted(c.alternative)]
    reached = int(counted(lowest)) + sum(c.kind == SAME for c in starts)
    replaced = answer if lowest is not answer else None
    if rivals:
        worst = min(rivals, key=lambda c: c.delta_cost)
        reason = (
            f"{worst.alternative.origin} fits the data as well (cost gap {worst.delta_cost:.3g} "
            f"<= {q_cost:.3g} noise variances) {_distance_words(worst.distance2, q_far)}: the "
            "data do not decide between them"
        )
        check = CheckRecord("rival minima", worst.delta_cost, q_cost, False, reason)
        status = Status.NOT_IDENTIFIABLE
    else:
        gaps = [c.delta_cost for c in comparisons if c.kind == WORSE]
        least = min(gaps, default=float("inf"))
        check = CheckRecord("rival minima", least, q_cost, True)
        status, reason = Status.CONVERGED, ""
    return Judgement(lowest, tuple(comparisons), check, status, reason, reached, minima, replaced)


def _distance_words(distance2: float, q_far: float) -> str:
    """How far a rival lies, in words."""
    return f"at information distance {distance2:.3g} (confidence region {q_far:.3g})"


def _distinct_minima(lowest, comparisons, counted, same) -> int:
    """Distinct minima among the counted candidates (the lowest's own when it is counted or
    one counted candidate reached it): each other a minimum of its own unless the ``same(a,
    b)`` answer as one already counted (within its confidence region or stated precision)."""
    at_lowest = counted(lowest) or any(
        c.kind == SAME and counted(c.alternative) for c in comparisons
    )
    others: list[Alternative] = []
    for c in comparisons:
        if not counted(c.alternative) or c.kind == SAME:
            continue
        if not any(same(rep, c.alternative) for rep in others):
            others.append(c.alternative)
    return int(at_lowest) + len(others)


def unseen_minima(starts: int, minima: int) -> float:
    """Boender and Rinnooy Kan's (1987) posterior expected number of local minima, given that
    ``starts`` uniform random starts of a local search reached ``minima`` distinct ones:
    ``minima (starts - 1) / (starts - minima - 2)``; infinite while ``starts <= minima + 2``."""
    if starts <= minima + 2:
        return float("inf")
    return minima * (starts - 1) / (starts - minima - 2)


def search_complete(starts: int, minima: int) -> bool:
    """The stopping rule of the random starts: the expected number of minima
    (:func:`unseen_minima`) is within half a minimum of those seen."""
    return unseen_minima(starts, minima) <= minima + 0.5


def starts_to_complete(minima: int) -> int:
    """The fewest starts at which :func:`search_complete` holds with ``minima`` minima seen:
    w (n - 1) / (n - w - 2) <= w + 1/2 first holds at n = 2 w^2 + 3 w + 2 (w = ``minima``),
    and with no minimum counted at n = 3, the first finite estimate."""
    return max(2 * minima**2 + 3 * minima + 2, 3)


def random_search(
    run: Callable[[list[Alternative]], Judgement],
    found: Sequence[Alternative],
    randoms: Iterator[Alternative | None],
    *,
    budget: int,
    at_least: int = 0,
) -> tuple[list[Alternative], int]:
    """The random starts of a search, apart from its judgement: alternatives drawn from
    ``randoms`` (an estimator's fit from a random start, None when the fit failed) and added to
    ``found`` (the counted starts made so far beside the answer) until the stopping rule
    (:func:`search_complete` on ``run(found)``'s distinct minima, the answer a start too) ends
    them after ``at_least`` draws, or ``budget`` draws are made (a failed fit counts as made,
    not as a start), or ``randoms`` ends (a generator with a budget of work of its own).
    Returns (the counted starts, the draws made).

    The rule is asked again once enough starts are made for it to hold at the w minima it last
    counted (:func:`starts_to_complete`), or at once when a draw lies below the lowest it
    judged: while the lowest stays, a new start adds a minimum or joins one, so w cannot fall
    and the search stops where asking after every draw would, without a judgement per draw
    (their cost grows as the square of the draws: 20 s for 100 starts at 36 minima). This
    holds for a ``run`` that is :func:`judge` of the starts in the order given (the answer and
    any fixed alternatives first), as every estimator's is."""
    found, made, ask_at, lowest = list(found), 0, 0, np.inf
    while made < budget:
        if made >= at_least and len(found) + 1 >= ask_at:
            judgement = run(found)
            if search_complete(len(found) + 1, judgement.minima):
                break
            ask_at, lowest = starts_to_complete(judgement.minima), judgement.answer.deviance
        try:
            alt = next(randoms)
        except StopIteration:
            break
        made += 1
        if alt is not None:
            found.append(alt)
            ask_at = 0 if alt.deviance < lowest else ask_at
    return found, made
