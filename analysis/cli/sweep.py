"""``biped sweep``: max|lambda| of A^z over many M1 (paper §V-A and Fig. 2).

    biped sweep --gait FILE --grid N --range LO HI --out DIR [--json]
                [--scheduler ADDRESS] [--workers K] [--processes] [--chunk-size K]
                [--no-progress]
    biped sweep --gait FILE --line N --range LO HI [--out DIR] [--plot DIR] [--json]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.plots import one_d_sweeps_plot, save_figure
from analysis.sweep import grid_points, line_points, one_d_sweeps, run_sweep

from .common import UserError, add_robot, load_gait, print_json


def cmd_sweep(args):

    lo, hi = args.range
    if not (np.isfinite(lo) and np.isfinite(hi)) or not lo < hi:
        raise UserError(f"--range: LO must be less than HI (both finite), got {lo:g} {hi:g}")
    if args.line is not None and args.grid is not None:
        raise UserError("--grid and --line exclude each other")
    if args.plot is not None and args.line is None:
        raise UserError("--plot needs --line (the 1-D sweeps of Fig. 2)")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers must be at least 1, got {args.workers}")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise UserError(f"--chunk-size must be at least 1, got {args.chunk_size}")
    gait = load_gait(args.gait, robot_arg=args.robot)   # GaitFileError (ValueError): exit 2
    model = gait.model
    kw = dict(out_dir=args.out, chunk_size=args.chunk_size, workers=args.workers,
              scheduler=args.scheduler, progress=not args.no_progress,
              executor="process" if args.processes else "thread")

    plots = []
    if args.line is not None:
        if args.line < 2:
            raise UserError(f"--line takes at least 2 points per component, got {args.line}")
        values = np.linspace(lo, hi, args.line)
        line_points(0, values, model.nu)
        lines = one_d_sweeps(model, gait, values, **kw)
        r = lines.sweep
        if args.plot is not None:
            folder = Path(args.plot)
            folder.mkdir(parents=True, exist_ok=True)
            plots = save_figure(one_d_sweeps_plot(lines), folder / "fig2_one_d_sweeps",
                                formats=("png", "pdf"))
    else:
        n = 9 if args.grid is None else args.grid
        if n < 1:
            raise UserError(f"--grid takes a positive number of points per component, got {n}")
        r = run_sweep(model, gait, grid_points(n, lo, hi, model.nu), **kw)

    if args.json:
        out = r.to_dict()
        if args.line is not None:
            out["singular_values"] = lines.singular_values.tolist()
            out["lines"] = [dict(component=j + 1, counts=p.counts)
                            for j, p in enumerate(lines.results)]
            out["plots"] = plots
        print_json(out)
        return 0

    mode = (f"1-D sweeps, {args.line} values of each M1(j) in [{lo:g}, {hi:g}]"
            if args.line is not None else
            f"grid {n}^{model.nu} = {r.n_points} M1, each component in linspace({lo:g}, "
            f"{hi:g}, {n})")
    print(f"sweep: {mode}")
    print(f"  {'status':10s} {'count':>8s}")
    for k, v in r.counts.items():
        print(f"  {k:10s} {v:8d}")
    print(f"  {'total':10s} {r.n_points:8d}")
    b = r.best()
    if b is not None:
        print(f"best: M1 = {np.array2string(b[0], precision=4)}, max|lambda| = {b[1]:.6g}")
    if args.line is not None:
        print("singular values of eq. (24), M1(j) = D11/D12(j) at q^d(T): "
              + ", ".join(f"{v:.6g}" for v in lines.singular_values))
        for j, p in enumerate(lines.results):
            print(f"  M1({j + 1}): " + ", ".join(f"{k} {v}" for k, v in p.counts.items()))
    print(f"computed {r.n_computed} points ({len(r.computed_chunks)} chunks), reused "
          f"{r.n_points - r.n_computed} ({len(r.reused_chunks)} chunks)"
          + (f", recomputed {len(r.corrupt_chunks)} damaged chunks" if r.corrupt_chunks else "")
          + f" in {r.elapsed:.2f} s")
    if r.out_dir is not None:
        print(f"results: {r.out_dir}")
    for p in plots:
        print(f"figure: {p}")
    return 0


def register(sub):
    p = sub.add_parser(
        "sweep", help="max|lambda| and stability status over a grid or lines of M1",
        description="Evaluate the restricted Poincare map's Jacobian A^z for many output "
                    "matrices M1 (paper section V-A): the N^nu grid (--grid; nu = 4 for "
                    "RABBIT, the paper's is 9 on [-10, 10]) or the 1-D sweeps of Fig. 2, one "
                    "per component (--line). Runs on "
                    "all local cores, or on a Dask cluster with --scheduler. With --out the "
                    "results are stored chunk by chunk (Parquet); rerunning with the same "
                    "--out resumes and recomputes only what is missing.")
    p.add_argument("--gait", required=True, metavar="FILE", help="reference gait file "
                   "(from `biped gait --out FILE`)")
    add_robot(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--grid", type=int, metavar="N",
                      help="N points per component: N^nu M1 (default 9)")
    mode.add_argument("--line", type=int, metavar="N",
                      help="Fig. 2 instead: N values of each component, the others zero")
    p.add_argument("--range", nargs=2, type=float, default=[-10.0, 10.0],
                   metavar=("LO", "HI"), help="range of each component (default -10 10)")
    p.add_argument("--out", metavar="DIR", help="results folder (resumable); "
                   "default: keep results in memory only")
    p.add_argument("--plot", metavar="DIR", help="with --line: write Fig. 2 (PNG and PDF)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask distributed scheduler, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--workers", type=int, metavar="K",
                   help="local workers (default: all cores; 1: chunk after chunk)")
    p.add_argument("--processes", action="store_true",
                   help="local workers as processes instead of threads (each rebuilds the "
                        "map: only worth it for very large sweeps)")
    p.add_argument("--chunk-size", type=int, metavar="K",
                   help="points per stored chunk (default 256, or the folder's own)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_sweep)
