"""``biped mujoco-running``: a saved running step run in MuJoCo under its tracking
controller, the landing states against the exact stride map's fixed point, and MuJoCo's
stride map fitted from a long run."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from biped_casadi.control.compiled import CompilerError
from biped_casadi.control.compiled_running import CompiledRunningLaw
from biped_casadi.control.export_running import RUNNING_LIBRARY
from biped_casadi.control.running import FLIGHT_CLOCKS
from biped_casadi.model.description import torque_bound_text
from biped_casadi.mujoco.running import TAKEOFF_CLOCKS, RunningLoop, fit_running_map
from analysis.stability.running_cycle import running_cycle, running_stability

from .common import (Progress, UserError, add_robot, check_torque_limit, load_running_gait,
                     print_json)
from .mujoco_options import (add_mujoco_settings, cone_text as _cone, gait_settings,
                             mujoco_settings, settings_error)
from .running import (MAX_STRIDES, add_tracking_arguments, check_strides_and_perturb,
                      check_tracking_arguments, running_controller)


def _check(args):
    check_tracking_arguments(args)
    check_torque_limit(args, clip_only=True)
    check_strides_and_perturb(args.strides, args.perturb)
    if args.fit != 0 and not 30 <= args.fit <= MAX_STRIDES:
        raise UserError(f"--fit must be 0 or between 30 and {MAX_STRIDES} strides, got "
                        f"{args.fit}")
    if not str(args.gait).strip():
        raise UserError("--gait: empty name")
    if args.compiled is not None and not str(args.compiled).strip():
        raise UserError("--compiled: empty folder name")
    if args.compiled is not None and not Path(args.compiled).is_dir():
        raise UserError(f"--compiled: {args.compiled} is not a folder (an export of "
                        "'biped export-running')")
    return mujoco_settings(args)


def _compiled(args, controller):
    """The law of --compiled DIR, checked to be this run's controller and built (None
    without)."""
    if args.compiled is None:
        return None
    try:
        with tempfile.TemporaryDirectory(prefix="biped-running-") as work:
            return CompiledRunningLaw.build(args.compiled, controller,
                                            Path(work) / RUNNING_LIBRARY)
    except (ValueError, CompilerError) as e:
        raise UserError(f"--compiled: {e}") from None


def cmd_mujoco_running(args):
    settings = _check(args)
    say = Progress("mujoco-running", quiet=args.json)
    gait, model = load_running_gait(args)
    settings = gait_settings(args, settings, gait)
    c = running_controller(args, gait, model, engine="MuJoCo")
    compiled = _compiled(args, c)
    exact = None
    x_star = A = None
    if args.exact:
        say("the exact stride map: fixed point and eigenvalues (about 20 s) ...")
        st = running_stability(running_cycle(c, flight_clock=args.flight_clock))
        if st.status == "failed":
            raise UserError(f"--exact: {st.message}")
        x_star, A = st.fixed_point, st.A
        exact = dict(status=st.status, spectral_radius=st.spectral_radius,
                     eigenvalues=st.eigenvalues, durations=st.durations,
                     fixed_point=st.fixed_point)
    try:
        loop = RunningLoop(c, settings, x_star, takeoff_clock=args.takeoff_clock,
                           flight_clock=args.flight_clock,
                           compiled=compiled)
    except ValueError as e:
        raise settings_error(e) from None
    x0 = loop.x_star.copy()
    x0[model.nq:] += args.perturb
    say(f"running {args.strides} stride(s) in MuJoCo ...")
    r = loop.run(x0, args.strides)
    fit = None
    if args.fit:
        say(f"MuJoCo's stride map from a run of {args.fit} strides ...")
        fit = fit_running_map(loop.run(loop.x_star, args.fit), reference=A)
    d = r.to_dict()
    d.update(exact=exact, fit=None if fit is None else fit.to_dict(),
             takeoff_clock=args.takeoff_clock, flight_clock=args.flight_clock,
             fixed_point_kind="exact" if args.exact else "collocated",
             perturb=args.perturb, file=str(args.gait),
             clipped_at=c.clipped_at)
    if args.json:
        print_json(d)
    else:
        _print(r, d, exact, fit)
    return 0 if r.success else 1


def _ev(ev) -> str:
    return "[" + ", ".join(f"{e.real:.3g}" if abs(e.imag) < 1e-12 else
                           f"{e.real:.3g}{e.imag:+.3g}j" for e in ev) + "]"


def _clip(d) -> str:
    return "" if d["clipped_at"] is None else \
        f", torques clipped at {torque_bound_text(d['clipped_at'])} N m"


def _print(r, d, exact, fit):
    s, g = r.settings, r.gait
    print(f"MuJoCo (solref {s['solref'] if s['solref'] is not None else 'default 0.02'} s, dt "
          f"{s['timestep']:g} s, feet {s['foot_radius']:g} m, mu {s['mu']:g}{_cone(s)}), M1 = "
          f"{r.controller['M1']}{_clip(d)}: {r.status} - {r.message}")
    if "compiled" in r.controller:
        print(f"  the law compiled from the export {r.controller['compiled']['export']}")
    print(f"  deviations from the {d['fixed_point_kind']} fixed point (largest entry of the "
          "landing state, rad or rad/s)")
    print("  stride  stance [s]  flight [s]  speed [m/s]  deviation  peak |u| [N m]  "
          "slip [mm]")
    for x in r.strides:
        print(f"  {x.index + 1:6d}  {x.stance:10.4f}  {x.flight:10.4f}  {x.speed:11.4f}  "
              f"{x.deviation:9.3g}  {x.peak_torque:14.1f}  {1e3 * x.slip:9.2f}")
    print(f"  the gait: stance {g['T_stance']:.4f} s, flight {g['T_flight']:.4f} s, "
          f"{g['speed']:.4f} m/s; {r.mujoco_steps} MuJoCo steps in {r.wall_time:.2f} s")
    if exact is not None:
        print(f"exact stride map: spectral radius {exact['spectral_radius']:.4g}, eigenvalues "
              f"{_ev(np.asarray(exact['eigenvalues'])[:4])} ...")
    if fit is not None:
        print(f"{fit.message}; eigenvalues {_ev(np.asarray(fit.eigenvalues)[:4])} ...")


def register(sub):
    p = sub.add_parser(
        "mujoco-running", help="run a running step in MuJoCo under its tracking controller",
        description="Run a step saved by 'biped running' in MuJoCo (the robot's MJCF, sphere "
                    "feet) under the tracking controller of 'biped running --stability' "
                    "(the same --kp, --kd, --m1, --law), called from Python every MuJoCo "
                    "step (or its C export: --compiled DIR): stance until the stance "
                    "foot's contact force vanishes, flight "
                    "until the swing foot touches, the legs relabelled there. Starts just "
                    "after a landing at the collocated landing state (--exact: the exact "
                    "stride map's fixed point, and its eigenvalues), PERTURB added to every "
                    "velocity; prints per stride the stance and flight durations, speed, "
                    "the landing state's deviation (the rigid landing map of MuJoCo's state "
                    "at touchdown, against the fixed point), peak torque and slip. --fit N: "
                    "MuJoCo's stride map, a least-squares fit of the landing states of an "
                    "N-stride run, and its eigenvalues. Exit 0 when the run completed its "
                    "strides, 1 when it stopped (fell, slipped, a phase too long, a double "
                    "contact, diverged).")
    p.add_argument("--gait", required=True, metavar="FILE",
                   help="a running step saved by 'biped running --out FILE'")
    add_robot(p)
    add_tracking_arguments(p)
    p.add_argument("--saturate", action="store_true",
                   help="the law clips its torques at the robot's limit (or --torque-limit), "
                        "as 'biped running --saturate' (MuJoCo's motors clip them anyway: "
                        "the strides' peak torque is then at most the limit); the design of "
                        "an export made with 'biped export-running --saturate'")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="with --saturate: the limit the law and MuJoCo's motors clip at, "
                        "N m (default the robot's)")
    p.add_argument("--strides", type=int, default=30, metavar="N",
                   help=f"strides to run, 1 to {MAX_STRIDES} (30)")
    p.add_argument("--perturb", type=float, default=0.0, metavar="DQ",
                   help="added to every velocity of the start, rad/s (default 0)")
    p.add_argument("--exact", action="store_true",
                   help="measure from the exact stride map's fixed point and print its "
                        "eigenvalues (builds the map: about 20 s)")
    p.add_argument("--compiled", metavar="DIR",
                   help="call the law compiled from DIR, an export of this gait and design "
                        "by 'biped export-running' (built with $CC, gcc or cc), instead of "
                        "its CasADi Functions")
    p.add_argument("--fit", type=int, default=0, metavar="N",
                   help="fit MuJoCo's stride map on a run of N strides from the fixed point "
                        "(30 to 5000; default 0: no fit). The 10 x 10 map needs a few hundred "
                        "strides: at dt 2 ms, 300 give max|lambda| 0.46 +- 0.06 (0.69 +- "
                        "0.05 with --takeoff-clock contact; 60 gave 0.87 +- 0.09) in 6 to "
                        "12 s. The estimate is biased upward: with "
                        "--exact the same fit is also run on the exact map driven by the "
                        "fit's residuals (reference_max_abs), the figure to compare with")
    p.add_argument("--takeoff-clock", choices=TAKEOFF_CLOCKS, default="guard",
                   help="where the flight law's clock starts: 'guard' (the rigid model's "
                        "takeoff guard on MuJoCo's states, default) or 'contact' (MuJoCo's "
                        "first zero-force state, whose scatter with the contact's chatter "
                        "makes most of the stride-to-stride jitter)")
    p.add_argument("--flight-clock", choices=FLIGHT_CLOCKS, default="takeoff",
                   help="the flight reference's clock: from the takeoff (default; dated by "
                        "--takeoff-clock) or the stance's continued (t - T_stance, t since "
                        "landing), as biped running --flight-clock")
    add_mujoco_settings(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_mujoco_running)
