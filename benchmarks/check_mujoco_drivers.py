"""The MuJoCo loop driven in C against the Python loop, bit for bit (issue 45's loop).

Every case is walked twice, by ``MujocoLoop(..., driver='c')`` and ``driver='python'``,
and the two :class:`~biped_casadi.mujoco.MujocoWalk` are compared field by field, floats
and arrays by their bytes (all but the wall time).  Cases: RABBIT's and the three-link
biped's default gaits, virtual constraints and a time-varying (deadbeat) design on each,
the stiff and MuJoCo's default contacts, touchdown on the grid and interpolated, the step
started by the impact map and by MuJoCo's contact, with and without the log, from the
gait and from perturbed starts (walking and failing ones), and with a small slip limit and
a short horizon (walks that end 'slipped' and 'no_impact'); and long walks (60 steps) from
the gait and the first perturbed start.

    python benchmarks/check_mujoco_drivers.py [--steps N] [--long N] [--quick] [--no-save]

Saves ``benchmarks/results/mujoco_drivers.json``: the cases, the outcomes met, the cases
that differ (none expected) and the time of each driver.
"""
from __future__ import annotations

import argparse
import collections
import itertools
import sys
import time
from pathlib import Path

from biped_casadi import Design, Perturbation, robot
from biped_casadi.mujoco import ContactSettings, MujocoLoop
from biped_casadi.mujoco.cloop import walk_differences
from biped_casadi.mujoco.walk import start_of
from gait_opt import optimize_gait

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

#: a deadbeat design on RABBIT's default gait (tests/test_mujoco.py's DEADBEAT)
DEADBEAT = [2.223419, -4.220774, 2.943679, 1.582508]


def designs(quick: bool) -> list:
    """(name, design, starts): the designs and the perturbed starts walked from each."""
    g5 = optimize_gait(robot("rabbit"), cache=True)
    paper = Perturbation.paper(5)
    s5 = [None] + [paper.scaled(k) for k in (1.0, 3.0)] + [(0.05, 0.5), (0.15, 1.5),
                                                           (-0.1, -2.0), (0.3, 3.0)]
    out = [("rabbit vc", Design.vc(g5), s5), ("rabbit tv", Design.tv(g5, DEADBEAT), s5)]
    if not quick:
        g3 = optimize_gait(robot("three_link"), cache=True)
        s3 = [None, (0.02, 0.2), (0.05, 0.5), (-0.05, -1.0), (0.2, 2.0)]
        out += [("three_link vc", Design.vc(g3), s3),
                ("three_link tv", Design.tv(g3, [0.5, -0.5]), s3)]
    return out


def cases(quick: bool):
    """(label, loop settings, starts) of every combination."""
    contacts = ("stiff", "default")
    limits = ((0.05, 2.0), (0.0005, 2.0), (0.05, 0.9))   # (max_slip, horizon)
    for (name, design, starts), contact, step_start, touchdown, (slip, horizon) in \
            itertools.product(designs(quick), contacts, ("impact", "contact"),
                              ("grid", "interpolated"), limits):
        kw = dict(settings=ContactSettings.of(contact), step_start=step_start,
                  touchdown=touchdown, max_slip=slip, horizon=horizon)
        yield (f"{name} {contact} {step_start} {touchdown} slip {slip:g} horizon "
               f"{horizon:g}"), design, kw, starts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=8, help="steps of each walk (default 8)")
    ap.add_argument("--long", type=int, default=60,
                    help="steps of the long walks: from the first two starts, at the "
                         "default slip limit and horizon, without the log (default 60)")
    ap.add_argument("--quick", action="store_true", help="RABBIT only")
    ap.add_argument("--no-save", action="store_true")
    a = ap.parse_args(argv)
    with Run("mujoco_drivers", "the MuJoCo loop driven in C against the Python loop, bit "
             "for bit", save=not a.no_save) as run:
        n, bad, outcomes, wall = compare(a.steps, a.long, a.quick)
        print(f"{n} cases, {len(bad)} differing; outcomes {outcomes}; wall C "
              f"{wall['c']:.2f} s, Python {wall['python']:.2f} s")
        run.row("cases compared bit for bit (walks driven in C and in Python)", n, unit="")
        run.row("cases that differ", len(bad), unit="", target="0")
        run.row(f"wall time of the {n} walks, C driver (Python driver as baseline)",
                wall["c"], wall["python"])
        run.data.update(outcomes=outcomes, steps=a.steps, long=a.long, differences=bad)
    return 1 if bad else 0


def compare(steps: int, long: int, quick: bool) -> tuple:
    """Walk every case with both drivers: (cases, differences, outcomes, wall times)."""
    n, bad, statuses, wall = 0, [], collections.Counter(), {"c": 0.0, "python": 0.0}
    for label, design, kw, starts in cases(quick):
        loops = {d: MujocoLoop(design, driver=d, **kw) for d in ("c", "python")}
        walks = [(start, steps, log) for start in starts for log in (False, True)]
        if (kw["max_slip"], kw["horizon"]) == (0.05, 2.0):
            walks += [(start, long, False) for start in starts[:2]]
        for start, n_steps, log in walks:
            q0, dq0 = start_of(design.gait, start)
            w = {}
            for d, loop in loops.items():
                t = time.perf_counter()
                w[d] = loop.run(q0, dq0, n_steps, log=log)
                wall[d] += time.perf_counter() - t
            diff = walk_differences(w["c"], w["python"])
            n += 1
            statuses[w["python"].status] += 1
            if diff:
                bad.append(dict(case=label, start=repr(start), steps=n_steps, log=log,
                                fields=diff[:8]))
                print(f"DIFFERS: {label} start {start!r} steps {n_steps} log {log}: "
                      f"{diff[:8]}", flush=True)
    return n, bad, dict(statuses), wall

if __name__ == "__main__":
    raise SystemExit(main())
