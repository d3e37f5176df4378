"""Report writers of the ``rangeslam`` command: Markdown tables, CSV rows, JSON summaries, TUM
trajectories, and the versions a report records."""

from __future__ import annotations

import csv
import json
import math
import platform
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

import numpy as np

from rangeslam.errors import InvalidInputError

__all__ = ["fmt", "markdown", "versions", "write_csv", "write_summary", "write_tum"]


def write_csv(path: str | Path, rows: Sequence[dict]) -> Path:
    """One row per trial; floats with 6 significant digits (the last bits of a float depend on
    the BLAS's threading, the CSV must not)."""
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    path = Path(path)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})
    return path


def write_tum(
    path: str | Path,
    positions: np.ndarray,
    step_seconds: float = 1.0,
    *,
    times: np.ndarray | None = None,
    quaternions: np.ndarray | None = None,
) -> Path:
    """A trajectory in the TUM format (``timestamp tx ty tz qx qy qz qw``; the orientations
    ``quaternions`` (M, 4) (qx, qy, qz, qw) when given, else the identity; one step per
    ``step_seconds`` unless ``times`` (M,) are given), which evo reads
    (``evo_ape tum truth.tum est.tum -a``). Rows that are not finite (a method that stopped) are
    not written."""
    x = np.asarray(positions, dtype=float)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise InvalidInputError(f"positions must have shape (M, 2) or (M, 3); got {x.shape}")
    if x.shape[1] == 2:
        x = np.column_stack([x, np.zeros(len(x))])
    t = np.arange(len(x)) * step_seconds if times is None else np.asarray(times, dtype=float)
    if t.shape != (len(x),):
        raise InvalidInputError(f"times must have shape ({len(x)},); got {t.shape}")
    q = np.column_stack([np.zeros((len(x), 3)), np.ones(len(x))])
    if quaternions is not None:
        q = np.asarray(quaternions, dtype=float)
        if q.shape != (len(x), 4):
            raise InvalidInputError(f"quaternions must have shape ({len(x)}, 4); got {q.shape}")
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(q), axis=1)
    data = np.column_stack([t, x, q])[ok]
    path = Path(path)
    np.savetxt(path, data, fmt="%.9f", header="timestamp tx ty tz qx qy qz qw")
    return path


def versions() -> dict[str, str]:
    """Versions of Python and of the packages the numbers depend on."""
    out = {"python": platform.python_version()}
    for name in ("rangeslam", "numpy", "scipy", "cvxpy", "clarabel", "scs", "gtsam", "filterpy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def write_summary(path: str | Path, **content) -> Path:
    """The JSON summary (seed, versions, options, per-cell figures); NaN written as null."""
    path = Path(path)
    path.write_text(json.dumps(_json_clean(content), indent=2) + "\n")
    return path


def _json_clean(v):
    """``v`` with every non-finite float (nested in dicts, lists, tuples) replaced by None."""
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _json_clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_json_clean(x) for x in v]
    return v


def fmt(v, scale: float = 1.0, digits: int = 4) -> str:
    """``v * scale`` with ``digits`` decimals; "-" for None, "none" for a non-finite float."""
    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return "none"
    return f"{v * scale:.{digits}f}"
