"""The running closed loop's stability across speeds: plain tracking, the hand-picked
output and the chosen one (docs/howto/running.md, "Choosing M1 for running").

For RABBIT's running gait at each speed (default grid, PD Kp 400 N m/rad, Kd 30 N m s/rad):
the spectral radius of the exact stride Jacobian at the closed loop's fixed point with
M1 = 0 (plain tracking), with the hand-picked M1 = (0, 0.95, 0.95, 0) of 1.5 m/s, along
M1 = (0, c, c, 0) on a grid of c, and with the M1 that
:func:`analysis.design.running_m1.choose_running_m1` chooses (Nelder-Mead from the best
of the hand-picked design and the grid).  The choice is checked at every speed: a fresh
``running_stability`` at it, central differences of the stride map against the AD
Jacobian, and 20 strides from the fixed point with 0.01 rad/s on every velocity (the
per-stride contraction against the radius).

Run: ``python benchmarks/bench_running_m1.py [--speeds 1.0 1.5 ...] [--max-evaluations N]
[--no-save] [--recheck SPEED ...]``; writes ``benchmarks/results/running_m1.json`` after
each speed and ``docs/_static/running_m1_speeds.png`` at the end (``--recheck 2.0``: the
checks of that saved speed measured again, nothing else).  Run again, it resumes: the
speeds the file holds, measured with the same settings (gains, hand-picked M1, grid of c,
evaluations, torque reserve, sliding foot), are not measured again; a file of other
settings, of another benchmark or not readable is one line and exit 2.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import RESULTS, Run, commit, machine  # noqa: E402

from biped_casadi import rabbit  # noqa: E402
from biped_casadi.control.running import RunningController  # noqa: E402
from gait_opt.running import RunningOptions, optimize_running  # noqa: E402
from analysis.design.running_m1 import choose_running_m1  # noqa: E402
from analysis.stability.hybrid_cycle import HybridCycleError  # noqa: E402
from analysis.stability.running_cycle import (finite_difference_jacobian,  # noqa: E402
                                              running_cycle, running_stability,
                                              simulate_running)

ROOT = Path(__file__).resolve().parents[1]
KP, KD = 400.0, 30.0
HAND = (0.0, 0.95, 0.95, 0.0)
CS = np.round(np.arange(0.5, 1.501, 0.05), 4)
TITLE = ("the running stride map's spectral radius across speeds: plain tracking, the "
         "hand-picked M1 and the chosen one")
FOOT = "sliding"        # running_cycle's default model of the stance foot at takeoff


def _radius(cyc, M1):
    r = running_stability(cyc.retuned(M1=M1))
    return (r.spectral_radius if r.status != "failed" else None), r


def _check(cyc, r, nq):
    """Central differences and a perturbed run at a design's fixed point."""
    t0 = time.perf_counter()
    try:                # a column's step shrinks where it leaves x*'s sequence of domains
        J, steps = finite_difference_jacobian(cyc, r.fixed_point, 1e-5, return_steps=True)
        fd, fd_message = float(np.abs(J - r.A).max() / np.abs(r.A).max()), ""
        steps = steps.tolist()
    except HybridCycleError as e:      # a fixed point on a constraint's or a domain's edge
        fd, fd_message, steps = None, str(e), None
    x = r.fixed_point.copy()
    x[nq:] += 1e-2
    run = simulate_running(cyc, r.fixed_point, x, 20)
    d = run.deviations
    mean = float((d[-1] / d[1]) ** (1 / (d.size - 2))) if d.size > 2 and d[1] > 0 else None
    st = run.strides
    return dict(fd_relative_error=fd, fd_message=fd_message, fd_steps=steps,
                run_status=run.status, run_message=run.message,
                deviations=d.tolist(), contraction=run.contraction.tolist(),
                mean_contraction_after_first=mean,
                torque_max=max((s.torque_max for s in st), default=None),
                friction_excess_max=max((s.friction_excess_max for s in st), default=None),
                fz_min=min((s.fz_min for s in st), default=None),
                seconds=time.perf_counter() - t0)


