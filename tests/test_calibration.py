"""Zero-knowledge calibration (Problem 2, MDU): the Fig. 3 criteria and the API."""

import dataclasses

import numpy as np
import pytest

from rangeslam import InvalidInputError, SolverError, align, calibrate, mdu_crlb
from rangeslam.app.experiments import calibration_experiment, fig3_scene
from rangeslam.geometry.edm import range_matrix
from rangeslam.sim.scenes import add_outliers, add_range_noise
from rangeslam.status import Status


def _fig3_runs(sigma, rng, n=100):
    return [calibration_experiment(sigma, rng) for _ in range(n)]


@pytest.mark.slow
def test_fig3_exact_recovery_and_honest_convergence(rng):
    """sigma = 0, 100 Fig. 3 configurations: at least 97 recover the microphones to < 1 mm up to a
    rigid motion (measured 100/100 on several seeds), and `converged` is True exactly for those."""
    runs = _fig3_runs(0.0, rng)
    recovered = np.array([r.mic_error < 1e-3 for r in runs])
    converged = np.array([r.result.converged for r in runs])
    assert recovered.sum() >= 97, [r.mic_error for r in runs if r.mic_error >= 1e-3]
    np.testing.assert_array_equal(converged, recovered)
    for r in runs:
        if not r.result.converged:
            assert r.result.message


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [1e-3, 5e-3])
def test_fig3_converged_answers_are_at_the_oracle(rng, sigma):
    """sigma = 1 mm and 5 mm, 100 configurations each: of the configurations that converge, at
    least 93% (1 mm) / 85% (5 mm) end at the oracle's answer (least squares from the truth on the
    same ranges: error within 1% + sigma / 10 of the oracle's), and most configurations
    converge. (The bound is not the yardstick here: over Fig. 3's scenes the oracle's RMS error
    was measured at 0.81-0.85x the RMS CRLB at 1 mm and 0.50-0.79x at 5 mm, so it is not attained;
    benchmarks/README.md, "Calibration against the oracle and the bound".)"""
    # measured on seeds 11 and 12: 97% and 100% at 1 mm, 94% and 93% at 5 mm
    runs = _fig3_runs(sigma, rng)
    errors = np.array([r.mic_error for r in runs])
    oracle = np.array([r.oracle_error for r in runs])
    converged = np.array([r.result.converged for r in runs])
    at_oracle = errors <= 1.01 * oracle + 0.1 * sigma
    share = np.mean(at_oracle[converged])
    assert share >= (0.93 if sigma < 2e-3 else 0.85), (share, errors[converged & ~at_oracle])
    # Converged means determined: at 5 mm this near-minimal geometry (redundancy 6 of 36) leaves
    # some configurations fixed only to decimetres, or with a second answer as good, and those
    # say so (measured on seeds 11 and 12: 62% and 67% converge at 5 mm, 99% and 95% at 1 mm).
    assert np.mean([r.result.converged for r in runs]) >= (0.85 if sigma < 2e-3 else 0.55)


def test_mask_with_missing_ranges_is_still_exact(rng):
    """Ten receivers and eight sources in 3-D with 15% of the ranges missing."""
    x, s = rng.uniform(0, 2, (10, 3)), rng.uniform(-2, 4, (8, 3))
    mask = rng.random((10, 8)) > 0.15
    ranges = np.where(mask, range_matrix(x, s), np.nan)
    out = calibrate(ranges, mask=mask, noise_std=0.0, rng=rng)
    assert out.converged
    assert align(out.receivers, x, reflection=True).rmse < 1e-6
    assert np.all(np.isnan(out.residuals[~mask]))
    np.testing.assert_array_equal(out.observed, mask)


def test_two_dimensional_calibration(rng):
    x, s = rng.uniform(0, 2, (7, 2)), rng.uniform(-2, 4, (6, 2))
    out = calibrate(range_matrix(x, s), dim=2, noise_std=0.0, rng=rng)
    assert out.converged and out.receivers.shape == (7, 2) and out.sources.shape == (6, 2)
    assert align(out.receivers, x, reflection=True).rmse < 1e-6
    assert align(out.sources, s, reflection=True).rmse < 1e-6


