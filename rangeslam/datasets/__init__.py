"""Loaders for real data sets. Each reads local files; nothing is downloaded or copied."""

from rangeslam.datasets.cmu_plaza import PLAZA_CITATION, PLAZA_NAMES, PlazaDataset, plaza
from rangeslam.datasets.dechorate import DEchorate, load_dechorate

__all__ = ["PLAZA_CITATION", "PLAZA_NAMES", "DEchorate", "PlazaDataset", "load_dechorate", "plaza"]
