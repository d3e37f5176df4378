"""The verdict benchmark's cases and classification (issue 17): does "converged" mean right?

The full benchmark is benchmarks/bench_verdicts.py (>= 500 cases); here, the classification
itself and a reduced run over every simulated estimator.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.evaluation.verdict_cases import (
    BOUND_FACTOR,
    OUTCOMES,
    REGIMES,
    VerdictCase,
    classify,
    draw_cases,
    make_case,
    run_case,
)
from rangeslam.status import HasStatus, Status


@dataclass(frozen=True)
class _Result(HasStatus):
    """A stand-in for an estimator's result: a status and a point estimate."""

    status: Status
    position: float
    message: str = ""


def _case(identifiable: bool, bound: float = 0.01) -> VerdictCase:
    """A case whose truth is 0 and whose estimate's error is |position|."""

    def judge(result):
        error = abs(result.position)
        return error, error <= BOUND_FACTOR * bound

    return VerdictCase("toy", "toy", lambda: None, judge, bound, 1.0, identifiable)


@pytest.mark.parametrize(
    ("identifiable", "status", "position", "expected"),
    [
        (True, Status.CONVERGED, 0.02, "converged-right"),
        (True, Status.CONVERGED, 0.05, "converged-wrong"),
        (False, Status.CONVERGED, 0.0, "converged-wrong"),  # right needs identifiable data
        (True, Status.INCONSISTENT, 0.5, "flagged-right"),
        (False, Status.NOT_IDENTIFIABLE, 0.0, "flagged-right"),
        (True, Status.OUTLIERS, 0.01, "flagged-wrong"),
    ],
)
def test_classify_the_outcomes(identifiable, status, position, expected):
    """Right = identifiable and error <= 3 x bound; flagged = any status but CONVERGED."""
    assert classify(_case(identifiable), _Result(status, position)) == expected


@pytest.mark.parametrize(
    ("status", "position", "expected"),
    [
        (Status.INCONSISTENT, 0.02, "flagged-inconsistent-call"),  # the right flag
        (Status.OUTLIERS, 0.02, "flagged-wrong"),  # any other flag is still a false alarm
        (Status.CONVERGED, 0.02, "converged-right"),
        (Status.INCONSISTENT, 0.5, "flagged-right"),
        (Status.CONVERGED, 0.5, "converged-wrong"),
    ],
)
def test_classify_a_call_whose_noise_std_is_too_small(status, position, expected):
    """With noise_std a third of the truth's, INCONSISTENT on a right estimate is a right flag of
    the call, counted apart from the false alarms; nothing else changes."""
    case = replace(_case(True), noise_std_too_small=True)
    assert classify(case, _Result(status, position)) == expected


def test_only_the_third_noise_regimes_contradict_the_call():
    """make_case marks the "noise_std /3" regimes, and no other, as calls with too small a
    noise_std."""
    marked = {
        (e, r)
        for e, regimes in REGIMES.items()
        for r in regimes
        if make_case(e, r, 3).noise_std_too_small
    }
    assert marked == {
        (e, r) for e, regimes in REGIMES.items() for r in regimes if r.endswith("noise_std /3")
    }
    assert marked  # multilaterate's and slam's


def test_classify_a_package_error():
    """A package error is a flag: right when the truth is not identifiable, else a false alarm;
    anything that is neither a result nor a package error is refused."""
    err = DegenerateGeometryError("anchors are collinear")
    assert classify(_case(False), err) == "flagged-right"
    assert classify(_case(True), err) == "flagged-wrong"
    with pytest.raises(InvalidInputError, match="result must be"):
        classify(_case(True), ValueError("foreign"))
    with pytest.raises(InvalidInputError, match="result must be"):
        classify(_case(True), 3.0)


def test_run_case_records_foreign_exceptions():
    """A foreign exception is recorded as such (a defect to report), a package error as flagged."""

    def boom():
        raise KeyError("x")

    def refuse():
        raise InvalidInputError("ranges must be finite")

    base = _case(True)
    out = run_case(VerdictCase("toy", "toy", boom, base.judge, 0.01, 1.0, True))
    assert out.classification == "foreign-exception" and "KeyError" in out.message
    out = run_case(VerdictCase("toy", "toy", refuse, base.judge, 0.01, 1.0, False))
    assert out.classification == "flagged-right" and out.status == "InvalidInputError"


def test_make_case_reproduces_and_draw_cases_spreads(rng):
    """The same seed gives the same data and truth; draw_cases covers every regime in turn."""
    seed = int(rng.integers(2**31))
    a, b = (
        make_case("multilaterate", "random 1 mm", seed),
        make_case("multilaterate", "random 1 mm", seed),
    )
    assert a.bound == b.bound and a.scale == b.scale
    np.testing.assert_array_equal(a.run().position, b.run().position)
    cases = draw_cases(2 * len(REGIMES["multilaterate"]), rng, estimators=["multilaterate"])
    assert sorted({c.regime for c in cases}) == sorted(REGIMES["multilaterate"])
    with pytest.raises(InvalidInputError, match="estimators must be"):
        draw_cases(3, rng, estimators=["kalman"])
    with pytest.raises(InvalidInputError, match="estimator and regime"):
        make_case("slam", "M=3", 0)


