"""Gait family by continuation against solving each speed cold, side by side.

In one process, after a warm-up (one solve, so that neither side pays the one-time
construction of the cached CasADi Functions), the same speeds are solved

* by continuation: ``gait_family(model, speeds)`` (one NLP with the speed as parameter,
  IPOPT warm-started from the secant predictor; every member polished to an exact orbit
  and checked on the dense grid), and
* cold: the one gait solve (``optimize_gait(model, GaitOptions(speed=v))``) for each speed (a new NLP, IPOPT
  from the built-in guess; the same polish and dense-grid check),

in the order continuation, cold, continuation, cold, ... (``--repeats`` rounds), so that
a drift of the machine's load affects both.  Then (unless ``--no-interpolation``) the
gaits between the members: at every midpoint of the grid, ``GaitFamily.gait_at`` (the
interpolant's residual, the polish's change, the violations) against
``optimize_gait`` at that speed (T and cost).  Reported: the wall and CPU times (the
process's, less sensitive to other work on a shared machine), their ratios (cold /
continuation, the median over the rounds), IPOPT iterations, the orbit
residuals, and how the two sets of gaits compare (T, cost: the continuation can follow
a branch that a cold solve misses).  The results go to ``--out`` as JSON
(default ``benchmarks/results/family.json``) with the machine, ``os.getloadavg()``
before and after, and the date.

Run: ``python benchmarks/bench_family.py [--robot rabbit] [--speeds 0.4:1.2:0.05]
[--repeats 3] [--out FILE]``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import time
from pathlib import Path

import casadi

from biped_casadi import robot
from biped_casadi.files import write_text_atomic
from biped_casadi.results import json_safe
import numpy as np

from gait_opt import GaitOptions, gait_family, optimize_gait, parse_speed_range
from gait_opt.optimize import _solve as solve_once     # the one gait solve, its result

ROOT = Path(__file__).resolve().parents[1]


def continuation(model, speeds) -> dict:
    t0, c0 = time.perf_counter(), time.process_time()
    fam = gait_family(model, speeds)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return dict(wall=wall, cpu=cpu, status=fam.status, build_time=fam.build_time,
                covered=[r.speed for r in fam.records],
                iterations=[r.iterations for r in fam.records],
                orbit_residual=[r.orbit_residual for r in fam.records],
                T=[r.T for r in fam.records], cost=[r.cost for r in fam.records],
                end=fam.end, events=fam.events)


def cold(model, speeds) -> dict:
    rows = []
    t0, c0 = time.perf_counter(), time.process_time()
    for v in speeds:
        t = time.perf_counter()
        r = solve_once(model, GaitOptions(speed=float(v)))
        g = r.gait
        rows.append(dict(speed=float(v), time=time.perf_counter() - t, status=r.status,
                         success=r.success, iterations=r.iterations,
                         orbit_residual=g.orbit_residual()["worst"] if g else None,
                         T=g.T if g else None,
                         cost=g.solver_stats["ipopt_cost"] if g else None))
    return dict(wall=time.perf_counter() - t0, cpu=time.process_time() - c0, rows=rows)


def interpolation(model, speeds) -> list:
    """gait_at at the grid's midpoints against the optimum solved there."""
    fam = gait_family(model, speeds)
    rows = []
    for v in (speeds[:-1] + speeds[1:]) / 2:
        r = fam.gait_at(float(v))
        best = optimize_gait(model, speed=float(v))
        rows.append(dict(speed=float(v), status=r.status, resolved=r.resolved,
                         interpolant_residual=r.interpolant_residual,
                         parameter_change=r.parameter_change, orbit_residual=r.orbit_residual,
                         T_minus_optimum=r.gait.T - best.T,
                         cost_relative_to_optimum=(r.gait.cost - best.cost) / best.cost,
                         violations=r.violations))
        print(f"  {v:.4f} m/s: {r.status}, interpolant residual {r.interpolant_residual:.1e}, "
              f"polish change {r.parameter_change:.1e}, T - T* {rows[-1]['T_minus_optimum']:+.1e}"
              f" s, cost {rows[-1]['cost_relative_to_optimum']:+.1e} relative", flush=True)
    return rows


