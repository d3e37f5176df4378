"""``rangeslam run`` on whole sessions: several loudspeakers at one array (walls fitted jointly)."""

import json

import numpy as np
import pytest
from sessions import two_loudspeaker_session, wall_errors

from rangeslam import InvalidInputError
from rangeslam.acoustics.joint_room import match_walls
from rangeslam.acoustics.pipeline import run_loudspeakers
from rangeslam.app.cli import main
from rangeslam.status import Status

# Held out: WALL_MATCH_* were set looking at seeds 5 and 11; these were drawn after the code was
# written (secrets.randbelow(10**6)). SESSION_SEEDS for one session; SEEDS_AFTER_SHARED were drawn
# after shared walls (acoustics.shared_walls) and the 12-microphone session default (cut-corner
# 552463 then missed the cut wall, whose microphone triple was not among the 200 tried: every
# triple is tried since). The figures of benchmarks/README.md are on seeds drawn after that.
SESSION_SEEDS = {"shoebox": 494335, "cut-corner": 223953}
SEEDS_AFTER_SHARED = {"shoebox": (273337, 951864), "cut-corner": (552463, 942114)}
SESSIONS = [(room, seed) for room, seeds in SEEDS_AFTER_SHARED.items() for seed in seeds]
WALL_TOL = 0.01  # metres: the "all walls within 1 cm"
# The case, frozen: seed 0 at --c 345 found 5 of 6 images and threw them away. (A fresh
# seed, 989824, converged at --c 345 instead, with one wall wrong and the others 4-13 mm off.)
WRONG_C_SEED = 0


def _session(tmp_path, room: str, *extra: str, seed: int | None = None, mics: str | None = None):
    """Simulate a two-loudspeaker session (``seed``, default SESSION_SEEDS[room]; ``mics``,
    default simulate's) and run it (with ``extra`` flags); (exit code, record, the two npz)."""
    seed = SESSION_SEEDS[room] if seed is None else seed
    sim = [] if mics is None else ["--mics", mics]
    code, record, (a, b) = two_loudspeaker_session(tmp_path, room, seed, sim=sim, run=extra)
    np.testing.assert_array_equal(a["mics"], b["mics"])
    assert np.linalg.norm(a["source"] - b["source"]) > 0.3
    return code, record, (a, b)


@pytest.mark.parametrize(
    ("room", "seed"),
    # the first session in the default run, the others slow
    [SESSIONS[0], *(pytest.param(*s, marks=pytest.mark.slow) for s in SESSIONS[1:])],
)
def test_two_loudspeakers_through_run_give_every_wall(tmp_path, room, seed):
    """Two loudspeakers simulated by ``simulate room --sources 2`` (12 microphones) in a shoebox
    and in a non-box convex room (7 walls, one a 1.1 m cut corner), run together: converged,
    every true wall found within 1 cm, no other wall, both loudspeakers within 1 cm."""
    code, record, (a, b) = _session(tmp_path, room, seed=seed)
    assert len(a["mics"]) == 12
    assert code == 0 and record["converged"], record["message"]
    errors = wall_errors(record)
    assert len(errors) == len(a["wall_normals"]) == len(record["walls"])
    true = np.array([a["source"], b["source"]])
    assert np.allclose(record["sources"], true, atol=WALL_TOL)
    assert np.all(errors <= WALL_TOL), errors


@pytest.mark.slow
def test_a_wall_each_loudspeaker_hears_at_three_microphones_is_found_jointly(tmp_path):
    """Frozen: cut-corner session 618300 at 8 microphones, whose cut wall each loudspeaker hears
    cleanly at 3 microphones only (it was left out, and the run said converged with 6 walls).
    Found jointly from the 6 echoes (and said so): converged, all 7 walls within 1 cm."""
    code, record, _ = _session(tmp_path, "cut-corner", seed=618300, mics="8")
    assert code == 0 and record["converged"], record["message"]
    assert "found jointly" in record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 7 and np.all(errors <= WALL_TOL), errors


def test_several_files_need_one_kind(tmp_path):
    """An .npz among WAV files is refused naming RIRS (exit 2)."""
    stem = tmp_path / "s.npz"
    assert main(["simulate", "room", "--mics", "5", "--sources", "2", "--out", str(stem)]) == 0
    wav = tmp_path / "x.wav"
    wav.write_bytes(b"")
    assert main(["run", str(tmp_path / "s-src0.npz"), str(wav), "--out", str(tmp_path)]) == 2


