"""The ``rangeslam`` command line: the README's main job end to end, and its bad-input branches."""

import os
import re
import subprocess
import sys

import pytest

from rangeslam.app.cli import main


@pytest.mark.slow
def test_demo_end_to_end(tmp_path, monkeypatch, capsys, opened_heartbeats):
    """`rangeslam demo`, as the README's first line runs it (no --out, in an empty folder), prints
    the wall table, a small Fig. 3 and Fig. 5 comparison, writes every plot (rooms, Fig. 3, Fig. 5,
    the SLAM estimate with its ellipses, the RIR matrix) to ./rangeslam-out, exits 0. Its progress
    goes to standard error: a line per finished cell of Fig. 3 and Fig. 5, and a heartbeat naming
    the step under way around the rooms and the SLAM example (checked through the heartbeats it
    opens: how many lines they write depends on the machine's speed)."""
    monkeypatch.chdir(tmp_path)
    code = main(["demo", "--seed", "3"])
    captured = capsys.readouterr()
    out, err = captured.out, captured.err
    assert code == 0
    assert opened_heartbeats == [
        ("demo", "step 1 of 4: rooms from echoes"),
        ("demo", "step 4 of 4: a SLAM estimate and the RIR matrix"),
    ]
    assert re.search(r"rangeslam: demo 2/4, Fig. 3: \d+/\d+ trials .*elapsed", err)
    assert re.search(r"rangeslam: demo 3/4, Fig. 5: \d+/\d+ trials .*elapsed", err)
    assert "demo 2/4, Fig. 3: 30/30 trials" in err and "demo 3/4, Fig. 5: 15/15 trials" in err
    tmp_path = tmp_path / "rangeslam-out"
    assert "| room | wall | true offset [m]" in out and "| shoebox | True |" in out
    assert (
        "| sigma (mm) | trials | failed | not identifiable | RMS CRLB (mm) | "
        "oracle RMS (Monte Carlo) (mm) | oracle / CRLB | bound | RMS error (mm) |" in out
    )
    assert "EKF + RTS: RMS (cm), / oracle, / CRLB" in out
    assert "beats" not in out
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
        (["demo", "--sigma", "-1"], "--sigma: must be from 0 to 10 m; got -1$"),
        (["demo", "--seed", "-1"], "--seed: must be from 0 to"),
        (["bench", "fig3", "--seed", "-1"], "--seed: must be from 0 to"),
        (["bench", "compare", "--seed", "x"], "--seed: must be an integer; got x$"),
        (["bench", "xtdoa", "--seed", "-1"], "--seed: must be from 0 to"),
        (["bench", "plaza", "--seed", "-1"], "--seed: must be from 0 to"),
        (["bench", "compare", "--seed", "-1"], "--seed: must be from 0 to"),
        (["simulate", "room", "--seed", "-1"], "--seed: must be from 0 to"),
        (["run", "x.npz", "--fs", "\x1dab"], r"--fs: must be a number; got '\\x1dab'$"),
        (["bench", "fig5", "--sigmas", "1e300"], "--sigmas: must be from 0 to 10 m; got 1e300$"),
        (["bench", "fig3", "--sigmas", "nan"], "--sigmas: must be from 0 to 10 m; got nan$"),
        (["demo", "--outliers", "1.5"], r"must be in \[0, 1\]"),
        (["demo", "--mics", "2"], "--mics: must be from 4 to 64; got 2$"),
        (["demo", "--sources", "x"], "--sources: must be an integer; got x$"),
        (["bench", "fig5", "--steps", "2"], "--steps: must be from 3 to"),
        # ["bench"] alone prints its experiments, then the error: tests/test_cli_inputs.py
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


def test_version(capsys):
    """`rangeslam --version` answers with the installed version."""
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert re.fullmatch(r"rangeslam \S+\n", capsys.readouterr().out)


