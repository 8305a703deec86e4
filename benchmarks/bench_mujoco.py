"""Walking in MuJoCo (issue 45): the loop's speed, the issue's walking figures, the C law
against the Python law in the loop, MuJoCo's eigenvalues beside the exact ones.

Designs: virtual constraints on RABBIT's default gait and the robust design of ``biped m1
--robust`` on its gait (about 2 minutes the first time, then cached in BIPED_CACHE_DIR).

- Speed: MuJoCo steps per second of a walk with the exported C law in the loop (its steps
  driven by the C function of biped_casadi.mujoco.cloop, and by the Python loop) and with
  the same law in Python, beside a bare ``mj_step`` loop in Python feeding the same
  walk's controls open loop, timed in the same run: the baseline is what MuJoCo costs
  alone.  Median of ``--repeats``.
- The issue's walking figures at the stiff settings (dt 2 ms, solref 4 ms, 5 mm feet,
  mu 0.6): 100 steps from the gait and 30 from the paper's perturbation at scale 2, the
  speed and period errors, the worst pre-impact errors after step 10; at MuJoCo's
  default contact the same walks (30 steps without falling asked); the contact variant
  of the step start at both.
- The C law in the loop against the Python law in the loop: touchdown times, the largest
  torque difference relative to the peak torque (10 steps).
- MuJoCo's limit cycle and stride-map eigenvalues beside the exact ones.
- The floor (the issue's stretch): how far MuJoCo's cycle lies from the gait and how
  much it jitters, at dt 2, 1 and 0.5 ms, with the touchdown on MuJoCo's time grid and
  interpolated between time steps.

    python benchmarks/bench_mujoco.py [--repeats R] [--no-robust] [--no-save]

The results go to ``benchmarks/results/mujoco.json`` (the docs' benchmarks page).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from analysis.cli import main as biped_main
from analysis.in_mujoco import exact_eigenvalues
from biped_casadi import Design, Perturbation, rabbit
from biped_casadi.mujoco import (MUJOCO_DEFAULT, STIFF, TOUCHDOWNS, ContactSettings,
                                 MujocoLoop, mujoco_module, stride_map)
from biped_casadi.results import json_safe
from gait_opt import Gait, optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

#: the issue's target: MuJoCo steps per second with the C law in the loop
TARGET = 20_000


def robust_design() -> Design:
    """The robust design of ``biped m1 --robust`` (its simulate_args) on its gait."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = biped_main(["m1", "--robust", "--json"])
    if rc != 0:
        raise SystemExit(f"biped m1 --robust failed (exit {rc})")
    a = json.loads(buf.getvalue())["simulate_args"]
    gait = Gait.load(a[a.index("--gait") + 1])
    i = a.index("--m1")
    M1 = [float(v) for v in a[i + 1:i + 1 + gait.model.nu]]
    return Design.tv(gait, M1, float(a[a.index("--rejoin") + 1]))


def bare_steps_per_second(loop: MujocoLoop, steps: int = 30) -> tuple:
    """The same MuJoCo steps without the law: a walk's controls replayed open loop.

    Returns (bare steps per second, the C-law walk's steps per second): the walk with the
    law in the loop is run with its log, then a Python loop of ``d.ctrl[:] = ...;
    mj_step`` feeds the same controls from the same start (the baseline: what MuJoCo
    costs alone, with the same contacts until the open loop drifts)."""
    mujoco = mujoco_module()
    m, d = loop.m, loop.d
    g = loop.gait
    w = loop.run(g.q(0.0), g.dq(0.0), steps, log=True)
    G = loop.layout.G
    ctrl = np.array([G[s] @ u for s, u in zip(w.stance, w.u)])
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = loop.initial_state(g.q(0.0), g.dq(0.0))
    step = mujoco.mj_step
    t0 = time.perf_counter()
    for c in ctrl:
        d.ctrl[:] = c
        step(m, d)
    return len(ctrl) / (time.perf_counter() - t0), w.steps_per_second


def speed(loops: dict, design: Design, repeats: int) -> dict:
    """Steps per second: bare MuJoCo, the C law in the loop (its steps driven in C, and
    by the Python loop), the Python law in the loop (the C-law walks without their log,
    30 steps; the Python law's, 10 steps)."""
    g = design.gait
    out = dict(bare=[], c=[], c_python_loop=[], python=[])
    for _ in range(repeats):
        out["bare"].append(bare_steps_per_second(loops["c"])[0])
        out["c"].append(loops["c"].run(g.q(0.0), g.dq(0.0), 30).steps_per_second)
        out["c_python_loop"].append(loops["c_python_loop"].run(g.q(0.0), g.dq(0.0), 30)
                                    .steps_per_second)
        out["python"].append(loops["python"].run(g.q(0.0), g.dq(0.0), 10).steps_per_second)
    return {k: statistics.median(v) for k, v in out.items()} | {"all": out}


