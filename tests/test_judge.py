"""The one judge (rangeslam.verdict.judge): one test for every alternative answer."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rangeslam.solvers.least_squares import unfolding_jacobian, unfolding_residuals
from rangeslam.status import Status
from rangeslam.verdict.judge import (
    AMBIGUITY,
    LOWER,
    RIVAL,
    SAME,
    WORSE,
    Alternative,
    ReachedLowest,
    cost_level,
    distance_level,
    information_distance,
    judge,
    marginal_precision,
    precision_spread,
    random_search,
    search_complete,
    starts_to_complete,
    unseen_minima,
)

SIGMA = 1e-3


def scene(rng, m=6, k=5):
    """Receivers and sources (M + K, 3) in a 3 m box, all ranges observed."""
    return rng.uniform(0, 3, (m + k, 3)), m, k


def scored(points, m, k, ranges, origin, **kw):
    """An Alternative scored by its sum of squared residuals over SIGMA^2."""
    pairs = np.argwhere(np.ones((m, k), dtype=bool))
    res = unfolding_residuals(points, m, ranges[pairs[:, 0], pairs[:, 1]], pairs) / SIGMA
    return Alternative(points, float(res @ res), origin, **kw)


def metric_for(m, k):
    """The judge's metric factory: the whitened range Jacobian at the reference."""
    pairs = np.argwhere(np.ones((m, k), dtype=bool))
    return lambda ref: information_distance(unfolding_jacobian(ref.points, m, pairs) / SIGMA)


def ranges_of(points, m):
    return np.linalg.norm(points[:m, None] - points[None, m:], axis=2)


def test_levels_are_chi_square_quantiles():
    """One level: the cost gap is chi-square(1), the distance chi-square(dof)."""
    assert cost_level(0.999) == pytest.approx(10.828, abs=1e-3)
    assert distance_level(10, 0.999) == pytest.approx(29.588, abs=1e-3)
    assert distance_level(30) > distance_level(10)


