"""Exported controllers: time per call of the C law against the Python/CasADi law.

For each controller (the robust design of ``biped m1 --robust`` on its gait, virtual
constraints on RABBIT's default gait, both controllers of the three-link biped): export
it (:mod:`biped_casadi.control.export`), build the export's example ``example/main.c``
and run its loop of ``biped_torque`` calls (C alone, ``--calls`` calls, ``--repeats``
times: the median and the best); in the same run, the Python law called one state at a
time on states of the reference (``TimeVaryingController.torque`` /
``VirtualConstraintController.evaluate``, the public one-state call), its bare CasADi
Function through :class:`~biped_casadi.numerics.FastCall` (the least Python can pay),
and the compiled library through ctypes.  Ratios are against the C loop of the same run.
The machine is shared: read the ratios, not the absolute figures.  The results go to
``benchmarks/results/export.json`` (machine, load, date, figures).

    python benchmarks/bench_export.py [--calls N] [--repeats R] [--python-calls M]
        [--no-robust] [--out FILE]

The robust design takes about 2 minutes the first time (then it is cached in
BIPED_CACHE_DIR).
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.cli import main as biped_main
from analysis.verify_export import time_example
from biped_casadi import TimeVaryingController, VirtualConstraintController, robot
from biped_casadi.control.compiled import CompiledController, build_library, find_c_compiler
from biped_casadi.control.export import c_sources, exported_law
from biped_casadi.control.export_folder import write_export
from biped_casadi.files import write_text_atomic
from biped_casadi.numerics import FastCall
from biped_casadi.results import json_safe
from gait_opt import Gait, optimize_gait

ROOT = Path(__file__).resolve().parents[1]
#: the issue's target for one biped_torque call, microseconds
TARGET_US = 5.0


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    return dict(cpu=cpu, nproc=os.cpu_count(), python=platform.python_version(),
                numpy=np.__version__, casadi=casadi.__version__)


def robust_controller():
    """The robust design of `biped m1 --robust` (its simulate_args) on its gait."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = biped_main(["m1", "--robust", "--json"])
    if rc != 0:
        raise SystemExit(f"biped m1 --robust failed (exit {rc})")
    a = json.loads(buf.getvalue())["simulate_args"]
    gait = Gait.load(a[a.index("--gait") + 1])
    i = a.index("--m1")
    M1 = [float(v) for v in a[i + 1:i + 1 + gait.model.nu]]
    rejoin = float(a[a.index("--rejoin") + 1])
    return TimeVaryingController(gait, M1, rejoin=rejoin)


def python_times(ctrl, n: int) -> dict:
    """Microseconds per call of the Python law one state at a time: the public call and
    the bare CasADi Function (FastCall), on n states of the reference."""
    ref, nu = ctrl.reference, ctrl.model.nu
    tau = np.linspace(0.0, ref.T, n, endpoint=False)
    q, dq = ref.q(tau), ref.dq(tau)
    p = ctrl.step_start(ref.q(0.0), ref.dq(0.0)).p
    r = ref.states(tau) if ctrl.n_ref else np.zeros((0, n))
    law = FastCall(ctrl.law)
    t0 = time.perf_counter()
    for k in range(n):
        if ctrl.n_ref:
            ctrl.torque(q[:, k], dq[:, k], tau[k], p[:nu], p[nu:])
        else:
            ctrl.evaluate(q[:, k], dq[:, k], tau[k], np.zeros(0), p)
    t1 = time.perf_counter()
    for k in range(n):
        law(q[:, k], dq[:, k], tau[k], r[:, k], p)
    t2 = time.perf_counter()
    return dict(python_us=1e6 * (t1 - t0) / n, casadi_fastcall_us=1e6 * (t2 - t1) / n)


def ctypes_time(lib, ctrl, n: int) -> float:
    ref = ctrl.reference
    tau = np.linspace(0.0, ref.T, n, endpoint=False)
    q, dq = ref.q(tau), ref.dq(tau)
    p = lib.step_start(ref.q(0.0), ref.dq(0.0)).p
    t0 = time.perf_counter()
    for k in range(n):
        lib.torque(float(tau[k]), q[:, k], dq[:, k], p)
    return 1e6 * (time.perf_counter() - t0) / n


