"""``rangeslam demo`` shows what it is doing (issue 43): each step named on standard error as it
starts, the Fig. 3 and Fig. 5 runs' progress under the step's name, and a bar on a terminal,
also on a pseudo-terminal nobody sized (where tqdm drew nothing for the minutes Fig. 3 and
Fig. 5 take)."""

from __future__ import annotations

import os
import re
import select
import sys

import pytest

from rangeslam.app import benchmarking, demo_command, experiments
from rangeslam.app.benchmarking import TrialOutcome
from rangeslam.app.cli import main
from rangeslam.app.progress import Progress, bar_size


def _drain(fd: int) -> str:
    """Everything written so far to the pseudo-terminal whose master end is ``fd``."""
    out = b""
    while select.select([fd], [], [], 0.2)[0]:
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        out += chunk
    return out.decode(errors="replace")


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_a_bar_shows_on_a_terminal_that_has_no_size(monkeypatch):
    """A fresh pseudo-terminal is 0 x 0 (as under ``docker exec -t`` or ``script``): tqdm,
    measuring standard error, took its bar's row as beyond the last one and wrote nothing; the
    bar is now 80 x 24 there, and it shows the label and the count."""
    master, slave = os.openpty()
    try:
        with os.fdopen(slave, "w", closefd=False) as stream:
            assert tuple(os.get_terminal_size(slave)) == (0, 0)
            assert bar_size(stream) == {"ncols": 80, "nrows": 24}
            monkeypatch.setattr(sys, "stderr", stream)  # what tqdm measures
            with Progress(3, "demo 2/4, Fig. 3") as progress:
                assert progress.bar is not None  # a terminal: a bar, not lines
                for _ in range(3):
                    progress.update()
            stream.flush()
            shown = _drain(master)
    finally:
        os.close(slave)
        os.close(master)
    assert "demo 2/4, Fig. 3" in shown and "3/3" in shown and "100%" in shown


def test_bar_size_leaves_a_sized_terminal_and_a_file_to_tqdm(tmp_path):
    """A file is not measured (tqdm is not asked to draw there); a sized terminal is tqdm's to
    measure."""
    with (tmp_path / "log.txt").open("w") as f:
        assert bar_size(f) == {}
    if hasattr(os, "openpty"):
        import fcntl
        import struct
        import termios

        master, slave = os.openpty()
        try:
            fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
            with os.fdopen(slave, "w", closefd=False) as stream:
                assert bar_size(stream) == {}
        finally:
            os.close(slave)
            os.close(master)


def test_the_demo_names_each_step_as_it_starts(tmp_path, monkeypatch, capsys):
    """The demo (its trials stood in for, one room, no SLAM example: the steps' naming is what
    is tested) says 'step k of 4' on standard error before each step, in order, and the Fig. 3
    and Fig. 5 progress lines carry the step's name and count every trial."""

    def stand_in(trial, keep=False):
        row = {"bench": trial.bench, "cell": trial.cell, "trial": trial.index}
        return TrialOutcome(row={**row, **dict(trial.params), "status": "failed: stand-in"})

    monkeypatch.setattr(benchmarking, "run_trial", stand_in)
    rooms = experiments.demo_rooms()
    monkeypatch.setattr(experiments, "demo_rooms", lambda: {"shoebox": rooms["shoebox"]})
    monkeypatch.setattr(demo_command, "demo_slam_example", lambda args: None)
    assert main(["demo", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    starts = re.findall(r"rangeslam: demo: step (\d) of 4: (.*) \.\.\.", err)
    assert [int(k) for k, _ in starts] == [1, 2, 3, 4]
    assert [name for _, name in starts] == list(demo_command.DEMO_STEPS)
    assert "rangeslam: demo 2/4, Fig. 3: 30/30 trials" in err
    assert "rangeslam: demo 3/4, Fig. 5: 15/15 trials" in err
    assert err.index("step 2 of 4") < err.index("demo 2/4, Fig. 3: 30/30")
    assert err.index("demo 2/4, Fig. 3: 30/30") < err.index("step 3 of 4")
