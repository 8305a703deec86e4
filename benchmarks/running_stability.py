"""The closed loop of RABBIT's 1.5 m/s running gait: the figures of docs/howto/running.md
("Closing the loop").

Solves the gait (default grid), builds its stride map under the tracking controller
once per law (the gains are the domains' parameters, retuned without a rebuild), and
measures: the fixed point and its distance from the collocation at 4, 8 and 16 RK4
steps per interval, the eigenvalues, the AD Jacobian against central differences, the
spectral radius along M1 = (0, c, c, 0) for several gains and along each component of M1
alone (the figure), 20 strides from the fixed point with 0.01 rad/s on every velocity
for the stable design and for plain tracking (M1 = 0).

Run: ``python benchmarks/running_stability.py [--out DIR]``; writes
``DIR/running_stability.png`` (default docs/_static) and prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from biped_casadi import rabbit
from biped_casadi.control.running import RunningController
from gait_opt.running import RunningOptions, optimize_running
from analysis.reporting.plots import running_stability_plot, save_figure
from analysis.stability.running_cycle import (finite_difference_jacobian, running_cycle,
                                              running_stability, simulate_running)

ROOT = Path(__file__).resolve().parents[1]
KP, KD, C = 400.0, 30.0, 0.95


def _radius(cyc, **kw):
    r = running_stability(cyc.retuned(**kw))
    return r.spectral_radius if r.status != "failed" else np.nan


def _run(cyc, r, nq):
    x = r.fixed_point.copy()
    x[nq:] += 1e-2
    t0 = time.perf_counter()
    run = simulate_running(cyc, r.fixed_point, x, 20)
    d = run.deviations
    st = run.strides
    return dict(status=run.status, message=run.message, seconds=time.perf_counter() - t0,
                deviations=d.tolist(), contraction=run.contraction.tolist(),
                mean_contraction_after_first=(float((d[-1] / d[1]) ** (1 / (d.size - 2)))
                                              if d.size > 2 else None),
                fz_min=min((s.fz_min for s in st), default=None),
                friction_ratio_max=max((s.friction_ratio_max for s in st), default=None),
                friction_excess_max=max((s.friction_excess_max for s in st), default=None),
                torque_max=max((s.torque_max for s in st), default=None),
                swing_min=min((s.swing_min for s in st), default=None),
                impulse_ratio_max=max((s.landing_impulse_ratio for s in st), default=None))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "_static"))
    a = ap.parse_args()
    m = rabbit()
    out = {}
    t0 = time.perf_counter()
    g = optimize_running(m, RunningOptions(speed=1.5))
    out["gait"] = dict(seconds=time.perf_counter() - t0, T_stance=g.T_stance,
                       T_flight=g.T_flight, success=g.success)
    t0 = time.perf_counter()
    c = RunningController(m, g, KP, KD, M1=(0, C, C, 0))
    cyc = running_cycle(c)
    out["build_seconds"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = running_stability(cyc)
    out["fixed_point_seconds"] = time.perf_counter() - t0
    sv = np.linalg.svd(r.A, compute_uv=False)
    out["stable"] = dict(status=r.status, residual=r.residual, distance=r.distance,
                         start_residual=r.newton_start_residual,
                         durations=r.durations.tolist(), spectral_radius=r.spectral_radius,
                         eigenvalues=[[e.real, e.imag] for e in r.eigenvalues],
                         moduli=np.abs(r.eigenvalues).tolist(),
                         smallest_singular_value=float(sv[-1]),
                         largest_singular_value=float(sv[0]))
    t0 = time.perf_counter()
    fd = {}
    for step in (1e-5, 1e-6, 1e-7):
        J = finite_difference_jacobian(cyc, r.fixed_point, step)
        fd[f"{step:g}"] = float(np.abs(J - r.A).max() / np.abs(r.A).max())
    out["fd_relative_error"] = fd
    out["fd_seconds"] = time.perf_counter() - t0
    out["run_stable"] = _run(cyc, r, m.nq)
    plain = cyc.retuned(M1=np.zeros(4))
    rp = running_stability(plain)
    out["plain"] = dict(spectral_radius=rp.spectral_radius, distance=rp.distance,
                        moduli=np.abs(rp.eigenvalues).tolist(), run=_run(plain, rp, m.nq))
    # the discretisation: the fixed point's distance from the collocation, h halved
    disc = {}
    for spi in (4, 16):
        rr = running_stability(running_cycle(c, steps_per_interval=spi))
        disc[spi] = dict(distance=rr.distance, spectral_radius=rr.spectral_radius)
    disc[8] = dict(distance=r.distance, spectral_radius=r.spectral_radius)
    out["steps_per_interval"] = disc
    # sweeps
    cs = np.round(np.arange(0.5, 1.551, 0.025), 4)
    fam = {}
    gains = [("pd", 400.0, 30.0), ("pd", 400.0, 60.0), ("pd", 1000.0, 100.0),
             ("pd", 2500.0, 100.0), ("pd", 150.0, 15.0)]
    for law, kp, kd in gains:
        rad = [_radius(cyc, Kp=kp, Kd=kd, M1=(0, v, v, 0)) for v in cs]
        fam[f"PD, Kp {kp:g} N m/rad, Kd {kd:g} N m s/rad"] = (cs, np.array(rad))
    cct = running_cycle(RunningController(m, g, 400.0, 40.0, law="computed_torque"))
    rad = [_radius(cct, M1=(0, v, v, 0)) for v in cs]
    fam["computed torque, Kp 400 1/s^2, Kd 40 1/s"] = (cs, np.array(rad))
    vals = np.round(np.arange(-2.0, 3.01, 0.25), 4)
    singles = {}
    for i in range(4):
        rad = []
        for v in vals:
            M1 = np.zeros(4)
            M1[i] = v
            rad.append(_radius(cyc, M1=M1))
        singles[f"M1[{i + 1}] ({m.joint_names[i + 1]})"] = (vals, np.array(rad))
    out["sweep_c"] = {k: dict(c=v[0].tolist(), radius=v[1].tolist(),
                              stable=[float(x) for x, y in zip(*v) if y < 1],
                              best=[float(v[0][np.nanargmin(v[1])]), float(np.nanmin(v[1]))])
                      for k, v in fam.items()}
    out["sweep_single"] = {k: dict(value=v[0].tolist(), radius=v[1].tolist(),
                                   best=[float(v[0][np.nanargmin(v[1])]),
                                         float(np.nanmin(v[1]))])
                           for k, v in singles.items()}
    folder = Path(a.out)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "running_stability.json").write_text(json.dumps(out, default=float))
    fig = running_stability_plot("RABBIT", 1.5, fam, singles, f"PD, Kp {KP:g}, Kd {KD:g}")
    out["figure"] = save_figure(fig, folder / "running_stability.png")
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
