"""Over a gait family (issue 47, item 4): a robust design for every member, an M1 schedule
over the whole range, and the ramp 0.4 -> 1.2 -> 0.4 m/s walked in full order.

1. The family ``biped gait --speeds 0.4:1.2:0.05`` (the default options, 17 gaits; kept in
   ``$BIPED_CACHE_DIR/codesign_family``).
2. At every member, the design of ``biped m1 --robust --gait MEMBER``
   (:data:`analysis.design.codesign.FIT`: M1 on the member as given, the member moved to
   the robust gait constraints near it when that misses the target), or why there is
   none (one line).
   A member without a design, and whose own orbit no controller walks (at 1.2 m/s the
   default optimum leans the torso 2.10 rad, past the simulator's fall bound pi/2),
   gets a gait by speed continuation from the nearest member with a design
   (:func:`analysis.design.codesign.continue_gait`: that design's gait options at the
   member's speed, the step length at most the neighbour's) and the co-design on it.
3. The M1 schedule: the designs as the points of an
   :class:`analysis.design.schedule.M1Schedule` (linear in speed between them: at each
   member its own design; a member still without a design holds the nearest one's M1,
   on its gait moved to the robust gait options' optimum at its speed).
4. The ramp 0.4 -> 1.2 -> 0.4 m/s by 0.05 per step, then 10 steps at 0.4 m/s: step k
   walks the gait of its speed's design (the member, or the member moved) with the
   schedule's M1, in full order (every validity condition, mu = 0.6, |u| <= 150 N m);
   virtual constraints on the same gaits beside it.

Results: ``benchmarks/results/codesign_family.json``; the ramp's figure
``docs/_static/codesign_ramp.png`` (``--figures DIR``).

    python benchmarks/bench_codesign_family.py [--range 0.4 1.2 0.05] [--hold 10]
        [--workers N] [--figures DIR] [--no-save] [--tag NAME]
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis.design.codesign import FIT, NoDesign, codesign, continue_gait, move_gait
from analysis.design.codesign.functions import TranscriptionSettings
from analysis.design.codesign.method import MOVED
from analysis.design.schedule import M1Schedule, ramp_speeds
from analysis.reporting.plots import save_figure, speed_profile_plot
from analysis.robustness.speed import walk_gaits
from biped_casadi import Design, SimulationOptions, cache_dir, rabbit
from biped_casadi.simulation.speed_profile import simulate_profile
from gait_opt import GaitOptimizationError, gait_family, speed_range

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OPTS = SimulationOptions(mu=0.6, torque_limit=150.0)


def _record(v, r, wall) -> dict:
    ch = r.gait_change.get("from_given") or {}
    return dict(speed=v, status=r.status, s_star=float(r.s_star),
                vc_s_star=float(r.vc_s_star), max_abs=float(r.max_abs),
                vc_eigenvalue=float(r.vc_eigenvalue), steps_to_converge=r.steps_to_converge,
                M1=[float(x) for x in r.design.M1], rejoin=float(r.design.rejoin),
                gait_moved=bool(ch), max_joint_change=ch.get("max_joint_change", 0.0),
                T=ch.get("T", [r.gait.T, r.gait.T]), wall=round(wall, 1),
                load=round(os.getloadavg()[0], 2), cached=bool(r.cached))


def _summary(r) -> dict:
    e = r.errors()
    return dict(status=r.status, message=r.message, n_steps=r.n_steps,
                valid_steps=sum(s.status == "ok" for s in r.steps), errors=e.tolist(),
                max_error_on_ramp=float(np.nanmax(e[:-10])) if len(e) > 10 else None,
                final_error=float(e[len(r.steps) - 1]) if len(r.steps) else None,
                peak_torque=r.peak_torque, friction_margin=r.friction_margin,
                min_normal_force=r.min_normal_force)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--range", nargs=3, type=float, default=[0.4, 1.2, 0.05],
                    metavar=("V1", "V2", "DV"))
    ap.add_argument("--hold", type=int, default=10)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--figures", default=str(ROOT / "docs" / "_static"))
    ap.add_argument("--no-save", action="store_true")
    ap.add_argument("--tag", default="", help="appended to the results' name (another range)")
    a = ap.parse_args(argv)
    v1, v2, dv = a.range
    with Run("codesign_family" + (f"_{a.tag}" if a.tag else ""), f"robust designs over the gait family {v1:g}:{v2:g}:{dv:g} "
             f"(default options), the M1 schedule and the ramp {v1:g} -> {v2:g} -> {v1:g} "
             "m/s in full order", save=not a.no_save) as bench:
        t = time.perf_counter()
        path = cache_dir() / "codesign_family" / f"family_{v1:g}_{v2:g}_{dv:g}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        fam = gait_family(rabbit(), speed_range(v1, v2, dv), path=path)
        bench.row(f"the family, {len(fam)} gaits", round(time.perf_counter() - t, 1))
        print(f"family: {fam.message}", flush=True)

        records, designs = [], {}
        t_all = time.perf_counter()
        for v in fam.member_speeds:
            t = time.perf_counter()
            try:
                r = codesign(fam.gait(v), FIT, workers=a.workers)
            except NoDesign as e:
                records.append(dict(speed=float(v), status="no_design", message=str(e),
                                    wall=round(time.perf_counter() - t, 1)))
                print(f"{v:.2f} m/s: no design: {e}", flush=True)
                continue
            rec = _record(float(v), r, time.perf_counter() - t)
            records.append(rec)
            designs[round(float(v), 6)] = r
            print(f"{v:.2f} m/s: {r.status}, s* {r.s_star:.3g} (virtual constraints "
                  f"{r.vc_s_star:.3g}), below 1e-3 from step {r.steps_to_converge}, "
                  f"max|lambda| {r.max_abs:.3g} (virtual constraints {r.vc_eigenvalue:.3g})"
                  f", gait {'moved' if rec['gait_moved'] else 'as given'}; {rec['wall']} s",
                  flush=True)
        # a member without a design whose own orbit is no walk: its gait by speed
        # continuation from the nearest member with a design, and the co-design on it
        for x in records:
            if x["status"] != "no_design":
                continue
            v = x["speed"]
            orbit = simulate_profile([Design.vc(fam.gait(v))], options=OPTS)
            x["own_orbit"] = dict(status=orbit.status, message=orbit.message)
            print(f"{v:.2f} m/s: the member's own orbit under virtual constraints: "
                  f"{orbit.status} {orbit.message}", flush=True)
        for x in sorted((x for x in records if x["status"] == "no_design"),
                        key=lambda x: min(abs(x["speed"] - d) for d in designs)
                        if designs else 0.0):
            if not designs:
                break
            v = x["speed"]
            src = min(designs, key=lambda d: abs(d - v))
            t = time.perf_counter()
            try:
                g = continue_gait(designs[src].gait, v)
                r = codesign(g, FIT, workers=a.workers)
            except (NoDesign, GaitOptimizationError) as e:
                x["continued"] = dict(source=src, message=str(e))
                print(f"{v:.2f} m/s, continued from {src:.2f} m/s: no design: {e}", flush=True)
                continue
            rec = _record(float(v), r, time.perf_counter() - t)
            rec.update(continued_from=src, member=x, torso_max=g.torso_lean(),
                       step_length=float(g.step_length), T=[float(g.T), float(r.gait.T)])
            records[records.index(x)] = rec
            designs[round(float(v), 6)] = r
            print(f"{v:.2f} m/s, gait continued from {src:.2f} m/s (step length "
                  f"{g.step_length:.4g} m, T {g.T:.4g} s, torso at most {rec['torso_max']:.3g} "
                  f"rad): {r.status}, s* {r.s_star:.3g} (virtual constraints "
                  f"{r.vc_s_star:.3g}), below 1e-3 from step {r.steps_to_converge}, "
                  f"max|lambda| {r.max_abs:.3g} (virtual constraints {r.vc_eigenvalue:.3g});"
                  f" {rec['wall']} s", flush=True)
        n_met = sum(x["status"] == "target_met" for x in records)
        n_cached = sum(bool(x.get("cached")) for x in records)
        n_cont = sum("continued_from" in x for x in records)
        bench.row(f"{len(fam)} co-designs (`biped m1 --robust --gait MEMBER`)"
                  + (f" and {n_cont} on gaits continued from a neighbour" if n_cont else "")
                  + (f"; {n_cached} read from the cache" if n_cached else ", cold"),
                  round(time.perf_counter() - t_all, 1))
        bench.row("members with a design (of the family's)", len(designs), unit="",
                  target=str(len(fam)))
        if n_cont:
            bench.row("... of them on a gait continued from the nearest member's design "
                      "(the member's own orbit is no walk)", n_cont, unit="")
        bench.row("members whose design meets the target (s* >= 1, below 1e-3 by step 5, "
                  "max|lambda| <= virtual constraints')", n_met, unit="", target=str(len(fam)))
        bench.data["members"] = records
        if not designs:
            print("no member has a design: the ramp is not walked", flush=True)
            return records
        missing = [float(v) for v in fam.member_speeds if round(float(v), 6) not in designs]
        if missing:
            bench.note("members without a design (the ramp walks their gait moved to the "
                       "robust gait options' optimum at their speed, with the M1 of the "
                       "nearest member's design held): " + "; ".join(
                           f"{x['speed']:.2f} m/s: {x['message']}" for x in records
                           if x["status"] == "no_design"))
            print(f"no design at {missing} m/s: walked on the gait moved (the robust options' "
                  "optimum), with the nearest design's M1", flush=True)

        # the schedule through the designs (a member without one holds its nearest
        # neighbour's M1), and the ramp on their gaits
        def nearest(v):
            return min(designs, key=lambda d: abs(d - v))
        vs = sorted(round(float(v), 6) for v in fam.member_speeds)
        sched = M1Schedule(tuple(vs),
                           tuple(tuple(designs[nearest(v)].design.M1) for v in vs),
                           tuple(designs[nearest(v)].design.rejoin for v in vs))
        bench.data["schedule"] = sched.to_dict()
        speeds = ramp_speeds(v1, v2, dv, hold=a.hold)
        # a member without a design: its gait moved as the co-design moves gaits (the
        # farthest move, the robust gait options' optimum at its speed), the held M1
        stand_in = {round(v, 6): move_gait(fam.gait(v), {k: val for k, val in
                                                         FIT.gait.items() if k in MOVED},
                                           replace(FIT.move, effort=math.inf),
                                           TranscriptionSettings()).gait
                    for v in missing}
        gaits = [designs[round(float(v), 6)].gait if round(float(v), 6) in designs
                 else stand_in[round(float(v), 6)] for v in speeds]
        t = time.perf_counter()
        runs = {"time-varying, M1 schedule": walk_gaits(gaits, speeds, "tv", sched, OPTS),
                "virtual constraints": walk_gaits(gaits, speeds, "vc", None, OPTS)}
        bench.row(f"the ramp, {len(speeds)} steps, two controllers",
                  round(time.perf_counter() - t, 1))
        for k, r in runs.items():
            s = _summary(r)
            bench.data.setdefault("ramp", {})[k] = s
            bench.row(f"ramp {v1:g} -> {v2:g} -> {v1:g} m/s by {dv:g} per step + {a.hold} "
                      f"at {v1:g}, {k}: valid steps ({r.status}); peak torque "
                      f"{r.peak_torque:.1f} N m", s["valid_steps"], unit="steps",
                      target=str(len(speeds)))
            print(f"ramp, {k}: {r.status}, {s['valid_steps']} of {len(speeds)} steps valid, "
                  f"largest error on the ramp {s['max_error_on_ramp']}, final "
                  f"{s['final_error']}, peak torque {r.peak_torque:.1f} N m", flush=True)
        figs = Path(a.figures)
        figs.mkdir(parents=True, exist_ok=True)
        fig = speed_profile_plot(runs, title=f"ramp {v1:g} -> {v2:g} -> {v1:g} m/s on the "
                                 "members' robust designs (full order)")
        bench.data["figure"] = save_figure(
            fig, figs / ("codesign_ramp" + (f"_{a.tag}" if a.tag else "") + ".png"))
    return records


if __name__ == "__main__":
    main()
