"""Robustness, side by side with the per-run path (issue 15).

    python benchmarks/bench_robust.py [--cells 101] [--baseline-cells 40]

(a) s* of one time-varying design with N = 16 directions (bisection, 8 rounds): the
    batched zero-dynamics walker (analysis.robustness.robustness) against the same
    bisection run direction by direction with the full-order simulator (JIT-compiled,
    2000 RK4 steps per T: the per-run path), in the same process; target < 60 s.
(b) a 101 x 101 basin on the Poincare section, 10 steps per cell: the batched walkers
    (time-varying and virtual constraints) against the full-order simulator cell by cell
    on ``--baseline-cells`` cells (the per-cell time extrapolated to the whole grid, and
    said so; for the time-varying controller the cost of 10 full-order steps from the
    cell's configuration, the simulator starting its steps at tau = 0); target < 60 s.

Both on the robust gait (analysis.design.ROBUST_GAIT) with the sampling search's robust
design (``TODAY_DESIGN``, evaluated on that gait by ``biped reproduce``).  Figures are wall
times after a warm-up of every path (builds and JIT compilation not counted); the machine's
load is printed at the start and the end.  The results go to
``benchmarks/results/robust.json`` (the docs' benchmarks page): ours beside the per-run
path, the ratio per-run / ours (above 1: ours is faster).
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from analysis.design import ROBUST_GAIT
from analysis.design.codesign import TODAY_DESIGN
from analysis.stability import poincare_map
from analysis.robustness import RobustnessSettings, basin, kept_directions, robustness
from analysis.robustness.s_star import KeptDirections
from biped_casadi.simulation import start_states
from biped_casadi.simulation import virtual_constraint_walker
from biped_casadi import Design, SimulationOptions, rabbit, simulate
from gait_opt import GaitOptions, optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

#: the rejoin time of the sampling search's design
REJOIN = 0.75


def baseline_s_star(design, dirs, st):
    """The same bisection as analysis.robustness, one full-order run at a time."""
    gait = design.gait
    opts = SimulationOptions(steps=st.steps, mu=st.mu, jit=True)

    def passes(s):
        for d in dirs:
            q0, dq0 = start_states(gait, d[None], s)
            r = simulate(design, q0[0], dq0[0], opts)
            if r.verdict(st.tol) != "ok":
                return False
        return True

    if passes(st.s_max):
        return st.s_max
    lo, hi = 0.0, st.s_max
    for _ in range(st.rounds - 1):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if passes(mid) else (lo, mid)
    return lo


def s_star_part(bench, g, design):
    """(a): s* by the batched walker against the full-order bisection."""
    st = RobustnessSettings(rounds=8)
    kept = kept_directions(g, st)
    dirs = kept.directions
    # warm both paths (JIT compilation, maps) so the figures compare evaluation
    robustness(design, RobustnessSettings(directions=1, rounds=1),
               kept=KeptDirections(dirs[:1], 1, {}))
    simulate(design, g.q(0.0), g.dq(0.0), SimulationOptions(steps=st.steps, mu=st.mu,
                                                            jit=True))
    print(f"\n(a) s* of one design, {len(dirs)} directions, {st.rounds} bisection rounds")
    t = time.perf_counter()
    r = robustness(design, st, kept=kept)
    t_ours = time.perf_counter() - t
    t = time.perf_counter()
    s_base = baseline_s_star(design, dirs, st)
    t_base = time.perf_counter() - t
    print(f"  batched zero-dynamics walker   {t_ours:7.1f} s   s* = {r.s_star:.4g}")
    print(f"  full-order simulator, per run  {t_base:7.1f} s   s* = {s_base:.4g}")
    print(f"  ratio {t_base / t_ours:.1f}x; target < 60 s: {'met' if t_ours < 60 else 'MISSED'}")
    bench.row(f"s* of one design, {len(dirs)} directions, {st.rounds} bisection rounds: "
              "batched zero-dynamics walker (baseline: full-order simulator run by run)",
              round(t_ours, 2), round(t_base, 2), ratio=round(t_base / t_ours, 1),
              target="< 60 s")
    bench.row("s* found by each (the same bisection; ratio: the baseline's s* / ours, 1 "
              "when they agree)", round(r.s_star, 4), round(s_base, 4), unit="",
              ratio=round(s_base / r.s_star, 4) if r.s_star else None, target="equal")
    bench.data["s_star"] = dict(ours_s=t_ours, baseline_s=t_base, s_star=r.s_star,
                                s_star_baseline=s_base, directions=len(dirs))


def basin_part(bench, m, g, design, n, n_base):
    """(b): the basins by the batched walkers against the simulator on sampled cells."""
    print(f"\n(b) basin {n} x {n} on the section, 10 steps per cell")
    rows = []
    opts = SimulationOptions(steps=10, jit=True)
    for label, d in (("time-varying (robust design)", design),
                     ("virtual constraints", Design.vc(g))):
        basin(d, n=3, steps=1)                   # build and compile once
        t = time.perf_counter()
        b = basin(d, n=n)
        t_ours = time.perf_counter() - t
        # the per-run path on a sample of the same cells, start states made first
        rng = np.random.default_rng(0)
        cells = rng.choice(n * n, size=n_base, replace=False)
        starts = cell_states(m, g, d, b, cells)
        simulate(d, *starts[0], opts)            # build and compile once
        t = time.perf_counter()
        walked = [len(simulate(d, q, dq, opts).steps) for q, dq in starts]
        per_cell = (time.perf_counter() - t) / len(cells)
        t_base = per_cell * n * n
        rows.append((label, t_ours, t_base, b.converged_fraction))
        print(f"  {label:30s} walker {t_ours:6.1f} s; per-run full order {per_cell:.2f} s/cell "
              f"-> {t_base:7.0f} s extrapolated ({len(cells)} cells timed); ratio "
              f"{t_base / t_ours:.0f}x; target < 60 s: {'met' if t_ours < 60 else 'MISSED'}")
        bench.row(f"basin {n} x {n}, 10 steps per cell, {label}: batched walker (baseline: "
                  f"full-order simulator cell by cell, {len(cells)} cells timed, "
                  f"extrapolated to {n * n})", round(t_ours, 2), round(t_base, 0),
                  ratio=round(t_base / t_ours, 0), target="< 60 s")
        bench.note(f"basin of {label}: {100 * b.converged_fraction:.2f} % of the cells "
                   f"converge; the full-order simulator {per_cell:.3f} s per cell, "
                   f"{sum(walked)} steps in all on its {len(cells)} cells (a run ends at its "
                   f"first invalid state)")
    bench.note("the full-order simulator starts a step at tau = 0, not at the section: for "
               "the time-varying design a cell's per-run cost is that of 10 full-order "
               "steps from the cell's configuration (the runs themselves differ)")
    bench.data["basins"] = [dict(label=r[0], ours_s=r[1], baseline_extrapolated_s=r[2],
                                 converged_fraction=r[3]) for r in rows]
    return rows


def cell_states(m, g, design, b, cells):
    """(q, dq) of the sampled cells of basin ``b`` for the full-order simulator."""
    xs = g.state_at(0.75 * g.T)
    A, B = np.meshgrid(b.q_u, b.dq_u, indexing="ij")
    out = []
    for c in cells:
        x = np.array([xs[0] + A.ravel()[c], xs[1] + B.ravel()[c]])
        if design.M1 is None:
            V = virtual_constraint_walker(g, SimulationOptions(), 100, jit=True)
            th, w = V.section_states(x[None])
            q, Q1, _ = (np.array(v).ravel() for v in V.vmap.curve(th[0]))
            out.append((q, Q1 * w[0]))
        else:
            out.append(tuple(np.array(v).ravel() for v in ZD_CONFIG(m, g, design, x)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", type=int, default=101)
    ap.add_argument("--baseline-cells", type=int, default=40)
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.2f}")
    with Run("robust", "s* and the section basin by the batched walkers, against the "
             "full-order simulator run by run", save=not args.no_save) as bench:
        m = rabbit()
        g = optimize_gait(m, GaitOptions(**ROBUST_GAIT), cache=True)
        design = Design.tv(g, TODAY_DESIGN, REJOIN)
        s_star_part(bench, g, design)
        rows = basin_part(bench, m, g, design, args.cells, args.baseline_cells)
        bench.note(f"design: the sampling search's, {design.label()}, on the robust gait")
    print(f"\nload at the end {os.getloadavg()[0]:.2f} (2 shared cores)")
    return rows


def ZD_CONFIG(model, gait, design, x):
    """(q, dq) of the zero-dynamics state (q_u, dq_u) = x at the section (v_c = 0)."""
    pm = poincare_map(gait, rejoin=design.rejoin)
    z = np.r_[x, gait.state(0.75 * gait.T)]
    return pm.configuration(z, 0.75 * gait.T, np.array(design.M1), np.zeros(model.nu),
                            np.zeros(model.nu))


if __name__ == "__main__":
    main()
