"""The running controller exported as C: time per call of the C law against the Python
law, and RABBIT running in MuJoCo with either in the loop.

RABBIT's 1.5 m/s running step (default grid, cached) under the how-to's design (PD
Kp 400 N m/rad, Kd 30 N m s/rad, M1 = (0, 0.95, 0.95, 0)) and under computed torque (Kp
100 1/s^2, Kd 20 1/s), each exported (:mod:`biped_casadi.control.export_running`) and
compiled with ``-O2``:

- per call, on states of both phases (alternately): the C law in the export's example
  loop (C alone, ``--calls`` calls, median of ``--repeats``); the library through
  ctypes as the MuJoCo loop calls it (:meth:`CompiledRunningLaw.stance` / ``flight``);
  the Python law as the loop calls it (the controller's CasADi Functions through
  :class:`~biped_casadi.numerics.FastCall`) and as an ordinary CasADi call;
- MuJoCo (stiff: dt 2 ms, solref 4 ms): 30 strides from the collocated landing state with
  0.01 rad/s on every velocity, with the Python law and with the library, wall time of
  each (median of ``--repeats``) and the largest difference between their stride
  records.

Ratios are the Python figure over the C one (above 1: C faster), from the same run.  The
machine is shared: read the ratios.  Results: ``benchmarks/results/export_running.json``.

    python benchmarks/bench_export_running.py [--calls N] [--repeats R] [--python-calls M]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

from analysis.verify_export import time_example  # noqa: E402
from analysis.verify_running_export import compare_running_mujoco  # noqa: E402
from biped_casadi import rabbit  # noqa: E402
from biped_casadi.control.compiled import find_c_compiler  # noqa: E402
from biped_casadi.control.compiled_running import CompiledRunningLaw  # noqa: E402
from biped_casadi.control.export_folder import write_export  # noqa: E402
from biped_casadi.control.export_running import (exported_running_law,  # noqa: E402
                                                 running_c_sources)
from biped_casadi.control.running import RunningController  # noqa: E402
from biped_casadi.numerics import FastCall  # noqa: E402
from gait_opt.running import RunningOptions, optimize_running  # noqa: E402

STABLE = (0.0, 0.95, 0.95, 0.0)


def _states(ctrl, n: int, rng) -> list:
    """n states alternating stance and flight: (phase, t, q, dq)."""
    g, out = ctrl.gait, []
    for k in range(n):
        phase = ("stance", "flight")[k % 2]
        X = np.asarray(getattr(g, f"x_{phase}"), float)
        ne, j = X.shape[0] // 2, int(rng.integers(X.shape[1]))
        t = float(rng.uniform(0, 1)) * float(getattr(g, f"T_{phase}"))
        out.append((k % 2, t, X[:ne, j] + rng.normal(0, 0.01, ne),
                    X[ne:, j] + rng.normal(0, 0.1, ne)))
    return out


def _per_call(calls: list, states: list) -> float:
    """Microseconds per call of calls[phase](q, dq, t) over the states."""
    t0 = time.perf_counter()
    for phase, t, q, dq in states:
        calls[phase](q, dq, t)
    return 1e6 * (time.perf_counter() - t0) / len(states)


def bench(ctrl, cc, args, work: Path) -> dict:
    folder = work / f"export_{ctrl.law}"
    t0 = time.perf_counter()
    write_export(running_c_sources(exported_running_law(ctrl)), folder)
    t_export = time.perf_counter() - t0
    t0 = time.perf_counter()
    lib = CompiledRunningLaw.build(folder, ctrl, work / f"lib_{ctrl.law}.so", cc)
    t_build = time.perf_counter() - t0
    c_runs = [time_example(folder, cc, args.calls, work, "biped_running_torque")[0]
              for _ in range(args.repeats)]
    states = _states(ctrl, args.python_calls, np.random.default_rng(0))
    fast = [FastCall(ctrl.stance_law), FastCall(ctrl.flight_law)]
    row = dict(law=ctrl.law, c_us=statistics.median(c_runs), c_us_runs=c_runs,
               ctypes_us=_per_call([lib.stance, lib.flight], states),
               python_fastcall_us=_per_call(fast, states),
               python_casadi_us=_per_call([ctrl.stance_law, ctrl.flight_law], states),
               export_seconds=t_export, build_seconds=t_build,
               source_bytes=sum(p.stat().st_size for p in folder.glob("*.c")))
    x0 = np.asarray(ctrl.gait.x_stance, float)[:, 0].copy()
    x0[ctrl.model.nq:] += 0.01
    cmp = [compare_running_mujoco(lib, ctrl, x0, 30) for _ in range(args.repeats)]
    row.update(mujoco=cmp[0].to_dict(),
               mujoco_python_s=statistics.median(c.python_seconds for c in cmp),
               mujoco_compiled_s=statistics.median(c.compiled_seconds for c in cmp))
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=1_000_000, help="C loop calls (1000000)")
    ap.add_argument("--repeats", type=int, default=5, help="C loop and MuJoCo runs (5)")
    ap.add_argument("--python-calls", type=int, default=4000,
                    help="calls of the Python law and through ctypes (4000)")
    ap.add_argument("--no-save", action="store_true")
    args = ap.parse_args(argv)
    cc = find_c_compiler()
    if cc is None:
        raise SystemExit("bench_export_running: no C compiler (gcc, cc or $CC)")
    m = rabbit()
    gait = optimize_running(m, RunningOptions(speed=1.5), cache=True)
    ctrls = [RunningController(m, gait, 400.0, 30.0, M1=STABLE),
             RunningController(m, gait, 100.0, 20.0, M1=STABLE, law="computed_torque")]
    with Run("export_running", "the running controller exported as C: time per call, "
                               "and in MuJoCo", save=not args.no_save) as run, \
            tempfile.TemporaryDirectory() as tmp:
        for ctrl in ctrls:
            r = bench(ctrl, cc, args, Path(tmp))
            law = r["law"]
            run.row(f"{law}: one torque call, C alone (example loop) against the Python law "
                    "as the MuJoCo loop calls it (FastCall)", r["c_us"],
                    r["python_fastcall_us"], unit="us")
            run.row(f"{law}: one torque call through ctypes as the MuJoCo loop calls it, "
                    "against the same Python call", r["ctypes_us"], r["python_fastcall_us"],
                    unit="us")
            run.row(f"{law}: one torque call, C alone, against an ordinary CasADi call",
                    r["c_us"], r["python_casadi_us"], unit="us")
            run.row(f"{law}: 30 MuJoCo strides (wall time of the loop) with the library "
                    "against the Python law", r["mujoco_compiled_s"], r["mujoco_python_s"],
                    unit="s")
            mj = r["mujoco"]
            steps = mj["mujoco_steps"]
            run.note(f"{law}: {mj['message']}; {steps} MuJoCo steps: "
                     f"{steps / r['mujoco_compiled_s']:.0f} steps/s with the library, "
                     f"{steps / r['mujoco_python_s']:.0f} with the Python law (the loop's own "
                     f"bookkeeping in Python included); export {r['export_seconds']:.2f} s, "
                     f"build {r['build_seconds']:.2f} s, {r['source_bytes']} bytes of C")
            run.data[law] = r
            print(f"{law:16s} C {r['c_us']:.3f} us, ctypes {r['ctypes_us']:.2f} us, Python "
                  f"(FastCall) {r['python_fastcall_us']:.1f} us, CasADi call "
                  f"{r['python_casadi_us']:.1f} us; MuJoCo 30 strides "
                  f"{r['mujoco_compiled_s']:.3f} s (C) / {r['mujoco_python_s']:.3f} s "
                  f"(Python); {mj['message']}")
        run.data.update(calls=args.calls, repeats=args.repeats,
                        python_calls=args.python_calls, compiler=cc, flags="-O2")
    return 0


if __name__ == "__main__":
    sys.exit(main())
