"""``rangeslam run`` on pyroomacoustics RIRs written as pyroomacoustics makes them (every RIR
delayed by its fractional-delay filter, ``frac_delay_length // 2`` = 40 samples), and on files
with a wrong ``fs`` or microphones in millimetres: the exit code, the cause the input check named
(``rangeslam.acoustics.input_sanity``) and the worst wall found against the truth.

    python benchmarks/bench_run_input_sanity.py [--order N] [--mics M] [--only NAME] [SEED ...]

Each seed draws M microphones and a loudspeaker 0.5 m from the walls of the demo's shoebox
(5.1 x 3.7 x 2.6 m) and of its cut-corner room (a slanted wall and a sloping ceiling), simulates
them with pyroomacoustics directly (``pra.ShoeBox``, or ``pra.Room`` of the room's wall polygons;
absorption 0.2, 48 kHz) and writes the RIRs as they come, with the truth, to an npz. Variants:

- ``as they come``: the file as written; ``--unknown-emission``: the same run with the flag;
- ``fs / 3``: the same RIRs labelled 16 kHz; ``fs / 3, no delay``: the 40 samples cut first;
- ``mm``: the microphones (and the truth's source) in millimetres;
- ``no delay``: the 40 samples cut (the RIRs ``rangeslam simulate room`` writes);
- ``as they come, unchecked``: ``run_rirs(check_input=False)`` with the options ``rangeslam run``
  passes (``estimate_c``, seed 0): what the pipeline alone makes of them (exit: 0 converged).

Prints one Markdown table: exit code, converged, the cause named (the message's first clause),
the worst wall found (mm) and how many of the true walls were found.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np
from _common import machine, markdown_table

from rangeslam.app.cli import main as cli
from rangeslam.app.experiments import demo_rooms
from rangeslam.sim.scenes import random_points_in_room

FS = 48000
DELAY = 40  # pra.constants.get("frac_delay_length") // 2 with pyroomacoustics' defaults


def wall_polygons(room) -> list[np.ndarray]:
    """(n_k, 3) corners of each wall face of a convex ``room``, counter-clockwise about its
    outward normal (pyroomacoustics' wall order)."""
    verts, out = room.vertices, []
    for n, o in zip(room.normals, room.offsets, strict=True):
        on = verts[np.abs(verts @ n - o) <= 1e-6]
        centre = on.mean(axis=0)
        u = (on[0] - centre) / np.linalg.norm(on[0] - centre)
        v = np.cross(n, u)
        out.append(on[np.argsort(np.arctan2((on - centre) @ v, (on - centre) @ u))])
    return out


def pra_rirs(kind: str, seed: int, *, order: int, n_mics: int):
    """(rirs (M, L) as pyroomacoustics writes them, mics (M, 3), source (3,), room)."""
    import pyroomacoustics as pra

    room = demo_rooms()[kind]
    rng = np.random.default_rng(seed)
    mics = random_points_in_room(room, n_mics, margin=0.5, rng=rng)
    src = random_points_in_room(room, 1, margin=0.5, rng=rng)[0]
    if kind == "shoebox":
        size = room.vertices.max(axis=0)
        sim = pra.ShoeBox(size, fs=FS, materials=pra.Material(0.2), max_order=order)
    else:
        walls = [pra.wall_factory(p.T, [0.2], [0.0]) for p in wall_polygons(room)]
        sim = pra.Room(walls, fs=FS, max_order=order)
    sim.add_source(src)
    sim.add_microphone_array(mics.T)
    sim.compute_rir()
    rows = [np.asarray(sim.rir[m][0]) for m in range(n_mics)]
    rirs = np.zeros((n_mics, max(len(r) for r in rows)))
    for m, r in enumerate(rows):
        rirs[m, : len(r)] = r
    return rirs, mics, src, room


def variants(rirs, mics, src, room) -> dict[str, tuple[dict, list[str]]]:
    """Each variant's npz contents and extra flags of ``rangeslam run``."""
    truth = {"wall_normals": room.normals, "wall_offsets": room.offsets}
    base = {"rirs": rirs, "fs": float(FS), "mics": mics, "source": src, **truth}
    cut = rirs[:, DELAY:]
    return {
        "as they come": (base, []),
        "as they come --unknown-emission": (base, ["--unknown-emission"]),
        "fs / 3": ({**base, "fs": FS / 3.0}, []),
        "fs / 3, no delay": ({**base, "rirs": cut, "fs": FS / 3.0}, []),
        "mm": ({**base, "mics": 1e3 * mics, "source": 1e3 * src}, []),
        "no delay": ({**base, "rirs": cut}, []),
        "as they come, unchecked": (base, [UNCHECKED]),
    }


UNCHECKED = "(library, check_input=False)"


def run_unchecked(data: dict) -> list[str]:
    """``run_rirs`` without the input check: (exit as run's, converged, message, worst, found)."""
    import warnings

    from rangeslam.acoustics.pipeline import run_rirs
    from rangeslam.evaluation.truth import matched_wall_errors
    from rangeslam.geometry.room import Room

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = run_rirs(data["rirs"], data["fs"], mics=data["mics"], estimate_c=True, rng=0,
                       check_input=False)  # fmt: skip
    room = Room(data["wall_normals"], data["wall_offsets"])
    walls = np.full(room.n_walls, np.inf)
    if res.wall_normals is not None and len(res.wall_normals):
        walls = matched_wall_errors(res.wall_normals, res.wall_offsets, room)
    found = np.isfinite(walls)
    worst = f"{1e3 * walls[found].max():.1f}" if found.any() else "-"
    return [str(int(not res.converged)), str(res.converged), res.status.name, worst,
            f"{int(found.sum())}/{len(walls)}"]  # fmt: skip


def run_one(folder: Path, name: str, data: dict, flags: list[str]) -> list[str]:
    """``rangeslam run`` on one variant: (exit, converged, cause, worst wall mm, found)."""
    if flags == [UNCHECKED]:
        return run_unchecked(data)
    path = folder / f"{name.replace(' ', '_').replace('/', '')}.npz"
    np.savez(path, **data)
    out = folder / "out"
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli(["run", str(path), "--mics-from-npz", "--out", str(out), *flags])
    summary = json.loads((out / "run_summary.json").read_text()) if code in (0, 1) else {}
    walls = np.array(list(summary.get("wall_errors_m", {}).values()) or [np.inf], dtype=float)
    found = np.isfinite(walls)
    worst = f"{1e3 * walls[found].max():.1f}" if found.any() else "-"
    cause = "-" if code == 0 else summary.get("message", err.getvalue()).split(";")[0]
    cause = cause.split(":")[0].strip()
    return [str(code), str(summary.get("converged", "-")), cause, worst,
            f"{int(found.sum())}/{len(walls)}"]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seeds", nargs="*", type=int, default=[257065, 875883, 906975, 324436])
    parser.add_argument("--order", type=int, default=2, help="reflection order (default 2)")
    parser.add_argument("--mics", type=int, default=8, help="microphones (default 8)")
    parser.add_argument("--only", action="append", help="run only this file variant (repeat)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("shoebox", "cut corner"):
            for seed in args.seeds:
                scene = pra_rirs(kind, seed, order=args.order, n_mics=args.mics)
                for name, (data, flags) in variants(*scene).items():
                    if args.only and name not in args.only:
                        continue
                    rows.append([kind, str(seed), name, *run_one(Path(tmp), name, data, flags)])
                    print(" | ".join(rows[-1]), flush=True)
    header = ["room", "seed", "file", "exit", "converged", "cause named", "worst wall [mm]",
              "walls found"]  # fmt: skip
    print()
    print(markdown_table(header, rows))
    print(f"\n{machine()}; order {args.order}, {args.mics} microphones, {FS} Hz")


if __name__ == "__main__":
    main()
