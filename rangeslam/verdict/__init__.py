"""The verdict: identifiable, consistent with the noise, no unexplained outliers.

- :mod:`rangeslam.verdict.thresholds`: every threshold, named once, with what it means and the
  measurement that set it (the README's "Verdict thresholds" table).
- :mod:`rangeslam.verdict.checks`: each check once (information, consistency, tail, ambiguity,
  flatness), returning a :class:`Check`.
"""

from rangeslam.verdict.checks import (
    PASSED,
    Check,
    ambiguity_check,
    consistency_check,
    first_failure,
    flatness_check,
    gauge_free_covariance,
    information_check,
    mirror_gap,
    mirror_point,
    noise_upper_bound,
    point_check,
    probed_failure,
    range_gauss_newton,
    reflected,
    rms_precision,
    verdict_noise,
    weak_moves,
)
from rangeslam.verdict.thresholds import *  # noqa: F403
from rangeslam.verdict.thresholds import __all__ as _THRESHOLDS

__all__ = [
    "PASSED",
    "Check",
    "ambiguity_check",
    "consistency_check",
    "first_failure",
    "flatness_check",
    "gauge_free_covariance",
    "information_check",
    "mirror_gap",
    "mirror_point",
    "noise_upper_bound",
    "point_check",
    "probed_failure",
    "range_gauss_newton",
    "reflected",
    "rms_precision",
    "verdict_noise",
    "weak_moves",
    *_THRESHOLDS,
]