def test_match_walls_pairs_the_same_wall():
    """Walls within the match limits are one wall, whatever their order; others stay apart."""
    n0 = np.eye(3)
    n1 = np.array([[0, 0, 1.0], [1, 0, 0], [0, -1.0, 0]])
    cols = match_walls([n0, n1], [np.array([5.0, 3.0, 2.5]), np.array([2.52, 5.01, 0.0])])
    assert cols.tolist() == [[1, 2, 3, 0], [2, 0, 1, 3]]


def test_run_loudspeakers_refuses_wrong_sets():
    """A set with another count of RIRs than microphones is refused naming it."""
    from rangeslam.acoustics.pipeline import run_loudspeakers

    mics = np.random.default_rng(0).uniform(0, 1, (5, 3))
    with pytest.raises(InvalidInputError, match=r"rir_sets\[1\]"):
        run_loudspeakers([np.ones((5, 100)), np.ones((4, 100))], 16000, mics=mics)


def test_failed_labelling_keeps_and_reports_the_walls_it_found(tmp_path):
    """RIRs simulated at c = 343 m/s run with --c 345 --fixed-c: whatever the labelling found is kept (its
    walls in the summary, the CSV and the record), and the run says not converged, with why."""
    path = tmp_path / "room.npz"
    assert main(["simulate", "room", "--seed", str(WRONG_C_SEED), "--out", str(path)]) == 0
    assert float(np.load(path)["c"]) == 343.0
    out = tmp_path / "out"
    code = main(["run", str(path), "--c", "345", "--fixed-c", "--out", str(out)])
    record = json.loads((out / "run_summary.json").read_text())
    assert code == 1 and not record["converged"]
    assert "did not converge" in record["message"]
    assert len(record["walls"]) >= 1
    assert (out / "run_walls.csv").is_file()


def test_room_from_rirs_keeps_the_walls_of_a_labelling_short_of_n_images(rng):
    """Asked for 7 images in a shoebox (6 exist): NOT_IDENTIFIABLE, and the 6 walls it found are
    reconstructed and kept, each within 1 mm of a true wall (zero noise)."""
    from rangeslam.acoustics.labelling import room_from_rirs
    from rangeslam.evaluation.truth import matched_wall_errors
    from rangeslam.geometry.room import Room
    from rangeslam.sim.recordings import room_recording

    room = Room.shoebox([5.1, 3.7, 2.6])
    rec = room_recording(room, n_mics=8, rng=rng)
    res = room_from_rirs(
        rec.rirs, rec.fs, rec.mics, c=rec.c, rng=rng, label_options={"n_images": 7}
    )
    assert res.status is Status.NOT_IDENTIFIABLE and "did not converge" in res.message
    walls = res.reconstruction
    assert walls is not None and len(walls.wall_normals) == 6
    errors = matched_wall_errors(walls.wall_normals, walls.wall_offsets, room)
    assert np.all(errors <= 1e-3), errors


# Drawn after estimate_c was written (seeds 0 and 989824 were the ones looked at).
C_SEEDS = {"shoebox": 378557, "cut-corner": 417048}


@pytest.mark.parametrize("room", ["shoebox", pytest.param("cut-corner", marks=pytest.mark.slow)])
def test_run_estimates_the_speed_of_sound(tmp_path, room):
    """RIRs simulated at c = 343 m/s run with --c 345 (a 3.5 degC error): c estimated within
    1 m/s (and within 3 of its reported standard deviations, floored at 1 mm/s), converged, the
    loudspeaker and every wall found within 1 cm."""
    path = tmp_path / "room.npz"
    sim = ["simulate", "room", "--room", room, "--seed", str(C_SEEDS[room])]
    assert main([*sim, "--out", str(path)]) == 0
    truth = np.load(path)
    out = tmp_path / "out"
    code = main(["run", str(path), "--c", "345", "--out", str(out)])
    record = json.loads((out / "run_summary.json").read_text())
    assert code == 0 and record["converged"], record["message"]
    error = abs(record["c_estimated"] - float(truth["c"]))
    assert error <= 1.0 and error <= 3 * max(record["c_std"], 1e-3)
    assert record["source_error_m"] <= WALL_TOL
    errors = wall_errors(record)
    assert np.all(errors[np.isfinite(errors)] <= WALL_TOL), errors
    assert np.isfinite(errors).sum() >= 6


