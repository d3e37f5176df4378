"""Loaders for real data sets. Each reads local files; nothing is downloaded or copied.

Each takes a path, or a name under the data folder (:func:`data_path`: ``$RANGESLAM_DATA``, else
``../shared/data`` relative to the current directory).
"""

from rangeslam.datasets.cmu_plaza import PLAZA_CITATION, PLAZA_NAMES, PlazaDataset, plaza
from rangeslam.datasets.dechorate import DEchorate, load_dechorate
from rangeslam.datasets.paths import DATA_ENV, data_path, data_root
from rangeslam.datasets.pyfg import PYFG_CITATION, load_pyfg, write_pyfg
from rangeslam.datasets.rir_files import LoadedRirs, SilentRirWarning, load_rirs
from rangeslam.datasets.xtdoa import XTDOA_CITATION, XtdoaDataset, xtdoa

__all__ = [
    "DATA_ENV",
    "PLAZA_CITATION",
    "PLAZA_NAMES",
    "PYFG_CITATION",
    "XTDOA_CITATION",
    "DEchorate",
    "LoadedRirs",
    "PlazaDataset",
    "SilentRirWarning",
    "XtdoaDataset",
    "data_path",
    "data_root",
    "load_dechorate",
    "load_pyfg",
    "load_rirs",
    "plaza",
    "write_pyfg",
    "xtdoa",
]
