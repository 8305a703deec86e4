"""RABBIT's 1.5 m/s running gait in MuJoCo under its tracking controller: the figures of
docs/howto/running.md ("Running in MuJoCo").

Solves the gait (default grid, cached), builds the exact stride map once (the fixed
points and eigenvalues of the stable design M1 = (0, 0.95, 0.95, 0) and of plain
tracking M1 = 0, PD Kp 400, Kd 30), then in MuJoCo at stiff contact (solref 4 ms) with
time steps 2, 1 and 0.5 ms: 30 strides of each design from its exact fixed point with
0.01 rad/s on every velocity (the exact run of the same start beside them), and a run of
300 strides of the stable design from its fixed point whose landing states give MuJoCo's
stride map (:func:`biped_casadi.mujoco.running.fit_running_map`).

Run: ``python benchmarks/mujoco_running.py [--out DIR]``; writes
``DIR/mujoco_running.png`` (default docs/_static) and prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from biped_casadi import rabbit
from biped_casadi.control.running import RunningController
from biped_casadi.mujoco import ContactSettings
from biped_casadi.mujoco.running import fit_running_map, run_in_mujoco
from biped_casadi.results import json_safe
from gait_opt.running import RunningOptions, optimize_running
from analysis.reporting.plots import save_figure
from analysis.stability.running_cycle import running_cycle, running_stability, simulate_running

ROOT = Path(__file__).resolve().parents[1]
KP, KD = 400.0, 30.0
STABLE = (0.0, 0.95, 0.95, 0.0)
TIMESTEPS = (0.002, 0.001, 0.0005)


def _summary(r, gait):
    s = r.strides
    late = s[len(s) // 3:] or s
    return dict(status=r.status, message=r.message, strides=len(s),
                deviations=r.deviations,
                stance=[x.stance for x in s], flight=[x.flight for x in s],
                speed=[x.speed for x in s],
                mean_stance=float(np.mean([x.stance for x in late])) if late else None,
                mean_flight=float(np.mean([x.flight for x in late])) if late else None,
                mean_speed=float(np.mean([x.speed for x in late])) if late else None,
                stance_range=[min(x.stance for x in s), max(x.stance for x in s)] if s else None,
                flight_range=[min(x.flight for x in s), max(x.flight for x in s)] if s else None,
                speed_range=[min(x.speed for x in s), max(x.speed for x in s)] if s else None,
                peak_torque=max((x.peak_torque for x in s), default=0.0),
                clipped_time=sum(x.clipped_time for x in s),
                slip_mm=[1e3 * x.slip for x in s],
                bounce_time=sum(x.bounce_time for x in s),
                wall_time=r.wall_time, mujoco_steps=r.mujoco_steps)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "_static"))
    ap.add_argument("--long", type=int, default=300, help="strides of the run fitted")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    m = rabbit()
    gait = optimize_running(m, RunningOptions(speed=1.5), cache=True)
    c = RunningController(m, gait, KP, KD, M1=STABLE)
    cyc = running_cycle(c)
    designs = {"stable": (c, cyc), "plain": (c.with_gains(M1=np.zeros(4)),
                                              cyc.retuned(M1=np.zeros(4)))}
    out = dict(gait=dict(T_stance=gait.T_stance, T_flight=gait.T_flight, speed=gait.speed),
               exact={}, mujoco={}, fits={})
    exact_runs = {}
    for name, (ctl, cy) in designs.items():
        st = running_stability(cy)
        x0 = st.fixed_point.copy()
        x0[m.nq:] += 1e-2
        ex = simulate_running(cy, st.fixed_point, x0, strides=30)
        exact_runs[name] = ex
        out["exact"][name] = dict(spectral_radius=st.spectral_radius,
                                  eigenvalues=st.eigenvalues[:4],
                                  durations=st.durations, fixed_point=st.fixed_point,
                                  run_status=ex.status, run_message=ex.message,
                                  deviations=ex.deviations)
        for dt in TIMESTEPS:
            r = run_in_mujoco(ctl, x0, 30, ContactSettings(timestep=dt),
                              fixed_point=st.fixed_point)
            out["mujoco"][f"{name}_{dt:g}"] = _summary(r, gait)
        if name == "stable":
            for dt in TIMESTEPS[:2]:
                r = run_in_mujoco(ctl, st.fixed_point, args.long,
                                  ContactSettings(timestep=dt), fixed_point=st.fixed_point)
                f = fit_running_map(r, reference=st.A)
                out["fits"][f"{dt:g}"] = dict(f.to_dict(), run=_summary(r, gait))
    out["wall_time"] = time.perf_counter() - t0

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.6))
    for i, name in enumerate(("stable", "plain")):
        a = ax[i]
        ex = exact_runs[name]
        a.semilogy(np.arange(len(ex.deviations)), ex.deviations, "k-o", ms=3,
                   label="exact stride map (RK4, rigid contact)")
        rho = out["exact"][name]["spectral_radius"]
        k = np.arange(0, 31)
        d1 = ex.deviations[1] if len(ex.deviations) > 1 else ex.deviations[0]
        a.semilogy(k[1:], d1 * rho ** (k[1:] - 1.0), "k:",
                   label=f"spectral radius {rho:.3g} per stride")
        for dt, style in zip(TIMESTEPS, ("C0-s", "C1-^", "C2-v")):
            d = out["mujoco"][f"{name}_{dt:g}"]["deviations"]
            a.semilogy(np.arange(len(d))[1:], d[1:], style, ms=3,
                       label=f"MuJoCo, dt {1e3 * dt:g} ms")
        a.set_xlabel("stride")
        a.set_ylabel("max |x_k - x*| at landing (rad, rad/s)")
        a.set_title(("M1 = (0, 0.95, 0.95, 0)" if name == "stable" else "M1 = 0 (plain tracking)")
                    + ", PD Kp 400, Kd 30")
        a.set_ylim(1e-9 if name == "stable" else 1e-3, 1e2)
        a.set_xlim(-0.5, 30.5 if name == "stable" else 6.5)
        a.grid(True, which="major", alpha=0.3)
        a.legend(fontsize=7, loc="lower left" if name == "stable" else "upper left")
    fig.suptitle("RABBIT running at 1.5 m/s, landing state's deviation per stride: MuJoCo "
                 "(stiff contact, solref 4 ms)\nagainst the exact stride map, from x* + 0.01 "
                 "rad/s on every velocity", fontsize=10)
    fig.tight_layout()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    out["figure"] = save_figure(fig, Path(args.out) / "mujoco_running.png")
    print(json.dumps(json_safe(out), indent=1))


if __name__ == "__main__":
    main()
