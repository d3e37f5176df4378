"""Range-aided SLAM: several robots (SE(2) or SE(3)), landmarks, relative-pose odometry with
covariances, ranges pose-landmark and pose-pose (A. Papalia et al., "Certifiably Correct
Range-Aided SLAM", IEEE T-RO 2024, whose benchmark files :mod:`rangeslam.datasets.pyfg` reads).

Modules: :mod:`~rangeslam.rangeaided.problem` (RangeAidedProblem and its measurement records),
:mod:`~rangeslam.rangeaided.poses` (pose algebra and dead reckoning, pure numpy),
:mod:`~rangeslam.rangeaided.start` (odometry and landmark starts),
:mod:`~rangeslam.rangeaided.placement` (each robot's first pose from the data, never the
reference), :mod:`~rangeslam.rangeaided.gtsam_solve` (the GTSAM graph, the solve, the verdict),
:mod:`~rangeslam.rangeaided.gtsam_values` (values and Levenberg-Marquardt),
:mod:`~rangeslam.rangeaided.rivals` (alternative answers and the one judge).
"""

from rangeslam.rangeaided.problem import (
    LandmarkObservations,
    LandmarkPriors,
    PosePriors,
    RangeAidedProblem,
    RangeMeasurements,
    RelativePoses,
)

__all__ = [
    "LandmarkObservations",
    "LandmarkPriors",
    "PosePriors",
    "RangeAidedProblem",
    "RangeMeasurements",
    "RelativePoses",
]