def speed_row(m, v, max_evaluations, gait_torque_limit=None):
    """Everything measured at one speed (the gait optimised with ``gait_torque_limit``,
    default the robot's; the controller always has the robot's)."""
    out = dict(speed=v, gait_torque_limit=gait_torque_limit)
    t0 = time.perf_counter()
    try:
        g = optimize_running(m, RunningOptions(speed=v, torque_limit=gait_torque_limit))
    except RuntimeError as e:              # IPOPT's failure (infeasible problem)
        out.update(gait_success=False, gait_message=str(e).splitlines()[-1],
                   gait_seconds=time.perf_counter() - t0)
        return out
    out.update(gait_success=bool(g.success), gait_seconds=time.perf_counter() - t0,
               T_stance=float(g.T_stance), T_flight=float(g.T_flight),
               step_length=float(g.step_length))
    if not g.success:
        return out
    t0 = time.perf_counter()
    cyc = running_cycle(RunningController(m, g, KP, KD, M1=HAND,
                                          torque_limit=m.description.torque_limit))
    out["build_seconds"] = time.perf_counter() - t0
    out["plain"], rp = _radius(cyc, np.zeros(4))
    out["plain_message"] = rp.message
    out["hand"], rh = _radius(cyc, HAND)
    out["hand_message"] = rh.message
    grid = []
    for c in CS:
        rad, _ = _radius(cyc, (0.0, c, c, 0.0))
        grid.append(rad)
    out["sweep_c"] = dict(c=CS.tolist(), radius=grid)
    ok = [(rad, c) for rad, c in zip(grid, CS) if rad is not None]
    best_c = min(ok) if ok else (None, None)
    out["best_c"] = dict(c=None if best_c[1] is None else float(best_c[1]), radius=best_c[0])
    starts = [(out["hand"], HAND, "hand-picked")] if out["hand"] is not None else []
    if best_c[0] is not None:
        starts.append((best_c[0], (0.0, best_c[1], best_c[1], 0.0), f"c = {best_c[1]:g}"))
    if not starts:
        out["chosen"] = None
        return out
    rad0, start, label = min(starts, key=lambda s: s[0])
    ch = choose_running_m1(cyc, start=start, max_evaluations=max_evaluations,
                           progress=lambda s: print(f"[{v:g} m/s] {s}", flush=True))
    out["chosen"] = dict(start=list(start), start_label=label, **ch.to_dict(),
                         evaluations=[e.to_dict() for e in ch.evaluations])
    if ch.stability is None:
        return out
    fresh = running_stability(cyc.retuned(M1=ch.M1))
    out["chosen"]["fresh_radius"] = fresh.spectral_radius
    out["chosen"]["moduli"] = np.abs(fresh.eigenvalues).tolist()
    out["chosen"]["distance"] = fresh.distance
    out["chosen"]["check"] = _check(cyc.retuned(M1=ch.M1), fresh, m.nq)
    if out["hand"] is not None:
        out["hand_check"] = _check(cyc.retuned(M1=HAND), rh, m.nq)
    return out


def _stamp() -> dict:
    """When, at which commit and on which processor a row or a check was measured (the
    file's own ``machine`` is its last run's)."""
    return dict(date=time.strftime("%Y-%m-%d %H:%M"), commit=commit(), cpu=machine()["cpu"])


def recheck(m, row):
    """A saved row's checks measured again (:func:`_check`: its gait optimised again, the
    hand-picked and the chosen M1 at their fixed points), each with the date and commit
    it was measured at.

    Raises
    ------
    ValueError
        One line: a fixed point whose spectral radius is not the saved one's.
    """
    v = row["speed"]
    g = optimize_running(m, RunningOptions(speed=v, torque_limit=row.get("gait_torque_limit")))
    cyc = running_cycle(RunningController(m, g, KP, KD, M1=HAND,
                                          torque_limit=m.description.torque_limit))
    stamp = _stamp()
    ch = row.get("chosen") or {}
    for where, key, M1, saved in ((row, "hand_check", HAND, row.get("hand")),
                                  (ch, "check", ch.get("M1"), ch.get("fresh_radius"))):
        if key not in where:
            continue
        r = running_stability(cyc.retuned(M1=M1))
        if not abs(r.spectral_radius - saved) <= 1e-9 * saved:
            raise ValueError(f"{v:g} m/s: the fixed point at M1 {tuple(M1)} is not the saved "
                             f"one (spectral radius {r.spectral_radius:.10g}, saved {saved:.10g})")
        where[key] = dict(_check(cyc.retuned(M1=M1), r, m.nq), measured=stamp)
        print(f"{v:g} m/s, {key}: central differences {where[key]['fd_relative_error']}",
              flush=True)


