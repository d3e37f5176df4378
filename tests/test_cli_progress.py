"""The command as people expect it: -v anywhere on the line and useful (each step and its time),
progress lines during a long run, and one run's files per output folder (issue 36, "Smaller,
each seen")."""

import io
import logging
import time

import pytest

from rangeslam.app import progress, run_command
from rangeslam.app.cli import main
from rangeslam.app.parser import build_parser
from rangeslam.app.progress import Heartbeat
from rangeslam.logsteps import logged_step


@pytest.mark.parametrize(
    "argv",
    [
        ["-v", "run", "x.npz"],
        ["run", "x.npz", "-v"],
        ["run", "--verbose", "x.npz"],
        ["simulate", "walk", "-v"],
        ["simulate", "-v", "room"],
        ["bench", "fig3", "-v"],
        ["bench", "-v", "compare"],
        ["bench", "xtdoa", "-v"],
        ["demo", "-v"],
    ],
)
def test_verbose_anywhere(argv):
    """-v is taken before the subcommand, after it, and after the options."""
    assert build_parser().parse_args(argv).verbose is True
    quiet = build_parser().parse_args([a for a in argv if a not in ("-v", "--verbose")])
    assert getattr(quiet, "verbose", False) is False


class _Records(logging.Handler):
    """Keeps the messages it receives."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.messages = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def test_logged_step_logs_start_time_and_failure():
    """A logged step says when it starts and how long it took, or that it failed."""
    log, seen = logging.getLogger("rangeslam.test_steps"), _Records()
    log.addHandler(seen)
    log.setLevel(logging.INFO)

    @logged_step(log, "step A")
    def ok(x):
        return x + 1

    @logged_step(log, "step B")
    def bad():
        raise ValueError("no")

    try:
        assert ok(1) == 2
        with pytest.raises(ValueError, match="no"):
            bad()
    finally:
        log.removeHandler(seen)
        log.setLevel(logging.NOTSET)
    assert seen.messages[0] == "step A ..." and seen.messages[1].startswith("step A: done in ")
    assert seen.messages[2] == "step B ..." and seen.messages[3].startswith("step B: failed after ")


def test_heartbeat_lines_name_the_step():
    """A heartbeat writes a line every interval with the elapsed time and the latest step the
    library logged; without -v the step records themselves are not printed, and the logger's
    settings are restored on exit."""
    stream, log = io.StringIO(), logging.getLogger("rangeslam.test_heartbeat")
    root = logging.getLogger("rangeslam")
    before = (root.level, root.propagate)
    root.setLevel(logging.WARNING)
    try:
        with Heartbeat("job", interval=0.05, stream=stream) as beat:
            log.info("walk: step under way ...")
            time.sleep(0.3)
        assert (root.level, root.propagate) == (logging.WARNING, before[1])
    finally:
        root.setLevel(before[0])
        root.propagate = before[1]
    lines = stream.getvalue().splitlines()
    assert beat.lines >= 2 and len(lines) == beat.lines
    assert lines[-1].startswith("rangeslam: job: ") and "elapsed; walk: step under way" in lines[-1]


@pytest.fixture(scope="module")
def room_npz(tmp_path_factory):
    """A simulated room recording (8 RIRs, seed 0)."""
    path = tmp_path_factory.mktemp("room") / "room.npz"
    assert main(["simulate", "room", "--out", str(path)]) == 0
    return path


def test_run_replaces_an_earlier_runs_files(room_npz, tmp_path, capsys, monkeypatch):
    """A run into a folder holding an earlier (walk) run's files deletes them and nothing else;
    every file it writes is one of RUN_FILES; with -v it logs its steps with their times and a
    progress line names the step under way; without -v no step is logged."""
    out = tmp_path / "out"
    out.mkdir()
    for name in ("run_trajectory.csv", "run_landmarks.csv", "run_trajectory.png", "notes.txt"):
        (out / name).write_text("earlier")
    monkeypatch.setattr(progress, "HEARTBEAT_SECONDS", 0.5)
    assert main(["run", str(room_npz), "--out", str(out), "-v"]) == 0
    err = capsys.readouterr().err
    names = {p.name for p in out.iterdir()}
    assert "run_trajectory.csv" not in names and "run_landmarks.csv" not in names
    assert "run_trajectory.png" not in names and (out / "notes.txt").read_text() == "earlier"
    assert {"run_summary.json", "run_walls.csv", "run_room.png"} <= names
    assert names - {"notes.txt"} <= set(run_command.RUN_FILES)
    assert "removed 3 files of an earlier run" in err
    assert (
        "rangeslam: room: detecting and labelling echoes, reconstructing the room: done in" in err
    )
    assert "rangeslam: run: drawing the plots: done in" in err
    assert "elapsed; room: detecting and labelling echoes" in err  # the progress line
    assert main(["run", str(room_npz), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "done in" not in err and "removed" not in err
    assert {p.name for p in out.iterdir()} == names


def test_simulate_walk_shows_progress(tmp_path, opened_heartbeats):
    """`simulate walk` (20 s at 600 steps) runs under a progress heartbeat naming what it
    simulates. (Checked through the heartbeat it opens, not through the lines it writes: those
    depend on how long the call takes, and a walk simulated earlier in the session was seen to
    finish before the first line.)"""
    assert main(["simulate", "walk", "--out", str(tmp_path / "w.npz")]) == 0
    assert opened_heartbeats == [("simulate walk", "113 RIRs (pyroomacoustics)")]


def test_slam_logs_its_steps():
    """slam (the longest step of a walk run) logs its EDM search with its time, which -v prints
    and the progress line names."""
    import numpy as np

    import rangeslam
    from rangeslam.geometry.edm import range_matrix
    from rangeslam.sim.trajectories import lemniscate, step_lengths

    walk = lemniscate(6, step=0.3, phase=0.0)
    src = np.array([1.2, 2.9, 1.4])
    room = rangeslam.Room.shoebox([5, 4, 2.6])
    landmarks = np.vstack([src, room.image_sources(src, 1).positions])
    steps = step_lengths(walk)
    log, seen = logging.getLogger("rangeslam.mdu.slam"), _Records()
    log.addHandler(seen)
    log.setLevel(logging.INFO)
    try:
        rangeslam.slam(range_matrix(walk, landmarks), step_bounds=(0.8 * steps, 1.2 * steps), rng=0)
    finally:
        log.removeHandler(seen)
        log.setLevel(logging.NOTSET)
    assert "slam: EDM starts (convex iteration), each refined with GTSAM ..." in seen.messages
    assert any(
        m.startswith("slam: EDM starts (convex iteration), each refined with GTSAM: done in")
        for m in seen.messages
    )


def test_the_heartbeat_never_names_a_finished_step_as_under_way():
    """A step's end takes the heartbeat's line back to the step it ran in (or the step given at
    the start): under load a beat after "x: done in 0.8 s" said that finished step was under way."""
    beat = progress.Heartbeat("run", step="reading", enabled=False)

    def log(message):
        beat.emit(logging.LogRecord("rangeslam", logging.INFO, __file__, 0, message, None, None))

    log("room: labelling ...")
    log("run: drawing the plots ...")
    assert beat.step == "run: drawing the plots ..."
    log("run: drawing the plots: done in 0.8 s")
    assert beat.step == "room: labelling ..."
    log("room: labelling: failed after 2.0 s")
    assert beat.step == "reading"
