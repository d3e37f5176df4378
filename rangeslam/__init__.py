"""rangeslam: microphones, trajectories and rooms from ranges (echoes and radio beacons).

The method follows Dokmanic, Daudet and Vetterli, "From acoustic room reconstruction to SLAM"
(ICASSP 2016). Points are rows, shape (N, d); ranges are metres; masks are True where observed.
"""

from rangeslam.acoustics.echoes import EchoDetection, detect_echoes, detect_echoes_many
from rangeslam.acoustics.labelling import EchoLabelling, RoomFromRirs, label_echoes, room_from_rirs
from rangeslam.acoustics.pipeline import LoadedRirs, RunResult, load_rirs, run_rirs
from rangeslam.acoustics.tracking import EchoTracks, track_echoes
from rangeslam.acoustics.walk import WalkFromRirs, walk_from_rirs
from rangeslam.beacons import (
    BeaconSlamResult,
    RangeOdometry,
    beacon_slam,
    beacon_slam_incremental,
)
from rangeslam.errors import (
    DataFormatError,
    DegenerateGeometryError,
    InvalidInputError,
    RangeSlamError,
    SolverError,
)
from rangeslam.geometry.alignment import Alignment, align
from rangeslam.geometry.edm import classical_mds, edm, edm_to_gram, gram_to_edm, is_edm
from rangeslam.geometry.room import ImageSources, Room
from rangeslam.localization.emission import (
    multilaterate_with_offset,
    reconstruct_room_unknown_emission,
)
from rangeslam.localization.multilateration import MultilaterationResult, multilaterate
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room
from rangeslam.mdu.calibration import Calibration, calibrate
from rangeslam.mdu.emission import calibrate_unknown_emission
from rangeslam.mdu.slam import SlamResult, slam
from rangeslam.verdict.crlb import MDUBound, mdu_crlb, multilateration_crlb, wall_crlb

__version__ = "0.1.0"

__all__ = [
    "Alignment",
    "BeaconSlamResult",
    "Calibration",
    "DataFormatError",
    "DegenerateGeometryError",
    "EchoDetection",
    "EchoLabelling",
    "EchoTracks",
    "ImageSources",
    "InvalidInputError",
    "LoadedRirs",
    "MDUBound",
    "MultilaterationResult",
    "RangeOdometry",
    "RangeSlamError",
    "Room",
    "RoomFromRirs",
    "RoomReconstruction",
    "RunResult",
    "SlamResult",
    "SolverError",
    "WalkFromRirs",
    "__version__",
    "align",
    "beacon_slam",
    "beacon_slam_incremental",
    "calibrate",
    "calibrate_unknown_emission",
    "classical_mds",
    "detect_echoes",
    "detect_echoes_many",
    "edm",
    "edm_to_gram",
    "gram_to_edm",
    "is_edm",
    "label_echoes",
    "load_rirs",
    "mdu_crlb",
    "multilaterate",
    "multilaterate_with_offset",
    "multilateration_crlb",
    "reconstruct_room",
    "reconstruct_room_unknown_emission",
    "room_from_rirs",
    "run_rirs",
    "slam",
    "track_echoes",
    "walk_from_rirs",
    "wall_crlb",
]
