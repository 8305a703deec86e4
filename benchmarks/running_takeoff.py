"""The running closed loop at the takeoff: where the stance ends, what the law's switch to
flight does to the torques and to the freed foot, with the flight clock restarted at the
takeoff ('takeoff') or the stance's continued ('stride') (docs/howto/running.md, "The
takeoff and the flight clock").

Per case (a robot, its running gait, PD Kp 400, Kd 30, M1 = (0, .95, .95, 0) unless
given), the takeoff of the pinned foot (``running_cycle(..., sliding=False)``, the model
before the sliding phase, whose failures the sliding phase answers): from the pinned
cycle's fixed point of the 'takeoff' clock plus 0.01 rad/s on every velocity
(the collocated landing state when there is no fixed point), the stance pass of each of
``--strides`` strides: its duration against T_stance, the ground force (Fz, Fx) at its
end, the torque jump of each clock at the switch, the freed foot's vertical
acceleration under the stance's last torques and under each clock's first flight
torques; then the normal force under the restarted clock's first flight torques, and
the cycle's push-off: how long the foot stays on the ground under them (unilateral
contact: stance dynamics under the flight law until that force reaches 0), the
tangential force and the foot's acceleration when it leaves, and the pushing foot's
minima in the flight after.  Then, per clock, the stride map's
status, spectral radius and the perturbed run (20 strides), with the sliding foot (the
default model: ``loops``) and with the pinned one (``pinned_loops``).

Run: ``python benchmarks/running_takeoff.py [--case ROBOT GAIT_FILE [M1 ...]] [--no-save]``
(default: RABBIT's gaits at 1.5 and 2.0 m/s and at 2.5 m/s optimised with |u| <= 145 N m,
from the cache or solved); writes ``benchmarks/results/running_takeoff.json``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

from analysis.cli.common import load_model  # noqa: E402
from analysis.stability.hybrid_cycle import HybridCycleError  # noqa: E402
from analysis.stability.running_cycle import (running_cycle, running_stability,  # noqa: E402
                                              simulate_running)
from biped_casadi.control.running import FLIGHT_CLOCKS, RunningController  # noqa: E402
from gait_opt.running import RunningGait, RunningOptions, optimize_running  # noqa: E402

HAND = (0.0, 0.95, 0.95, 0.0)
CHOSEN_25 = (-1.8546200457197717, 1.322012671072324, 2.562564925658691, 0.8382205038714805)


def _foot_acceleration(fl, q, dq, u) -> float:
    """The freed foot's vertical acceleration (the base's: the foot is the base)."""
    qe, dqe = fl.takeoff(q, dq)
    return float(np.array(fl.flight_dynamics(qe, dqe, u))[-1, 0])


def takeoff(cyc, x) -> tuple:
    """The stance pass from x, what happens at its end and the push-off after it (the
    cycle's: stance dynamics under the restarted clock's flight law until the normal
    force reaches 0); the next state (or None)."""
    c, g = cyc.controller, cyc.controller.gait
    nq, fl = c.model.nq, c.fl
    try:
        ps, xp, _, _ = cyc._domain(0, x, None, False, False)
    except HybridCycleError as e:
        return dict(stance=str(e)), None
    q, dq, t = ps.exit_state[:nq], ps.exit_state[nq:], ps.duration
    u_st = np.array(c.stance_law(q, dq, t)).ravel()
    Fz, Fx = (float(v) for v in fl.takeoff_guard(q, dq, u_st))
    qe, dqe = (np.array(v).ravel() for v in fl.takeoff(q, dq))
    out = dict(stance=t, stance_less_reference=t - float(g.T_stance), fz=Fz, fx=Fx,
               foot_acceleration_stance_torques=_foot_acceleration(fl, q, dq, u_st))
    for clock, tf in (("takeoff", 0.0), ("stride", t - float(g.T_stance))):
        u_fl = np.array(c.flight_law(qe, dqe, tf)).ravel()
        out[f"torque_jump_{clock}"] = float(np.abs(u_fl - u_st).max())
        out[f"foot_acceleration_{clock}"] = _foot_acceleration(fl, q, dq, u_fl)
    u_fl = np.array(c.flight_law(qe, dqe, 0.0)).ravel()
    fz0, fx0 = (float(v) for v in fl.takeoff_guard(q, dq, u_fl))
    push = out["push_off"] = dict(fz_at_switch=fz0, fx_at_switch=fx0)
    try:
        po, xp, _, _ = cyc._domain(1, xp, None, False, False)
    except HybridCycleError as e:
        push["error"] = str(e)
        return out, None
    q, dq = po.exit_state[:nq], po.exit_state[nq:]
    qe, dqe = fl.takeoff(q, dq)
    u_end = np.array(c.flight_law(qe, dqe, po.duration)).ravel()
    push.update(duration=po.duration, fx_at_end=float(fl.takeoff_guard(q, dq, u_end)[1]),
                foot_acceleration=_foot_acceleration(fl, q, dq, u_end))
    try:
        fp = cyc._domain(2, xp, None, False, False, po.duration)[0]
        out["flight_dips"] = [v for _, _, v in fp.dips]
        nxt = fp.next_state
    except HybridCycleError as e:
        out["flight"] = str(e)
        nxt = None
    return out, nxt


def loop(cyc, strides) -> tuple:
    """The stride map's fixed point and the perturbed run (a dict), and the fixed point's
    analysis."""
    r = running_stability(cyc)
    out = dict(status=r.status, message=r.message, spectral_radius=r.spectral_radius,
               moduli=np.abs(r.eigenvalues).tolist(), residual=r.residual)
    if r.status != "failed":
        x = r.fixed_point.copy()
        x[cyc.controller.model.nq:] += 1e-2
        run = simulate_running(cyc, r.fixed_point, x, strides)
        out.update(run_status=run.status, run_message=run.message,
                   deviations=run.deviations.tolist())
    return out, r


def case(robot, gait, M1, strides, saturate) -> dict:
    m = load_model(robot)
    c = RunningController(m, gait, 400.0, 30.0, M1=M1, saturate=saturate)
    # the pinned foot's takeoff (the model before sliding), whose push-off this studies
    cycles = {k: running_cycle(c, flight_clock=k, sliding=False) for k in FLIGHT_CLOCKS}
    loops, pinned, fixed = {}, {}, {}
    for k in FLIGHT_CLOCKS:
        pinned[k], fixed[k] = loop(cycles[k], strides)
        loops[k] = loop(running_cycle(c, flight_clock=k), strides)[0]    # sliding (default)
    r = fixed["takeoff"]
    x = np.asarray(gait.x_stance, float)[:, 0].copy()
    if r.status != "failed":
        x = r.fixed_point.copy()
        x[m.nq:] += 1e-2
    passes = []
    for _ in range(3):
        p, x = takeoff(cycles["takeoff"], x)
        passes.append(p)
        if x is None:
            break
    return dict(robot=m.params.name, speed=gait.speed, M1=list(M1), saturate=saturate,
                T_stance=gait.T_stance, takeoffs=passes, loops=loops, pinned_loops=pinned)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs="+", action="append", metavar="ARG",
                    help="ROBOT GAIT_FILE [M1 ...] [saturate]")
    ap.add_argument("--strides", type=int, default=20)
    ap.add_argument("--no-save", action="store_true")
    a = ap.parse_args()
    cases = []
    for arg in a.case or []:
        sat = arg[-1] == "saturate"
        m1 = [float(v) for v in arg[2:len(arg) - sat]] or HAND
        cases.append((arg[0], RunningGait.load(arg[1]), tuple(m1), sat))
    if not cases:
        m = load_model("rabbit")
        for v, lim, M1, sat in ((1.5, None, HAND, False), (2.0, None, HAND, False),
                                (2.5, 145.0, CHOSEN_25, True)):
            g = optimize_running(m, RunningOptions(speed=v, torque_limit=lim), cache=True)
            cases.append(("rabbit", g, M1, sat))
    with Run("running_takeoff", "the running closed loop at the takeoff, with the flight "
             "clock restarted or continued", save=not a.no_save) as run:
        rows = []
        for robot, g, M1, sat in cases:
            r = case(robot, g, M1, a.strides, sat)
            rows.append(r)
            what = f"{r['robot']} {g.speed:g} m/s{', clipped' if sat else ''}"
            for model, key in (("sliding", "loops"), ("pinned", "pinned_loops")):
                for k, v in r[key].items():
                    run.row(f"{what}, flight clock {k}, {model} foot: spectral radius",
                            v["spectral_radius"], unit="")
                    print(what, k, model, v["status"], v.get("run_message", v["message"]),
                          flush=True)
            for i, t in enumerate(r["takeoffs"]):
                print(f"  takeoff {i + 1}:", {k: (round(v, 6) if isinstance(v, float) else v)
                                             for k, v in t.items()}, flush=True)
            t0 = r["takeoffs"][0]
            if "fz" in t0:
                run.row(f"{what}: torque jump at the first takeoff, restarted clock",
                        t0["torque_jump_takeoff"], unit="N m")
                run.row(f"{what}: torque jump at the first takeoff, continued clock",
                        t0["torque_jump_stride"], unit="N m")
        run.data["rows"] = rows
        run.note("PD Kp 400, Kd 30; 0.01 rad/s on every velocity of the restarted clock's "
                 "fixed point (the collocated landing state when it has none)")
        run.note("the takeoffs (stance pass, switch, push-off) are the pinned foot's "
                 "(sliding=False); the loops are measured with the sliding foot (the "
                 "default) and, for comparison, the pinned one")


if __name__ == "__main__":
    main()
