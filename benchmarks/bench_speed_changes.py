"""Speed changes on the robust co-design's gait family, in full order (issue 33, item 4).

1. The family: ``gait_family(rabbit(), speed_range(0.45, 1.05, 0.05),
   GaitOptions(**ROBUST_GAIT))`` (kept in ``$BIPED_CACHE_DIR/speed_changes``).
2. One M1 for all speeds: the co-design's on its own 0.75 m/s gait (``--m1``, rejoin
   0.75); max|lambda| of A^z on every member, beside the virtual constraints'.
3. The M1 schedule: ``codesign(gait_v, QUICK)`` (the gait fixed) at ``--points`` speeds,
   interpolated linearly in speed; max|lambda| on every member and at the midpoints
   (gaits interpolated and polished).
4. The ramp 0.5 -> 1.0 -> 0.5 m/s by 0.05 per step, then 10 steps at 0.5 m/s (mu = 0.6,
   |u| <= 150 N m), for virtual constraints, the schedule and the one M1; the same ramp
   as a staircase (each speed held ``--each`` steps: the steps each switch takes to
   converge below 1e-3); the one M1 on the ramp 0.6 -> 1.0 -> 0.6 too.
5. The largest single-step change survived from every member (one step on v1's orbit,
   the switch, 10 steps on v2; survived: every step valid and the last error < 1e-3),
   bisected ``--refine`` times between the members, for each controller.

Figures (``--figures``, default docs/_static): speed_ramp.png, speed_staircase.png,
speed_jumps.png.  Results: benchmarks/results/speed_changes.json.

    python benchmarks/bench_speed_changes.py [--points 0.45 0.5 0.6 0.75 0.9 1.0 1.05]
        [--each 10] [--refine 3] [--figures DIR] [--no-save]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from analysis.design import ROBUST_GAIT
from analysis.design.codesign import QUICK, codesign
from analysis.design.schedule import M1Schedule, profile_gaits
from analysis.reporting.plots import save_figure, speed_jumps_plot, speed_profile_plot
from analysis.robustness.speed import schedule_eigenvalues, speed_jumps, speed_ramp
from biped_casadi import SimulationOptions, cache_dir, rabbit
from biped_casadi.results import json_safe
from gait_opt import GaitOptions, gait_family, speed_range

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: the robust co-design's M1 on its own 0.75 m/s gait, v_c rejoining at 0.75 T
CODESIGN_M1 = (0.32978, -0.07573, 0.63068, -0.39785)
OPTS = SimulationOptions(mu=0.6, torque_limit=150.0)


def _summary(r) -> dict:
    """A profile's figures: status, where it failed, errors, torque, friction."""
    e = r.errors()
    return dict(status=r.status, message=r.message, n_steps=r.n_steps,
                fail_step=r.fail_step, speeds=list(r.speeds), errors=e.tolist(),
                step_peak_torque=[s.peak_torque for s in r.steps],
                step_friction_margin=[s.friction_margin for s in r.steps],
                peak_torque=r.peak_torque, friction_margin=r.friction_margin,
                min_normal_force=r.min_normal_force,
                segments=[s.to_dict() for s in r.segments])


def _show(label, r):
    e = r.errors()
    seg = r.segments[-1]
    print(f"  {label:28s} {r.status:22s} steps {len(r.steps)}/{r.n_steps}, max error on "
          f"the ramp {np.nanmax(e[:21]):.3g}, final {e[len(r.steps) - 1]:.3g}, hold "
          f"converged at step {seg.steps_to_converge:g} of it, peak |u| "
          f"{r.peak_torque:.1f} N m, friction margin {r.friction_margin:.3f}", flush=True)
    if not r.ok:
        print(f"    {r.message}")


