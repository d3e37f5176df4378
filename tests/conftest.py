"""Shared fixtures: a seeded ``rng`` (``--seed`` to re-run with another seed) and the dEchorate data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

DEFAULT_SEED = 20261121

# The property-based tests draw the same examples on every run (as the rng fixture does), so
# the suite's verdict does not change from one run to the next; HYPOTHESIS_PROFILE=explore
# draws fresh ones and keeps a database of failures, for hunting new bad inputs.
settings.register_profile("repeatable", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help=f"seed of the rng fixture (default {DEFAULT_SEED}); re-run with others to vary data",
    )


def pytest_report_header(config: pytest.Config) -> str:
    return f"rangeslam rng seed: {config.getoption('--seed')}"


@pytest.fixture
def rng(request: pytest.FixtureRequest) -> np.random.Generator:
    """A fresh Generator per test, seeded from --seed, so tests do not depend on their order."""
    return np.random.default_rng(request.config.getoption("--seed"))


@pytest.fixture
def dechorate_dir() -> Path:
    """Path of the dEchorate data, as the loaders find it (rangeslam.datasets.data_path:
    $RANGESLAM_DATA/dechorate, else ../shared/data/dechorate); skip, naming the paths tried, when
    it is absent."""
    from rangeslam.datasets import data_path
    from rangeslam.errors import DataNotFoundError

    try:
        return data_path("dechorate").resolve()
    except DataNotFoundError as exc:
        pytest.skip(str(exc))


@pytest.fixture
def keep_figure(monkeypatch):
    """Keep the figures ``save_figure`` closes (matplotlib's ``plt.close``), to read them back;
    closed at the end of the test."""
    import matplotlib.pyplot as plt

    kept = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    yield kept
    for fig in kept:
        close(fig)


@pytest.fixture
def opened_heartbeats(monkeypatch):
    """The (label, step) of every progress heartbeat a command opens, in order (how many lines a
    heartbeat writes depends on the machine's speed; which heartbeats open does not)."""
    from rangeslam.app import progress

    opened = []

    class Recording(progress.Heartbeat):
        def __enter__(self):
            opened.append((self.label, self.step))
            return super().__enter__()

    monkeypatch.setattr(progress, "Heartbeat", Recording)
    return opened