@pytest.mark.parametrize("experiment", ["fig3", "fig5", "compare", "plaza"])
def test_each_bench_experiment_has_its_own_help(experiment, capsys):
    """`rangeslam bench EXPERIMENT -h` lists that experiment's options with their defaults, and
    not the options of the others."""
    with pytest.raises(SystemExit) as exc:
        main(["bench", experiment, "-h"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "(default:" in text and "--seed" in text
    assert ("--dataset" in text) == (experiment == "plaza")
    assert ("--steps" in text) == (experiment in ("fig5", "compare"))


def test_bench_in_an_empty_folder_writes_its_default_folder(tmp_path, monkeypatch, capsys):
    """`rangeslam bench fig3` without --out writes to ./rangeslam-bench, created on the way."""
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "fig3", "--trials", "1", "--sigmas", "0"]) == 0
    written = {p.name for p in (tmp_path / "rangeslam-bench").iterdir()}
    assert {"fig3_trials.csv", "fig3_summary.json", "fig3_summary.md", "fig3.png"} <= written


@pytest.mark.slow
def test_progress_off_a_terminal_comes_before_the_end(tmp_path):
    """Piped (no terminal), a bench prints a progress line per finished cell, with the count and
    the time left, on standard error, and the first one arrives before the run's last line."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rangeslam.app.cli",
            "bench",
            "fig3",
            "--trials",
            "1",
            "--sigmas",
            "0",
            "0.001",
            "0.002",
            "--out",
            str(tmp_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines = [line.rstrip("\n") for line in proc.stdout]
    assert proc.wait() == 0
    progress = [i for i, line in enumerate(lines) if line.startswith("rangeslam: fig3: ")]
    final = [i for i, line in enumerate(lines) if "trials (0 failed)" in line]
    assert progress and final and progress[0] < final[0]
    assert re.search(
        r"1/3 trials \(sigma=0.0 done\), [\d.]+ s elapsed, about .+ left", lines[progress[0]]
    )
    table = [i for i, line in enumerate(lines) if line.startswith("| sigma")]
    assert progress[-1] < table[0]


def test_an_interrupted_bench_keeps_what_it_finished(tmp_path, monkeypatch, capsys):
    """A run stopped after two trials (Ctrl-C) exits 130 and its CSV holds the two trials."""
    import csv

    from rangeslam.app import benchmarking

    real = benchmarking.run_trial
    calls = []

    def stop_at_the_third(trial, keep_trajectories=False):
        calls.append(trial)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(trial, keep_trajectories)

    monkeypatch.setattr(benchmarking, "run_trial", stop_at_the_third)
    code = main(
        ["bench", "fig3", "--trials", "2", "--sigmas", "0", "0.001", "--out", str(tmp_path)]
    )
    assert code == 130
    assert "what finished is in the output folder" in capsys.readouterr().err
    with (tmp_path / "fig3_trials.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["cell"], r["trial"], r["status"]) for r in rows] == [
        ("0", "0", "ok"),
        ("0", "1", "ok"),
    ]


def test_python_dash_m_rangeslam_runs():
    """``python -m rangeslam`` is the command (it failed: no __main__)."""
    proc = subprocess.run(
        [sys.executable, "-m", "rangeslam", "--version"], capture_output=True, text=True
    )
    assert proc.returncode == 0 and proc.stdout.startswith("rangeslam ")


def test_statuses_print_by_name_and_the_package_is_typed():
    """``str(result.status)`` printed 0; the package ships its PEP 561 marker."""
    from importlib import resources

    from rangeslam.status import Status

    assert str(Status.CONVERGED) == "CONVERGED" and f"{Status.OUTLIERS:>9}" == " OUTLIERS"
    assert int(Status.NO_AGREEMENT) == 6 and Status.OUTLIERS == 3
    assert resources.files("rangeslam").joinpath("py.typed").is_file()


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["bench", "plaza", "--help"]])
def test_version_and_help_load_no_heavy_module(argv):
    """``rangeslam --version`` took 3.4 s loading cvxpy, GTSAM and scipy.signal: the package
    loads its modules on first use, and the parser needs none of them (checked by what is
    imported, not by a clock)."""
    code = (
        "import sys\n"
        "from rangeslam.app.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = ('cvxpy', 'gtsam', 'scipy.signal', 'scipy.optimize', 'matplotlib', 'filterpy')\n"
        "print('heavy:' + ','.join(m for m in heavy if m in sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "heavy:", proc.stdout
