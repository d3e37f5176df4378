"""The verdict: identifiable, consistent with the noise, no unexplained outliers.

- :mod:`rangeslam.verdict.thresholds`: every threshold, named once, with what it means and the
  measurement that set it (the README's "Verdict thresholds" table).
- :mod:`rangeslam.verdict.checks`: each check once (information, consistency, tail, ambiguity,
  flatness), returning a :class:`Check`.
- :mod:`rangeslam.verdict.breakdown`: a robust answer judged on what it left out.
- :mod:`rangeslam.verdict.crlb`: the Cramer-Rao information the checks and the yardsticks share
  (imported from there: it needs the step bounds of :mod:`rangeslam.solvers`).
"""

from rangeslam.verdict import checks, thresholds
from rangeslam.verdict.checks import *  # noqa: F403
from rangeslam.verdict.thresholds import *  # noqa: F403

__all__ = [*checks.__all__, *thresholds.__all__]