def test_same_answer_moved_by_the_gauge_confirms(rng):
    """The answer under a rigid motion with reflection is the same answer: SAME, CONVERGED."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m)
    answer = scored(pts, m, k, ranges, "answer")
    moved = pts @ Rotation.random(random_state=1).as_matrix().T * np.array([1, 1, -1]) + 2.0
    alt = scored(moved, m, k, ranges, "random start 0")
    out = judge(answer, [alt], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.comparisons[0].kind == SAME
    assert out.comparisons[0].distance2 == pytest.approx(0.0, abs=1e-12)
    assert out.status is Status.CONVERGED and out.check.passed
    assert out.reached == 2 and out.minima == 1


def test_equal_cost_far_alternative_is_a_rival(rng):
    """An alternative as cheap as the answer but far in the information metric: NOT_IDENTIFIABLE,
    its origin named in the reason."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m)
    far = pts.copy()
    far[0] += 0.2  # a different configuration ...
    answer = scored(pts, m, k, ranges, "answer")
    rival = Alternative(far, answer.deviance + 1.0, "the refit without source 2")  # ... as cheap
    out = judge(answer, [rival], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.comparisons[0].kind == RIVAL
    assert out.status is Status.NOT_IDENTIFIABLE and not out.check.passed
    assert "the refit without source 2" in out.reason


def _rigid_step(m):
    """step(a, b) of precision_spread: b's first m points aligned onto a's, minus a's."""
    from rangeslam.geometry.alignment import align

    def step(a, b):
        return (align(b.points[:m], a.points[:m], reflection=True).aligned - a.points[:m]).ravel()

    return step


@pytest.mark.parametrize("thickness", [3.0, 1e-4])
def test_point_variances_are_the_schur_complement_covariance(rng, thickness):
    """The receivers' variances with the sources profiled out, from the whitened Jacobian and
    from the information's Schur complement, agree, by one convention for the gauge (singular
    values under RANK_RTOL, eigenvalues under its square): in a well-spread scene and in a
    near-planar one (receivers within 0.1 mm of a plane)."""
    from rangeslam.verdict.judge import jacobian_point_variances
    from rangeslam.verdict.thresholds import RANK_RTOL

    pts, m, k = scene(rng)
    pts[:m, 2] = 1.0 + thickness * rng.uniform(0, 1, m)
    pairs = np.argwhere(np.ones((m, k), dtype=bool))
    jac = unfolding_jacobian(pts, m, pairs) / SIGMA
    info = jac.T @ jac
    r, n = slice(0, 3 * m), slice(3 * m, None)
    f_nn = np.linalg.pinv(info[n, n], rcond=RANK_RTOL**2, hermitian=True)
    schur = info[r, r] - info[r, n] @ f_nn @ info[n, r]
    values, vectors = np.linalg.eigh(schur)
    keep = values > RANK_RTOL**2 * values[-1]
    from_info = ((vectors[:, keep] ** 2) @ (1.0 / values[keep])).reshape(-1, 3).sum(axis=1)
    from_jac = jacobian_point_variances(jac, np.arange(m), 3)
    assert from_jac == pytest.approx(from_info, rel=1e-3)
    answer = Alternative(pts, 0.0, "answer")
    spread2 = marginal_precision(lambda alt: jac, np.arange(m))
    assert spread2(answer, answer) == pytest.approx(0.0, abs=1e-12)


def _outside_the_region(rng, pts, m, k, answer, dof):
    """pts moved along a random direction to twice the confidence region's radius."""
    metric = metric_for(m, k)
    direction = rng.standard_normal(pts.shape)
    direction -= direction.mean(axis=0)
    unit = Alternative(pts + 1e-3 * direction, answer.deviance, "probe")
    size = 1e-3 * np.sqrt(2 * distance_level(dof) / metric(answer)(answer, unit, ()))
    return pts + size * direction


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_alternative_within_the_stated_precision_is_the_same_answer(seed):
    """An alternative as likely as the answer (within the cost level), outside its confidence
    region, but with every point within level_sigmas() standard deviations of the answer's:
    SAME, CONVERGED. One point beyond its own precision: a rival."""
    rng = np.random.default_rng(seed)
    pts, m, k = scene(rng)
    answer = scored(pts, m, k, ranges_of(pts, m), "answer")
    dof = 3 * (m + k) - 6
    far_points = _outside_the_region(rng, pts, m, k, answer, dof)
    far = Alternative(far_points, answer.deviance + 1.0, "random start 3")
    assert metric_for(m, k)(answer)(answer, far, ()) > distance_level(dof)
    moved = np.sum(_rigid_step(m + k)(answer, far).reshape(-1, 3) ** 2, axis=1)
    worst = int(np.argmax(moved))
    for scale, kind in ((2.0, SAME), (0.5, RIVAL)):
        variances = moved * 4.0 / cost_level()  # every point well within its precision ...
        variances[worst] = scale * moved[worst] / cost_level()  # ... but the worst one
        spread = precision_spread(lambda alt, v=variances: v, _rigid_step(m + k))
        out = judge(answer, [far], metric=metric_for(m, k), dof=dof, precision=spread)
        assert out.comparisons[0].kind == kind
        assert out.status is (Status.CONVERGED if kind == SAME else Status.NOT_IDENTIFIABLE)


def test_the_precision_does_not_excuse_a_decisive_cost_gap(rng):
    """Within the precision but costlier than the lowest by more than the level: not the same
    answer. The answer itself is then LOWER (replaced by the lowest)."""
    pts, m, k = scene(rng)
    answer = scored(pts, m, k, ranges_of(pts, m), "answer")
    dof = 3 * (m + k) - 6
    lower_points = _outside_the_region(rng, pts, m, k, answer, dof)
    lower = Alternative(lower_points, answer.deviance - 2 * cost_level(), "the refit without 1")
    wide = precision_spread(lambda alt: np.full(m + k, 1e6), _rigid_step(m + k))
    out = judge(answer, [lower], metric=metric_for(m, k), dof=dof, precision=wide)
    assert out.answer is lower and out.comparisons[0].kind == LOWER


def test_the_more_precise_of_two_minima_sets_each_points_precision(rng):
    """An imprecise minimum does not make a precise one near: each point's variance is the
    smaller of the two candidates', whichever is the lowest, and one weak point does not excuse
    the others."""
    pts, m, k = scene(rng)
    answer = Alternative(pts, 10.0, "answer")
    other = Alternative(pts + np.r_[[[0.1, 0.0, 0.0]] * m, np.zeros((k, 3))], 9.0, "random start")
    variances = {id(answer): np.ones(m + k), id(other): np.full(m + k, 1e-4)}
    spread = precision_spread(lambda alt: variances[id(alt)], _rigid_step(m + k))
    moved = np.sum(_rigid_step(m + k)(answer, other).reshape(-1, 3) ** 2, axis=1)
    assert spread(answer, other) == pytest.approx(moved.max() / 1e-4)
    assert spread(other, answer) == pytest.approx(moved.max() / 1e-4, rel=1e-6)
    worst = int(np.argmax(moved))
    variances[id(other)][worst] = 1e6  # one weak point: the others still count
    assert spread(answer, other) == pytest.approx(np.delete(moved, worst).max() / 1e-4)


def test_minima_within_the_precision_count_as_one(rng):
    """The stopping rule's count: two random starts at places within each other's precision
    (and as likely) reached one minimum; beyond it, two."""
    pts, m, k = scene(rng)
    answer = scored(pts, m, k, ranges_of(pts, m), "answer", payload=True)
    dof = 3 * (m + k) - 6
    a_points = _outside_the_region(rng, pts, m, k, answer, dof)
    a = Alternative(a_points, answer.deviance + 30.0, "random start 0", payload=True)
    b = Alternative(2 * a_points - pts, a.deviance + 1.0, "random start 1", payload=True)
    for variance, minima in ((1e6, 2), (1e-12, 3)):
        spread = precision_spread(lambda alt, v=variance: np.full(m + k, v), _rigid_step(m + k))
        out = judge(answer, [a, b], metric=metric_for(m, k), dof=dof,
                    counted=lambda alt: bool(alt.payload), precision=spread)  # fmt: skip
        assert out.minima == minima


def test_costlier_far_alternative_is_worse(rng):
    """A minimum whose cost exceeds the answer's by more than the level is ruled out."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m)
    far = pts.copy()
    far[0] += 0.2
    answer = scored(pts, m, k, ranges, "answer")
    alt = Alternative(far, answer.deviance + 1.01 * cost_level(), "random start 1", payload=True)
    out = judge(answer, [alt], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.comparisons[0].kind == WORSE
    assert out.status is Status.CONVERGED
    assert out.check.statistic == pytest.approx(1.01 * cost_level())


def test_an_alternative_the_data_could_not_be_expected_to_rule_out_is_a_rival(rng):
    """A far alternative beyond the level on the data as observed, but within it on the data the
    answer predicts (its expected gap, the likelihood ratio's noncentrality), is a rival: the
    observed gap is the noise's luck. Beyond the level on both, or without an expected gap, it
    is worse."""
    pts, m, k = scene(rng)
    far = pts.copy()
    far[0] += 0.2
    answer = scored(pts, m, k, ranges_of(pts, m), "answer")
    gap = answer.deviance + 1.5 * cost_level()
    for expected, kind in ((0.8 * cost_level(), RIVAL), (1.2 * cost_level(), WORSE), (None, WORSE)):
        alt = Alternative(far, gap, "the mirror", expected_gap=expected)
        out = judge(answer, [alt], metric=metric_for(m, k), dof=3 * (m + k) - 6)
        assert out.comparisons[0].kind == kind
        assert out.status is (Status.NOT_IDENTIFIABLE if kind == RIVAL else Status.CONVERGED)


def test_multilaterate_mirror_of_nearly_coplanar_anchors_is_judged_by_its_expected_gap(rng):
    """Anchors within 1 cm of a plane, the point 12-30 cm above it at 1 mm noise: the noise-free
    mirror gap is under the level, so whatever the noisy gap, multilaterate does not say
    CONVERGED: five draws whose noise makes the mirror look worse than the level (without the
    expected gap the judge called them CONVERGED)."""
    import rangeslam
    from rangeslam.verdict.checks import mirror_gap

    for _ in range(5):
        a = np.column_stack([rng.uniform(0, 4, (7, 2)), rng.uniform(-0.01, 0.01, 7)])
        for _ in range(2000):
            x = np.array([*rng.uniform(1, 3, 2), rng.uniform(0.12, 0.3)])
            true_r = np.linalg.norm(a - x, axis=1)
            r = true_r + SIGMA * rng.standard_normal(7)
            level = cost_level() * SIGMA**2
            if mirror_gap(x, a, true_r) < level < mirror_gap(x, a, r):
                break
        else:
            pytest.fail("no such draw in 2000")
        out = rangeslam.multilaterate(a, r, noise_std=SIGMA, rng=rng)
        assert out.status is not Status.CONVERGED


def test_lower_alternative_replaces_the_answer(rng):
    """An alternative lower by more than the level replaces the answer, which is LOWER then (or
    a rival, were it within the level)."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m)
    wrong = pts.copy()
    wrong[1] += 0.1
    answer = scored(wrong, m, k, ranges, "answer")
    right = scored(pts, m, k, ranges, "the refit without receiver 1")
    out = judge(answer, [right], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.answer is right and out.replaced is answer
    assert out.comparisons[0].kind == LOWER
    assert out.status is Status.CONVERGED


def test_lower_within_the_level_near_is_the_same_answer(rng):
    """Lower by less than the level and near: the lowest is taken (the most likely point) and the
    search's answer is the SAME minimum (LM's tolerance), not a rival."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m) + rng.normal(0, SIGMA, (6, 5))
    answer = scored(pts, m, k, ranges, "answer")
    near = Alternative(pts + 1e-9, answer.deviance - 0.5 * cost_level(), "random start 0")
    out = judge(answer, [near], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.answer is near and out.comparisons[0].kind == SAME
    assert out.status is Status.CONVERGED


def test_lower_within_the_level_far_is_a_rival(rng):
    """Lower by less than the level and far (Fig. 3's S2 scene: 5.8 noise variances apart): the
    lower one is the answer and the one it displaced its rival."""
    pts, m, k = scene(rng)
    far = pts.copy()
    far[2] += 0.2
    answer = Alternative(far, 6.0, "answer")
    lower = Alternative(pts, 0.2, "the refit without source 0")
    out = judge(answer, [lower], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.answer is lower and out.comparisons[0].kind == RIVAL
    assert out.status is Status.NOT_IDENTIFIABLE


def test_named_ambiguity_is_not_a_rival(rng):
    """Coplanar receivers: a source's mirror fits exactly and the receivers stay; the judge names
    the ambiguity of that source and the rest converges."""
    m, k = 6, 4
    receivers = np.c_[rng.uniform(0, 1, (m, 2)), np.zeros(m)]
    sources = np.c_[rng.uniform(0, 3, (k, 2)), rng.uniform(0.5, 2, k)]
    pts = np.vstack([receivers, sources])
    ranges = ranges_of(pts, m)
    mirrored = pts.copy()
    mirrored[m + 2, 2] *= -1
    answer = scored(pts, m, k, ranges, "answer")
    alt = scored(mirrored, m, k, ranges, "source 2 mirrored", ambiguous=(m + 2,), ambiguity="x")
    out = judge(answer, [alt], metric=metric_for(m, k), dof=3 * (m + k) - 6)
    assert out.comparisons[0].kind == AMBIGUITY
    assert out.status is Status.CONVERGED
    assert out.ambiguities and not out.rivals


def test_distinct_minima_counted_once(rng):
    """Two starts at one wrong minimum and one at the answer: two distinct minima, two starts
    (the answer's own included) reached the answer."""
    pts, m, k = scene(rng)
    ranges = ranges_of(pts, m)
    wrong = pts.copy()
    wrong[0] += 0.3
    answer = scored(pts, m, k, ranges, "answer", payload=True)
    alts = [
        scored(wrong, m, k, ranges, "random start 0", payload=True),
        scored(wrong + 1e-12, m, k, ranges, "random start 1", payload=True),
        scored(pts, m, k, ranges, "random start 2", payload=True),
    ]
    out = judge(
        answer, alts, metric=metric_for(m, k), dof=3 * (m + k) - 6, counted=lambda a: a.payload
    )
    assert out.minima == 2 and out.reached == 2


def test_unseen_minima_formula():
    """Boender and Rinnooy Kan: w (n - 1) / (n - w - 2), infinite while n <= w + 2."""
    assert unseen_minima(3, 1) == float("inf")
    assert unseen_minima(7, 1) == pytest.approx(1.5)
    assert unseen_minima(10, 2) == pytest.approx(18 / 6)
    assert not search_complete(6, 1) and search_complete(7, 1)
    assert not search_complete(15, 2) and search_complete(16, 2)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.floats(-100.0, 100.0),
)
def test_distance_gauge_invariant(seed, shift):
    """delta^2 is invariant to a rigid motion of the alternative (the gauge) and symmetric
    between two candidates to first order."""
    rng = np.random.default_rng(seed)
    pts, m, k = scene(rng)
    pairs = np.argwhere(np.ones((m, k), dtype=bool))
    d2 = information_distance(unfolding_jacobian(pts, m, pairs))
    other = pts + rng.normal(0, 1e-3, pts.shape)
    a, b = Alternative(pts, 0.0, "a"), Alternative(other, 0.0, "b")
    rot = Rotation.random(random_state=seed % 1000).as_matrix()
    moved = Alternative(other @ rot.T + shift, 0.0, "b moved")
    assert d2(a, moved, ()) == pytest.approx(d2(a, b, ()), rel=1e-6, abs=1e-12)


def test_calibrate_reports_the_judge(rng):
    """calibrate's result lists the judge's checks (name, statistic, level, passed), how many
    alternatives it judged and how many starts reached the answer; exact data stay exact."""
    from rangeslam import align, calibrate

    pts, m, k = scene(rng, m=8, k=5)
    out = calibrate(ranges_of(pts, m), noise_std=0.0, rng=rng)
    assert out.converged, out.message
    assert align(out.receivers, pts[:m], reflection=True).rmse < 1e-6
    names = [c.name for c in out.checks]
    assert names[:2] == ["rival minima", "search complete"]
    assert out.checks[0].passed and out.checks[0].level == pytest.approx(cost_level())
    # every source and receiver left out once, each point mirrored, the fold, the starts
    assert out.judged >= 2 * (m + k) + 1
    assert 1 <= out.reached <= 8 and "alternatives judged" in out.message


def test_nuisance_points_are_profiled_out(rng):
    """With the receivers as the points of interest, an alternative that moves only a source
    is at distance 0 (the source's columns absorb it: a source's mirror is no rival of the
    receivers), while moving a receiver is measured in their marginal information, never more
    than in the joint one."""
    pts, m, k = scene(rng, m=8, k=6)
    pairs = np.argwhere(np.ones((m, k), dtype=bool))
    jac = unfolding_jacobian(pts, m, pairs) / SIGMA
    joint = information_distance(jac)
    marginal = information_distance(jac, interest=np.arange(m))
    source_moved, receiver_moved = pts.copy(), pts.copy()
    source_moved[m + 1] += 0.01
    receiver_moved[2] += 0.01
    a = Alternative(pts, 0.0, "a")
    assert marginal(a, Alternative(source_moved, 0.0, "s"), ()) == pytest.approx(0.0, abs=1e-9)
    assert joint(a, Alternative(source_moved, 0.0, "s"), ()) > 1.0
    moved = Alternative(receiver_moved, 0.0, "r")
    assert 0.0 < marginal(a, moved, ()) <= joint(a, moved, ()) * (1 + 1e-9)


def test_random_search_stops_by_the_rule_the_budget_or_at_least():
    """The random starts of every estimator's search: drawn until the stopping rule ends them
    (every start at one minimum: 7 starts with the answer, so 6 draws that fitted), a failed fit
    counted as a draw but not as a start, at most ``budget`` draws, at least ``at_least``."""
    answer = Alternative(np.zeros((1, 2)), 0.0, "the answer")

    def draws(fail_every: int = 0):
        j = 0
        while True:
            j += 1
            failed = fail_every and j % fail_every == 0
            yield None if failed else Alternative(np.zeros((1, 2)), 0.0, f"random start {j}")

    def run(found):
        assert all(alt is not None for alt in found)
        return type("Seen", (), {"minima": 1, "answer": answer})()

    found, made = random_search(run, [], draws(), budget=20)
    assert (len(found), made) == (6, 6) and search_complete(len(found) + 1, 1)
    found, made = random_search(run, [], draws(fail_every=2), budget=20)
    assert (len(found), made) == (6, 11)  # 6 fitted, 5 failed between them
    found, made = random_search(run, [answer] * 3, draws(), budget=20)
    assert (len(found), made) == (6, 3)  # the search's own starts count
    assert random_search(run, [], draws(), budget=4)[1] == 4
    assert random_search(run, [], draws(), budget=20, at_least=9)[1] == 9


@pytest.mark.parametrize("minima", [1, 2, 3, 6])
def test_random_search_asks_the_rule_only_when_it_can_hold(minima):
    """The rule holds first at 2 w^2 + 3 w + 2 starts for w minima seen; a search of a constant
    w stops there (or at the budget) and asks the judge twice, not once per draw (a judgement
    per draw made a 100-start search of 36 minima cost 20 s)."""
    calls, answer = [], Alternative(np.zeros((1, 2)), 0.0, "the answer")

    def run(found):
        calls.append(len(found))
        return type("Seen", (), {"minima": minima, "answer": answer})()

    draws = (Alternative(np.zeros((1, 2)), 0.0, f"random start {j}") for j in itertools.count())
    need = starts_to_complete(minima)
    assert search_complete(need, minima) and not search_complete(need - 1, minima)
    found, made = random_search(run, [], draws, budget=1000)
    assert len(found) + 1 == need and made == need - 1
    assert len(calls) == 2
    found, made = random_search(run, [], draws, budget=need - 3)
    assert made == need - 3 and len(calls) == 3


def test_random_search_asks_again_at_a_new_lowest_where_the_minima_may_fall():
    """A draw below the lowest judged may merge the minima counted (here 6 fall to 1 once a
    lower start appears): the rule is asked at once, and the search stops where asking after
    every draw would (7 starts), not at the 92 that 6 minima need."""
    answer = Alternative(np.zeros((1, 2)), 0.0, "the answer")
    deviances = [5.0, 4.0, 3.0, 2.0, 1.0, -1.0] + [0.0] * 200

    def run(found):
        lowest = min([answer, *found], key=lambda a: a.deviance)
        return type("Seen", (), {"minima": 1 if lowest.deviance < 0 else 6, "answer": lowest})()

    draws = (Alternative(np.zeros((1, 2)), d, f"random start {j}") for j, d in enumerate(deviances))
    found, made = random_search(run, [], draws, budget=1000)
    assert len(found) + 1 == starts_to_complete(1) == 7 and made == 6
    assert search_complete(len(found) + 1, run(found).minima)


def test_reached_lowest_counts_the_starts_at_the_lowest():
    """The searches' vote: a candidate that reaches the lowest adds a hit; a lower one that
    reached the lowest before it carries the hits on, one that did not starts afresh; the same
    test is made once per lowest. Candidates here are (cost, place); "the same" is the same
    place."""
    made = []

    def same_at(best):
        made.append(best)
        return lambda cand: cand[1] == best[1]

    lowest = ReachedLowest(same_at, lambda cand: cand[0])
    assert lowest.add((5.0, "a")) is False and (lowest.hits, lowest.confirmed) == (1, False)
    assert lowest.add((6.0, "b")) is False and lowest.hits == 1
    assert lowest.add((5.5, "a")) is True and lowest.confirmed
    assert lowest.add((4.0, "a")) is True and (lowest.best, lowest.hits) == ((4.0, "a"), 3)
    assert lowest.add((3.0, "c")) is False and (lowest.hits, lowest.confirmed) == (1, False)
    assert made == [(5.0, "a"), (4.0, "a")]  # the test at (3.0, "c") is not yet needed


def test_no_precision_is_stated_beyond_the_precision_test(rng):
    """A candidate whose RMS standard deviation per point exceeds the precision test's limit
    states no useful precision: nothing is near it (spread2 infinite), at either end."""
    pts, m, k = scene(rng)
    answer = Alternative(pts, 0.0, "answer")
    other = Alternative(pts + 1e-3, 0.0, "random start")
    variances = {id(answer): np.full(m + k, 0.01**2), id(other): np.full(m + k, 0.2**2)}
    spread = precision_spread(lambda alt: variances[id(alt)], _rigid_step(m + k), rms_limit=0.1)
    assert spread(answer, other) == np.inf and spread(other, answer) == np.inf
    variances[id(other)][:] = 0.05**2
    assert np.isfinite(spread(answer, other))
