"""Issue 43, item 4 (CSV, WAV, command line): WAV files one per loudspeaker, header rows in the
CSV inputs, RIRs stored transposed named as such, and ``rangeslam`` alone listing its commands."""

from __future__ import annotations

import json
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from rangeslam import InvalidInputError
from rangeslam.app.cli import main
from rangeslam.app.run_command import load_for_run, read_matrix
from rangeslam.datasets.rir_files import load_rirs, one_per_loudspeaker
from rangeslam.errors import DataFormatError

SEED = 423699  # drawn for issue 43 (secrets.randbelow(10**6))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """``simulate room --sources 2 --mics 8``: the two npz, each also as one multichannel WAV
    (float64, channel m: microphone m) and as a directory of mono WAVs; the microphones as a CSV
    with an ``x,y,z`` header."""
    root = tmp_path_factory.mktemp("session")
    argv = ["simulate", "room", "--sources", "2", "--mics", "8", "--seed", str(SEED)]
    assert main([*argv, "--out", str(root / "s.npz")]) == 0
    npz = [np.load(root / f"s-src{j}.npz") for j in range(2)]
    for j, d in enumerate(npz):
        wavfile.write(root / f"src{j}.wav", int(d["fs"]), d["rirs"].T.copy())
        (root / f"src{j}").mkdir()
        for m, rir in enumerate(d["rirs"]):
            wavfile.write(root / f"src{j}" / f"mic{m}.wav", int(d["fs"]), rir)
    np.savetxt(root / "mics.csv", npz[0]["mics"], delimiter=",", header="x,y,z", comments="")
    return root, npz


def _args(paths, **flags) -> Namespace:
    return Namespace(rirs=[Path(p) for p in paths], fs=flags.get("fs"))


@pytest.mark.parametrize("form", ["src{}.wav", "src{}"])
def test_wav_files_one_per_loudspeaker_load_as_the_npz(session, form):
    """Two multichannel WAVs, or two directories of mono WAVs, are two loudspeakers: the same
    RIRs as the npz files, sample for sample (was: 'with several files each must be mono')."""
    root, npz = session
    paths = [root / form.format(j) for j in range(2)]
    assert one_per_loudspeaker(paths)
    loaded = load_for_run(_args(paths))
    assert isinstance(loaded, list) and len(loaded) == 2
    for got, d in zip(loaded, npz, strict=True):
        np.testing.assert_array_equal(got.rirs, d["rirs"])
        assert got.fs == d["fs"]


def test_mono_wavs_stay_one_loudspeaker_and_forms_do_not_mix(session):
    root, _ = session
    mono = sorted((root / "src0").glob("*.wav"))
    assert not one_per_loudspeaker(mono)
    assert load_for_run(_args(mono)).n_rirs == 8
    for mixed in (
        [root / "src0.wav", root / "src1"],
        [root / "src0.wav", mono[0]],
        [root / "s-src0.npz", root / "src1.wav"],
    ):
        with pytest.raises(InvalidInputError, match=r"RIRS: .* not a mix; got .*src0"):
            load_for_run(_args(mixed))


def test_rangeslam_run_takes_a_wav_file_per_loudspeaker(session, tmp_path):
    """End to end: two multichannel WAVs with ``--mics`` a CSV with a header row: converged, both
    loudspeakers within 1 cm of the truth (the npz run's tolerance, tests/test_run_sessions)."""
    root, npz = session
    out = tmp_path / "out"
    code = main(["run", str(root / "src0.wav"), str(root / "src1.wav"), "--mics",
                 str(root / "mics.csv"), "--out", str(out)])  # fmt: skip
    record = json.loads((out / "run_summary.json").read_text())
    assert code == 0 and record["converged"], record["message"]
    np.testing.assert_allclose(record["sources"], [d["source"] for d in npz], atol=0.01)


@pytest.mark.parametrize(
    ("text", "want"),
    [
        ("x,y,z\n1,2,3\n4,5,6\n", [[1, 2, 3], [4, 5, 6]]),
        ("# mics\nx y z\n1 2 3\n4 5 6\n", [[1, 2, 3], [4, 5, 6]]),
        ("mic, x [m], y [m], z [m]\n0, 1, 2, 3\n", [[0, 1, 2, 3]]),
        ("1,2,3\n4,5,6\n", [[1, 2, 3], [4, 5, 6]]),
    ],
)
def test_a_header_row_is_taken_in_csv_inputs(tmp_path, text, want):
    """--mics (and --step-bounds, --keyframes, --excitation) as CSV: a first row of column names
    is skipped (``x,y,z`` was refused)."""
    path = tmp_path / "m.csv"
    path.write_text(text)
    np.testing.assert_array_equal(read_matrix(path, "--mics"), want)


def test_a_second_row_of_words_is_still_refused(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("x,y,z\n1,2,3\na,b,c\n")
    with pytest.raises(InvalidInputError, match=r"--mics .*m\.csv: not a readable numeric"):
        read_matrix(path, "--mics")


def test_rirs_stored_transposed_are_named(session, tmp_path, capsys):
    """An npz whose ``rirs`` is (L, M) was blamed on its mics ('mics must have shape (2619, 3)')
    or on --mics: the error names ``rirs``, the shape expected and the shape got."""
    root, npz = session
    raw = dict(npz[0])
    raw["rirs"] = raw["rirs"].T
    length, m = raw["rirs"].shape
    np.savez(tmp_path / "t.npz", **raw)
    want = rf"t\.npz: rirs must have shape \(M, L\).* got \({length}, {m}\).*stored transposed"
    with pytest.raises(DataFormatError, match=want):
        load_rirs(tmp_path / "t.npz")
    del raw["mics"]
    np.savez(tmp_path / "t.npz", **raw)
    argv = ["run", str(tmp_path / "t.npz"), "--mics", str(root / "mics.csv")]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "rirs must have shape (M, L)" in err and f"({length}, {m})" in err
    assert "stored transposed" in err and "--mics" in err


@pytest.mark.parametrize(
    ("argv", "lists"),
    [([], ("demo", "bench", "simulate", "run")), (["bench"], ("fig3", "fig5", "plaza"))],
)
def test_a_missing_command_prints_the_list_of_commands(capsys, argv, lists):
    """``rangeslam`` alone (and ``rangeslam bench``) prints its help, with the commands, then the
    error; exit 2, as argparse does for a missing argument (it printed the error only)."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: rangeslam") and all(f"    {c} " in err for c in lists), err
    assert err.rstrip().endswith("the following arguments are required: " + (
        "EXPERIMENT" if argv else "COMMAND"))  # fmt: skip


def test_run_help_documents_the_inputs(capsys):
    """``rangeslam run --help``: the beacon log's records and settings, and the forms of several
    loudspeakers."""
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    for part in ("# range_sigma = ", "odometry, ", "range, ", "beacon, ", "outlier",
                 "one multichannel WAV per loudspeaker", "a directory of mono WAVs per loudspeaker",
                 "header"):  # fmt: skip
        assert part in text, part
