"""rangeslam: microphones, trajectories and rooms from ranges (echoes and radio beacons).

The method follows Dokmanic, Daudet and Vetterli, "From acoustic room reconstruction to SLAM"
(ICASSP 2016). Points are rows, shape (N, d); ranges are metres; masks are True where observed.
"""

from .alignment import Alignment, align
from .beacon_slam import BeaconSlamResult, RangeOdometry, beacon_slam, beacon_slam_incremental
from .calibration import Calibration, calibrate
from .crlb import MDUBound, mdu_crlb, multilateration_crlb, wall_crlb
from .edm import classical_mds, edm, edm_to_gram, gram_to_edm, is_edm
from .errors import (
    DataFormatError,
    DegenerateGeometryError,
    InvalidInputError,
    RangeSlamError,
    SolverError,
)
from .geometry import ImageSources, Room
from .multilateration import MultilaterationResult, multilaterate
from .room_reconstruction import RoomReconstruction, reconstruct_room
from .slam import SlamResult, slam

__version__ = "0.1.0"

__all__ = [
    "Alignment",
    "BeaconSlamResult",
    "Calibration",
    "DataFormatError",
    "DegenerateGeometryError",
    "ImageSources",
    "InvalidInputError",
    "MDUBound",
    "MultilaterationResult",
    "RangeOdometry",
    "RangeSlamError",
    "Room",
    "RoomReconstruction",
    "SlamResult",
    "SolverError",
    "__version__",
    "align",
    "beacon_slam",
    "beacon_slam_incremental",
    "calibrate",
    "classical_mds",
    "edm",
    "edm_to_gram",
    "gram_to_edm",
    "is_edm",
    "mdu_crlb",
    "multilaterate",
    "multilateration_crlb",
    "reconstruct_room",
    "slam",
    "wall_crlb",
]
