"""Monte Carlo on stochastic terrain: steps walked per second, side by side with the
per-run path (issue 22).

    python benchmarks/bench_terrain.py [--runs 400] [--steps 40] [--sigma 0.01]

(a) Zero-dynamics steps (the robust time-varying design on its gait, a perfect model):
    ``analysis.terrain.monte_carlo`` through a Dask LocalCluster of the cores (one
    process per core, the batched walker in each), against today's per-run path (the
    full-order simulator, JIT, 2000 RK4 steps per T, run by run) on a subset of the same
    runs, and against today's walker settings (400 RK4 steps per T) in one process.
    Every walker setting's verdicts (status and failing step of every run) are compared
    with those of the 400-step walker: fewer RK4 steps are used only where they agree.
(b) Full-order steps (the same design with the torso 20 % heavier than the controller
    believes): the Monte Carlo through the LocalCluster (the full-order simulator in each
    process, JIT -O1, ``full_rk4_steps`` per T), against the per-run path (JIT, 2000 RK4
    steps per T) on a subset; the verdicts of both compared.

The machine's load is printed at the start and the end: the figures are wall times on a
machine shared with other jobs, each ratio measured in the same run.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from analysis.design import ROBUST_GAIT
from analysis.terrain import MonteCarloSettings, WalkerSpec, monte_carlo
from biped_casadi import SimulationOptions, rabbit, simulate
from biped_casadi.simulation import WalkBatch
from gait_opt import GaitOptions, optimize_gait

#: the robust design of this repository's reproduction (README)
M1, REJOIN = (-8.2618, 2.5374, 0.0034, 8.5090), 0.75


def per_run(spec, gait, st, runs, rk4=2000):
    """Today's per-run path: the full-order simulator (JIT), one run at a time."""
    ctrl = spec.controller_for(gait)
    opts = SimulationOptions(steps=st.max_steps, mu=st.mu, jit=True, rk4_steps=rk4,
                             saturate=spec.saturate)
    plant = spec.plant_model()
    H = st.heights(runs)
    simulate(ctrl, options=opts, steps=1, plant=plant)                  # build, compile
    t = time.perf_counter()
    out = [simulate(ctrl, options=opts, terrain=H[i], plant=plant) for i in range(len(runs))]
    el = time.perf_counter() - t
    b = WalkBatch.concat(out)
    return b, el


def verdicts(status, fail_step):
    return np.array([f"{s}@{k}" for s, k in zip(status, fail_step)])


def mc_verdicts(r):
    return verdicts(np.where(r.failed, "fail", "ok"), r.walked)


def main(runs=400, steps=40, sigma=0.01, baseline_runs=8, workers=None, chunk=None,
         parts="ab"):
    print(f"{platform.node()}: {os.cpu_count()} cores, load {os.getloadavg()}")
    model = rabbit()
    gait = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)
    spec = WalkerSpec("tv", M1, REJOIN)
    rows = {}
    nw = workers or len(os.sched_getaffinity(0))

    print(f"(a) zero dynamics: {runs} runs of up to {steps} steps, sigma = {sigma} m, "
          f"chunks of {chunk or max(1, runs // (2 * nw))} runs")
    ref = None
    for rk in (400, 128, 64, 48):
        st = MonteCarloSettings(sigma=sigma, runs=runs, max_steps=steps, rk4_steps=rk,
                                chunk=chunk or max(1, runs // (2 * nw)))
        monte_carlo(gait, spec, MonteCarloSettings(sigma=sigma, runs=4, max_steps=2,
                                                   rk4_steps=rk), scheduler="inline")
        r1 = monte_carlo(gait, spec, st, scheduler="inline")          # one process
        rd = monte_carlo(gait, spec, st, workers=workers)              # LocalCluster
        v = mc_verdicts(rd)
        if ref is None:
            ref = v
        same = float(np.mean(v == ref))
        rows[f"zd{rk}"] = (r1.steps_per_second, rd.steps_per_second, same,
                           nw * rd.steps_per_process_second)
        print(f"  walker, {rk:3d} RK4/T: one process {r1.steps_per_second:8.0f} steps/s; "
              f"LocalCluster of {nw} {rd.steps_per_second:8.0f} steps/s (wall {rd.elapsed:.1f} s, "
              f"start-up and builds included), {nw * rd.steps_per_process_second:8.0f} "
              f"steps/s walking; verdicts equal to 400 RK4/T: {100 * same:.1f} %; "
              f"MFPT {rd.estimate.mfpt:.4g}")
    st = MonteCarloSettings(sigma=sigma, runs=runs, max_steps=steps)
    b, el = per_run(spec, gait, st, np.arange(baseline_runs))
    base = b.scenario_steps / el
    same = np.mean(verdicts(np.where(b.status != "ok", "fail", "ok"),
                            np.where(b.status != "ok", b.fail_step, steps)) == ref[:baseline_runs])
    print(f"  per-run full-order simulator (JIT, 2000 RK4/T), {baseline_runs} runs: "
          f"{base:.1f} steps/s; verdicts equal to the walker's: {100 * same:.0f} %")
    for k, (one, dask, s, walking) in rows.items():
        print(f"  ratio {k}: LocalCluster wall / per-run = {dask / base:.0f}x (walking "
              f"{walking / base:.0f}x), one process / per-run = {one / base:.0f}x")

    if "b" not in parts:
        print(f"load at the end {os.getloadavg()}")
        return rows
    print(f"(b) full order, torso 20 % heavier: {runs // 4} runs of up to {steps} steps")
    plant = model.description.scaled(torso_mass=1.2)
    spec_e = WalkerSpec("tv", M1, REJOIN, plant=plant.to_dict())
    n_b = max(2, runs // 4)
    for rk in (400, 200):
        st = MonteCarloSettings(sigma=sigma, runs=n_b, max_steps=steps, full_rk4_steps=rk,
                                chunk=max(1, n_b // 4))
        rd = monte_carlo(gait, spec_e, st, workers=workers)
        b, el = per_run(spec_e, gait, st, np.arange(baseline_runs))
        base = b.scenario_steps / el
        vb = verdicts(np.where(b.status != "ok", "fail", "ok"),
                      np.where(b.status != "ok", b.fail_step, steps))
        same = np.mean(mc_verdicts(rd)[:baseline_runs] == vb)
        walking = nw * rd.steps_per_process_second
        print(f"  full order {rk} RK4/T via LocalCluster: {rd.steps_per_second:.0f} steps/s "
              f"(wall {rd.elapsed:.1f} s), {walking:.0f} steps/s walking; per-run (JIT, 2000 "
              f"RK4/T): {base:.1f} steps/s; ratio {rd.steps_per_second / base:.1f}x wall, "
              f"{walking / base:.1f}x walking; verdicts equal on the "
              f"{baseline_runs} compared runs: {100 * same:.0f} %; MFPT {rd.estimate.mfpt:.4g}")
    print(f"load at the end {os.getloadavg()}")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=400)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--baseline-runs", type=int, default=8)
    ap.add_argument("--workers", type=int)
    ap.add_argument("--chunk", type=int, help="runs per chunk (default: runs / (2 workers))")
    ap.add_argument("--parts", default="ab", help="a: zero dynamics, b: full order")
    a = ap.parse_args()
    main(a.runs, a.steps, a.sigma, a.baseline_runs, a.workers, a.chunk, a.parts)
