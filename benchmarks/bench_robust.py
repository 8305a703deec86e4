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

Both on the robust design's gait (analysis.design.ROBUST_GAIT) with the robust
design of this repository's reproduction.  Figures are wall times; the machine's load
is printed at the start and the end.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from analysis.design import ROBUST_GAIT
from analysis.stability import poincare_map
from analysis.robustness import (Design, KeptDirections, RobustnessSettings, basin,
                                 kept_directions, robustness)
from biped_casadi.simulation import start_states
from biped_casadi.simulation import virtual_constraint_walker
from biped_casadi import (SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, rabbit, simulate)
from gait_opt import GaitOptions, optimize_gait

#: the robust design found by `biped m1 --robust` (README); any stable design would do
DESIGN = Design((-8.2618, 2.5374, 0.0034, 8.5090), 0.75)


def baseline_s_star(model, gait, design, dirs, st):
    """The same bisection as analysis.robustness, one full-order run at a time."""
    ctrl = TimeVaryingController(gait, np.array(design.M1), rejoin=design.rejoin)
    opts = SimulationOptions(steps=st.steps, mu=st.mu, jit=True)

    def passes(s):
        for d in dirs:
            q0, dq0 = start_states(gait, d[None], s)
            r = simulate(ctrl, q0[0], dq0[0], opts)
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=101)
    ap.add_argument("--baseline-cells", type=int, default=40)
    args = ap.parse_args(argv)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.2f}")
    m = rabbit()
    g = optimize_gait(m, GaitOptions(**ROBUST_GAIT), cache=True)
    st = RobustnessSettings(rounds=8)
    kept = kept_directions(g, st)
    dirs = kept.directions
    # warm both paths (JIT compilation, maps) so the figures compare evaluation
    robustness(g, DESIGN, RobustnessSettings(directions=1, rounds=1), kept=KeptDirections(dirs[:1], 1, {}))
    ctrl = TimeVaryingController(g, np.array(DESIGN.M1), rejoin=DESIGN.rejoin)
    simulate(ctrl, g.q(0.0), g.dq(0.0), SimulationOptions(steps=1, jit=True))

    print(f"\n(a) s* of one design, {len(dirs)} directions, {st.rounds} bisection rounds")
    t = time.perf_counter()
    r = robustness(g, DESIGN, st, kept=kept)
    t_ours = time.perf_counter() - t
    t = time.perf_counter()
    s_base = baseline_s_star(m, g, DESIGN, dirs, st)
    t_base = time.perf_counter() - t
    print(f"  batched zero-dynamics walker   {t_ours:7.1f} s   s* = {r.s_star:.4g}")
    print(f"  full-order simulator, per run  {t_base:7.1f} s   s* = {s_base:.4g}")
    print(f"  ratio {t_base / t_ours:.1f}x; target < 60 s: {'met' if t_ours < 60 else 'MISSED'}")

    n = args.cells
    print(f"\n(b) basin {n} x {n} on the section, 10 steps per cell")
    rows = []
    for label, design in (("time-varying (robust design)", DESIGN), ("virtual constraints", None)):
        basin(g, design, n=3, steps=1)                   # build and compile once
        t = time.perf_counter()
        b = basin(g, design, n=n)
        t_ours = time.perf_counter() - t
        # the per-run path on a sample of the same cells
        rng = np.random.default_rng(0)
        cells = rng.choice(n * n, size=args.baseline_cells, replace=False)
        xs = g.state_at(0.75 * g.T)
        A, B = np.meshgrid(b.q_u, b.dq_u, indexing="ij")
        opts = SimulationOptions(steps=10, jit=True)
        t = time.perf_counter()
        for c in cells:
            x = np.array([xs[0] + A.ravel()[c], xs[1] + B.ravel()[c]])
            if design is None:
                V = virtual_constraint_walker(g, SimulationOptions(), 100, jit=True)
                th, w = V.section_states(x[None])
                q, Q1, _ = (np.array(v).ravel() for v in V.vmap.curve(th[0]))
                simulate(VirtualConstraintController(g), q, Q1 * w[0], opts)
            else:
                # the full-order simulator starts a step at tau = 0, not at the section:
                # the per-run path's cost of a cell is that of 10 full-order steps from
                # the cell's configuration (the runs themselves differ)
                q, dq = (np.array(v).ravel() for v in ZD_CONFIG(m, g, design, x))
                simulate(ctrl, q, dq, opts)
        per_cell = (time.perf_counter() - t) / len(cells)
        t_base = per_cell * n * n
        rows.append((label, t_ours, t_base, b.converged_fraction))
        print(f"  {label:30s} walker {t_ours:6.1f} s; per-run full order {per_cell:.2f} s/cell "
              f"-> {t_base:7.0f} s extrapolated ({len(cells)} cells timed); ratio "
              f"{t_base / t_ours:.0f}x; target < 60 s: {'met' if t_ours < 60 else 'MISSED'}")
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