def walk_figures(design: Design, settings) -> dict:
    """The issue's walks at one setting: from the gait (100 steps) and from the paper's
    perturbation at scale 2 (30 steps), with both step starts."""
    g = design.gait
    q2, dq2 = Perturbation.paper(g.model.nq).scaled(2.0).initial_state(g)
    out = {}
    for start in ("impact", "contact"):
        loop = MujocoLoop(design, settings, step_start=start)
        for key, (q0, dq0, n) in dict(gait=(g.q(0.0), g.dq(0.0), 100),
                                      scale_2=(q2, dq2, 30)).items():
            w = loop.run(q0, dq0, n)
            d = {k: v for k, v in w.to_dict().items() if k != "steps"}
            d["max_impact_travel"] = max((s.impact_travel for s in w.steps), default=0.0)
            d["max_airborne_time"] = max((s.airborne_time for s in w.steps), default=0.0)
            out[f"{key}_{start}"] = d
    return out


def c_against_python(loops: dict, design: Design, steps: int = 10) -> dict:
    """The C law in the loop against the Python law in the loop."""
    g = design.gait
    c, py = (loops[k].run(g.q(0.0), g.dq(0.0), steps, log=True) for k in ("c", "python"))
    n = min(len(c.u), len(py.u))
    return dict(statuses=[c.status, py.status], steps=c.steps_walked,
                same_touchdowns=[s.t_touchdown for s in c.steps] ==
                [s.t_touchdown for s in py.steps],
                max_torque_rel=float(np.abs(c.u[:n] - py.u[:n]).max() / np.abs(py.u[:n]).max()),
                max_qpos=float(np.abs(c.qpos[:n] - py.qpos[:n]).max()))


def eigen(design: Design) -> dict:
    """MuJoCo's stride map at both settings beside the exact eigenvalues."""
    ex = exact_eigenvalues(design)
    out = dict(exact=ex, exact_max_abs=max(abs(e) for e in ex))
    for name, st in (("stiff", STIFF), ("default", MUJOCO_DEFAULT)):
        out[name] = stride_map(design, st).to_dict()
        out[name]["message"] = out[name]["message"].split(";")[0]
    return out


def floor(design: Design) -> list:
    """The stretch: MuJoCo's cycle against the gait (its distance and jitter in dq_u at the
    section) and its eigenvalues, at dt 2, 1 and 0.5 ms (solref 4 ms), with the touchdown
    on MuJoCo's time grid and interpolated to where the foot meets the floor."""
    out = []
    for dt in (0.002, 0.001, 0.0005):
        for td in TOUCHDOWNS:
            loop = MujocoLoop(design, ContactSettings.of("stiff", timestep=dt), touchdown=td)
            g = design.gait
            w = loop.run(g.q(0.0), g.dq(0.0), 60)
            sm = stride_map(design, loop=loop, walk=w)
            c = sm.cycle
            out.append(dict(timestep=dt, touchdown=td, status=w.status,
                            speed_error=w.speed_error, period_error=w.period_error,
                            section_distance=c.section_distance, jitter=c.jitter,
                            eigenvalues=sm.eigenvalues, max_abs=sm.max_abs,
                            max_abs_spread=sm.max_abs_spread,
                            relative_residual=sm.relative_residual))
            print(f"  floor dt {1e3 * dt:g} ms, {td}: cycle - gait {np.round(c.section_distance, 4)}"
                  f", jitter {np.round(c.jitter, 4)}, max|lambda| {sm.max_abs:.3g} +- "
                  f"{sm.max_abs_spread:.2g} (res {sm.relative_residual:.2g})")
    return out


def _ev(ev) -> str:
    ev = [complex(*e) if isinstance(e, (list, tuple)) else complex(e) for e in ev]
    return "[" + ", ".join(f"{e.real:.3g}" if abs(e.imag) < 1e-12 else
                           f"{e.real:.3g}{e.imag:+.3g}j" for e in ev) + "]"


