"""Helpers of the session tests (test_run_sessions, test_run_recordings): a two-loudspeaker
session simulated and run through the command line, and the run's wall errors."""

from __future__ import annotations

import json

import numpy as np

from rangeslam.app.cli import main

__all__ = ["two_loudspeaker_session", "wall_errors"]


def two_loudspeaker_session(tmp_path, room: str, seed: int, *, sim=(), run=()):
    """``simulate room --sources 2`` with ``sim`` flags, then ``run`` of both files with ``run``
    flags; (exit code, the run's JSON record, the two npz)."""
    stem = tmp_path / "session.npz"
    argv = ["simulate", "room", "--room", room, "--sources", "2", "--seed", str(seed), *sim]
    assert main([*argv, "--out", str(stem)]) == 0
    files = [str(tmp_path / f"session-src{j}.npz") for j in range(2)]
    out = tmp_path / "out"
    code = main(["run", *files, *run, "--out", str(out)])
    record = json.loads((out / "run_summary.json").read_text())
    return code, record, tuple(np.load(f) for f in files)


def wall_errors(record) -> np.ndarray:
    """The true walls' errors, metres (inf: not found; the JSON writes it as null)."""
    return np.array([np.inf if e is None else e for e in record["wall_errors_m"].values()])
