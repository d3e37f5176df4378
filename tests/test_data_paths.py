"""Where the data are: a path as given, else a name under $RANGESLAM_DATA, else under
../shared/data relative to the current directory (rangeslam.datasets.data_path), the same rule
for every loader, the command and the benchmark scripts; a missing data set is one error naming
the paths tried and the variable."""

import numpy as np
import pytest
from scipy.io import savemat

from rangeslam.app.cli import main
from rangeslam.datasets import DATA_ENV, data_path, data_root, load_dechorate, load_rirs, xtdoa
from rangeslam.errors import DataNotFoundError, InvalidInputError


def _fake_xtdoa(folder):
    """A tiny well-formed xtdoa file (4 microphones, 5 events) in ``folder``."""
    folder.mkdir(parents=True)
    savemat(
        folder / "real_data_M12_K65.mat",
        {"T": np.ones((4, 5)), "W": np.ones((4, 5)), "X_r": np.zeros((3, 4))},
    )
    return folder


def test_existing_path_is_used_as_given(tmp_path, monkeypatch):
    """A path that exists is returned unchanged, whatever $RANGESLAM_DATA says."""
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "elsewhere"))
    (tmp_path / "here").mkdir()
    assert data_path(tmp_path / "here") == tmp_path / "here"


def test_name_under_the_variable(tmp_path, monkeypatch):
    """A name that is not a path here is looked up under $RANGESLAM_DATA; the xtdoa loader's
    default name finds its data there."""
    _fake_xtdoa(tmp_path / "data" / "xtdoa")
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "data"))
    monkeypatch.chdir(tmp_path)
    assert data_root() == tmp_path / "data"
    assert data_path("xtdoa") == tmp_path / "data" / "xtdoa"
    assert xtdoa().arrivals.shape == (4, 5)
    assert xtdoa("xtdoa/real_data_M12_K65.mat").receivers.shape == (4, 3)


def test_default_is_shared_data_beside_the_clone(tmp_path, monkeypatch):
    """Without the variable the data folder is ../shared/data from the current directory (a
    clone sitting beside shared/, as the README says)."""
    monkeypatch.delenv(DATA_ENV, raising=False)
    _fake_xtdoa(tmp_path / "shared" / "data" / "xtdoa")
    (tmp_path / "clone").mkdir()
    monkeypatch.chdir(tmp_path / "clone")
    assert data_path("xtdoa").resolve() == (tmp_path / "shared" / "data" / "xtdoa").resolve()
    assert xtdoa().clean.shape == (4, 5)


def test_rir_files_by_name(tmp_path, monkeypatch):
    """load_rirs takes a file named relative to the data folder (as `rangeslam run
    dechorate/rirs_src0_12mics.npz` does)."""
    (tmp_path / "data" / "set").mkdir(parents=True)
    np.savez(tmp_path / "data" / "set" / "r.npz", rirs=np.eye(4, 64), fs=16000.0)
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "data"))
    monkeypatch.chdir(tmp_path)
    assert load_rirs("set/r.npz").rirs.shape == (4, 64)
    assert load_rirs(["set/r.npz"]).fs == 16000.0


@pytest.mark.parametrize("env", [None, "nowhere-data"])
def test_missing_data_names_the_paths_and_the_variable(tmp_path, monkeypatch, env):
    """Missing data: DataNotFoundError (an InvalidInputError and a FileNotFoundError) naming
    both paths tried and $RANGESLAM_DATA (set or not)."""
    monkeypatch.chdir(tmp_path)
    if env is None:
        monkeypatch.delenv(DATA_ENV, raising=False)
    else:
        monkeypatch.setenv(DATA_ENV, env)
    with pytest.raises(DataNotFoundError) as info:
        load_dechorate()
    text = str(info.value)
    assert isinstance(info.value, InvalidInputError) and isinstance(info.value, FileNotFoundError)
    assert str(tmp_path / "dechorate") in text and "$RANGESLAM_DATA" in text
    root = (tmp_path / (env or "../shared/data")).resolve()
    assert str(root / "dechorate") in text
    assert ("is not set" in text) == (env is None)
    with pytest.raises(DataNotFoundError, match=r"RIR file missing\.npz does not exist"):
        load_rirs("missing.npz")


def test_cli_data_flag_missing(tmp_path, monkeypatch, capsys):
    """`bench xtdoa --data` takes a name too; a missing one is one line naming --data and the
    variable, exit 2."""
    monkeypatch.setenv(DATA_ENV, str(tmp_path))
    code = main(["bench", "xtdoa", "--data", "nowhere", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("rangeslam: error: --data nowhere")
    assert "RANGESLAM_DATA" in err