def test_invariances_units_and_order(rng):
    """Ranges in millimetres give the same configuration scaled by 1000; permuting receivers and
    sources permutes the answer."""
    scene = fig3_scene(rng)
    a = calibrate(scene.ranges, noise_std=0.0, rng=rng)
    b = calibrate(scene.ranges * 1000, noise_std=0.0, rng=rng)
    assert a.converged and b.converged
    assert align(b.receivers / 1000, a.receivers, reflection=True).rmse < 1e-9
    pr, ps = rng.permutation(6), rng.permutation(6)
    c = calibrate(scene.ranges[pr][:, ps], noise_std=0.0, rng=rng)
    assert c.converged
    assert align(c.receivers, scene.mics[pr], reflection=True).rmse < 1e-6
    assert align(c.sources, scene.sources[ps], reflection=True).rmse < 1e-6


def test_frame_is_the_receivers_principal_axes(rng):
    scene = fig3_scene(rng)
    out = calibrate(scene.ranges, noise_std=0.0, rng=rng)
    np.testing.assert_allclose(out.receivers.mean(axis=0), 0, atol=1e-12)
    cov = np.cov(out.receivers.T, bias=True)
    np.testing.assert_allclose(cov, np.diag(np.diag(cov)), atol=1e-12)
    assert np.all(np.diff(np.diag(cov)) <= 0)
    np.testing.assert_allclose(range_matrix(out.receivers, out.sources), scene.ranges, atol=1e-9)


def test_result_is_frozen_and_input_untouched(rng):
    scene = fig3_scene(rng)
    ranges = scene.ranges.copy()
    out = calibrate(ranges, noise_std=0.0, rng=rng)
    np.testing.assert_array_equal(ranges, scene.ranges)
    with pytest.raises(ValueError):
        out.receivers[0, 0] = 1.0
    with pytest.raises(AttributeError):
        out.converged = False  # type: ignore[misc]


def test_minimal_configuration_is_not_claimed(rng):
    """M = 4, K = 6 in 3-D: 24 ranges for 24 unknowns. The data fit exactly, but the unfolding
    has many solutions (38, paper section 3.1), so the answer is not reported as converged."""
    x, s = rng.uniform(0, 2, (4, 3)), rng.uniform(-2, 4, (6, 3))
    out = calibrate(range_matrix(x, s), noise_std=0.0, max_attempts=1, rng=rng)
    assert not out.converged and "minimal configuration" in out.message
    assert out.status is Status.NOT_IDENTIFIABLE
    assert out.redundancy == 0


def test_failure_is_reported_not_hidden(rng):
    """Ranges with 1 cm noise checked against a claimed 1 um: nothing passes, and the best fit
    found is returned with converged False and a message (never the input)."""
    scene = fig3_scene(rng)
    noisy = add_range_noise(scene.ranges, 0.01, rng=rng)
    out = calibrate(noisy, noise_std=1e-6, max_attempts=2, random_starts=3, rng=rng)
    assert not out.converged and out.status is Status.INCONSISTENT
    assert "no start in 5 passed the residual test" in out.message
    assert out.attempts == 2 and out.random_starts == 3
    assert out.residual_rms > 1e-4


def test_unknown_noise_one_start_says_the_budget_ended_its_search(rng):
    """Without noise_std and with one start and no random ones, the stopping rule cannot end the
    search (it needs minima + 3 starts): the result says the budget did ("search complete" not
    passed, named in the message), and the answer is right or not converged; exact data are
    accepted at once."""
    x, s = rng.uniform(0, 2, (10, 3)), rng.uniform(-2, 4, (8, 3))
    exact = calibrate(range_matrix(x, s), max_attempts=1, random_starts=0, rng=rng)
    assert exact.converged and align(exact.receivers, x, reflection=True).rmse < 1e-6
    noisy = add_range_noise(range_matrix(x, s), 1e-3, rng=rng)
    once = calibrate(noisy, max_attempts=1, random_starts=0, rng=rng)
    search = {c.name: c for c in once.checks}["search complete"]
    assert not search.passed and "stopped by the budget" in once.message
    assert not once.converged or align(once.receivers, x, reflection=True).rmse < 3e-3


