"""Where the data sets are: a path as given, else a name under ``$RANGESLAM_DATA``, else under
``../shared/data`` (relative to the current directory: a clone of rangeslam beside ``shared/``).

Every loader of :mod:`rangeslam.datasets`, the command and the benchmark scripts resolve their
data here, so one rule holds everywhere: ``load_dechorate("dechorate")``,
``load_dechorate("/data/dechorate")`` and ``load_dechorate()`` all work, and a missing data set is
one error naming the paths tried and the variable.
"""

from __future__ import annotations

import os
from pathlib import Path

from rangeslam.errors import DataNotFoundError

__all__ = ["DATA_ENV", "DEFAULT_DATA_ROOT", "data_path", "data_root"]

#: The environment variable naming the folder that holds the data sets (``dechorate/``,
#: ``xtdoa/``).
DATA_ENV = "RANGESLAM_DATA"
#: The folder of the data sets when ``$RANGESLAM_DATA`` is not set, relative to the current
#: directory.
DEFAULT_DATA_ROOT = Path("..") / "shared" / "data"


def data_root() -> Path:
    """The folder of the data sets: ``$RANGESLAM_DATA`` when set (and not empty), else
    ``../shared/data`` relative to the current directory. It need not exist."""
    env = os.environ.get(DATA_ENV)
    return Path(env).expanduser() if env else DEFAULT_DATA_ROOT


def data_path(path_or_name: str | os.PathLike[str], *, what: str = "data") -> Path:
    """The file or folder ``path_or_name`` names: itself when it exists, else (a relative path or
    a data set's name, e.g. ``"dechorate"`` or ``"dechorate/rirs_src0_12mics.npz"``) the same
    under :func:`data_root`. ``what`` names it in the error ('RIR file').

    Raises:
        DataNotFoundError (an InvalidInputError and a FileNotFoundError): neither exists; the
        message names both paths tried and ``$RANGESLAM_DATA``.
    """
    if not isinstance(path_or_name, str | os.PathLike):
        raise DataNotFoundError(
            f"{what}: a path or name must be a string or a path; got {type(path_or_name).__name__}"
        )
    given = Path(path_or_name)
    if str(path_or_name) == "":
        raise DataNotFoundError(f"{what}: a path or name must not be empty")
    if given.exists():
        return given
    tried = [Path(os.path.abspath(given))]
    if not given.is_absolute():
        under = data_root() / given
        if under.exists():
            return under
        tried.append(Path(os.path.abspath(under)))
    env = os.environ.get(DATA_ENV)
    where = (
        f"${DATA_ENV} is {env!r}"
        if env
        else f"${DATA_ENV} is not set, so the data folder is {DEFAULT_DATA_ROOT}"
    )
    raise DataNotFoundError(
        f"{what} {path_or_name} does not exist (tried {' and '.join(str(p) for p in tried)}; {where}): "
        f"pass its path, or set {DATA_ENV} to the folder that holds it"
    )
