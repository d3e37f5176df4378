"""``run_rirs(unknown_emission=True)`` on shoebox RIRs delayed by an unknown 1-200 samples: the
emission time's error against its reported std, whether the echoes' second pass ran, the status
and the worst wall.

    python benchmarks/bench_unknown_emission_run.py [--measured] [SEED ...]

Each seed draws 8 microphones and a loudspeaker in a 5.1 x 3.7 x 2.6 m shoebox
(``room_recording``, 48 kHz) and a delay uniform in [1, 200] samples; the RIRs are delayed by it
(``shift_signals``, band-limited) and run with ``unknown_emission=True`` (``--measured``: with
``MEASURED_RIR_OPTIONS``). Default seeds 900100-900111. Prints one Markdown table.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from _common import machine, markdown_table

from rangeslam.acoustics.deconvolution import shift_signals
from rangeslam.acoustics.pipeline import MEASURED_RIR_OPTIONS, run_rirs
from rangeslam.evaluation.truth import matched_wall_errors
from rangeslam.geometry.room import Room
from rangeslam.sim.recordings import room_recording

ROOM = Room.shoebox([5.1, 3.7, 2.6])


def one(seed: int, measured: bool) -> list[str]:
    """One seed's table row."""
    rng = np.random.default_rng(seed)
    rec = room_recording(ROOM, n_mics=8, rng=rng)
    delay = float(rng.uniform(1, 200))
    late = shift_signals(np.pad(rec.rirs, ((0, 0), (0, 210))), delay)
    opts = MEASURED_RIR_OPTIONS if measured else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = run_rirs(
            late, rec.fs, mics=rec.mics, c=rec.c, rng=seed, unknown_emission=True, **opts
        )
    err = res.emission_offsets[0] * rec.fs - delay
    std = res.emission_offset_stds[0] * rec.fs
    walls = (
        matched_wall_errors(res.wall_normals, res.wall_offsets, ROOM)
        if res.wall_normals is not None and len(res.wall_normals)
        else np.array([np.inf])
    )
    return [
        str(seed), f"{delay:.2f}", f"{err:+.3f}", f"{std:.3f}", f"{abs(err) / std:.1f}",
        "yes" if "second pass" in res.message else "no", res.status.name,
        f"{1e3 * np.max(walls):.2f}",
    ]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seeds", nargs="*", type=int, default=list(range(900100, 900112)))
    parser.add_argument("--measured", action="store_true", help="MEASURED_RIR_OPTIONS")
    args = parser.parse_args()
    header = [
        "seed", "delay [samples]", "offset error [samples]", "reported std [samples]",
        "error / std", "second pass", "status", "worst wall [mm]",
    ]  # fmt: skip
    print(markdown_table(header, [one(s, args.measured) for s in args.seeds]))
    print(f"\n{machine()}")


if __name__ == "__main__":
    main()
