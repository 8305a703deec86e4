"""Full-order closed-loop simulation: simulated steps per second of wall time.

Ours: :func:`biped_casadi.simulation.simulate` (fixed-step RK4, 2000 steps per T, a
chunk of 500 steps per CasADi call, impact located by Newton), interpreted and
JIT-compiled.  Baseline, in the same run: ``scipy.integrate.solve_ivp`` (DOP853,
rtol 1e-10, atol 1e-12, the guard as a terminal event) on the same closed-loop
right-hand side, a CasADi Function called once per evaluation: the usual way to
simulate a CasADi model from Python.  Both from the same perturbed state; the
printed difference of impact times shows they simulate the same motion.

    python benchmarks/bench_simulate.py [--steps N] [--gait FILE] [--no-save]

The results go to ``benchmarks/results/simulate.json`` (the docs' benchmarks page): our
steps per second beside the baseline's, the ratio ours / baseline in steps per second
(= the baseline's wall time per step over ours: above 1, ours is faster).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
from scipy.integrate import solve_ivp

from analysis import PoincareMap
from biped_casadi import (SimulationOptions, Simulator, TimeVaryingController,
                          VirtualConstraintController, perturbed_initial_state)
from gait_opt import Gait, optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402


def load_gait(path):
    return Gait.load(path) if path else optimize_gait(cache=True)


def scipy_baseline(ctrl, q0, dq0, steps):
    """The same hybrid closed loop with solve_ivp; returns the impact times."""
    m = ctrl.model
    X = ca.SX.sym("X", 10 + ctrl.n_ref)
    tau = ca.SX.sym("tau")
    p = ca.SX.sym("p", ctrl.n_par)
    q, dq, r = X[:5], X[5:10], X[10:]
    u, _, _, _, dr, _ = ctrl.law(q, dq, tau, r, p)
    f = ca.Function("rhs", [tau, X, p], [ca.vertcat(dq, m.forward_dynamics(q, dq, u), dr)])
    zsw = ca.Function("z_sw", [X], [m.swing_foot(q)[1], m.swing_foot(q)[0]])
    T = ctrl.gait.T
    times, t0 = [], 0.0
    for _ in range(steps):
        st = ctrl.step_start(q0, dq0)
        pp = st.p

        def rhs(t, x):
            return np.array(f(t, x, pp)).ravel()

        def guard(t, x):
            z, xs = zsw(x)
            return float(z) if float(xs) > 0 else 1.0
        guard.terminal, guard.direction = True, -1
        sol = solve_ivp(rhs, (0.0, 2 * T), np.r_[q0, dq0, st.r], method="DOP853",
                        rtol=1e-10, atol=1e-12, events=guard)
        if not sol.t_events[0].size:
            break
        te, xe = sol.t_events[0][0], sol.y_events[0][0]
        t0 += te
        times.append(t0)
        qp, dqp = m.impact(xe[:5], xe[5:10])
        q0, dq0 = np.array(qp).ravel(), np.array(dqp).ravel()
    return np.array(times)


def best_stable_m1(model, gait):
    v = np.linspace(-10, 10, 5)
    pts = np.array(np.meshgrid(v, v, v, v, indexing="ij")).reshape(4, -1).T
    jb = PoincareMap(model, gait).jacobian_batch(pts)
    status, mx = jb.status, jb.max_abs
    return pts[int(np.argmin(np.where(status == "stable", mx, np.inf)))]


def main(steps=10, gait_path=None, save=True):
    print(f"load {os.getloadavg()[0]:.2f}")
    with Run("simulate", "full-order closed-loop simulation, simulated steps per second, "
             "against SciPy solve_ivp on the same closed loop", save=save) as bench:
        rows = measure(steps, gait_path)
        for name, jit, ours, base, t_build, diff, status in rows:
            bench.row(f"{name}: RK4 ({'JIT-compiled' if jit else 'CasADi VM'}), {steps} "
                      f"steps (baseline: solve_ivp DOP853 rtol 1e-10)", round(ours, 2),
                      round(base, 2), unit="steps/s", ratio=round(ours / base, 1))
            bench.note(f"{name}, {'JIT' if jit else 'VM'}: build {t_build:.1f} s (not in the "
                       f"rate); {status}; max |impact time - baseline's| {diff:.1e} s")
        bench.data["rows"] = [dict(controller=r[0], jit=r[1], steps_per_s=r[2],
                                   baseline_steps_per_s=r[3], build_s=r[4],
                                   impact_time_diff_s=r[5], status=r[6]) for r in rows]
    print(f"load at the end {os.getloadavg()[0]:.2f}")
    return rows


def measure(steps, gait_path):
    gait = load_gait(gait_path)
    model = gait.model
    q0, dq0 = perturbed_initial_state(gait, 1e-3, 1e-2)
    M1 = best_stable_m1(model, gait)
    rows = []
    for name, ctrl in (("time-varying, M1 = [" + ", ".join(f"{v:.3g}" for v in M1) + "]",
                        TimeVaryingController(gait, M1)),
                       ("virtual constraints", VirtualConstraintController(gait))):
        print(name)
        t = time.perf_counter()
        base = scipy_baseline(ctrl, q0, dq0, steps)
        t_base = time.perf_counter() - t
        print(f"  scipy solve_ivp DOP853 (baseline) {len(base) / t_base:8.2f} steps/s")
        for jit in (False, True):
            t = time.perf_counter()
            sim = Simulator(ctrl, SimulationOptions(steps=steps, jit=jit))
            t_build = time.perf_counter() - t
            t = time.perf_counter()
            res = sim.run(q0, dq0)
            el = time.perf_counter() - t
            n = len(res.steps)
            diff = np.max(np.abs(res.impact_times[:len(base)] - base[:n]))
            label = "RK4, JIT-compiled   " if jit else "RK4, CasADi VM      "
            print(f"  ours {label}          {n / el:8.2f} steps/s  x{(n / el) / (len(base) / t_base):6.1f}"
                  f" of baseline  (build {t_build:.1f} s; {res.status}; "
                  f"max |impact time - baseline| {diff:.1e} s)")
            rows.append((name, jit, n / el, len(base) / t_base, t_build, float(diff),
                         res.status))
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--gait", metavar="FILE")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    a = ap.parse_args()
    main(a.steps, a.gait, not a.no_save)
