"""Reference-gait optimisation: wall time and transcription accuracy.

1. Wall time of ``optimize_gait(rabbit())`` at the default options, each run in a fresh
   process (imports, model, NLP build, IPOPT, polish, Gait all included), against
   baselines measured side by side in the same run: the first implementation of
   ``gait_opt`` (commit 99d60a0 with its own ``biped_casadi``, read from git: cost
   coupled through the step length, CasADi's MX Hessian, no common-subexpression
   elimination), the current NLP with CasADi deriving the exact Jacobian and Hessian
   from the whole MX graph (``derivatives='casadi'``), and that with ``expand=True``.
   Target: < 10 s on 2 cores.
2. Transcriptions (Legendre / Radau, a few n_intervals): solve time, IPOPT iterations,
   accuracy of the dynamics between the nodes before the polish (max |q_u collocation
   polynomial - exact solution of the unactuated row from the same initial state, with
   the same q_a^d|, on a dense grid), size of the polish correction, and the cost of the
   polished gait against the default transcription.

Run: ``python benchmarks/bench_gait.py [--quick] [--no-save]`` (--quick: no expand
baseline, one repeat).  The results go to ``benchmarks/results/gait.json`` (the docs'
benchmarks page): each baseline beside the default in the same run, the ratio baseline /
default (above 1: the default is faster), and each transcription's time beside the
default transcription's.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

FRESH = r"""
import json, sys, time
t0 = time.perf_counter()
from biped_casadi import rabbit
from gait_opt import optimize_gait
m = rabbit()
t1 = time.perf_counter()
g = optimize_gait(m, **json.loads(sys.argv[1]))
t2 = time.perf_counter()
s = g.solver_stats
print(json.dumps(dict(total=t2 - t0, optimize=t2 - t1, build=s["build_time"],
                      solve=s["solve_time"], polish=s["polish_time"],
                      iterations=s["iterations"], T=g.T, cost=g.cost,
                      hess=s["ipopt_timing"].get("nlp_hess_l"),
                      jac=s["ipopt_timing"].get("nlp_jac_g"))))
