"""Geometry: rooms and image sources, EDMs, rigid motions and alignment.

- :mod:`.room`: :class:`Room` (convex polygon/polyhedron as half-spaces), image sources of any
  order and the walls that made them (the image source model of section 2, Fig. 1).
- :mod:`.edm`: the EDM (eq. 5), K(G) (eq. 6), the Gram matrix from an EDM (eq. 7), Gower's test,
  classical MDS, and the range matrix between two point sets.
- :mod:`.rigid_motion`: the infinitesimal rigid motions (the gauge of every unfolding) and the
  projection onto the receivers' gauge.
- :mod:`.alignment`: rigid, reflection and similarity alignment (Umeyama) and errors after it.
"""

from __future__ import annotations

from rangeslam.geometry.alignment import Alignment, align
from rangeslam.geometry.edm import (
    centring_matrix,
    classical_mds,
    edm,
    edm_to_gram,
    gram_to_edm,
    is_edm,
)
from rangeslam.geometry.room import ImageSources, Room, reflect

__all__ = [
    "Alignment",
    "ImageSources",
    "Room",
    "align",
    "centring_matrix",
    "classical_mds",
    "edm",
    "edm_to_gram",
    "gram_to_edm",
    "is_edm",
    "reflect",
]
