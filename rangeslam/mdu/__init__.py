"""Problem 2 and acoustic SLAM: multidimensional unfolding (MDU).

- :mod:`.core`: the unfolding shared by every estimator (eq. 9: W and D-tilde, the count of
  unknowns up to the gauge, the canonical frame, the convex-iteration restart schedule of eq. 10,
  the residual test and verdict, covariance rotation).
- :mod:`.calibration`: :func:`calibrate`, zero-knowledge calibration (eqs. 4, 8-10).
- :mod:`.slam`: :func:`slam`, acoustic range-only SLAM with step bounds (section 4, eq. 11).
- :mod:`.emission`: :func:`calibrate_unknown_emission`, MDU with one range offset per event.
- :mod:`.subsets`: the EDM start at size (the SDP of keyframes of a long walk or a core of a
  large array, the other points placed from it).
"""

from __future__ import annotations

from rangeslam.mdu.calibration import Calibration, calibrate
from rangeslam.mdu.core import mdu_edm, mdu_mask, unknowns_up_to_rigid_motion
from rangeslam.mdu.slam import SlamResult, slam

__all__ = [
    "Calibration",
    "SlamResult",
    "calibrate",
    "mdu_edm",
    "mdu_mask",
    "slam",
    "unknowns_up_to_rigid_motion",
]
