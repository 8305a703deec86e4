"""``biped sweep``: max|lambda| of A^z over many M1 (paper §V-A and Fig. 2).

    biped sweep --gait FILE --grid N --range LO HI --out DIR [--plot DIR] [--json]
                [--scheduler ADDRESS] [--workers K] [--processes] [--chunk-size K]
                [--no-progress]
    biped sweep --gait FILE --line N --range LO HI [--out DIR] [--plot DIR] [--json]
"""
from __future__ import annotations

import numpy as np

from analysis.reporting.plots import grid_sweep_plot, one_d_sweeps_plot, save_figures
from analysis.sweeps import grid_points, max_grid_n, one_d_sweeps, run_sweep
from biped_casadi.control.output_law import M1_LIMIT, check_M1_range

from .common import (Progress, UserError, add_gait_arguments, add_robot, output_dir,
                     print_json, scheduler_and_gait)

#: --line N evaluates nu N points
MAX_LINE = 1_000_000
#: --workers beyond this only adds overhead (and threads)
MAX_WORKERS = 256


def cmd_sweep(args):
    """``biped sweep``: check the arguments and output folders, run the grid or the 1-D
    sweeps, draw the grid's figure or Fig. 2 (--plot), then report (JSON or a table of
    the counts)."""
    # ---- arguments, then the output folders: all before any work
    lo, hi, n = _check_arguments(args)
    say = Progress("sweep", quiet=args.json or args.no_progress)
    gait = scheduler_and_gait(args, say)      # before any output: one line, nothing left
    model = gait.model
    if args.line is None and n > max_grid_n(model.nu):
        raise UserError(f"--grid takes 2 to {max_grid_n(model.nu)} points per component for "
                        f"this robot ({model.nu} components of M1), got {n}")

    # ---- the sweep
    r, lines = _run(args, gait, lo, hi, n, say)
    plots = []
    if args.plot is not None:
        if args.line is not None:
            figures = {"fig2_one_d_sweeps": one_d_sweeps_plot(lines)}
        else:
            figures = {"m1_grid_" + "x".join([str(n)] * model.nu): grid_sweep_plot(r, gait)}
        plots = save_figures(figures, args.plot, formats=("png", "pdf"))

    if args.json:
        out = r.to_dict()
        if args.line is not None:
            out["singular_values"] = lines.singular_values.tolist()
            out["lines"] = [dict(component=j + 1, counts=p.counts)
                            for j, p in enumerate(lines.results)]
        if args.line is not None or args.plot is not None:
            out["plots"] = plots
        print_json(out)
        return 0
    _print_report(args, r, lines, plots, lo, hi, n, model.nu)
    return 0


def _check_arguments(args):
    """The range, the grid and the run's options, and the output folders: (lo, hi, n)."""
    lo, hi = args.range
    if not (np.isfinite(lo) and np.isfinite(hi)) or not lo < hi:
        raise UserError(f"--range: LO must be less than HI (both finite), got {lo:g} {hi:g}")
    try:
        check_M1_range([lo, hi], "--range")
    except ValueError as e:
        raise UserError(str(e)) from None
    if args.line is not None and not 2 <= args.line <= MAX_LINE:
        raise UserError(f"--line takes 2 to {MAX_LINE} points per component, got {args.line}")
    n = 9 if args.grid is None else args.grid
    if args.line is None and not 2 <= n <= max_grid_n(2):
        raise UserError(f"--grid takes 2 to {max_grid_n(4)} points per component (the grid "
                        f"spans LO to HI; up to {max_grid_n(2)} for two torques), got {n}")
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise UserError(f"--workers must be between 1 and {MAX_WORKERS}, got {args.workers}")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise UserError(f"--chunk-size must be at least 1, got {args.chunk_size}")
    if args.out is not None:
        output_dir(args.out, "--out")
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    return lo, hi, n


def _run(args, gait, lo, hi, n, say):
    """The 1-D sweeps (--line) or the grid: (the sweep, the 1-D sweeps or None)."""
    model = gait.model
    kw = dict(out_dir=args.out, chunk_size=args.chunk_size, workers=args.workers,
              scheduler=args.scheduler, progress=not (args.no_progress or args.json),
              executor="process" if args.processes else "thread")
    lines = None
    try:
        if args.line is not None:
            lines = one_d_sweeps(gait, np.linspace(lo, hi, args.line), **kw)
            r = lines.sweep
        else:
            r = run_sweep(gait, grid_points(n, lo, hi, model.nu), **kw)
    except ValueError as e:       # the library names out / scheduler: say --out / --scheduler
        msg = str(e)
        raise UserError("--" + msg if msg.startswith(("out:", "scheduler:")) else msg) from None
    return r, lines


def _print_report(args, r, lines, plots, lo, hi, n, nu):
    """The text report: the counts per status, the best M1, the lines, the chunks."""
    mode = (f"1-D sweeps, {args.line} values of each M1(j) in [{lo:g}, {hi:g}]"
            if args.line is not None else
            f"grid {n}^{nu} = {r.n_points} M1, each component in linspace({lo:g}, "
            f"{hi:g}, {n})")
    print(f"sweep: {mode}")
    print(f"  {'status':10s} {'count':>8s}")
    for k, v in r.counts.items():
        print(f"  {k:10s} {v:8d}")
    print(f"  {'total':10s} {r.n_points:8d}")
    b = r.best()
    if b is not None:
        print(f"best: M1 = {np.array2string(b.M1, precision=4)}, max|lambda| = {b.max_abs:.6g}"
              + ("" if b.status == "stable" else f" ({b.status})"))
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
    add_gait_arguments(p, required=True)
    add_robot(p)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--grid", type=int, metavar="N",
                      help=f"N points per component, at least 2: N^nu M1 (default 9; at most "
                           f"{max_grid_n(4)} for RABBIT's nu = 4)")
    mode.add_argument("--line", type=int, metavar="N",
                      help="Fig. 2 instead: N values of each component, the others zero")
    p.add_argument("--range", nargs=2, type=float, default=[-10.0, 10.0],
                   metavar=("LO", "HI"), help=f"range of each component, within "
                   f"+-{M1_LIMIT:.0e} (default -10 10)")
    p.add_argument("--out", metavar="DIR", help="results folder (resumable); "
                   "default: keep results in memory only")
    p.add_argument("--plot", metavar="DIR", help="write the figure (PNG and PDF): with "
                   "--grid, max|lambda| over M1 (the plane of two components, or one panel "
                   "per pair of components, the smallest over the others); with --line, "
                   "Fig. 2")
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
