"""SOFA files (AES69) of RIRs, read with sofar: the same RIRs, microphones, source and room as
the .npz they were written beside, so the same room from `rangeslam run`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rangeslam.datasets import load_rirs
from rangeslam.errors import DataFormatError
from rangeslam.sim.rir import shoebox_rirs

sofar = pytest.importorskip("sofar")

FS = 48000
SIZE = np.array([6.0, 4.5, 3.0])
C = 343.0


def scene(rng):
    """(source (3,), listener (3,), receivers (10, 3) in the listener's frame, rirs (10, L)):
    test_run's scene, with the array given as a listener and receivers around it."""
    src = rng.uniform([0.8, 0.8, 0.8], SIZE - 0.8)
    centre = rng.uniform([1.5, 1.5, 1.0], SIZE - [1.5, 1.5, 1.0])
    local = rng.uniform(-0.3, 0.3, (10, 3))
    return src, centre, local


def write_sofa(path, rirs, src, listener, local, *, view=(1.0, 0.0, 0.0), delay=None):
    """A SingleRoomSRIR file as sofar writes it: one measurement, R receivers (cartesian,
    relative to the listener), the shoebox's corners."""
    s = sofar.Sofa("SingleRoomSRIR")
    r = len(local)
    s.Data_IR = rirs[None, :, :]
    s.Data_SamplingRate = FS
    s.Data_Delay = np.zeros((1, r)) if delay is None else np.asarray(delay, float)[None, :]
    s.ListenerPosition = np.asarray(listener)[None, :]
    s.ListenerView = np.asarray(view)[None, :]
    s.SourcePosition = np.asarray(src)[None, :]
    s.ReceiverPosition = np.asarray(local)[:, :, None]
    s.ReceiverPosition_Type, s.ReceiverPosition_Units = "cartesian", "metre"
    s.ReceiverView = np.tile([1.0, 0.0, 0.0], (r, 1))[:, :, None]
    s.ReceiverUp = np.tile([0.0, 0.0, 1.0], (r, 1))[:, :, None]
    # sofar 1.3 with netCDF4 1.7.5 and numpy 2.4 cannot write the optional string arrays
    # (AttributeError in netCDF4.stringtochar); they say nothing this reader uses
    s.delete("ReceiverDescriptions")
    s.delete("EmitterDescriptions")
    s.RoomCornerA, s.RoomCornerB = np.zeros((1, 3)), SIZE[None, :]
    sofar.write_sofa(str(path), s)
    return path


def test_sofa_loads_as_its_npz(rng, tmp_path):
    """The RIRs, sampling rate, microphones (listener + receivers), source and room size of a
    SOFA file equal those of the .npz of the same simulation (sofar stores float64: exact)."""
    src, listener, local = scene(rng)
    mics = listener + local
    rirs = shoebox_rirs(SIZE, src, mics, fs=FS, absorption=0.2, max_order=1)
    np.savez(tmp_path / "r.npz", rirs=rirs, fs=FS, mics=mics, source=src, room_size=SIZE)
    from_npz = load_rirs(tmp_path / "r.npz")
    from_sofa = load_rirs(write_sofa(tmp_path / "r.sofa", rirs, src, listener, local))
    np.testing.assert_array_equal(from_sofa.rirs, from_npz.rirs)
    assert from_sofa.fs == from_npz.fs == FS
    np.testing.assert_allclose(from_sofa.mics, from_npz.mics, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(from_sofa.source, src)
    np.testing.assert_array_equal(from_sofa.room_size, SIZE)
    assert from_sofa.names[3] == "r.sofa:Data_IR[0, 3]"


def test_listener_view_and_delays(rng, tmp_path):
    """A listener looking along +y turns its receivers by 90 degrees; whole-sample delays
    put that many zeros before each RIR (sample 0 stays the emission)."""
    src, listener, local = scene(rng)
    rirs = rng.normal(size=(10, 50))
    path = write_sofa(tmp_path / "v.sofa", rirs, src, listener, local, view=(0.0, 2.0, 0.0),
                      delay=np.arange(10))  # fmt: skip
    loaded = load_rirs(path)
    turned = np.column_stack([-local[:, 1], local[:, 0], local[:, 2]])
    np.testing.assert_allclose(loaded.mics, listener + turned, atol=1e-12)
    assert loaded.rirs.shape == (10, 59)
    np.testing.assert_array_equal(loaded.rirs[3, 3:53], rirs[3])
    assert not loaded.rirs[3, :3].any() and not loaded.rirs[3, 53:].any()


def test_bad_sofa_files_are_named(rng, tmp_path):
    """Not a SOFA file, fractional delays, and an fs that contradicts the file are refused
    naming the file."""
    (tmp_path / "x.sofa").write_bytes(b"not netcdf")
    with pytest.raises(DataFormatError, match=r"x.sofa: not a SOFA file sofar can read"):
        load_rirs(tmp_path / "x.sofa")
    src, listener, local = scene(rng)
    rirs = rng.normal(size=(10, 50))
    bad = write_sofa(tmp_path / "d.sofa", rirs, src, listener, local, delay=np.full(10, 0.5))
    with pytest.raises(DataFormatError, match=r"d.sofa: Data_Delay must be whole samples"):
        load_rirs(bad)
    good = write_sofa(tmp_path / "g.sofa", rirs, src, listener, local)
    with pytest.raises(DataFormatError, match=r"g.sofa: fs is 48000 Hz, but fs=16000"):
        load_rirs(good, fs=16000)


@pytest.mark.slow
def test_cli_run_gives_the_same_room_from_sofa_and_npz(rng, tmp_path, capsys):
    """`rangeslam run r.sofa` and `rangeslam run r.npz` on the same simulation give the same
    walls and source and both converge (about 10 s); each summary names where the microphones
    came from (the npz, the sofa file)."""
    from rangeslam.app.cli import main

    src, listener, local = scene(rng)
    mics = listener + local
    rirs = shoebox_rirs(SIZE, src, mics, fs=FS, absorption=0.2, max_order=3)
    np.savez(tmp_path / "r.npz", rirs=rirs, fs=FS, mics=mics, source=src, room_size=SIZE)
    write_sofa(tmp_path / "r.sofa", rirs, src, listener, local)
    out = {}
    for name in ("r.npz", "r.sofa"):
        assert (
            main(["run", str(tmp_path / name), "--c", str(C), "--out", str(tmp_path / name[2:])])
            == 0
        )
        out[name] = json.loads((tmp_path / name[2:] / "run_summary.json").read_text())
        assert f"mics from the {name[2:]}" in capsys.readouterr().out
    a, b = out["r.npz"], out["r.sofa"]
    assert a["converged"] and b["converged"]
    np.testing.assert_allclose(b["source"], a["source"], atol=1e-9)
    for wall, err in a["wall_errors_m"].items():
        assert abs(b["wall_errors_m"][wall] - err) < 1e-9
