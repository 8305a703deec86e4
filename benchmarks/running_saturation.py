"""RABBIT's running closed loop at 2.0 and 2.5 m/s with the torques clipped at the limit
(docs/howto/running.md, "Across speeds", the bullet on ``--saturate``).

Per case (the gait optimised at a torque bound, a design M1 and gains, clipping on or
off): the stride map's spectral radius, and 20 strides from the fixed point with
0.01 rad/s on every velocity: the status and the reason it stopped, the deviations, the
mean contraction per stride after the first, the largest torque the law asked for and
the time saturated in each completed stride.

The chosen M1 are read from the choices ``benchmarks/bench_running_m1.py`` saved: 2.0 and
2.5 m/s (the gait at 145 N m) from ``results/running_m1.json``, the gait at 140 N m from
``results/running_m1_140.json`` (``bench_running_m1.py --speeds 2.5 --reserve 10 --name
running_m1_140``); a missing or other choice is one line and exit 2.

Run: ``python benchmarks/running_saturation.py [--strides N] [--no-save]``; writes
``benchmarks/results/running_saturation.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import RESULTS, Run  # noqa: E402

from biped_casadi import rabbit  # noqa: E402
from biped_casadi.control.running import RunningController  # noqa: E402
from gait_opt.running import RunningOptions, optimize_running  # noqa: E402
from analysis.stability.running_cycle import (running_cycle, running_stability,  # noqa: E402
                                              simulate_running)

HAND = (0.0, 0.95, 0.95, 0.0)
# the chosen M1: (results file of bench_running_m1.py, speed, the gait's torque bound)
CHOICES = {"chosen 2.0": ("running_m1", 2.0, None), "chosen 2.5": ("running_m1", 2.5, 145.0),
           "chosen at 140": ("running_m1_140", 2.5, 140.0)}
# (speed, gait's torque bound or None for the robot's, saturate, Kp, Kd, [(label, M1 or
# the key of CHOICES)])
CASES = [
    (2.0, None, False, 400.0, 30.0, [("hand-picked", HAND), ("chosen", "chosen 2.0")]),
    (2.0, None, True, 400.0, 30.0, [("hand-picked", HAND), ("chosen", "chosen 2.0")]),
    (2.5, 145.0, False, 400.0, 30.0, [("hand-picked", HAND), ("chosen", "chosen 2.5")]),
    (2.5, 145.0, True, 400.0, 30.0, [("hand-picked", HAND), ("chosen", "chosen 2.5")]),
    (2.5, 145.0, True, 400.0, 60.0, [("hand-picked", HAND), ("chosen", "chosen 2.5")]),
    (2.5, 145.0, True, 1000.0, 100.0, [("hand-picked", HAND), ("chosen", "chosen 2.5")]),
    (2.5, 140.0, True, 400.0, 30.0, [("hand-picked", HAND), ("chosen at 140", "chosen at 140")]),
    (2.5, None, True, 400.0, 30.0, [("hand-picked", HAND), ("chosen", "chosen 2.5")]),
]


def chosen_m1(name, speed, gait_limit):
    """The M1 ``bench_running_m1.py`` chose with the sliding foot at ``speed`` on the gait
    optimised at ``gait_limit`` (None: the robot's limit), from ``results/NAME.json``.

    Raises
    ------
    ValueError
        One line: no such file, row or choice, or the choice of another foot or gait.
    """
    path = RESULTS / f"{name}.json"
    try:
        data = json.loads(path.read_text())["data"]
        row = next((r for r in data["rows"] if r["speed"] == speed), None)
        foot = data.get("foot", "not recorded")
    except OSError as e:
        raise ValueError(f"{path}: {e.strerror}") from None
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: no choice of M1 to read ({type(e).__name__}: {e})") from None
    if foot != "sliding":
        raise ValueError(f"{path}: foot {foot}, not the sliding one")
    if row is None or row.get("gait_torque_limit") != gait_limit or not row.get("chosen") \
            or row["chosen"].get("M1") is None:
        raise ValueError(f"{path}: no M1 chosen at {speed:g} m/s on the gait at "
                         + (f"{gait_limit:g} N m" if gait_limit else "the robot's limit"))
    return tuple(float(x) for x in row["chosen"]["M1"])


def one(cyc, M1, nq, strides):
    """The radius at M1 and the perturbed run."""
    c = cyc.retuned(M1=M1)
    r = running_stability(c)
    if r.status == "failed":        # no fixed point: its last iterate's radius means nothing
        return dict(M1=list(M1), status=r.status, spectral_radius=None, message=r.message)
    out = dict(M1=list(M1), status=r.status, spectral_radius=r.spectral_radius)
    x = r.fixed_point.copy()
    x[nq:] += 1e-2
    run = simulate_running(c, r.fixed_point, x, strides)
    d = run.deviations
    n = d.size - 1
    st = run.strides
    out.update(run_status=run.status, message=run.message, strides=len(st),
               deviations=d.tolist(),
               mean_contraction=float((d[-1] / d[1]) ** (1 / (n - 1))) if n >= 2 else None,
               torque_asked=[s.torque_max for s in st],
               saturated_time=[s.saturated_time for s in st],
               other_foot_min=[s.other_foot_min for s in st])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strides", type=int, default=20)
    ap.add_argument("--no-save", action="store_true")
    a = ap.parse_args()
    try:
        choices = {k: chosen_m1(*v) for k, v in CHOICES.items()}
    except ValueError as e:
        raise SystemExit(print(f"error: {e}; run benchmarks/bench_running_m1.py first",
                               file=sys.stderr) or 2)
    m = rabbit()
    gaits = {}
    with Run("running_saturation", "the running closed loop at 2.0 and 2.5 m/s with the "
             "torques clipped at the limit", save=not a.no_save) as run:
        rows = []
        for v, lim, sat, kp, kd, designs in CASES:
            if (v, lim) not in gaits:
                g = optimize_running(m, RunningOptions(speed=v, torque_limit=lim), cache=True)
                gaits[v, lim] = g
                run.row(f"{v:g} m/s, gait at {lim or 'the robot limit'}: cost", g.cost,
                        unit="N^2 m s")
            g = gaits[v, lim]
            t0 = time.perf_counter()
            cyc = running_cycle(RunningController(m, g, kp, kd, M1=HAND, saturate=sat))
            for label, M1 in designs:
                M1 = choices.get(M1, M1)
                r = dict(speed=v, gait_torque_limit=lim, saturate=sat, Kp=kp, Kd=kd,
                         design=label, **one(cyc, M1, m.nq, a.strides))
                rows.append(r)
                what = (f"{v:g} m/s, gait {lim or 150:g} N m, {label}, Kp {kp:g}, Kd {kd:g}"
                        f"{', clipped' if sat else ''}")
                run.row(f"{what}: spectral radius", r["spectral_radius"], unit="")
                run.row(f"{what}: strides run", r.get("strides"), unit="")
                print(what, r["status"], r.get("message"), flush=True)
            print(f"  {time.perf_counter() - t0:.1f} s", flush=True)
        run.data["rows"] = rows
        run.data["chosen"] = {k: dict(M1=list(choices[k]), file=f"{v[0]}.json", speed=v[1],
                                      gait_torque_limit=v[2]) for k, v in CHOICES.items()}
        run.note(f"0.01 rad/s on every velocity, {a.strides} strides; torque_asked is the "
                 "law's, before clipping")


if __name__ == "__main__":
    main()