"""


ORIGINAL_COMMIT = "99d60a041d04afaec00e31a984875da942acaf3e"
ROOT = Path(__file__).resolve().parents[1]


def original_package(tmp: Path):
    """The first implementation (ORIGINAL_COMMIT: its ``biped_casadi`` and ``gait_opt``,
    which the first gait_opt needs) unpacked in ``tmp``; None when git or the commit is
    unavailable."""
    try:
        tar = subprocess.run(["git", "archive", ORIGINAL_COMMIT, "biped_casadi", "gait_opt"],
                             cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tmp)], input=tar, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return tmp


def fresh_run(overrides: dict, path: Path | None = None) -> dict:
    """optimize_gait(rabbit()) in a fresh process; with ``path``, the first implementation
    found there first on the import path."""
    t0 = time.perf_counter()
    code = FRESH
    env = dict(os.environ)
    if path is not None:               # the original reported no callback/polish timings
        code = code.replace('s["ipopt_timing"].get', "{}.get").replace('s["polish_time"]', "None")
        env["PYTHONPATH"] = f"{path}{os.pathsep}{env.get('PYTHONPATH', '')}"
    out = subprocess.run([sys.executable, "-c", code, json.dumps(overrides)],
                         capture_output=True, text=True, check=True, env=env, cwd=path)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    r["process"] = time.perf_counter() - t0      # interpreter start-up included
    return r


def wall_times(quick: bool):
    with tempfile.TemporaryDirectory(prefix="bench_gait_") as tmp:
        return _wall_times(quick, original_package(Path(tmp)))


def _wall_times(quick: bool, orig):
    cases = [("structured derivatives (default)", {}, 1 if quick else 3, None),
             ("baseline: CasADi AD of the MX graph", {"derivatives": "casadi"}, 1, None)]
    if not quick:
        cases.append(("baseline: CasADi AD, expand=True", {"derivatives": "casadi",
                                                           "expand": True}, 1, None))
    if orig is not None:
        cases.append(("baseline: first implementation", {}, 1, orig))
    else:
        print("(git or commit 99d60a0 unavailable: no first-implementation baseline)")
    rows = []
    for name, ov, reps, path in cases:
        runs = [fresh_run(ov, path) for _ in range(reps)]
        med = {k: statistics.median(np.nan if r[k] is None else r[k] for r in runs) for k in
               ("process", "total", "optimize", "build", "solve", "polish", "hess", "jac")}
        rows.append((name, med, runs[0]))
    base = rows[0][1]["process"]
    print("\n1. optimize_gait(rabbit()) at default options, fresh process each "
          "(median of the repeats)")
    print(f"{'variant':38s} {'process':>8s} {'build':>7s} {'solve':>7s} {'hess':>7s} "
          f"{'jac_g':>7s} {'polish':>7s} {'iter':>5s} {'T (s)':>11s} {'cost':>12s} {'ratio':>6s}")

    def f(v):
        return f"{v:7.2f}" if np.isfinite(v) and v > 0 else f"{'-':>7s}"

    for name, m, r in rows:
        print(f"{name:38s} {m['process']:8.2f} {f(m['build'])} {f(m['solve'])} "
              f"{f(m['hess'])} {f(m['jac'])} {f(m['polish'])} {r['iterations']:5d} "
              f"{r['T']:11.8f} {r['cost']:12.6f} {m['process'] / base:6.2f}")
    ok = rows[0][1]["process"] < 10.0
    print(f"target < 10 s for the default gait in a fresh process: "
          f"{'met' if ok else 'MISSED'} ({rows[0][1]['process']:.2f} s)")
    return rows


def collocation_polynomial(opts, Xs, Xc, s):
    """q_u of the collocation solution at s (Lagrange polynomial on each interval)."""
    import casadi as ca
    N, d = opts.n_intervals, opts.degree
    tau = np.r_[0.0, np.array(ca.collocation_points(d, opts.scheme))]
    k = np.minimum((s * N).astype(int), N - 1)
    th = s * N - k
    vals = np.zeros_like(s)
    for j in range(d + 1):
        lj = np.ones_like(s)
        for m_ in range(d + 1):
            if m_ != j:
                lj *= (th - tau[m_]) / (tau[j] - tau[m_])
        node = Xs[0, k] if j == 0 else Xc[0, k * d + j - 1]
        vals += lj * node
    return vals


def transcriptions():
    from biped_casadi import rabbit
    from gait_opt import Gait, GaitOptions
    from gait_opt.optimize import solve_collocation
    from gait_opt.polish import polish

    m = rabbit()
    configs = [("legendre", 3, 30), ("legendre", 3, 20), ("legendre", 3, 15),
               ("legendre", 3, 10), ("radau", 3, 30), ("radau", 3, 20), ("radau", 3, 15)]
    rows = []
    for scheme, d, N in configs:
        opts = GaitOptions(scheme=scheme, degree=d, n_intervals=N)
        t0 = time.perf_counter()
        r = solve_collocation(m, opts)
        t_solve = time.perf_counter() - t0
        exact = Gait(m, opts, r.alpha, r.Xs[:, 0], r.T)     # unactuated row from x(0), RK4
        s = np.linspace(0.0, 1.0, 4001)
        err = np.max(np.abs(collocation_polynomial(opts, r.Xs, r.Xc, s) - exact.q(s * r.T)[0]))
        t1 = time.perf_counter()
        a, x0, T, _ = polish(m, opts, r.alpha, r.Xs[:, 0], r.T)
        t_polish = time.perf_counter() - t1
        change = np.max(np.abs(np.r_[(a - r.alpha).ravel(), x0 - r.Xs[:, 0], T - r.T]))
        g = Gait(m, opts, a, x0, T)
        rows.append(dict(scheme=scheme, d=d, N=N, time=t_solve + t_polish, iters=r.iterations,
                         err=err, change=change, T=g.T, cost=g.cost,
                         valid=not g.violations()))
    ref = rows[0]
    print("\n2. transcriptions of the unactuated row (Bezier degree 6 for q_a^d in all); "
          "time = build + IPOPT + polish, in process")
    print(f"{'scheme':9s} {'d':>2s} {'N':>3s} {'time s':>7s} {'iter':>5s} "
          f"{'|q_u colloc - exact|':>21s} {'polish |dp|':>12s} {'T (s)':>11s} "
          f"{'cost':>11s} {'cost/ref-1':>11s} {'valid':>6s}")
    for r in rows:
        print(f"{r['scheme']:9s} {r['d']:2d} {r['N']:3d} {r['time']:7.2f} {r['iters']:5d} "
              f"{r['err']:21.2e} {r['change']:12.2e} {r['T']:11.8f} {r['cost']:11.5f} "
              f"{r['cost'] / ref['cost'] - 1:11.2e} {str(r['valid']):>6s}")
    return rows


def record_wall_times(bench: Run, rows, quick: bool):
    """Rows: the default gait's fresh-process time beside each baseline's."""
    name, ours, first = rows[0]
    reps = 1 if quick else 3
    for i, (bname, m, r) in enumerate(rows[1:]):
        bench.row(f"`optimize_gait(rabbit())` in a fresh process (median of {reps}), "
                  f"{bname}", round(ours["process"], 2), round(m["process"], 2),
                  ratio=round(m["process"] / ours["process"], 2),
                  target="< 10 s (ours)" if i == 0 else "")
        bench.data.setdefault("wall", {})[bname] = dict(median=m, iterations=r["iterations"],
                                                        T=r["T"], cost=r["cost"])
    bench.data.setdefault("wall", {})[name] = dict(median=ours, iterations=first["iterations"],
                                                   T=first["T"], cost=first["cost"])
    bench.note("fresh process: interpreter start-up, imports, model, NLP build, IPOPT, "
               "polish and the Gait all included; the baselines are one run each")


def record_transcriptions(bench: Run, rows):
    """Rows: each transcription's time beside the default's (Legendre d = 3, N = 30)."""
    ref = rows[0]
    for r in rows[1:]:
        bench.row(f"{r['scheme'].capitalize()} d = {r['d']}, N = {r['N']}: build + IPOPT + "
                  f"polish, in process (baseline: Legendre d = 3, N = 30, the default)",
                  round(r["time"], 2), round(ref["time"], 2),
                  ratio=round(ref["time"] / r["time"], 2))
    for r in rows:
        bench.note(f"{r['scheme']} d = {r['d']}, N = {r['N']}: {r['iters']} IPOPT iterations, "
                   f"|q_u collocation - exact| {r['err']:.1e} rad before the polish, polish "
                   f"change {r['change']:.1e}, cost / default - 1 = "
                   f"{r['cost'] / ref['cost'] - 1:.1e}, valid {r['valid']}")
    bench.data["transcriptions"] = rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, no expand baseline")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    args = ap.parse_args(argv)
    import casadi
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}, CasADi {casadi.__version__}; load "
          f"{os.getloadavg()[0]:.2f}")
    with Run("gait", "the default gait's optimisation in a fresh process against earlier "
             "derivative strategies; transcriptions against the default one",
             save=not args.no_save) as bench:
        record_wall_times(bench, wall_times(args.quick), args.quick)
        record_transcriptions(bench, transcriptions())
    print(f"load at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