def test_truth_by_construction(rng):
    """Constructions with an exact ambiguity are never identifiable, whatever the bound says."""
    for est, regime in [
        ("multilaterate", "d anchors"),
        ("calibrate", "linear array"),
        ("calibrate", "planar at dim=3"),
        ("calibrate", "receiver heard by 3"),
        ("calibrate", "3-D data at dim=2"),
        ("slam", "random walk M=10, dim=2"),
    ]:
        case = make_case(est, regime, int(rng.integers(2**31)))
        assert not case.identifiable and case.reason, (est, regime)


def test_truth_of_a_room_heard_from_a_table(rng):
    """Microphones on a table (z spread 1 mm) hear the room and its mirror image through the
    table within the noise: the truth says not identifiable (the estimator rightly flags it);
    microphones spread through the room do not, and the mirror's gap is exactly 0 for a flat
    array."""
    from rangeslam.evaluation.verdict_cases import mirror_room_gap
    from rangeslam.geometry.room import Room

    for _ in range(3):
        table = make_case("reconstruct_room", "mics on a table", int(rng.integers(2**31)))
        assert not table.identifiable and "mirror image" in table.reason
        spread = make_case("reconstruct_room", "shoebox 1 mm", int(rng.integers(2**31)))
        assert spread.identifiable, spread.reason
    room = Room.shoebox([5.0, 4.0, 2.6])
    flat = np.column_stack([rng.uniform(0.5, 4.5, (6, 2)), np.full(6, 0.9)])
    source = np.array([[2.0, 1.5, 1.7]])
    assert mirror_room_gap(room, flat, source) == pytest.approx(0.0, abs=1e-20)
    flat[:, 2] += rng.uniform(-0.5, 0.5, 6)
    assert mirror_room_gap(room, flat, source) > 1e-3


# --- the reduced benchmark ----------------------------------------------------------------------

#: Fast regimes per estimator and cases per regime. Left out (run only in the full benchmark, for
#: time): calibrate with 20% wrong picks, without noise_std and at dim=2 (10-70 s a case), slam
#: without noise_std. Also left out: "noise_std /3" (a noise level given three times too small),
#: which every estimator rightly rejects as inconsistent with that noise: counted apart as
#: "flagged-inconsistent-call" in the full benchmark's table.
REDUCED = {
    "multilaterate": ([r for r in REGIMES["multilaterate"] if r != "noise_std /3"], 2),
    "calibrate": (
        [
            "clean 1 mm",
            "clean 1 cm",
            "10% wrong, defaults",
            "linear array",
            "planar at dim=3",
            "receiver heard by 3",
        ],
        1,
    ),
    "slam": (
        [r for r in REGIMES["slam"] if "not given" not in r and "/3" not in r],
        1,
    ),
    "reconstruct_room": (list(REGIMES["reconstruct_room"]), 2),
    "calibrate_unknown_emission": (list(REGIMES["calibrate_unknown_emission"]), 2),
}


def _reduced(estimator: str, rng) -> list:
    regimes, per = REDUCED[estimator]
    cases = [make_case(estimator, r, int(rng.integers(2**31))) for r in regimes for _ in range(per)]
    return [run_case(c) for c in cases]


@pytest.mark.parametrize(
    "estimator",
    [
        "multilaterate",
        pytest.param("calibrate", marks=pytest.mark.slow),
        pytest.param("slam", marks=pytest.mark.slow),
        "reconstruct_room",
        pytest.param("calibrate_unknown_emission", marks=pytest.mark.slow),
    ],
)
def test_reduced_benchmark(estimator, rng):
    """Over the fast regimes: no converged-wrong case, no foreign exception, and false alarms at
    most 15% (or two) of the cases the truth says are right (the full benchmark's target: 0
    and 5%)."""
    outcomes = _reduced(estimator, rng)
    counts = {
        k: sum(o.classification == k for o in outcomes) for k in (*OUTCOMES, "foreign-exception")
    }
    detail = [
        (o.case.regime, o.case.seed, o.classification, o.message[:120])
        for o in outcomes
        if o.classification in ("converged-wrong", "flagged-wrong", "foreign-exception")
    ]
    assert counts["foreign-exception"] == 0, detail
    assert counts["converged-wrong"] == 0, detail
    right = counts["converged-right"] + counts["flagged-wrong"]
    # A few dozen cases estimate a rate of a few per cent poorly: at most 15% or two (measured
    # over seeds 0-2: up to 2 of 13, reconstruct_room at 30-40% wrong picks); the full
    # benchmark reports the rate itself.
    assert counts["flagged-wrong"] <= max(2, 0.15 * right), detail
