"""Loaders for real data sets. Each reads local files; nothing is downloaded or copied."""

from rangeslam.datasets.cmu_plaza import PLAZA_CITATION, PLAZA_NAMES, PlazaDataset, plaza
from rangeslam.datasets.dechorate import DEchorate, load_dechorate
from rangeslam.datasets.rir_files import LoadedRirs, SilentRirWarning, load_rirs
from rangeslam.datasets.xtdoa import XTDOA_CITATION, XtdoaDataset, xtdoa

__all__ = [
    "PLAZA_CITATION",
    "PLAZA_NAMES",
    "XTDOA_CITATION",
    "DEchorate",
    "LoadedRirs",
    "PlazaDataset",
    "SilentRirWarning",
    "XtdoaDataset",
    "load_dechorate",
    "load_rirs",
    "plaza",
    "xtdoa",
]