def bench(name, ctrl, cc, args) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "export"
        t0 = time.perf_counter()
        write_export(c_sources(exported_law(ctrl)), folder)
        t_export = time.perf_counter() - t0
        t0 = time.perf_counter()
        lib = CompiledController(build_library(folder, Path(tmp) / "lib.so", cc), ctrl)
        t_build = time.perf_counter() - t0
        c_runs = [time_example(folder, cc, args.calls)[0] for _ in range(args.repeats)]
        size = sum(p.stat().st_size for p in folder.glob("*.c"))
    py = python_times(ctrl, args.python_calls)
    c_med = statistics.median(c_runs)
    row = dict(name=name, controller=ctrl.describe(), robot=ctrl.model.params.name,
               c_us_median=c_med, c_us_best=min(c_runs), c_us_runs=c_runs,
               c_calls=args.calls, ctypes_us=ctypes_time(lib, ctrl, args.python_calls),
               **py, python_calls=args.python_calls,
               ratio_python_to_c=py["python_us"] / c_med,
               ratio_fastcall_to_c=py["casadi_fastcall_us"] / c_med,
               export_seconds=t_export, build_seconds=t_build, source_bytes=size,
               target_us=TARGET_US, target_met=c_med <= TARGET_US)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=1_000_000, help="C loop calls (1000000)")
    ap.add_argument("--repeats", type=int, default=5, help="C loop runs (5)")
    ap.add_argument("--python-calls", type=int, default=2000,
                    help="Python calls, one state at a time (2000)")
    ap.add_argument("--no-robust", action="store_true",
                    help="skip the robust design (about 2 minutes when not cached)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "export.json"))
    args = ap.parse_args(argv)
    cc = find_c_compiler()
    if cc is None:
        raise SystemExit("bench_export: no C compiler (gcc, cc or $CC)")
    load0 = os.getloadavg()
    rabbit_gait = optimize_gait(cache=True)
    m3 = robot("three_link")
    g3 = optimize_gait(m3, cache=True)
    cases = []
    if not args.no_robust:
        cases.append(("robust design (RABBIT, its gait)", robust_controller()))
    cases += [("virtual constraints (RABBIT, default gait)",
               VirtualConstraintController(rabbit_gait)),
              ("time-varying M1 = (0.3, 1.7) (three-link)",
               TimeVaryingController(g3, [0.3, 1.7])),
              ("virtual constraints (three-link)", VirtualConstraintController(g3))]
    rows = [bench(name, ctrl, cc, args) for name, ctrl in cases]
    load1 = os.getloadavg()
    info = machine_info()
    print(f"machine: {info['cpu']}, {info['nproc']} cores, load {load0[0]:.2f} -> "
          f"{load1[0]:.2f}; compiler {' '.join(cc)} -O2; {args.calls} C calls x "
          f"{args.repeats}, {args.python_calls} Python calls")
    print(f"{'controller':44s} {'C us':>7s} {'best':>7s} {'ctypes':>7s} {'CasADi':>8s} "
          f"{'Python':>8s} {'Python/C':>9s}")
    for r in rows:
        print(f"{r['name']:44s} {r['c_us_median']:7.3f} {r['c_us_best']:7.3f} "
              f"{r['ctypes_us']:7.2f} {r['casadi_fastcall_us']:8.2f} {r['python_us']:8.1f} "
              f"{r['ratio_python_to_c']:9.0f}")
    met = all(r["target_met"] for r in rows)
    print(f"target: one biped_torque call <= {TARGET_US:g} us in C: "
          + ("met by every controller" if met else "NOT met"))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    body = dict(benchmark="export", date=datetime.datetime.now().isoformat(timespec="seconds"),
                machine=info, load=dict(before=list(load0), after=list(load1)),
                compiler=cc, flags="-O2", calls=args.calls, repeats=args.repeats,
                python_calls=args.python_calls, target_us=TARGET_US, target_met=met,
                results=rows)
    write_text_atomic(out, json.dumps(json_safe(body), indent=1) + "\n")
    print(f"results: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