def _staircase(r, each: int) -> dict:
    """Per switch of a staircase: the speeds and the steps to converge."""
    segs = [s for s in r.segments]
    return dict(speeds=[s.speed for s in segs], steps_to_converge=[s.steps_to_converge
                                                                   for s in segs],
                first_error=[s.first_error for s in segs], each=each)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", nargs="+", type=float,
                    default=[0.45, 0.5, 0.6, 0.75, 0.9, 1.0, 1.05])
    ap.add_argument("--each", type=int, default=10)
    ap.add_argument("--refine", type=int, default=3)
    ap.add_argument("--figures", default=str(ROOT / "docs" / "_static"))
    ap.add_argument("--no-save", action="store_true")
    args = ap.parse_args(argv)
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)
    with Run("speed_changes", "Speed changes on the robust gait family in full order: the "
             "ramp 0.5 -> 1.0 -> 0.5 m/s and the largest single-step change",
             save=not args.no_save) as bench:
        t = time.perf_counter()
        path = cache_dir() / "speed_changes" / "robust_family.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        fam = gait_family(rabbit(), speed_range(0.45, 1.05, 0.05),
                          GaitOptions(**ROBUST_GAIT), path=path)
        bench.row("the robust family, 13 gaits (0.45 to 1.05 m/s)",
                  round(time.perf_counter() - t, 1))
        print(f"family: {fam.message}", flush=True)
        one = M1Schedule.constant(CODESIGN_M1, 0.75)
        eig_one = schedule_eigenvalues(fam.gaits, one)
        print("one M1, max|lambda| per member: " + ", ".join(
            f"{e['speed']:.2f}: {e['max_abs']:.3f}" for e in eig_one), flush=True)

        # ---- the schedule of gait-fixed co-designs
        t = time.perf_counter()
        res = [codesign(fam.gait(v), QUICK, workers=1) for v in args.points]
        sched = M1Schedule(tuple(args.points), tuple(tuple(r.design.M1) for r in res),
                           tuple(r.design.rejoin for r in res))
        bench.row(f"{len(args.points)} gait-fixed co-designs (QUICK)",
                  round(time.perf_counter() - t, 1))
        mids, _ = profile_gaits(fam, fam.member_speeds[:-1] + 0.025)
        eig_s = schedule_eigenvalues(list(fam.gaits) + mids, sched)
        eig_s.sort(key=lambda e: e["speed"])
        print("schedule, max|lambda|: " + ", ".join(f"{e['speed']:.3f}: {e['max_abs']:.3f}"
                                                     for e in eig_s), flush=True)

        # ---- the ramp, and the staircase
        t = time.perf_counter()
        ramps = {"virtual constraints": speed_ramp(fam, "vc", None, OPTS, 0.5, 1.0, 0.05),
                 "time-varying, M1 schedule": speed_ramp(fam, "tv", sched, OPTS, 0.5, 1.0,
                                                         0.05),
                 "time-varying, one M1": speed_ramp(fam, "tv", one, OPTS, 0.5, 1.0, 0.05)}
        one_high = speed_ramp(fam, "tv", one, OPTS, 0.6, 1.0, 0.05)
        bench.row("the ramp, three controllers and 0.6-1.0 for one M1 (31 steps each)",
                  round(time.perf_counter() - t, 1))
        print("ramp 0.5 -> 1.0 -> 0.5 by 0.05 per step, then 10 steps at 0.5:")
        for k, r in ramps.items():
            _show(k, r)
            bench.row(f"ramp, {k}: valid steps of 31 ({r.status}); peak torque "
                      f"{r.peak_torque:.1f} N m", sum(s.status == "ok" for s in r.steps),
                      unit="steps", target="31")
        _show("one M1, ramp 0.6 -> 1.0 -> 0.6", one_high)
        stairs = {k: speed_ramp(fam, c, s, OPTS, 0.5, 1.0, 0.05, hold=0, each=args.each)
                  for k, c, s in (("virtual constraints", "vc", None),
                                  ("time-varying, M1 schedule", "tv", sched))}
        for k, r in stairs.items():
            st = _staircase(r, args.each)
            print(f"  staircase ({args.each} steps a speed), {k}: {r.status}; steps to "
                  f"converge per switch " + " ".join(f"{x:g}" for x in st["steps_to_converge"]))
        save_figure(speed_profile_plot(ramps, title="Ramp 0.5 -> 1.0 -> 0.5 m/s by 0.05 m/s "
                                       "per step, then 10 steps at 0.5 (full order, mu = 0.6, "
                                       "|u| <= 150 N m)"), figs / "speed_ramp.png")
        save_figure(speed_profile_plot(stairs, title=f"Staircase 0.5 -> 1.0 -> 0.5 m/s, each "
                                       f"speed held {args.each} steps (full order)"),
                    figs / "speed_staircase.png")

        # ---- the largest single-step change
        t = time.perf_counter()
        jumps = {"virtual constraints": speed_jumps(fam, "vc", None, OPTS, refine=args.refine),
                 "time-varying, M1 schedule": speed_jumps(fam, "tv", sched, OPTS,
                                                          refine=args.refine),
                 "time-varying, one M1": speed_jumps(fam, "tv", one, OPTS, refine=args.refine)}
        bench.row("the largest jumps from 13 speeds, three controllers",
                  round(time.perf_counter() - t, 1))
        for k, j in jumps.items():
            print(f"  largest change survived, {k}:")
            for v1, up, uf, dn, df, fails, bey, val in zip(
                    j.v1, j.up, j.up_failed, j.down, j.down_failed, j.failures, j.beyond,
                    j.valid):
                fu = "censored" if uf is None else f"{fails[0][1]} at {uf:+.4f}"
                fd = "censored" if df is None else f"{fails[1][1]} at {df:+.4f}"
                print(f"    v1 {v1:.2f}: up {up:+.4f} ({fu}), down {dn:+.4f} ({fd}); valid "
                      f"{val[0]:+.4f} {val[1]:+.4f}"
                      + (f", survived again beyond: {[round(b, 4) for b in bey]}" if bey
                         else ""))
        save_figure(speed_jumps_plot(jumps, (0.45, 1.05)), figs / "speed_jumps.png")
        for k, j in jumps.items():
            big = j.largest()
            bench.row(f"largest single-step change survived, {k}: smallest over v1 (at "
                      f"{j.v1[int(np.argmin(big))]:g} m/s) / largest", round(float(big.min()), 4),
                      unit="m/s", target=f"{float(big.max()):.4f}")
        bench.data.update(json_safe(dict(
            family=dict(message=fam.message, speeds=list(fam.member_speeds)),
            one_m1=dict(M1=list(CODESIGN_M1), rejoin=0.75, eigenvalues=eig_one),
            schedule=dict(schedule=sched.to_dict(), eigenvalues=eig_s,
                          codesigns=[dict(speed=v, status=r.status, s_star=r.s_star,
                                          max_abs=r.max_abs) for v, r in zip(args.points, res)]),
            ramp={k: _summary(r) for k, r in ramps.items()},
            ramp_one_m1_from_0p6=_summary(one_high),
            staircase={k: _staircase(r, args.each) | dict(status=r.status,
                                                          peak_torque=r.peak_torque,
                                                          friction_margin=r.friction_margin)
                       for k, r in stairs.items()},
            jumps={k: dict(v1=j.v1, up=j.up, down=j.down, up_failed=j.up_failed,
                           down_failed=j.down_failed, failures=j.failures, beyond=j.beyond,
                           valid=j.valid,
                           resolution=j.resolution,
                           changes=[[dict(v2=c.v2, dv=c.dv, status=c.status,
                                          steps_to_converge=c.steps_to_converge,
                                          switch_error=c.switch_error,
                                          peak_torque=c.peak_torque,
                                          friction_margin=c.friction_margin)
                                     for c in cs] for cs in j.changes])
                   for k, j in jumps.items()})))
        bench.note("full order (RK4, 2000 steps per T), every validity condition checked; "
                   "a change survives when every step is valid and the last error < 1e-3")


if __name__ == "__main__":
    main()
