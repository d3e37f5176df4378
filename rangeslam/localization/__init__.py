"""Problem 1: points and walls from ranges to a known array.

- :mod:`.multilateration`: one point from ranges to known anchors (eq. 3, SR-LS), robust variant.
- :mod:`.room_reconstruction`: the source, its image sources and the walls (eq. 2 with known
  sorting), several loudspeakers, wrong picks rejected.
- :mod:`.robust_start`: the LMedS/MSAC start over minimal anchor subsets and the
  threshold-and-refit loop, shared by both multilaterations.
- :mod:`.pseudorange`: one point and one unknown range offset (pseudoranges).
- :mod:`.emission`: the room with an unknown emission time (one range offset per event).
"""

from __future__ import annotations

from rangeslam.localization.emission import (
    OffsetMultilaterationResult,
    UnknownEmissionRoom,
    multilaterate_with_offset,
    reconstruct_room_unknown_emission,
)
from rangeslam.localization.multilateration import (
    MultilaterationResult,
    affine_rank,
    minimal_subset_points,
    multilaterate,
)
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room

__all__ = [
    "MultilaterationResult",
    "OffsetMultilaterationResult",
    "RoomReconstruction",
    "UnknownEmissionRoom",
    "affine_rank",
    "minimal_subset_points",
    "multilaterate",
    "multilaterate_with_offset",
    "reconstruct_room",
    "reconstruct_room_unknown_emission",
]
