"""`rangeslam run` on simulated sessions: two loudspeakers jointly, and the speed of sound.

    python benchmarks/bench_run_sessions.py --seed 618299 --sessions 8
    python benchmarks/bench_run_sessions.py --seed 532865 --sessions 6 --what c --noise 0.01

``--what sessions`` (default): for each room (shoebox, cut-corner) and seed, ``rangeslam simulate
room --sources 2`` then ``rangeslam run`` on both files; prints each true wall's error (mm; inf:
not found) and the walls found, and counts converged with every wall within 1 cm (and no other
wall), and converged with a wall missed, off or extra. ``--what c``: ``simulate room`` (one
loudspeaker, c = 343 m/s) then ``run --c 345``; prints the estimated c, its reported standard
deviation and the worst wall. ``--mics M``: simulate's ``--mics`` (default: simulate's own).
``--what visibility``: how many loudspeaker-microphone pairs hear the cut corner's wall at all.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from rangeslam.app.cli import main as cli

WALL_TOL = 0.01


def _quiet(argv: list[str]) -> int:
    """Run the CLI with its output swallowed; its exit code."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return cli(argv)


def _record(out: Path) -> tuple[dict, np.ndarray]:
    """The run's JSON record and its (W,) wall errors in metres (inf: not found)."""
    rec = json.loads((out / "run_summary.json").read_text())
    errs = np.array([np.inf if v is None else v for v in rec["wall_errors_m"].values()])
    return rec, errs


def sessions(tmp: Path, seeds: list[int], noise: str, mics: list[str]) -> None:
    """Two-loudspeaker sessions in both rooms (``mics``: ["--mics", M] or [], the default)."""
    for room in ("shoebox", "cut-corner"):
        good = wrong = 0
        for seed in seeds:
            stem = tmp / f"{room}-{seed}.npz"
            sim = ["simulate", "room", "--room", room, "--sources", "2", "--seed", str(seed)]
            _quiet([*sim, *mics, "--noise", noise, "--out", str(stem)])
            files = [str(stem.with_name(f"{stem.stem}-src{j}.npz")) for j in range(2)]
            out = tmp / f"out-{room}-{seed}"
            code = _quiet(["run", *files, "--out", str(out)])
            rec, errs = _record(out)
            msg = rec["message"]
            extra = len(rec["walls"]) - len(errs)  # walls found beyond the true ones
            ok = rec["converged"] and bool(np.all(errs <= WALL_TOL)) and extra <= 0
            good += ok
            wrong += rec["converged"] and not ok
            print(
                f"{room} {seed}: exit {code}, walls [mm] {np.round(errs * 1e3, 2).tolist()}, "
                f"{len(rec['walls'])} found"
                + ("; a wall left out as contradicted" if "echoes of it are absent" in msg else "")
                + ("; echoes left unexplained" if "echoes left unexplained" in msg else "")
            )
        print(
            f"{room}: converged with every wall within 1 cm {good}/{len(seeds)}; converged with a "
            f"wall missed, off or extra {wrong}/{len(seeds)}"
        )


def speed(tmp: Path, seeds: list[int], noise: str, mics: list[str]) -> None:
    """One loudspeaker at 343 m/s run with --c 345."""
    for seed in seeds:
        path = tmp / f"c-{seed}.npz"
        sim = ["simulate", "room", "--seed", str(seed), *mics, "--noise", noise]
        _quiet([*sim, "--out", str(path)])
        out = tmp / f"out-c-{seed}"
        code = _quiet(["run", str(path), "--c", "345", "--out", str(out)])
        rec, errs = _record(out)
        c_err = rec.get("c_estimated", np.nan) - 343.0
        print(
            f"seed {seed} noise {noise}: exit {code}, converged {rec['converged']}, c error "
            f"{c_err:+.4f} m/s (reported std {rec.get('c_std', np.nan):.2g}), worst wall "
            f"{errs.max() * 1e3:.2f} mm"
        )


def visibility(seed: int, scenes: int = 2000) -> None:
    """Geometry only: over random scenes of two loudspeakers (margin 0.5 m, as simulate), the
    loudspeaker-microphone pairs whose specular point on the cut corner's wall is on its face
    (the pairs that hear that echo at all), for 8, 12 and 16 microphones."""
    from rangeslam.app.experiments import demo_rooms
    from rangeslam.sim.scenes import random_points_in_room

    room = demo_rooms()["cut corner"]
    n, o = room.normals[6], room.offsets[6]
    rng = np.random.default_rng(seed)
    for m_n in (8, 12, 16):
        pairs = []
        for _ in range(scenes):
            mics = random_points_in_room(room, m_n, margin=0.5, rng=rng)
            heard = 0
            for s in random_points_in_room(room, 2, margin=0.5, rng=rng):
                img = s - 2.0 * (n @ s - o) * n
                t = (o - mics @ n) / ((img - mics) @ n)
                q = mics + t[:, None] * (img - mics)
                heard += int(np.all(q @ room.normals.T <= room.offsets + 1e-9, axis=1).sum())
            pairs.append(heard)
        pairs = np.array(pairs)
        print(
            f"{m_n} microphones: the cut wall heard by fewer than 4 pairs in "
            f"{np.mean(pairs < 4):.1%} of {scenes} scenes, fewer than 6 in {np.mean(pairs < 6):.1%}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=618299, help="first seed")
    ap.add_argument("--sessions", type=int, default=8, help="seeds: seed, seed + 1, ...")
    ap.add_argument("--what", choices=("sessions", "c", "visibility"), default="sessions")
    ap.add_argument("--noise", default="0", help="simulate --noise (fraction of the peak)")
    ap.add_argument("--mics", default=None, help="simulate --mics (default: simulate's)")
    args = ap.parse_args()
    if args.what == "visibility":
        visibility(args.seed)
        return
    seeds = list(range(args.seed, args.seed + args.sessions))
    with tempfile.TemporaryDirectory() as tmp:
        mics = [] if args.mics is None else ["--mics", args.mics]
        (sessions if args.what == "sessions" else speed)(Path(tmp), seeds, args.noise, mics)


if __name__ == "__main__":
    main()