def figure(rows):
    """Spectral radius against speed, log scale, the three designs (and the best c)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    sp = [r["speed"] for r in rows]

    def line(vals, **kw):
        v = np.array([np.nan if x is None else x for x in vals], float)
        ax.semilogy(sp, v, marker="o", **kw)

    line([r.get("plain") for r in rows], label="plain tracking, M1 = 0", color="C3")
    line([r.get("hand") for r in rows], label="hand-picked M1 = (0, 0.95, 0.95, 0)",
         color="C0")
    line([r["best_c"]["radius"] if r.get("best_c") else None for r in rows],
         label="best M1 = (0, c, c, 0), c on a 0.05 grid", color="C2", ls="--", ms=4)
    line([r["chosen"]["spectral_radius"] if r.get("chosen") else None for r in rows],
         label="chosen M1 (choose_running_m1)", color="k")
    ax.axhline(1.0, color="0.5", lw=0.8, ls=":")
    notes = [f"at {r['speed']:g} m/s the gait optimised at |u| <= {r['gait_torque_limit']:g}"
             " N m" for r in rows if r.get("gait_torque_limit") is not None and r.get("chosen")]
    missing = [f"{r['speed']:g}" for r in rows if not r.get("chosen")]
    notes += [f"no stable design at {', '.join(missing)} m/s"] if missing else []
    ax.set_xlabel("\n".join(["running speed (m/s)"] + ["; ".join(notes)] * bool(notes)))
    ax.set_ylabel("spectral radius of the stride Jacobian (-)")
    ax.set_title(f"RABBIT running: the stride map's spectral radius against speed\n"
                 f"PD Kp {KP:g} N m/rad, Kd {KD:g} N m s/rad, the {FOOT} stance foot",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.58, 0.78))
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def settings(max_evaluations, reserve):
    """What a row's figures depend on besides its speed (saved with the rows)."""
    return dict(Kp=KP, Kd=KD, hand=list(HAND), c_grid=CS.tolist(),
                max_evaluations=max_evaluations, reserve=reserve, foot=FOOT)


def saved_rows(path, want, torque_limit):
    """The rows of a saved run of this benchmark, checked against the settings ``want``.

    Files written before the settings were saved whole: the grid of c is read from their
    rows and the reserve from a row that needed it (none: any reserve matches).  Each row
    gets ``measured``, the date and commit of the run that measured it.

    Raises
    ------
    ValueError
        One line: the file is not readable, is another benchmark's or was measured with
        other settings.
    """
    try:
        body = json.loads(Path(path).read_text())
        data, rows = body["data"], body["data"]["rows"]
        if body.get("title") != TITLE:
            raise ValueError(f"{path}: not a result of bench_running_m1.py "
                             f"(title {body.get('title')!r})")
        have = {k: data[k] for k in ("Kp", "Kd", "hand", "max_evaluations")}
        have["foot"] = data.get("foot", "not recorded")
        grids = {tuple(r["sweep_c"]["c"]) for r in rows if "sweep_c" in r}
        have["c_grid"] = data.get("c_grid", list(grids.pop()) if len(grids) == 1 else None)
        used = {torque_limit - r["gait_torque_limit"] for r in rows if "default_gait" in r}
        have["reserve"] = data.get("reserve", used.pop() if len(used) == 1 else
                                   (want["reserve"] if not used else None))
        speeds = [float(r["speed"]) for r in rows]
        for r in rows:                          # when and where each row was measured
            r.setdefault("measured", dict(date=body["date"], commit=body["commit"]))
    except ValueError as e:
        raise ValueError(str(e) if str(e).startswith(str(path)) else
                         f"{path}: not readable JSON ({e})") from None
    except OSError as e:
        raise ValueError(f"{path}: {e.strerror}") from None
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{path}: not a result of bench_running_m1.py (no {e})") from None
    diff = [f"{k} {have[k]} (now {want[k]})" for k in want if have[k] != want[k]]
    if diff:
        raise ValueError(f"{path}: measured with other settings: " + ", ".join(diff)
                         + "; remove it or choose another --name")
    if len(set(speeds)) != len(speeds):
        raise ValueError(f"{path}: a speed twice ({sorted(speeds)})")
    return rows


def page_rows(run, rows):
    """The benchmarks page's lines of the rows (those written before replaced)."""
    run.rows.clear()
    for row in rows:
        ch = row.get("chosen") or {}
        v = row["speed"]
        for key, label in (("plain", "plain tracking"), ("hand", "hand-picked M1")):
            run.row(f"{v:g} m/s, {label}: spectral radius", row.get(key), unit="")
        run.row(f"{v:g} m/s, chosen M1: spectral radius", ch.get("spectral_radius"), unit="")
        run.row(f"{v:g} m/s, the choice ({ch.get('n_evaluations')} evaluations)",
                ch.get("seconds"), unit="s")


