"""Basins of attraction on the adaptive grid against the full grid, side by side: the
five basins of ``biped reproduce`` (101 x 101; the deadbeat M1 and virtual constraints
on the default gait; the co-design, the sampling search's design and virtual
constraints on the robust gait), each walked cell by cell and on the adaptive grid
(``refine=4``: every 4th row and column first, the boundary cell by cell).

Prints per basin the two times, their ratio, the cells walked, the cells whose outcome
differs and the converged fractions.  The README and the basin docstring quote it.

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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reproduce import machine  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=101, help="cells per axis (101)")
    ap.add_argument("--refine", type=int, default=4, help="the adaptive grid's stride (4)")
    a = ap.parse_args()
    from analysis.design import ROBUST_GAIT, optimize_m1
    from analysis.design.codesign import TODAY_DESIGN
    from analysis.robustness import Design, basin
    from biped_casadi import RABBIT, BipedModel
    from gait_opt import GaitOptions, optimize_gait
    m = BipedModel(RABBIT)
    g, gr = optimize_gait(m, cache=True), optimize_gait(m, GaitOptions(**ROBUST_GAIT), cache=True)
    M1 = optimize_m1(g, group=1).M1
    cases = [("deadbeat M1 (default gait)", g, Design(tuple(M1))),
             ("virtual constraints (default gait)", g, None),
             ("co-design M1 (robust gait)", gr, Design((0.0999, 0.5312, 0.4220, -0.6522), 0.75)),
             ("sampling search's design (robust gait)", gr, Design(tuple(TODAY_DESIGN), 0.75)),
             ("virtual constraints (robust gait)", gr, None)]
    print(f"machine: {machine()}; load {os.getloadavg()[0]:.2f}; n = {a.n}, refine = "
          f"{a.refine}")
    tot_f = tot_a = 0.0
    diff_all = 0
    for label, gg, d in cases:
        basin(gg, d, n=3)                       # build and compile the walker first
        t = time.perf_counter()
        full = basin(gg, d, n=a.n)
        tf = time.perf_counter() - t
        t = time.perf_counter()
        ad = basin(gg, d, n=a.n, refine=a.refine)
        ta = time.perf_counter() - t
        diff = int(np.sum(full.outcome != ad.outcome))
        tot_f, tot_a, diff_all = tot_f + tf, tot_a + ta, diff_all + diff
        print(f"{label:40s} full {tf:6.1f} s  adaptive {ta:5.1f} s  ({tf / ta:4.1f}x)  "
              f"walked {ad.walked_cells:5d} of {a.n * a.n}  differ {diff:3d} cells "
              f"({100 * diff / a.n ** 2:.2f} %)  converged {100 * full.converged_fraction:.2f}"
              f" % vs {100 * ad.converged_fraction:.2f} %")
    print(f"all five: full {tot_f:.1f} s, adaptive {tot_a:.1f} s ({tot_f / tot_a:.1f}x); "
          f"{diff_all} of {5 * a.n ** 2} cells differ; load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