def compare(c: dict, k: dict) -> dict:
    """Where the two sets of gaits agree (same local optimum) and where not."""
    by_speed = {r["speed"]: r for r in k["rows"]}
    same, other = [], []
    for v, T, cost in zip(c["covered"], c["T"], c["cost"]):
        r = by_speed.get(v)
        if r is None or r["T"] is None:
            other.append(dict(speed=v, cold="failed"))
        elif abs(r["T"] - T) < 1e-6:
            same.append(v)
        else:
            other.append(dict(speed=v, T_continuation=T, T_cold=r["T"],
                              cost_continuation=cost, cost_cold=r["cost"]))
    return dict(same_optimum=same, different=other)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="rabbit")
    ap.add_argument("--speeds", default="0.4:1.2:0.05")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "family.json"))
    ap.add_argument("--no-interpolation", action="store_true")
    args = ap.parse_args(argv)
    model = robot(args.robot)
    speeds = parse_speed_range(args.speeds)
    load_before = os.getloadavg()
    solve_once(model, GaitOptions(speed=float(speeds[0])))        # warm-up
    rounds = []
    for i in range(args.repeats):
        c = continuation(model, speeds)
        k = cold(model, speeds)
        rounds.append(dict(continuation=c, cold=k, ratio=k["wall"] / c["wall"],
                           cpu_ratio=k["cpu"] / c["cpu"]))
        print(f"round {i + 1}: continuation {c['wall']:.2f} s wall, {c['cpu']:.2f} s CPU "
              f"({sum(c['iterations'])} IPOPT iterations, {len(c['covered'])} gaits), cold "
              f"{k['wall']:.2f} s wall, {k['cpu']:.2f} s CPU "
              f"({sum(r['iterations'] for r in k['rows'])} iterations, "
              f"{sum(r['success'] for r in k['rows'])} gaits): ratio {rounds[-1]['ratio']:.2f} "
              f"wall, {rounds[-1]['cpu_ratio']:.2f} CPU", flush=True)
    last = rounds[-1]
    c, k = last["continuation"], last["cold"]
    result = dict(
        benchmark="bench_family", date=datetime.datetime.now(datetime.timezone.utc)
        .isoformat(timespec="seconds"),
        machine=dict(machine=platform.machine(), cores=os.cpu_count(),
                     python=platform.python_version(), casadi=casadi.__version__,
                     system=platform.system(), release=platform.release()),
        loadavg_before=list(load_before), loadavg_after=list(os.getloadavg()),
        robot=args.robot, speeds=args.speeds, n_speeds=len(speeds),
        ratio_median=statistics.median(r["ratio"] for r in rounds),
        ratios=[r["ratio"] for r in rounds],
        cpu_ratio_median=statistics.median(r["cpu_ratio"] for r in rounds),
        cpu_ratios=[r["cpu_ratio"] for r in rounds],
        continuation_wall=[r["continuation"]["wall"] for r in rounds],
        cold_wall=[r["cold"]["wall"] for r in rounds],
        continuation_cpu=[r["continuation"]["cpu"] for r in rounds],
        cold_cpu=[r["cold"]["cpu"] for r in rounds],
        continuation=dict(status=c["status"], covered=[c["covered"][0], c["covered"][-1]],
                          n_gaits=len(c["covered"]), iterations=sum(c["iterations"]),
                          iterations_per_speed=c["iterations"], build_time=c["build_time"],
                          max_orbit_residual=max(c["orbit_residual"]), end=c["end"],
                          events=c["events"]),
        cold=dict(n_gaits=sum(r["success"] for r in k["rows"]),
                  iterations=sum(r["iterations"] for r in k["rows"]),
                  iterations_per_speed=[r["iterations"] for r in k["rows"]],
                  max_orbit_residual=max((r["orbit_residual"] for r in k["rows"]
                                          if r["orbit_residual"] is not None), default=None),
                  failed=[r["speed"] for r in k["rows"] if not r["success"]]),
        agreement=compare(c, k))
    if not args.no_interpolation:
        print("gaits between the members:")
        result["interpolation"] = interpolation(model, np.asarray(speeds))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(json_safe(result), indent=1, allow_nan=False))
    print(f"median ratio cold / continuation {result['ratio_median']:.2f} wall, "
          f"{result['cpu_ratio_median']:.2f} CPU over {args.repeats} rounds; load "
          f"{load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}; written {out}")
    return result


if __name__ == "__main__":
    main()