def _pct(x):
    return "n/a" if x is None or not np.isfinite(x) else f"{100 * x:+.2f} %"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats (3)")
    ap.add_argument("--no-robust", action="store_true",
                    help="skip the robust design (about 2 minutes when not cached)")
    ap.add_argument("--no-save", action="store_true", help="do not write the results file")
    args = ap.parse_args(argv)
    g = optimize_gait(rabbit(), cache=True)
    designs = {"virtual constraints": Design.vc(g)}
    if not args.no_robust:
        designs["robust design"] = robust_design()
    with Run("mujoco", "walking in MuJoCo with the exported C law in the loop",
             save=not args.no_save) as run:
        for label, design in designs.items():
            loops = {law: MujocoLoop(design, STIFF, law) for law in ("c", "python")}
            loops["c_python_loop"] = MujocoLoop(design, STIFF, "c", driver="python")
            sp = speed(loops, design, args.repeats)
            print(f"{label}: bare MuJoCo {sp['bare']:.0f} steps/s, C law {sp['c']:.0f} "
                  f"(steps driven by {loops['c'].driver}; by Python "
                  f"{sp['c_python_loop']:.0f}), Python law {sp['python']:.0f}")
            run.row(f"{label}: MuJoCo steps/s with the C law in the loop (bare mj_step loop "
                    "as baseline; ratio = ours / bare)", round(sp["c"]), round(sp["bare"]),
                    "steps/s", ratio=sp["c"] / sp["bare"], target=f">= {TARGET} steps/s")
            run.row(f"{label}: MuJoCo steps/s with the C law, the steps driven in C (driven "
                    "by the Python loop as baseline)", round(sp["c"]),
                    round(sp["c_python_loop"]), "steps/s", ratio=sp["c"] / sp["c_python_loop"])
            run.row(f"{label}: the same with the Python law", round(sp["python"]),
                    round(sp["bare"]), "steps/s", ratio=sp["python"] / sp["bare"])
            walks = {name: walk_figures(design, st) for name, st in
                     (("stiff", STIFF), ("default", MUJOCO_DEFAULT))}
            for name, w in walks.items():
                for key, r in w.items():
                    print(f"  {name} {key}: {r['status']} {r['steps_walked']}/{r['n_steps']}, "
                          f"speed {_pct(r['speed_error'])}, period {_pct(r['period_error'])}, "
                          f"worst after 10: {r['worst_qu_error']} rad, "
                          f"{r['worst_dqu_error']} rad/s; {r['message']}")
            eq = c_against_python(loops, design)
            print(f"  C against Python in the loop: {eq}")
            ev = eigen(design)
            print(f"  eigenvalues: exact {ev['exact']}; {ev['stiff']['message']}; "
                  f"default contact: {ev['default']['message']}")
            run.note(f"{label}: exact eigenvalues {_ev(ev['exact'])}; MuJoCo's, stiff "
                     f"{_ev(ev['stiff']['eigenvalues'])} (max|lambda| "
                     f"{ev['stiff']['max_abs']:.3g} +- {ev['stiff']['max_abs_spread']:.2g}, "
                     f"relative residual {ev['stiff']['relative_residual']:.2g}), default "
                     f"{_ev(ev['default']['eigenvalues'])} (max|lambda| "
                     f"{ev['default']['max_abs']:.3g} +- {ev['default']['max_abs_spread']:.2g}, "
                     f"relative residual {ev['default']['relative_residual']:.2g})")
            s = walks["stiff"]
            run.note(f"{label}, stiff: from the gait {s['gait_impact']['status']} "
                     f"{s['gait_impact']['steps_walked']}/100 (speed "
                     f"{_pct(s['gait_impact']['speed_error'])}, period "
                     f"{_pct(s['gait_impact']['period_error'])}, worst after step 10 "
                     f"{s['gait_impact']['worst_qu_error']:.3g} rad, "
                     f"{s['gait_impact']['worst_dqu_error']:.3g} rad/s); scale 2 "
                     f"{s['scale_2_impact']['status']} {s['scale_2_impact']['steps_walked']}/30 "
                     f"(speed {_pct(s['scale_2_impact']['speed_error'])}, period "
                     f"{_pct(s['scale_2_impact']['period_error'])}); MuJoCo's default contact: "
                     f"{walks['default']['gait_impact']['status']} "
                     f"{walks['default']['gait_impact']['steps_walked']}/100 (speed "
                     f"{_pct(walks['default']['gait_impact']['speed_error'])}), scale 2 "
                     f"{walks['default']['scale_2_impact']['status']} "
                     f"{walks['default']['scale_2_impact']['steps_walked']}/30")
            run.note(f"{label}: C law against Python law in the loop over {eq['steps']} steps: "
                     f"same touchdowns {eq['same_touchdowns']}, torques differ by at most "
                     f"{eq['max_torque_rel']:.2g} of the peak")
            fl = floor(design)
            worst = max(abs(r["section_distance"][1]) + r["jitter"][1] for r in fl
                        if r["timestep"] == 0.002)
            run.note(f"{label}, the floor (stretch) at dt 2 ms: MuJoCo's cycle lies "
                     + ", ".join(f"{r['section_distance'][1]:+.3f} rad/s ({r['touchdown']} "
                                 f"touchdown, jitter {r['jitter'][1]:.3f})"
                                 for r in fl if r["timestep"] == 0.002)
                     + " from the gait's dq_u at 0.75 T; at 1 and 0.5 ms: "
                     + ", ".join(f"{r['section_distance'][1]:+.3f} (jitter {r['jitter'][1]:.3f})"
                                 for r in fl if r["timestep"] < 0.002 and r["touchdown"] == "grid")
                     + f"; the cycle spans up to {worst:.2g} rad/s off the gait at 2 ms")
            run.data[label] = json_safe(dict(speed=sp, walks=walks, c_against_python=eq,
                                             eigenvalues=ev, floor=fl,
                                             design=design.to_dict()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
