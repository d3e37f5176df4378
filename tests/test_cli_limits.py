"""Bad values on the command line: one line naming the flag (never a library argument), exit 2,
and the limits stated in --help (issue 36, "Smaller, each seen")."""

import re

import numpy as np
import pytest

from rangeslam.app import parser, simulate_command
from rangeslam.app.cli import main

#: Library argument names that must not reach a command-line error.
LIBRARY_NAMES = ("fs=", "max_order", "path_or_paths", "points must", "dims must", "n_mics")


@pytest.fixture
def npz(tmp_path):
    """A small npz of 4 RIRs at 16 kHz with microphones."""
    path = tmp_path / "r.npz"
    np.savez(path, rirs=np.eye(4, 64), fs=16000.0, mics=np.eye(4, 3))
    return path


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["simulate", "room", "--fs", "1"], "--fs"),
        (["simulate", "walk", "--fs", "2000000"], "--fs"),
        (["simulate", "room", "--order", "13"], "--order"),
        (["simulate", "walk", "--order", "0"], "--order"),
        (["simulate", "room", "--source", "1", "1", "nan"], "--source"),
        (["simulate", "room", "--size", "1e20", "1", "1"], "--size"),
        (["simulate", "walk", "--size", "5", "4", "inf"], "--size"),
        (["simulate", "room", "--mics", "100000"], "--mics"),
        (["simulate", "room", "--noise", "1e300"], "--noise"),
        (["simulate", "walk", "--steps", "100000"], "--steps"),
        (["simulate", "walk", "--steps", "1000", "--rirs-per-step", "64"], "--steps"),
        (["simulate", "walk", "--rirs-per-step", "1000"], "--rirs-per-step"),
        (["run", "NPZ", "--c", "1e300"], "--c"),
        (["run", "NPZ", "--fs", "1e300"], "--fs"),
        (["run", "NPZ", "--fs", "8000"], "--fs"),
        (["run", "NPZ", "x.wav"], "RIRS"),  # several .npz are several loudspeakers
        (["bench", "fig5", "--trials", "100000000000000000000"], "--trials"),
        (["bench", "compare", "--jobs", "100000"], "--jobs"),
        (["bench", "plaza", "--trials", "5000"], "--trials"),
        (["bench", "xtdoa", "--robust", "1001"], "--robust"),
        (["bench", "xtdoa", "--subsets", "1000000"], "--subsets"),
    ],
)
def test_bad_value_is_one_line_naming_the_flag(argv, flag, npz, tmp_path, capsys):
    """Exit 2 and one line `rangeslam: error: ...` naming the flag, with no library argument
    name and no traceback; nothing is written."""
    argv = [str(npz) if a == "NPZ" else a for a in argv]
    out = tmp_path / ("out.npz" if argv[0] == "simulate" else "out")
    try:
        code = main([*argv, "--out", str(out)])
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("rangeslam: error: "), err
    assert flag in err and "Traceback" not in err
    assert not any(name in err for name in LIBRARY_NAMES), err
    assert not (tmp_path / "out.npz").exists()


def test_steps_refused_before_simulating(capsys, tmp_path):
    """`simulate walk --steps 100000` (pyroomacoustics ran out of memory) is refused up front
    with the limit in the message; so is a walk of more RIRs than MAX_WALK_RIRS."""
    out = tmp_path / "w.npz"
    with pytest.raises(SystemExit) as info:
        main(["simulate", "walk", "--steps", "100000", "--out", str(out)])
    assert info.value.code == 2
    assert f"--steps: must be from 3 to {simulate_command.MAX_STEPS}" in capsys.readouterr().err
    assert (
        main(["simulate", "walk", "--steps", "200", "--rirs-per-step", "60", "--out", str(out)])
        == 2
    )
    err = capsys.readouterr().err
    assert f"are 11941 RIRs; at most {simulate_command.MAX_WALK_RIRS}" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "texts"),
    [
        (["simulate", "walk"], ["3 (SLAM's least) to 1000", "at most 10000", "1 to 64"]),
        (["simulate", "walk"], ["1000 to 1000000", "1 to 12", "0.5 to 100", "(0 to 100)"]),
        (["simulate", "room"], ["4 (a room in 3-D) to 256", "1 to 12", "1000 to 1000000"]),
        (["run"], ["1000 to 1e+06", "100 to 2000"]),
        (["bench", "fig5"], ["trials per cell, 1 to 100000", "1 to 64"]),
        (["bench", "plaza"], ["1 to 1000"]),
        (["bench", "xtdoa"], ["1 to 100000", "RUNS (1 to 1000)"]),
    ],
)
def test_limits_are_in_help(argv, texts, capsys):
    """The limits the parser enforces are printed by --help."""
    with pytest.raises(SystemExit):
        main([*argv, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for t in texts:
        assert t in text


def test_cli_limits_match_the_library():
    """The simulate limits are within the ones rangeslam.sim.rir checks (copied to keep --help
    fast): --fs the same, --order lower (for time)."""
    from rangeslam.sim import rir

    assert simulate_command.FS_LIMITS == (rir.MIN_SIM_FS, rir.MAX_SIM_FS)
    assert 1 <= simulate_command.MAX_ORDER <= rir.MAX_SIM_ORDER
    assert parser.RUN_FS_LIMITS[0] <= 16000 <= parser.RUN_FS_LIMITS[1]


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--keyframes", "{tmp}/kf.txt"], r"--keyframes .*kf\.txt: must be at least 3 increasing"),
        (
            ["--step-bounds", "{tmp}/swapped.txt"],
            r"--step-bounds .*swapped\.txt: step 0 has bounds",
        ),
        (["--mics", "{tmp}/nan.csv"], r"--mics .*nan\.csv: microphone positions must be finite"),
        (["--mics", "{tmp}/mics.csv", "--dim", "2"], "--dim 2: a room is 3-D"),
    ],
)
def test_run_geometry_errors_name_the_flag(extra, match, tmp_path, capsys):
    """Keyframes out of range, swapped or non-finite bounds and microphones, --dim 2 for a room:
    refused in the flag's terms (they reached run_rirs and came back as keyframes=, step_bounds=,
    dim=), exit 2, one line."""
    path = tmp_path / "walk.npz"
    np.savez(path, rirs=np.eye(10, 64), fs=16000.0, step_bounds=np.ones((2, 9)))
    np.savetxt(tmp_path / "kf.txt", [0, 5, 500])
    np.savetxt(tmp_path / "swapped.txt", np.vstack([np.full(9, 0.4), np.full(9, 0.2)]))
    np.savetxt(tmp_path / "nan.csv", np.full((10, 3), np.nan), delimiter=",")
    np.savetxt(tmp_path / "mics.csv", np.random.default_rng(0).random((10, 3)), delimiter=",")
    argv = ["run", str(path), "--out", str(tmp_path / "out")]
    argv += [a.format(tmp=tmp_path) for a in extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rangeslam: error: "), err
    assert re.search(match, err), err
    assert not any(name in err for name in ("step_bounds must", "dim must", "keyframes must"))
