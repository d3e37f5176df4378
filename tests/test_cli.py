"""The ``rangeslam`` command line: the README's main job end to end, and its bad-input branches."""

import os
import re
import subprocess
import sys

import pytest

from rangeslam.app.cli import main


def test_demo_end_to_end(tmp_path, capsys):
    """`rangeslam demo` prints the wall table, a small Fig. 3 and Fig. 5 comparison, writes every
    plot (rooms, Fig. 3, Fig. 5, the SLAM estimate with its ellipses, the RIR matrix), exits 0."""
    code = main(["demo", "--out", str(tmp_path), "--seed", "3"])
    out = capsys.readouterr().out
    assert code == 0
    assert "| room | wall | true offset [m]" in out and "| shoebox | True |" in out
    assert "| sigma (mm) | trials | failed | median error (mm)" in out
    assert "EKF + RTS mean / median (cm)" in out
    for name in (
        "room_shoebox.png",
        "room_cut_corner.png",
        "fig3.png",
        "compare.png",
        "slam_estimate.png",
        "rir_matrix.png",
    ):
        path = tmp_path / name
        assert path.stat().st_size > 10_000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_console_script_runs():
    """The installed entry point answers --help (the module runs as a program)."""
    proc = subprocess.run(
        [sys.executable, "-m", "rangeslam.app.cli", "--help"], capture_output=True, text=True
    )
    assert proc.returncode == 0 and "demo" in proc.stdout


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["frobnicate"], "invalid choice"),
        (["demo", "--sigma", "-1"], "must be >= 0"),
        (["demo", "--outliers", "1.5"], r"must be in \[0, 1\]"),
        (["demo", "--mics", "2"], "invalid choice"),
    ],
)
def test_bad_options_give_one_line_errors(argv, match, capsys):
    """Unknown subcommands and out-of-range options: exit code 2 and a one-line message, no traceback."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("rangeslam: error:") and err.count("\n") == 1
    assert re.search(match, err)


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_out(tmp_path, capsys):
    """An --out that cannot be written is a one-line error with exit code 2."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(locked / "sub")])
    assert exc.value.code == 2
    assert "cannot write to --out" in capsys.readouterr().err


def test_out_that_is_a_file(tmp_path, capsys):
    """An --out that is an existing file is refused with a one-line error (also as root)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(blocker)])
    assert exc.value.code == 2
    assert "cannot write to --out" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "folder"),
    [
        (["demo"], "rangeslam-out"),
        (["bench", "fig3"], "rangeslam-bench"),
        (["run", "x.npz"], "rangeslam-run"),
    ],
)
def test_default_output_folder_is_created(tmp_path, monkeypatch, argv, folder):
    """Without --out, each command's default output folder is created in the working directory
    (argparse applies ``type`` only to string defaults: a Path default was never created)."""
    from rangeslam.app.parser import build_parser

    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args(argv)
    assert args.out == tmp_path / folder or args.out.resolve() == tmp_path / folder
    assert (tmp_path / folder).is_dir()
