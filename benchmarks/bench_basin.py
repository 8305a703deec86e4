"""Basins of attraction on the adaptive grid against the full grid, side by side: the
five basins of ``biped reproduce`` (101 x 101; the deadbeat M1 and virtual constraints
on the default gait; the co-design (``biped m1 --robust``, its gait), the sampling
search's design and virtual constraints on the co-design's gait), each walked cell by
cell (the baseline) and on the adaptive grid (``refine=4``: every 4th row and column
first, the boundary cell by cell).  Target (issue 21): the adaptive grid draws the same
picture, with the difference stated.

Prints per basin the two times, their ratio, the cells walked, the cells whose outcome
differs and the converged fractions.  The results go to ``benchmarks/results/basin.json``
(the docs' benchmarks page; ratio full / adaptive: above 1, the adaptive grid is faster).
The co-design is read from ``BIPED_CACHE_DIR`` (about 2-3 minutes on 2 cores the first
time, not part of the figures).

    python benchmarks/bench_basin.py            # n = 101
    python benchmarks/bench_basin.py --n 41     # the quick run's grid
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from analysis.design import ROBUST_GAIT, optimize_m1
from analysis.design.codesign import FULL, TODAY_DESIGN, codesign
from analysis.robustness import basin
from biped_casadi import Design, rabbit
from gait_opt import GaitOptions, optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run, machine  # noqa: E402


def cases():
    """The five basins of the full reproduction: (label, design)."""
    m = rabbit()
    g, gr = optimize_gait(m, cache=True), optimize_gait(m, GaitOptions(**ROBUST_GAIT), cache=True)
    M1 = optimize_m1(g, group=1).M1
    co = codesign(m, FULL, progress=lambda s: print(f"  {s}", flush=True)).design
    return [("deadbeat M1 (default gait)", Design.tv(g, M1)),
            ("virtual constraints (default gait)", Design.vc(g)),
            ("co-design (its gait)", co),
            ("sampling search's design (robust gait)", Design.tv(gr, TODAY_DESIGN, 0.75)),
            ("virtual constraints (the co-design's gait)", Design.vc(co.gait))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=101, help="cells per axis (101)")
    ap.add_argument("--refine", type=int, default=4, help="the adaptive grid's stride (4)")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    a = ap.parse_args(argv)
    todo = cases()
    print(f"machine: {machine()}; load {os.getloadavg()[0]:.2f}; n = {a.n}, refine = "
          f"{a.refine}")
    with Run("basin", f"basins {a.n} x {a.n} on the adaptive grid (refine = {a.refine}) "
             "against the full grid", save=not a.no_save) as bench:
        tot_f = tot_a = 0.0
        diff_all = 0
        for label, d in todo:
            basin(d, n=3)                       # build and compile the walker first
            t = time.perf_counter()
            full = basin(d, n=a.n)
            tf = time.perf_counter() - t
            t = time.perf_counter()
            ad = basin(d, n=a.n, refine=a.refine)
            ta = time.perf_counter() - t
            diff = int(np.sum(full.outcome != ad.outcome))
            tot_f, tot_a, diff_all = tot_f + tf, tot_a + ta, diff_all + diff
            print(f"{label:44s} full {tf:6.1f} s  adaptive {ta:5.1f} s  ({tf / ta:4.1f}x)  "
                  f"walked {ad.walked_cells:5d} of {a.n * a.n}  differ {diff:3d} cells "
                  f"({100 * diff / a.n ** 2:.2f} %)  converged "
                  f"{100 * full.converged_fraction:.2f} % vs {100 * ad.converged_fraction:.2f} %")
            bench.row(f"{label}: adaptive grid (baseline: every cell walked)", round(ta, 2),
                      round(tf, 2), ratio=round(tf / ta, 2))
            bench.note(f"{label}: walked {ad.walked_cells} of {a.n * a.n} cells; {diff} cells "
                       f"differ; converged {100 * full.converged_fraction:.2f} % (full) vs "
                       f"{100 * ad.converged_fraction:.2f} % (adaptive)")
            bench.data[label] = dict(full_s=tf, adaptive_s=ta, walked=ad.walked_cells,
                                     differ=diff, converged_full=full.converged_fraction,
                                     converged_adaptive=ad.converged_fraction,
                                     design=d.to_dict())
        print(f"all five: full {tot_f:.1f} s, adaptive {tot_a:.1f} s ({tot_f / tot_a:.1f}x); "
              f"{diff_all} of {5 * a.n ** 2} cells differ; load {os.getloadavg()[0]:.2f}")
        bench.row("all five basins: adaptive grid (baseline: every cell walked)",
                  round(tot_a, 2), round(tot_f, 2), ratio=round(tot_f / tot_a, 2))
        bench.row(f"cells whose outcome differs, all five (of {5 * a.n ** 2})", diff_all,
                  unit="cells", target="the same picture, the difference stated")


if __name__ == "__main__":
    main()
