"""rangeslam: microphones, trajectories and rooms from ranges (echoes and radio beacons).

The method follows Dokmanic, Daudet and Vetterli, "From acoustic room reconstruction to SLAM"
(ICASSP 2016). Points are rows, shape (N, d); ranges are metres; masks are True where observed.
"""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time each name loads on first use
    from rangeslam.acoustics.echoes import EchoDetection, detect_echoes, detect_echoes_many
    from rangeslam.acoustics.labelling import (
        EchoLabelling,
        RoomFromRirs,
        label_echoes,
        room_from_rirs,
    )
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

#: Where each public name lives. The package imports a module the first time one of its names is
#: used (PEP 562), so ``rangeslam --version`` and ``--help`` do not load scipy.signal, cvxpy or
#: GTSAM.
_LAZY = {
    "Alignment": "rangeslam.geometry.alignment",
    "BeaconSlamResult": "rangeslam.beacons",
    "Calibration": "rangeslam.mdu.calibration",
    "DataFormatError": "rangeslam.errors",
    "DegenerateGeometryError": "rangeslam.errors",
    "EchoDetection": "rangeslam.acoustics.echoes",
    "EchoLabelling": "rangeslam.acoustics.labelling",
    "EchoTracks": "rangeslam.acoustics.tracking",
    "ImageSources": "rangeslam.geometry.room",
    "InvalidInputError": "rangeslam.errors",
    "LoadedRirs": "rangeslam.acoustics.pipeline",
    "MDUBound": "rangeslam.verdict.crlb",
    "MultilaterationResult": "rangeslam.localization.multilateration",
    "RangeOdometry": "rangeslam.beacons",
    "RangeSlamError": "rangeslam.errors",
    "Room": "rangeslam.geometry.room",
    "RoomFromRirs": "rangeslam.acoustics.labelling",
    "RoomReconstruction": "rangeslam.localization.room_reconstruction",
    "RunResult": "rangeslam.acoustics.pipeline",
    "SlamResult": "rangeslam.mdu.slam",
    "SolverError": "rangeslam.errors",
    "WalkFromRirs": "rangeslam.acoustics.walk",
    "align": "rangeslam.geometry.alignment",
    "beacon_slam": "rangeslam.beacons",
    "beacon_slam_incremental": "rangeslam.beacons",
    "calibrate": "rangeslam.mdu.calibration",
    "calibrate_unknown_emission": "rangeslam.mdu.emission",
    "classical_mds": "rangeslam.geometry.edm",
    "detect_echoes": "rangeslam.acoustics.echoes",
    "detect_echoes_many": "rangeslam.acoustics.echoes",
    "edm": "rangeslam.geometry.edm",
    "edm_to_gram": "rangeslam.geometry.edm",
    "gram_to_edm": "rangeslam.geometry.edm",
    "is_edm": "rangeslam.geometry.edm",
    "label_echoes": "rangeslam.acoustics.labelling",
    "load_rirs": "rangeslam.acoustics.pipeline",
    "mdu_crlb": "rangeslam.verdict.crlb",
    "multilaterate": "rangeslam.localization.multilateration",
    "multilaterate_with_offset": "rangeslam.localization.emission",
    "multilateration_crlb": "rangeslam.verdict.crlb",
    "reconstruct_room": "rangeslam.localization.room_reconstruction",
    "reconstruct_room_unknown_emission": "rangeslam.localization.emission",
    "room_from_rirs": "rangeslam.acoustics.labelling",
    "run_rirs": "rangeslam.acoustics.pipeline",
    "slam": "rangeslam.mdu.slam",
    "track_echoes": "rangeslam.acoustics.tracking",
    "walk_from_rirs": "rangeslam.acoustics.walk",
    "wall_crlb": "rangeslam.verdict.crlb",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'rangeslam' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


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