def test_auto_says_when_the_redundancy_is_too_small_to_look_for_wrong_picks(rng):
    """robust="auto" with fewer redundant ranges than unknowns (10 x 8: 32 for 48) fits least
    squares and says it did not search for wrong picks, whatever the verdict; robust=False says
    nothing of the kind (nor does enough redundancy: tests/test_verdicts.py, 16 x 10)."""
    x, s = rng.uniform(0, 2, (10, 3)), rng.uniform(-2, 4, (8, 3))
    noisy = add_range_noise(range_matrix(x, s), 1e-3, rng=rng)
    small = calibrate(noisy, max_attempts=1, rng=rng)
    assert small.message.startswith(
        "robust='auto': wrong picks not searched for (32 redundant ranges for 48 unknowns"
    )
    plain = calibrate(noisy, robust=False, max_attempts=1, rng=rng)
    assert "not searched for" not in plain.message


def test_unknown_noise_vote_on_a_well_posed_array(rng):
    """10 receivers, 8 sources, 1 mm noise, noise_std unknown: all 4 runs are made, the vote
    passes and the error is at the CRLB level (at most 3x)."""
    x, s = rng.uniform(0, 2, (10, 3)), rng.uniform(-2, 4, (8, 3))
    noisy = add_range_noise(range_matrix(x, s), 1e-3, rng=rng)
    out = calibrate(noisy, max_attempts=4, rng=rng)
    assert out.converged, out.message
    assert out.attempts == 4
    bound = mdu_crlb(x, s, 1e-3).receiver_rmse
    assert align(out.receivers, x, reflection=True).rmse < 3 * bound
    assert out.noise_estimate == pytest.approx(1e-3, rel=0.5)


def test_an_sdp_failure_in_one_run_is_noted_and_the_others_go_on(rng, monkeypatch):
    from rangeslam.solvers import sdp

    original = sdp.EDMCompletionSDP.solve
    calls = {"n": 0}

    def first_fails(self, z):
        calls["n"] += 1
        if calls["n"] == 1:
            raise SolverError("EDM completion SDP failed", status="CLARABEL: error; SCS: error")
        return original(self, z)

    monkeypatch.setattr(sdp.EDMCompletionSDP, "solve", first_fails)
    scene = fig3_scene(rng)
    out = calibrate(scene.ranges, noise_std=0.0, rng=rng)
    assert "1 SDP runs failed" in out.message
    assert out.attempts >= 1 and calls["n"] > 1


def test_robust_calibration_drops_wrong_picks(rng):
    """20 receivers, 12 sources, 2 mm noise and 5% wrong picks of 5-50 cm: the wrong picks are
    found and the receivers are as good as without them (measured 1.6-2.3 mm, every wrong pick
    caught, at most 2 good ranges dropped, on 10 draws with these settings)."""
    x, s = rng.uniform(0, 2, (20, 3)), rng.uniform(-2, 4, (12, 3))
    clean = add_range_noise(range_matrix(x, s), 0.002, rng=rng)
    ranges, wrong = add_outliers(clean, 0.05, min_error=0.05, max_error=0.5, rng=rng)
    out = calibrate(
        ranges, noise_std=0.002, robust=True, max_attempts=4, max_iterations=20, rng=rng
    )
    assert out.converged, out.message
    assert align(out.receivers, x, reflection=True).rmse < 0.006
    caught = np.sum(wrong & ~out.inliers)
    assert caught >= 0.9 * wrong.sum()
    assert out.n_outliers <= wrong.sum() + 3


@pytest.mark.slow
def test_robust_answer_of_one_start_is_right_or_not_converged(rng):
    """Issue 17: dropping ranges lets a wrong configuration pass the residual test on the ranges
    it kept; judged on the Cauchy cost over every range against the judge's alternatives (the
    refits without each source and each receiver among them), one start's robust answer is
    right or not converged, and with four runs the same data converge right or say they did
    not."""
    x, s = rng.uniform(0, 2, (20, 3)), rng.uniform(-2, 4, (12, 3))
    clean = add_range_noise(range_matrix(x, s), 0.002, rng=rng)
    ranges, _ = add_outliers(clean, 0.05, min_error=0.05, max_error=0.5, rng=rng)
    options = {"noise_std": 0.002, "robust": True, "max_iterations": 20, "rng": rng}
    one = calibrate(ranges, max_attempts=1, random_starts=0, **options)
    assert not one.converged or align(one.receivers, x, reflection=True).rmse < 0.006
    more = calibrate(ranges, max_attempts=4, **options)
    assert not more.converged or align(more.receivers, x, reflection=True).rmse < 0.006