def test_estimate_sound_speed_under_noise_is_within_its_stated_spread():
    """Direct paths with 1 mm of Gaussian range noise at 12 microphones: over 40 draws the c
    error is within 3 reported standard deviations in at least 36, and the RMS error within a
    factor 1.5 of the RMS reported deviation."""
    from rangeslam.acoustics.echoes import EchoDetection
    from rangeslam.acoustics.sound_speed import estimate_sound_speed

    gen = np.random.default_rng(735286)
    c, errs, stds = 343.0, [], []
    for _ in range(40):
        mics = gen.uniform([0.5, 0.5, 0.5], [4.5, 3.5, 2.0], (12, 3))
        src = gen.uniform([0.5, 0.5, 0.5], [4.5, 3.5, 2.0])
        t = (np.linalg.norm(mics - src, axis=1) + gen.normal(0, 1e-3, 12)) / c
        dets = [
            EchoDetection(
                times=np.array([ti]), amplitudes=np.ones(1), direct=0, noise_level=0.0,
                threshold=0.0, fs=48000.0,
            )
            for ti in t
        ]  # fmt: skip
        est = estimate_sound_speed(dets, mics, c0=345.0)
        assert est.converged, est.message
        errs.append(est.c - c)
        stds.append(est.c_std)
    errs, stds = np.array(errs), np.array(stds)
    assert (np.abs(errs) <= 3 * stds).sum() >= 36
    rms, rms_std = np.sqrt(np.mean(errs**2)), np.sqrt(np.mean(stds**2))
    assert rms_std / 1.5 <= rms <= 1.5 * rms_std


@pytest.mark.slow
def test_two_loudspeakers_estimate_the_speed_of_sound_together(tmp_path):
    """The shoebox session simulated at 343 m/s run with --c 345: c from both loudspeakers'
    direct paths within 1 m/s, converged, every wall within 1 cm."""
    code, record, (a, _) = _session(tmp_path, "shoebox", "--c", "345")
    assert code == 0 and record["converged"], record["message"]
    assert abs(record["c_estimated"] - float(a["c"])) <= 1.0
    errors = wall_errors(record)
    assert len(errors) == 6 and np.all(errors <= WALL_TOL), errors


def test_a_wrong_wall_one_loudspeaker_labelled_is_left_out(tmp_path, monkeypatch):
    """Frozen: shoebox session 618299 (8 microphones), where loudspeaker 0 labelled a plane 0.6 m above the
    ceiling as a wall, so the 7 walls matched did not bound a room (not converged). That wall,
    labelled by one loudspeaker only, is left out and said so: converged, 6 walls within 1 cm."""
    monkeypatch.setitem(SESSION_SEEDS, "shoebox", 618299)
    code, record, _ = _session(tmp_path, "shoebox", mics="8")
    assert code == 0 and "left out wall" in record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 6 and np.all(errors <= WALL_TOL), errors


def test_a_session_whose_echoes_give_no_room_is_not_converged(tmp_path):
    """Frozen: shoebox session 462163 recorded as sweeps with noise 0.3, where loudspeaker 0
    labels no echo and loudspeaker 1 one wall: the one wall, labelled by one loudspeaker, was
    left out to look for a room without it, and the empty range matrix raised InvalidInputError
    (exit 2). Now a result that is not converged (exit 1) naming the wall found and why, each
    loudspeaker in its own row."""
    stem = tmp_path / "s.npz"
    sim = ["simulate", "room", "--sources", "2", "--seed", "462163", "--recordings", "sweep"]
    assert main([*sim, "--noise", "0.3", "--out", str(stem)]) == 0
    files = [str(tmp_path / f"s-src{j}.npz") for j in range(2)]
    out = tmp_path / "out"
    assert main(["run", *files, "--out", str(out)]) == 1
    record = json.loads((out / "run_summary.json").read_text())
    assert not record["converged"]
    assert "1 walls found do not bound a room" in record["message"], record["message"]
    assert len(record["walls"]) == 1
    # loudspeaker 1 alone was located: its row, not loudspeaker 0's (row 0 once held it)
    assert record["sources"][0] is None
    true1 = np.load(files[1])["source"]
    assert np.linalg.norm(np.array(record["sources"][1]) - true1) <= WALL_TOL


@pytest.mark.slow
def test_a_wall_the_other_loudspeaker_does_not_hear_is_left_out(tmp_path):
    """Frozen: cut-corner session 241681 at 8 microphones, where loudspeaker 0 alone labelled a
    plane 237 mm off the cut wall (from 5 microphones) and the run said converged. Loudspeaker
    1's image in that plane predicts echoes at 2 microphones whose specular points lie on its
    face, and its detections hold neither: the plane is left out (and said so), its peaks are
    searched again, and the cut wall is found jointly: converged, all 7 walls within 1 cm."""
    code, record, _ = _session(tmp_path, "cut-corner", seed=241681, mics="8")
    assert code == 0 and record["converged"], record["message"]
    assert "echoes of it are absent at 2 of the 2" in record["message"], record["message"]
    assert "found jointly" in record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 7 and np.all(errors <= WALL_TOL), errors