def measure(m, v, a):
    """One speed's row (the gait again with the torque reserve where no design on the
    robot's limit is stable: none feasible, or the chosen one's radius at least 1)."""
    t0 = time.perf_counter()
    row = speed_row(m, v, a.max_evaluations)
    ch = row.get("chosen") or {}
    rho = ch.get("spectral_radius")
    if row.get("gait_success") and not (rho is not None and rho < 1) and a.reserve > 0:
        lim = m.description.torque_limit - a.reserve
        why = ch.get("message") if ch else f"no design feasible: {row.get('hand_message')}"
        print(f"{v:g} m/s: no stable design ({why}); the gait "
              f"again with the torque limit {lim:g} N m", flush=True)
        row = dict(speed_row(m, v, a.max_evaluations, lim), default_gait=row)
    row["seconds"] = time.perf_counter() - t0
    row["measured"] = _stamp()
    ch = row.get("chosen") or {}
    print(f"{v:g} m/s: plain {row.get('plain')}, hand {row.get('hand')}, best c "
          f"{row.get('best_c')}, chosen {ch.get('M1')} {ch.get('spectral_radius')} "
          f"({row['seconds']:.0f} s)", flush=True)
    return row


def _arguments():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[1.0, 1.5, 2.0, 2.5, 3.0])
    ap.add_argument("--max-evaluations", type=int, default=150)
    ap.add_argument("--reserve", type=float, default=5.0,
                    help="where no design is stable on the default gait (none feasible, or "
                         "the chosen one's radius at least 1), optimise the gait again with "
                         "the torque limit this much lower (N m) and measure that")
    ap.add_argument("--out", default=str(ROOT / "docs" / "_static"))
    ap.add_argument("--no-save", action="store_true",
                    help="write nothing (and resume from nothing)")
    ap.add_argument("--name", default="running_m1",
                    help="the results file's name (benchmarks/results/NAME.json)")
    ap.add_argument("--recheck", type=float, nargs="+", metavar="SPEED",
                    help="measure nothing new: the checks (central differences, the perturbed "
                         "run) of these saved speeds again, their gaits optimised again")
    ap.add_argument("--combine", nargs="+", metavar="FILE",
                    help="measure nothing: merge the rows of saved results (runs over parts "
                         "of the speeds, with these settings) into NAME.json and draw the "
                         "figure")
    return ap.parse_args()


def main():
    a = _arguments()
    from analysis.reporting.plots import save_figure
    m = rabbit()
    want = settings(a.max_evaluations, a.reserve)
    lim = m.description.torque_limit
    try:
        if a.combine:
            rows = [r for f in a.combine for r in saved_rows(f, want, lim)]
        else:
            path = RESULTS / f"{a.name}.json"
            rows = saved_rows(path, want, lim) if path.exists() and not a.no_save else []
    except ValueError as e:
        raise SystemExit(print(f"error: {e}", file=sys.stderr) or 2)
    if len({r["speed"] for r in rows}) != len(rows):
        raise SystemExit(print("error: the files hold a speed twice", file=sys.stderr) or 2)
    rows.sort(key=lambda r: r["speed"])
    with Run(a.name, TITLE, save=not a.no_save) as run:
        run.data.update(rows=rows, **want)
        run.note("Nelder-Mead on the exact spectral radius, from the better of the "
                 "hand-picked M1 and the best of M1 = (0, c, c, 0) on a 0.05 grid; "
                 "each row's 'measured' is the date, commit and processor of the run that "
                 "measured it (rows measured before 2026-12-08 lack the processor)")
        if a.combine:
            run.note("merged from " + ", ".join(Path(f).name for f in a.combine))
        elif rows:
            print("resumed: " + ", ".join(f"{r['speed']:g}" for r in rows)
                  + " m/s already measured", flush=True)
        for v in a.recheck or []:
            try:
                recheck(m, next(r for r in rows if r["speed"] == v))
            except StopIteration:
                raise SystemExit(print(f"error: --recheck {v:g}: no saved row at that speed",
                                       file=sys.stderr) or 2)
            except ValueError as e:
                raise SystemExit(print(f"error: {e}", file=sys.stderr) or 2)
            if run.save:
                run.write()
        for v in [] if a.combine or a.recheck else a.speeds:
            if any(r["speed"] == v for r in rows):
                continue
            rows.append(measure(m, v, a))
            rows.sort(key=lambda r: r["speed"])
            page_rows(run, rows)
            if run.save:
                run.write()
        page_rows(run, rows)
        run.note("rows measured: " + "; ".join(
            f"{r['speed']:g} m/s {r['measured']['date']} at {r['measured']['commit']}"
            for r in rows if r.get("measured")))
        Path(a.out).mkdir(parents=True, exist_ok=True)
        run.data["figure"] = save_figure(figure(rows), Path(a.out) / "running_m1_speeds.png")


if __name__ == "__main__":
    main()
