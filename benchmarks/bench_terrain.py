"""Monte Carlo on stochastic terrain: steps walked per second, side by side with the
per-run path (issue 22).

    python benchmarks/bench_terrain.py [--runs 400] [--steps 40] [--sigma 0.01]

(a) Zero-dynamics steps (the sampling search's robust time-varying design on its gait, a
    perfect model): ``analysis.terrain.monte_carlo`` through a Dask LocalCluster of the
    cores (one process per core, the batched walker in each), against the per-run path
    (the full-order simulator, JIT, 2000 RK4 steps per T, run by run) on a subset of the
    same runs, and the walker in one process (``scheduler='synchronous'``).  Every walker
    setting's verdicts (status and failing step of every run) are compared with those of
    the 400-step walker: fewer RK4 steps are used only where they agree.
(b) Full-order steps (the same design with the torso 20 % heavier than the controller
    believes): the Monte Carlo through the LocalCluster (the full-order simulator in each
    process, JIT -O1, ``full_rk4_steps`` per T), against the per-run path (JIT, 2000 RK4
    steps per T) on a subset; the verdicts of both compared.

Targets (issue 22): at least 20,000 zero-dynamics steps/s and 200 full-order steps/s on
2 cores.  The machine's load is printed at the start and the end: the figures are wall
times on a machine shared with other jobs, each ratio measured in the same run.  The
results go to ``benchmarks/results/terrain.json`` (the docs' benchmarks page): our steps/s
beside the per-run path's, the ratio ours / per-run in steps/s (above 1: ours is faster).
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
from analysis.terrain import MonteCarloSettings, monte_carlo
from biped_casadi import Design, SimulationOptions, rabbit, robot, simulate
from biped_casadi.simulation import WalkBatch
from gait_opt import GaitOptions, optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

#: the rejoin time of the sampling search's robust design (TODAY_DESIGN)
REJOIN = 0.75
ZD_TARGET, FULL_TARGET = 20_000, 200


def per_run(design, st, runs, plant=None, rk4=2000):
    """The per-run path: the full-order simulator (JIT), one run at a time."""
    opts = SimulationOptions(steps=st.max_steps, mu=st.mu, jit=True, rk4_steps=rk4)
    H = st.heights(runs)
    simulate(design, options=opts, steps=1, plant=plant)                  # build, compile
    t = time.perf_counter()
    out = [simulate(design, options=opts, terrain=H[i], plant=plant) for i in range(len(runs))]
    el = time.perf_counter() - t
    b = WalkBatch.concat(out)
    return b, el


def verdicts(status, fail_step):
    return np.array([f"{s}@{k}" for s, k in zip(status, fail_step)])


def mc_verdicts(r):
    return verdicts(np.where(r.failed, "fail", "ok"), r.walked)


def batch_verdicts(b, steps):
    return verdicts(np.where(b.status != "ok", "fail", "ok"),
                    np.where(b.status != "ok", b.fail_step, steps))


def zero_dynamics(bench, design, runs, steps, sigma, baseline_runs, workers, chunk, nw):
    """(a): the walkers' Monte Carlo against the per-run full-order path."""
    chunk = chunk or max(1, runs // (2 * nw))
    print(f"(a) zero dynamics: {runs} runs of up to {steps} steps, sigma = {sigma} m, "
          f"chunks of {chunk} runs")
    ref, rows = None, {}
    for rk in (400, 128, 64, 48):
        st = MonteCarloSettings(sigma=sigma, runs=runs, max_steps=steps, rk4_steps=rk,
                                chunk=chunk)
        monte_carlo(design, MonteCarloSettings(sigma=sigma, runs=4, max_steps=2,
                                               rk4_steps=rk), scheduler="synchronous")
        r1 = monte_carlo(design, st, scheduler="synchronous")          # one process
        rd = monte_carlo(design, st, workers=workers)                  # LocalCluster
        v = mc_verdicts(rd)
        if ref is None:
            ref = v
        same = float(np.mean(v == ref))
        rows[rk] = (r1.steps_per_second, rd.steps_per_second, same,
                    nw * rd.steps_per_process_second, rd.elapsed, rd.estimate.mfpt)
        print(f"  walker, {rk:3d} RK4/T: one process {r1.steps_per_second:8.0f} steps/s; "
              f"LocalCluster of {nw} {rd.steps_per_second:8.0f} steps/s (wall {rd.elapsed:.1f} s, "
              f"start-up and builds included), {nw * rd.steps_per_process_second:8.0f} "
              f"steps/s walking; verdicts equal to 400 RK4/T: {100 * same:.1f} %; "
              f"MFPT {rd.estimate.mfpt:.4g}")
    st = MonteCarloSettings(sigma=sigma, runs=runs, max_steps=steps)
    b, el = per_run(design, st, np.arange(baseline_runs))
    base = b.scenario_steps / el
    same = np.mean(batch_verdicts(b, steps) == ref[:baseline_runs])
    print(f"  per-run full-order simulator (JIT, 2000 RK4/T), {baseline_runs} runs: "
          f"{base:.1f} steps/s; verdicts equal to the walker's: {100 * same:.0f} %")
    for k, (one, dask, s, walking, el, mfpt) in rows.items():
        print(f"  ratio {k} RK4/T: LocalCluster wall / per-run = {dask / base:.0f}x (walking "
              f"{walking / base:.0f}x), one process / per-run = {one / base:.0f}x")
        bench.row(f"zero dynamics, walker {k} RK4/T, LocalCluster of {nw} (wall, start-up "
                  f"included; baseline: full-order simulator run by run, {baseline_runs} "
                  f"runs)", round(dask), round(base, 1), unit="steps/s",
                  ratio=round(dask / base), target=f">= {ZD_TARGET:,} steps/s")
        bench.row(f"zero dynamics, walker {k} RK4/T, one process (same baseline)",
                  round(one), round(base, 1), unit="steps/s", ratio=round(one / base))
        bench.note(f"walker {k} RK4/T: {walking:.0f} steps/s walking in the workers, "
                   f"LocalCluster wall {el:.1f} s; verdicts equal to 400 RK4/T on "
                   f"{100 * s:.1f} % of {runs} runs; MFPT {mfpt:.4g}")
    bench.note(f"zero dynamics: the per-run path's verdicts equal the 400-step walker's on "
               f"{100 * same:.0f} % of its {baseline_runs} runs")
    bench.data["zero_dynamics"] = dict(
        runs=runs, steps=steps, sigma=sigma, chunk=chunk, baseline_runs=baseline_runs,
        baseline_steps_per_s=base, baseline_verdicts_equal=float(same),
        walkers={str(k): dict(one_process=v[0], local_cluster=v[1], verdicts_equal=v[2],
                              walking=v[3], elapsed=v[4], mfpt=v[5])
                 for k, v in rows.items()})
    return rows


def full_order(bench, design, model, runs, steps, sigma, baseline_runs, workers, nw):
    """(b): the full-order Monte Carlo with a model error against the per-run path."""
    print(f"(b) full order, torso 20 % heavier: {max(2, runs // 4)} runs of up to {steps} steps")
    desc = model.description.scaled(torso_mass=1.2)
    plant = robot(desc)
    n_b = max(2, runs // 4)
    out = {}
    for rk in (400, 200):
        st = MonteCarloSettings(sigma=sigma, runs=n_b, max_steps=steps, full_rk4_steps=rk,
                                chunk=max(1, n_b // 4))
        rd = monte_carlo(design, st, workers=workers, plant=desc.to_dict())
        b, el = per_run(design, st, np.arange(baseline_runs), plant=plant)
        base = b.scenario_steps / el
        same = np.mean(mc_verdicts(rd)[:baseline_runs] == batch_verdicts(b, steps))
        walking = nw * rd.steps_per_process_second
        print(f"  full order {rk} RK4/T via LocalCluster: {rd.steps_per_second:.0f} steps/s "
              f"(wall {rd.elapsed:.1f} s), {walking:.0f} steps/s walking; per-run (JIT, 2000 "
              f"RK4/T): {base:.1f} steps/s; ratio {rd.steps_per_second / base:.1f}x wall, "
              f"{walking / base:.1f}x walking; verdicts equal on the "
              f"{baseline_runs} compared runs: {100 * same:.0f} %; MFPT {rd.estimate.mfpt:.4g}")
        bench.row(f"full order, torso 20 % heavier, {rk} RK4/T, LocalCluster of {nw} (wall; "
                  f"baseline: the simulator run by run, 2000 RK4/T, {baseline_runs} runs)",
                  round(rd.steps_per_second, 1), round(base, 1), unit="steps/s",
                  ratio=round(rd.steps_per_second / base, 1),
                  target=f">= {FULL_TARGET} steps/s")
        bench.note(f"full order {rk} RK4/T: {walking:.0f} steps/s walking in the workers, "
                   f"wall {rd.elapsed:.1f} s for {n_b} runs; verdicts equal to the per-run "
                   f"path's on {100 * same:.0f} % of {baseline_runs} runs; MFPT "
                   f"{rd.estimate.mfpt:.4g}")
        out[str(rk)] = dict(local_cluster=rd.steps_per_second, walking=walking,
                            elapsed=rd.elapsed, baseline_steps_per_s=base,
                            verdicts_equal=float(same), mfpt=rd.estimate.mfpt, runs=n_b)
    bench.data["full_order"] = out
    return out


def main(runs=400, steps=40, sigma=0.01, baseline_runs=8, workers=None, chunk=None,
         parts="ab", save=True):
    print(f"{platform.node()}: {os.cpu_count()} cores, load {os.getloadavg()}")
    model = rabbit()
    gait = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)
    design = Design.tv(gait, TODAY_DESIGN, REJOIN)
    nw = workers or len(os.sched_getaffinity(0))
    with Run("terrain", "Monte Carlo on stochastic terrain, steps walked per second, "
             "against the full-order simulator run by run", save=save) as bench:
        rows = zero_dynamics(bench, design, runs, steps, sigma, baseline_runs, workers,
                             chunk, nw)
        if "b" in parts:
            full_order(bench, design, model, runs, steps, sigma, baseline_runs, workers, nw)
        bench.note(f"design: the sampling search's, {design.label()}, on the robust gait; "
                   f"sigma {sigma} m, up to {steps} steps per run")
    print(f"load at the end {os.getloadavg()}")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=400)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--baseline-runs", type=int, default=8)
    ap.add_argument("--workers", type=int)
    ap.add_argument("--chunk", type=int, help="runs per chunk (default: runs / (2 workers))")
    ap.add_argument("--parts", default="ab", help="a: zero dynamics, b: full order")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    a = ap.parse_args()
    main(a.runs, a.steps, a.sigma, a.baseline_runs, a.workers, a.chunk, a.parts,
         not a.no_save)