@pytest.mark.slow
def test_measured_preset_runs_several_loudspeakers(tmp_path):
    """``run A.npz B.npz --measured`` (each loudspeaker's RIRs matched-filtered with its own
    direct sound, the measured preset's detection and 4 cm labelling tolerance) on a simulated
    shoebox session: converged, every wall within 1 cm, both loudspeakers within 1 cm. It was
    refused ("--measured takes one loudspeaker")."""
    code, record, (a, b) = _session(tmp_path, "shoebox", "--measured")
    assert code == 0 and record["converged"], record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 6 and np.all(errors <= WALL_TOL), errors
    assert np.allclose(record["sources"], [a["source"], b["source"]], atol=WALL_TOL)


def test_run_loudspeakers_passes_the_direct_template_on(rng):
    """A direct template reaches each loudspeaker's detection (a reversed window is refused
    naming it), and is refused with ``estimate_c`` (c from the direct paths is for RIRs that are
    not matched-filtered), both as InvalidInputError."""
    mics = rng.uniform(0.5, 2.5, size=(6, 3))
    rirs = rng.standard_normal((6, 400))
    with pytest.raises(InvalidInputError, match="direct_template must be"):
        run_loudspeakers([rirs, rirs], 48000.0, mics=mics, direct_template=(0.001, -0.001))
    with pytest.raises(InvalidInputError, match="estimate_c is for RIRs without direct_template"):
        run_loudspeakers(
            [rirs, rirs], 48000.0, mics=mics, direct_template=(1e-4, 1e-3), estimate_c=True
        )


@pytest.mark.slow
def test_a_wall_left_out_whose_echoes_stay_unexplained_is_not_converged(tmp_path):
    """Frozen: cut-corner session 272702 at 8 microphones (held out from the first rule, which
    checked only the other loudspeaker's echoes: 1 predicted, and said converged with a 7th wall
    205 mm off). Loudspeaker 1 alone labelled that plane; its own and loudspeaker 0's predicted
    echoes of it are absent, so it is left out; its image is then no higher-order image of the
    6 walls found and the cut wall is not found jointly, so its echoes stay unexplained: not
    converged (exit 1), the 6 walls reported all right."""
    code, record, _ = _session(tmp_path, "cut-corner", seed=272702, mics="8")
    assert code == 1 and not record["converged"], record["message"]
    assert "echoes of it are absent" in record["message"], record["message"]
    assert "stay unexplained" in record["message"], record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 6 and np.all(errors[np.isfinite(errors)] <= WALL_TOL), errors


@pytest.mark.parametrize(
    ("seed", "n_walls"),
    [
        # Frozen: the cut wall heard at 4 + 1 echoes in all (5 < JOINT_WALL_RANGES): converged
        # with 6 walls, the cut wall missing although the message named its echoes.
        pytest.param(762848, 6, marks=pytest.mark.slow),
        # Frozen: shared_walls added a plane 261 mm off the cut wall (5 + 1 echoes) while the
        # cut wall's own 5 echoes (3 + 2) were named as unexplained: converged and wrong.
        (487130, 7),
    ],
)
def test_echoes_left_unexplained_make_the_run_not_converged(tmp_path, seed, n_walls):
    """Cut-corner sessions at 8 microphones whose leftover echoes fit a wall that too few echoes
    confirm (5, 6 needed) and the predicted echoes do not deny: the echo set is named as left
    unexplained and the run is not converged (exit 1), the walls found kept. Both said converged
    with a wall missing or wrong before."""
    code, record, _ = _session(tmp_path, "cut-corner", seed=seed, mics="8")
    assert code == 1 and not record["converged"], record["message"]
    assert "echoes left unexplained" in record["message"], record["message"]
    assert len(record["walls"]) == n_walls


@pytest.mark.slow
def test_an_echo_set_the_predicted_echoes_deny_is_not_left_unexplained(tmp_path):
    """Frozen: cut-corner session 762848 at 12 microphones, every wall right, where 5 leftover
    echoes (2 + 3) fit a plane through the room (normal [-0.66, 0.72, -0.19]) and were named as
    left unexplained. Its image predicts 17 echoes on its face where the loudspeakers hear walls;
    12 are absent (34-203 mm from every peak), so it is no wall: no note, converged, all 7 walls
    within 1 cm."""
    code, record, _ = _session(tmp_path, "cut-corner", seed=762848)
    assert code == 0 and record["converged"], record["message"]
    assert "echoes left unexplained" not in record["message"], record["message"]
    errors = wall_errors(record)
    assert len(record["walls"]) == 7 and np.all(errors <= WALL_TOL), errors
