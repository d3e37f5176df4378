"""``rangeslam bench``: plan, run and write a benchmark (Fig. 3, Fig. 5, compare, Plaza, xtdoa).

Each command here parses nothing and computes nothing: it calls the benchmarks-as-library
(:mod:`rangeslam.app.benchmarking`, :mod:`rangeslam.app.plaza_bench`,
:mod:`rangeslam.app.xtdoa_bench`) and writes what they return.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["bench", "run_bench", "run_plaza_bench", "run_regimes_bench", "run_xtdoa_bench"]


def bench(args: argparse.Namespace) -> int:
    """``rangeslam bench EXPERIMENT``: the Plaza bench, or a simulated one with the parsed
    options."""
    from rangeslam.app.benchmarking import BOUND_SETTINGS

    if args.which == "plaza":
        return run_plaza_bench(args)
    if args.which == "xtdoa":
        return run_xtdoa_bench(args)
    if args.which == "pyfg":
        from rangeslam.app.pyfg_bench import run_pyfg_bench

        return run_pyfg_bench(args)
    if getattr(args, "regimes", False):
        return run_regimes_bench(args)
    slam = {}
    if args.which != "fig3":
        slam = dict(steps=args.steps, bounds=BOUND_SETTINGS[args.bounds], placement=args.placement)
    return run_bench(
        args.which,
        trials=args.trials,
        seed=args.seed,
        out=args.out,
        jobs=args.jobs,
        scheduler=args.scheduler,
        sigmas=args.sigmas,
        tum=args.tum,
        **slam,
    )


def run_bench(
    which: str,
    *,
    trials: int,
    seed: int,
    out: Path,
    jobs: int = 1,
    scheduler: str | None = None,
    sigmas=None,
    steps=None,
    bounds=(True, False),
    placement: str = "random",
    tum: bool = False,
    label: str | None = None,
) -> int:
    """Plan, run and write a benchmark: CSV per trial (rewritten as trials finish, so a run
    stopped late keeps what it finished), timings, JSON and Markdown summaries, a plot,
    optionally TUM trajectories. Shows progress on standard error (named ``label``, default
    ``which``); prints the Markdown table. Returns 0, or 1 when every trial failed (the reasons
    are in the CSV's status column)."""
    from rangeslam.app import benchmarking as bm
    from rangeslam.app.progress import Progress

    plan = bm.plan(
        which, trials, seed, sigmas=sigmas, steps=steps, bounds=bounds, placement=placement
    )
    t0 = time.perf_counter()
    finished: list = []

    def keep(outcome) -> None:
        finished.append(outcome)
        _write_trial_csvs(out, which, finished)

    outcomes = bm.run_trials(
        plan,
        jobs=jobs,
        scheduler=scheduler,
        keep_trajectories=tum,
        progress=Progress(len(plan), label or which),
        on_outcome=keep,
    )
    wall = time.perf_counter() - t0
    written = _write_trial_csvs(out, which, outcomes)
    written += _write_bench_summary(
        out, which, outcomes, wall=wall, seed=seed, trials=trials, jobs=jobs, scheduler=scheduler
    )
    rows = [o.row for o in outcomes]
    written.append(_plot_bench(out, which, rows))
    if tum:
        written.append(_write_bench_tum(out, which, outcomes))
    return _finish("trials", rows, wall=wall, seed=seed, written=written)


def _write_bench_summary(out: Path, which: str, outcomes, *, wall: float, seed: int, **run):
    """The Markdown table (printed and written) and the JSON summary of a finished run."""
    from rangeslam.app import benchmarking as bm

    rows = [o.row for o in outcomes]
    header, table, records = bm.summary_table(which, rows, [o.seconds for o in outcomes])
    text = bm.markdown(header, table)
    markdown_path = out / f"{which}_summary.md"
    markdown_path.write_text(text + "\n")
    print(text)
    json_path = bm.write_summary(
        out / f"{which}_summary.json",
        bench=which,
        seed=seed,
        trials_per_cell=run["trials"],
        jobs=run["jobs"],
        scheduler=run["scheduler"],
        failed_trials=sum(r["status"] != "ok" for r in rows),
        wall_seconds=wall,
        versions=bm.versions(),
        cells=records,
    )
    return [markdown_path, json_path]


def _write_trial_csvs(out: Path, which: str, outcomes) -> list[Path]:
    """The per-trial CSV (deterministic values, in the plan's order) and the timings CSV (wall
    times apart)."""
    from rangeslam.app.reports import write_csv

    ordered = sorted(outcomes, key=lambda o: (o.row["cell"], o.row["trial"]))
    rows = [o.row for o in ordered]
    timings = [{"cell": o.row["cell"], "trial": o.row["trial"], **o.seconds} for o in ordered]
    return [
        write_csv(out / f"{which}_trials.csv", rows),
        write_csv(out / f"{which}_timings.csv", timings),
    ]


def _plot_bench(out: Path, which: str, rows: list[dict]) -> Path:
    """The run's figure: Fig. 3 (error against noise) or Fig. 5 (error against steps)."""
    from rangeslam.app import benchmarking as bm
    from rangeslam.app.plotting import plot_fig3, plot_fig5

    if which == "fig3":
        return plot_fig3(out / "fig3.png", rows)
    names = {m: bm.METHOD_NAMES[m] for m in bm.bench_methods(which)}
    return plot_fig5(out / f"{which}.png", rows, names)


def _write_bench_tum(out: Path, which: str, outcomes) -> Path:
    """Every kept trajectory of the run in the TUM format, in ``out/tum``."""
    from rangeslam.app.reports import write_tum

    folder = out / "tum"
    folder.mkdir(exist_ok=True)
    for o in outcomes:
        for name, x in (o.trajectories or {}).items():
            write_tum(folder / f"{which}_cell{o.row['cell']}_trial{o.row['trial']}_{name}.tum", x)
    return folder


def run_plaza_bench(args: argparse.Namespace) -> int:
    """Every method on a Plaza data set, the cost against length, a plot; CSV, JSON, Markdown,
    each CSV rewritten as runs finish; progress on standard error."""
    from rangeslam.app import plaza_bench as pb
    from rangeslam.app.progress import Progress
    from rangeslam.app.reports import write_csv
    from rangeslam.datasets import plaza

    dataset = plaza(args.dataset)
    out, stem = args.out, f"plaza_{dataset.name}"
    lengths = args.lengths or []
    n_runs = len(pb.method_runs(args.methods, args.trials)) + 2 * len(lengths)
    t0 = time.perf_counter()
    kept: dict = {}
    with Progress(n_runs, f"{dataset.name}", unit="runs", min_interval=0.0) as progress:
        rows = pb.method_rows(
            dataset,
            trials=args.trials,
            seed=args.seed,
            methods=args.methods,
            keep=kept,
            progress=progress,
            on_row=lambda r: write_csv(out / f"{stem}_methods.csv", r),
        )
        length_rows = pb.length_rows(
            dataset,
            lengths,
            seed=args.seed,
            progress=progress,
            on_row=lambda r: write_csv(out / f"{stem}_lengths.csv", r),
        )
    wall = time.perf_counter() - t0
    written = [out / f"{stem}_methods.csv"] + ([out / f"{stem}_lengths.csv"] if lengths else [])
    written += _write_plaza_outputs(args, dataset, rows, length_rows, kept, wall)
    return _finish("runs", rows, wall=wall, seed=args.seed, written=written)


def run_regimes_bench(args: argparse.Namespace) -> int:
    """The regime map (:mod:`rangeslam.app.regime_map`), SLAM then calibration: a CSV row per
    trial (rewritten as trials finish), a Markdown table per figure of merit (printed and
    written), the SLAM figures; progress on standard error."""
    from rangeslam.app.benchmarking import FIG5_STEPS
    from rangeslam.app.calibration_regimes import (
        CALIBRATION_METHODS,
        calibration_cells,
        run_calibration_trial,
    )
    from rangeslam.app.regime_map import MERITS, criterion_table, regime_tables
    from rangeslam.app.regime_plot import plot_regimes
    from rangeslam.app.regimes import REGIME_STEPS, regime_cells
    from rangeslam.app.reports import markdown

    steps = REGIME_STEPS if args.steps == list(FIG5_STEPS) else args.steps
    slam_cells, cal_cells = regime_cells(steps, args.sigmas), calibration_cells(args.sigmas)
    t0 = time.perf_counter()
    slam_rows = _map_with_progress(args, slam_cells, "regimes", None)
    cal_rows = _map_with_progress(args, cal_cells, "regimes_calibration", run_calibration_trial)
    wall = time.perf_counter() - t0
    cal_merits = [t for t in MERITS if "landmark" not in t]
    criterion = "does the EDM start lead? (success, 90th percentile)"
    sections = [("SLAM", [(criterion, *criterion_table(slam_rows)), *regime_tables(slam_rows)])]
    cal_criterion = criterion_table(cal_rows, "calibrate", CALIBRATION_METHODS, "ls_k")
    cal_tables = regime_tables(cal_rows, CALIBRATION_METHODS, cal_merits)
    sections.append(("Calibration", [(criterion, *cal_criterion), *cal_tables]))
    text = "\n\n".join(
        f"### {name}: {t}\n\n" + markdown(h, tab)
        for name, tables in sections
        for t, h, tab in tables
    )
    (args.out / "regimes_summary.md").write_text(text + "\n")
    print(text)
    written = [args.out / f"{s}_trials.csv" for s in ("regimes", "regimes_calibration")]
    written += [args.out / "regimes_summary.md", *plot_regimes(args.out, slam_rows)]
    rows = slam_rows + cal_rows
    return _finish("trials", rows, wall=wall, seed=args.seed, written=written)


def _map_with_progress(args: argparse.Namespace, cells, stem: str, run) -> list[dict]:
    """:func:`~rangeslam.app.regime_map.regime_map` of ``cells`` by ``run`` (None: the SLAM
    trial) with progress, the rows written to ``{stem}_trials.csv`` as they finish."""
    from rangeslam.app.progress import Progress
    from rangeslam.app.regime_map import regime_map
    from rangeslam.app.reports import write_csv

    finished: list[dict] = []
    path = args.out / f"{stem}_trials.csv"
    with Progress(len(cells) * args.trials, stem) as progress:

        def keep(row: dict) -> None:
            finished.append(row)
            write_csv(path, finished)
            progress.update()

        extra = {} if run is None else {"run": run}
        rows = regime_map(
            cells, trials=args.trials, seed=args.seed, jobs=args.jobs, on_row=keep, **extra
        )
    write_csv(path, rows)
    return rows


def _finish(unit: str, rows: list[dict], *, wall: float, seed: int, written: list[Path]) -> int:
    """The run's last line (counts, time, seed, files written); 1 with the first reason on
    standard error when every trial or run failed, else 0."""
    failed = [r for r in rows if r["status"] != "ok"]
    print(
        f"\n{len(rows)} {unit} ({len(failed)} failed) in {wall:.1f} s; seed {seed}; written: "
        + ", ".join(str(p) for p in written)
    )
    if len(failed) == len(rows):
        print(
            f"rangeslam: every {unit[:-1]} failed; the first: {failed[0]['status']}",
            file=sys.stderr,
        )
        return 1
    return 0


def _write_plaza_outputs(args, dataset, rows, length_rows, kept: dict, wall: float) -> list[Path]:
    """The Markdown table (printed), the JSON summary, the plot and the TUM files of a Plaza
    bench."""
    from rangeslam.app import plaza_bench as pb
    from rangeslam.app.plotting import plot_plaza
    from rangeslam.app.reports import markdown, versions, write_summary

    out, stem = args.out, f"plaza_{dataset.name}"
    text = f"## {dataset.name}: methods\n\n" + markdown(*pb.methods_table(rows))
    if length_rows:
        text += "\n\n## Cost against trajectory length\n\n" + markdown(
            *pb.lengths_table(length_rows)
        )
    (out / f"{stem}_summary.md").write_text(text + "\n")
    print(text)
    written = [
        out / f"{stem}_summary.md",
        write_summary(
            out / f"{stem}_summary.json",
            bench="plaza",
            dataset=dataset.name,
            citation=dataset.citation,
            seed=args.seed,
            trials=args.trials,
            wall_seconds=wall,
            versions=versions(),
            methods=rows,
            lengths=length_rows,
        ),
    ]
    evaluations = {name: pb.evaluate(res, dataset) for name, res in kept.items()}
    written.append(plot_plaza(out / f"{stem}.png", dataset, kept, evaluations, rows=rows))
    if args.tum:
        written.append(_write_plaza_tum(out, stem, dataset, kept))
    return written


def _write_plaza_tum(out: Path, stem: str, dataset, kept: dict) -> Path:
    """The truth and each kept method's positions at its pose times, TUM format, in ``out/tum``."""
    from rangeslam.app.reports import write_tum

    folder = out / "tum"
    folder.mkdir(exist_ok=True)
    truth = dataset.truth_at(dataset.pose_time)
    write_tum(folder / f"{stem}_truth.tum", truth, times=dataset.pose_time)
    for name, res in kept.items():
        write_tum(
            folder / f"{stem}_{name.replace(' ', '_').replace('+', '_')}.tum",
            res.poses[:, :2],
            times=res.pose_time,
        )
    return folder


def run_xtdoa_bench(args: argparse.Namespace) -> int:
    """The xtdoa protocol (:mod:`rangeslam.app.xtdoa_bench`): a CSV row per solve (rewritten as
    solves finish), the Markdown table (printed) and a JSON summary; progress on standard error."""
    from rangeslam.app import xtdoa_bench as xb
    from rangeslam.app.progress import Progress
    from rangeslam.app.reports import markdown, versions, write_csv, write_summary
    from rangeslam.datasets import XTDOA_CITATION, data_path, xtdoa

    data = xtdoa(data_path(args.data, what="--data"))
    out, rows = args.out, []
    t0 = time.perf_counter()
    if getattr(args, "robust", None):
        with Progress(args.robust, "xtdoa robust", unit="runs") as progress:
            for seed in range(args.seed, args.seed + args.robust):
                rows.append(xb.robust_row(data, seed))
                write_csv(out / "xtdoa_robust.csv", rows)
                progress.update()
        text = "## xtdoa: all 65 events without the mask\n\n" + markdown(*xb.robust_table(rows))
        (out / "xtdoa_robust.md").write_text(text + "\n")
        print(text)
        written = [out / "xtdoa_robust.csv", out / "xtdoa_robust.md"]
        return _finish("runs", [{"status": "ok"} for _ in rows], wall=time.perf_counter() - t0,
                       seed=args.seed, written=written)  # fmt: skip
    with Progress(len(args.sizes) * args.subsets, "xtdoa", unit="solves") as progress:

        def keep(row: dict) -> None:
            rows.append(row)
            write_csv(out / "xtdoa_solves.csv", rows)
            progress.update(stage=f"K={row['K']}" if len(rows) % args.subsets == 0 else None)

        xb.subset_rows(data, args.sizes, args.subsets, seed=args.seed, on_row=keep)
    wall = time.perf_counter() - t0
    summary = xb.summary_rows(rows)
    text = "## xtdoa: the authors' protocol\n\n" + markdown(*xb.summary_table(summary))
    (out / "xtdoa_summary.md").write_text(text + "\n")
    print(text)
    json_path = write_summary(
        out / "xtdoa_summary.json", bench="xtdoa", citation=XTDOA_CITATION, seed=args.seed,
        subsets=args.subsets, wall_seconds=wall, versions=versions(), sizes=summary,
    )  # fmt: skip
    written = [out / "xtdoa_solves.csv", out / "xtdoa_summary.md", json_path]
    return _finish("solves", [{"status": "ok"} for _ in rows], wall=wall, seed=args.seed,
                   written=written)  # fmt: skip
