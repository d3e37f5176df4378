"""Range-only SLAM with odometry and radio beacons (paper, section 4, on real radio data).

A robot at unknown poses measures its odometry and ranges to beacons at unknown positions. The
geometry is the acoustic SLAM's: the poses are the receivers, the beacons the landmarks, and the
ranges fill the off-diagonal block of an EDM (eq. 9). What changes at this scale:

- **Windows of the MDU problem.** One SDP cannot take thousands of poses, so the trajectory is cut
  into windows of ``window_length`` metres of travel. Within a window dead reckoning is nearly
  rigid, so the pose-pose block of the EDM is taken from it and the pose-beacon block holds the
  ranges: the EDM completion (eq. 10, convex iteration, l1 fit) places the beacons heard from
  non-collinear poses in the window's dead-reckoning frame. The ranges enter uncalibrated (7 %
  long on Plaza): the start only needs to be within the refinement's reach.
- **Stitching.** One rigid correction per window and one position per beacon are fitted to the
  windows' beacons (GTSAM, Huber), with consecutive corrections tied by the odometry's drift; the
  corrections, interpolated along the path, carry the dead-reckoned poses into the map.
- **Refinement.** GTSAM: Pose2 odometry between factors, robust range factors, and the range
  calibration as an unknown (:data:`RANGE_CALIBRATIONS`). The radio ranges of the Plaza data are
  about 7 % long (range minus true distance grows as 0.07 times the distance, intercept within
  0.1 m), which a constant bias cannot model, hence a scale and an offset.
- **Incremental mode** (:func:`beacon_slam_incremental`): iSAM2 consumes odometry and ranges in time
  order; each beacon is initialised from the first window whose EDM places it, and its earlier
  ranges join the graph then.

Data: :class:`RangeOdometry` (``RangeOdometry.from_plaza`` for the CMU Plaza sets: J. Djugash,
B. Hamner and S. Roth, "Navigating with ranging radios: five data sets with ground truth",
Journal of Field Robotics 26(9), 2009).

Modules: :mod:`~rangeslam.beacons.data` (RangeOdometry, dead reckoning),
:mod:`~rangeslam.beacons.options` (BeaconSlamOptions), :mod:`~rangeslam.beacons.known` (known beacons, fixed or
under a prior), :mod:`~rangeslam.beacons.defaults` (the
settings left at None derived from the data: range and odometry noise, window, spread), :mod:`~rangeslam.beacons.windows` (EDM
windows, submaps, stitching), :mod:`~rangeslam.beacons.graph` (keys, factors, graph building),
:mod:`~rangeslam.beacons.lm` (Levenberg-Marquardt), :mod:`~rangeslam.beacons.batch`
(beacon_slam), :mod:`~rangeslam.beacons.incremental` (beacon_slam_incremental),
:mod:`~rangeslam.beacons.simulation` (simulate_beacon_run), :mod:`~rangeslam.beacons.result`
(BeaconSlamResult).
"""

from __future__ import annotations

from rangeslam.beacons.batch import beacon_slam
from rangeslam.beacons.data import RangeOdometry, dead_reckoning
from rangeslam.beacons.incremental import beacon_slam_incremental
from rangeslam.beacons.options import RANGE_CALIBRATIONS, BeaconSlamOptions
from rangeslam.beacons.result import BeaconSlamResult
from rangeslam.beacons.simulation import SimulatedBeaconRun, simulate_beacon_run

__all__ = [
    "RANGE_CALIBRATIONS",
    "BeaconSlamOptions",
    "BeaconSlamResult",
    "RangeOdometry",
    "SimulatedBeaconRun",
    "beacon_slam",
    "beacon_slam_incremental",
    "dead_reckoning",
    "simulate_beacon_run",
]