def test_solver_failure_propagates(rng, monkeypatch):
    from rangeslam.solvers import sdp

    def broken(self, z):
        raise SolverError("EDM completion SDP failed", status="CLARABEL: error; SCS: error")

    monkeypatch.setattr(sdp.EDMCompletionSDP, "solve", broken)
    with pytest.raises(SolverError, match="every SDP run failed") as info:
        calibrate(fig3_scene(rng).ranges, noise_std=0.0, max_attempts=2)
    assert info.value.status == "CLARABEL: error; SCS: error"


def test_integer_seed_is_accepted():
    scene = fig3_scene(np.random.default_rng(5))
    a = calibrate(scene.ranges, noise_std=0.0, rng=3)
    b = calibrate(scene.ranges, noise_std=0.0, rng=3)
    np.testing.assert_allclose(a.receivers, b.receivers, atol=1e-9)


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((np.ones(5),), {}, r"ranges must be an \(M, K\) array"),
        ((np.ones((6, 6)),), {"dim": 4}, "dim must be 2 or 3"),
        ((np.ones((6, 6)),), {"mask": np.ones((6, 6))}, "mask must be a boolean array"),
        ((np.ones((6, 6)),), {"mask": np.ones((5, 6), dtype=bool)}, r"mask must have shape"),
        ((-np.ones((6, 6)),), {}, "non-negative"),
        ((np.full((6, 6), np.nan),), {}, "finite where observed"),
        ((np.ones((6, 6)),), {"noise_std": -1.0}, "noise_std must be"),
        (
            (np.ones((6, 6)),),
            {"max_attempts": 0},
            r"max_attempts must be an integer in \[1, 1000\]",
        ),
        (
            (np.ones((6, 6)),),
            {"random_starts": -1},
            r"random_starts must be an integer in \[0, 100000\]",
        ),
        ((np.ones((3, 6)),), {}, "under-determined: 18 observed ranges for 21 unknowns"),
        ((np.zeros((6, 6)),), {}, "must not all be zero"),
        ((np.ones((6, 6)),), {"fit_weight": -1.0}, "fit_weight must be positive"),
        ((np.ones((6, 6)),), {"gap_tol": 0.0}, "gap_tol must be in"),
        ((np.ones((6, 6)),), {"robust": True, "refine": False}, "robust=True needs refine=True"),
    ],
)
def test_bad_input(args, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        calibrate(*args, **kwargs)


def test_under_determined_point_is_named():
    mask = np.ones((6, 6), dtype=bool)
    mask[2, :4] = False  # receiver 2 keeps 2 ranges
    with pytest.raises(InvalidInputError, match="receiver 2 has 2 observed ranges"):
        calibrate(np.ones((6, 6)), mask=mask)
    mask = np.ones((8, 6), dtype=bool)
    mask[:6, 4] = False  # source 4 keeps 2 ranges
    with pytest.raises(InvalidInputError, match="source 4 has 2 observed ranges"):
        calibrate(np.ones((8, 6)), mask=mask)


def test_a_receiver_that_kept_half_its_ranges_is_outvoted():
    """breakdown_check: a robust answer that keeps at most half of a receiver's observed ranges
    places it against the other half (past the 50% breakdown point); unobserved ranges do not
    count; sources are judged only when asked."""
    from rangeslam.verdict.breakdown import breakdown_check

    observed = np.ones((4, 6), bool)
    observed[2, :2] = False  # receiver 2 heard by 4 sources
    inliers = observed.copy()
    inliers[0, :2] = False  # 4 of 6 kept
    assert breakdown_check(inliers, observed, 100, judge_sources=False).passed
    inliers[2, 2:4] = False  # 2 of its 4 kept: half
    check = breakdown_check(inliers, observed, 100, judge_sources=False)
    assert check.status is Status.OUTLIERS
    assert check.reason.startswith("receiver 2: only 2 of its 4 ranges agree with the fit")
    inliers[0, 2] = False  # 3 of 6 kept
    reason = breakdown_check(inliers, observed, 100, judge_sources=False).reason
    assert "receiver 0: only 3 of its 6 ranges" in reason
    assert "(and 1 more)" in reason


def test_a_robust_answer_past_its_breakdown_point_is_outliers():
    """breakdown_check: more than half the redundant ranges left out is OUTLIERS whatever the
    points kept; a source column kept at most half is judged with ``judge_sources``."""
    from rangeslam.verdict.breakdown import breakdown_check

    observed = np.ones((6, 6), bool)
    kept = observed.copy()
    kept[np.arange(6), np.arange(6)] = False  # one range of each point: 6 left out
    assert breakdown_check(kept, observed, 12, judge_sources=True).passed
    check = breakdown_check(kept, observed, 11, judge_sources=True)
    assert check.status is Status.OUTLIERS
    assert check.reason.startswith("6 of the 36 ranges were left out as wrong, more than half")
    kept = observed.copy()
    kept[:3, 5] = False  # source 5 keeps 3 of its 6
    assert breakdown_check(kept, observed, 100, judge_sources=False).passed
    check = breakdown_check(kept, observed, 100, judge_sources=True, names=("step", "landmark"))
    assert check.reason.startswith("landmark 5: only 3 of its 6 ranges")


def _moved_outcome(rng):
    """A Fig. 3 scene at 1 mm and its search, the best candidate's receiver 0 moved 0.5 m (a
    worse minimum the judge's block refits climb out of): (problem, outcome, the unmoved best)."""
    from rangeslam.mdu import calibration as cal

    scene = fig3_scene(rng)
    ranges = add_range_noise(scene.ranges, 1e-3, rng=rng)
    mask = np.ones(ranges.shape, dtype=bool)
    problem = cal.parse_calibration(
        ranges, mask, 3, 1e-3, True, False, 0, cal.ConvexIterationOptions()
    )
    outcome = cal.search(problem, rng)
    best = outcome.best
    pts = np.vstack([best.fit.receivers, best.fit.sources])
    pts[0] += 0.5
    moved = dataclasses.replace(best, fit=dataclasses.replace(best.fit, receivers=pts[:6]))
    return problem, dataclasses.replace(outcome, best=moved, candidates=[moved]), best


def test_a_replacement_is_judged_in_its_turn(rng):
    """Issue 42: the judge's lower minimum replaces the answer, and the judgement reported is
    the replacement's own (its lowest the answer itself or the same answer), so the verdict
    speaks of the answer returned; the answer is back at the search's minimum."""
    from rangeslam.mdu import calibration as cal
    from rangeslam.mdu import calibration_judge
    from rangeslam.verdict.judge import LOWER

    problem, outcome, unmoved = _moved_outcome(rng)
    replaced, judged = cal.judged_outcome(outcome, problem, rng)
    assert replaced.best is not outcome.best
    first = judged.judgement.comparisons[0] if judged.judgement.replaced else None
    assert first is None or first.kind != LOWER
    status, message = calibration_judge.judged_status(judged, replaced.best, problem, "")
    assert status is Status.CONVERGED, message
    back = align(replaced.best.fit.receivers, unmoved.fit.receivers, reflection=True)
    assert back.rmse < 1e-3  # back at the search's minimum


def test_an_answer_its_judge_finds_lower_than_is_not_converged(rng, monkeypatch):
    """When the fit from the judge's lowest falls back to the worse answer (here forced), the
    judge finds the lower minimum again: NO_AGREEMENT, never CONVERGED on the worse one."""
    from rangeslam.mdu import calibration as cal
    from rangeslam.mdu import calibration_judge

    problem, outcome, _ = _moved_outcome(rng)
    monkeypatch.setattr(cal, "fit_start", lambda *a, **k: outcome.best)
    kept, judged = cal.judged_outcome(outcome, problem, rng)
    assert kept.best.fit is outcome.best.fit
    status, message = calibration_judge.judged_status(judged, kept.best, problem, "")
    assert status is Status.NO_AGREEMENT and "lower minimum" in message, message


def test_cheap_runs_stop_once_settled_and_reach_the_full_schedule_minimum(rng):
    """Issue 45: with edm_start="cheap" every least-squares convex-iteration run of calibrate
    stops once its embedding settles (the judge compares each run's refined minimum with every
    alternative): fewer SDP solves than running each to the gap, the same verdict, and the same
    minimum (on 30 held-out Fig. 3 scenes every answer was the same, benchmarks/README.md)."""
    scene = fig3_scene(rng)
    ranges = add_range_noise(scene.ranges, 1e-3, rng=rng)
    cheap = calibrate(ranges, edm_start="cheap", rng=0)
    full = calibrate(ranges, edm_start="full", rng=0)
    assert cheap.iterations < full.iterations
    assert cheap.status is full.status, (cheap.message, full.message)
    ssr = [float(np.nansum(c.residuals**2)) for c in (cheap, full)]
    assert ssr[0] <= ssr[1] * (1 + 1e-6) + 1e-18
    assert align(cheap.receivers, full.receivers, reflection=True).errors.max() < 1e-6


def _spy_on_the_judge(monkeypatch) -> list:
    """Record (``draws`` allowed, draws made) of every judge_calibration call of
    judged_outcome."""
    from rangeslam.mdu import calibration as cal

    judged_draws, judge = [], cal.judge_calibration

    def spy(*args, **kwargs):
        judged = judge(*args, **kwargs)
        judged_draws.append((kwargs.get("draws"), judged.draws))
        return judged

    monkeypatch.setattr(cal, "judge_calibration", spy)
    return judged_draws


def test_when_the_sdp_runs_miss_the_judge_draws_random_starts_to_their_limit(rng, monkeypatch):
    """Issue 42: an answer from one of the search's random starts (no convex-iteration run
    reached it) is judged by random starts drawn until the stopping rule ends them or
    ``random_starts`` are made in all, not within SEARCH_BUDGET. (Verdict benchmark seed
    170618752, case 1637106663: CONVERGED 42 cm off at a minimum one random start reached after
    the eight SDP runs missed; the oracle's minimum, 12 noise variances lower, was one start in
    eight.) Here the SDP runs are taken away: every start is random."""
    from rangeslam.mdu import calibration as cal
    from rangeslam.verdict.thresholds import SEARCH_BUDGET

    scene = fig3_scene(rng, n_mics=8, n_images=6)
    ranges = add_range_noise(scene.ranges, 1e-2, rng=rng)
    monkeypatch.setattr(cal, "core_runs", lambda *args, **kwargs: iter(()))
    judged_draws = _spy_on_the_judge(monkeypatch)
    out = calibrate(ranges, noise_std=1e-2, random_starts=40, rng=rng)
    assert out.attempts == 0 and out.origin == "random_start" and out.random_starts >= 1
    allowed, made = zip(*judged_draws, strict=True)
    assert allowed[0] == 40 - out.random_starts
    # a descent's later judgements draw what is left, failed fits counted
    assert all(allowed[i + 1] == max(allowed[i] - made[i], 0) for i in range(len(made) - 1))
    assert sum(made) <= 40 - out.random_starts
    search = next(c for c in out.checks if c.name == "search complete")
    if not search.passed:  # the limit ended the draws: every one was made
        assert "random_starts limit" in search.reason, search.reason
        starts = int(search.reason.split(" starts reached")[0].split()[-1])
        assert starts > SEARCH_BUDGET


def test_an_answer_an_sdp_run_reached_is_judged_within_the_search_budget(rng, monkeypatch):
    """The converse: with a convex-iteration run's answer the judge's random starts stay
    within SEARCH_BUDGET (``draws`` None)."""
    scene = fig3_scene(rng)
    ranges = add_range_noise(scene.ranges, 1e-3, rng=rng)
    judged_draws = _spy_on_the_judge(monkeypatch)
    out = calibrate(ranges, noise_std=1e-3, rng=rng)
    assert out.attempts >= 1 and out.random_starts == 0
    assert judged_draws and all(allowed is None for allowed, _ in judged_draws)
