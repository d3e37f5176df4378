"""From room impulse responses to ranges, labels, tracks and maps.

- :mod:`.echoes`: echo detection in one RIR (direct path and echoes, eq. 1).
- :mod:`.labelling`: which peak is which image source for a known array; RIRs to a room.
- :mod:`.label_search`, :mod:`.label_audit`: the point search and the column audit of the labelling.
- :mod:`.joint_room`, :mod:`.shared_walls`: several loudspeakers at one array, walls fitted jointly;
  walls each loudspeaker hears at too few microphones to label alone, found from all their echoes.
- :mod:`.tracking`: echoes of a moving microphone followed from RIR to RIR.
- :mod:`.walk`: RIRs of a moving microphone to its trajectory and landmarks.
- :mod:`.pipeline`: RIR files plus what is known to a room map or a walk.
- :mod:`.input_sanity`: what is wrong with the RIRs, named before a room is estimated: silent and
  clipped RIRs; from the direct paths, a delay before the emission, a wrong ``fs``, microphones
  not in metres.
"""

from __future__ import annotations

from rangeslam.acoustics.echoes import (
    SPEED_OF_SOUND,
    ClippedRirWarning,
    EchoDetection,
    detect_echoes,
    detect_echoes_many,
)
from rangeslam.acoustics.labelling import EchoLabelling, RoomFromRirs, label_echoes, room_from_rirs
from rangeslam.acoustics.pipeline import (
    MEASURED_RIR_OPTIONS,
    SHOEBOX_WALLS,
    LoadedRirs,
    RunErrors,
    RunResult,
    SilentRirWarning,
    evaluate_run,
    load_rirs,
    run_rirs,
    shoebox_wall_errors,
)
from rangeslam.acoustics.tracking import EchoTracks, track_echoes
from rangeslam.acoustics.walk import WalkFromRirs, walk_from_rirs

__all__ = [
    "MEASURED_RIR_OPTIONS",
    "SHOEBOX_WALLS",
    "SPEED_OF_SOUND",
    "ClippedRirWarning",
    "EchoDetection",
    "EchoLabelling",
    "EchoTracks",
    "LoadedRirs",
    "RoomFromRirs",
    "RunErrors",
    "RunResult",
    "SilentRirWarning",
    "WalkFromRirs",
    "detect_echoes",
    "detect_echoes_many",
    "evaluate_run",
    "label_echoes",
    "load_rirs",
    "room_from_rirs",
    "run_rirs",
    "shoebox_wall_errors",
    "track_echoes",
    "walk_from_rirs",
]
