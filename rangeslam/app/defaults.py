"""The benchmark defaults the command's parser shows, in a module light enough for ``--help``
(:mod:`rangeslam.app.benchmarking` re-exports them beside the code that uses them)."""

from __future__ import annotations

__all__ = ["DEFAULT_METHODS", "FIG3_SIGMAS", "FIG5_SIGMAS", "FIG5_STEPS", "PLAZA_METHODS"]

#: Range noise levels of ``bench fig3``, metres.
FIG3_SIGMAS = (0.0, 1e-3, 5e-3, 1e-2)
#: Trajectory lengths (steps) of ``bench fig5``.
FIG5_STEPS = (4, 5, 6, 8, 10, 15, 20)
#: Range noise levels of ``bench fig5`` and ``bench compare``, metres.
FIG5_SIGMAS = (1e-3, 1e-2)
#: Methods of the bench: ours (batch, incremental), the same graph from random beacons, GTSAM's
#: example (random beacons, iSAM2), odometry alone and the EKF baseline.
PLAZA_METHODS = (
    "edm+gtsam",
    "edm+isam2",
    "gtsam random beacons",
    "isam2 random beacons",
    "gtsam example",
    "odometry",
    "ekf",
)
#: Run by default: all but "isam2 random beacons" (our iSAM2 graph with each beacon entering at
#: its first range from N(0, I), as GTSAM's example starts them): on Plaza1 its beacons ran off to
#: 1e4-1e8 m in both seeds tried and a run took 200 s.
DEFAULT_METHODS = tuple(m for m in PLAZA_METHODS if m != "isam2 random beacons")
