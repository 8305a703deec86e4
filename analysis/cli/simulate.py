"""``biped simulate``: full-order closed-loop walking with the time-varying controller
(paper §III) or virtual constraints (§V-C); paper Fig. 5 and Fig. 6, a stick-figure GIF."""
from __future__ import annotations

import math

import numpy as np

from biped_casadi import (Gains, Perturbation, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, simulate)
from biped_casadi.simulation import Terrain
from biped_casadi.simulation.speed_profile import CONVERGED
from biped_casadi.simulation.terrain import MAX_HEIGHT
from analysis.reporting.plots import (save_figures, swing_torques_plot, unactuated_error_plot,
                            walking_animation)

from .common import (Progress, UserError, add_design_arguments, add_gait_arguments, add_robot,
                     check_m1_values, check_not_singular, figure_or_na, gait_friction, load_gait,
                     MU_HELP, output_dir, output_file, parse_m1, positive, print_json,
                     rejoin_fraction)
from .simulate_profile import (add_profile_arguments, check_profile_arguments, cmd_profile,
                               walked)

#: errors below this at every impact are round-off: no trend is read from them
ROUND_OFF = 1e-8
#: --steps beyond this fill the memory with the logged states (2000 RK4 steps a step)
MAX_STEPS = 1000


def _controller(kind, model, gait, M1, gains, rejoin=0.5):
    if kind == "tv":
        return TimeVaryingController(gait, M1, gains, rejoin=rejoin)
    return VirtualConstraintController(gait, gains=gains)


#: the largest initial errors taken: half a turn on an angle (beyond, the same posture
#: again), and a rate far beyond any a biped has (beyond, the integration overflows)
MAX_ANGLE_ERROR, MAX_RATE_ERROR = math.pi, 100.0


def _check_perturbation(args):
    """What can be checked of the perturbation before the gait is loaded."""
    per_joint = args.perturb_q is not None or args.perturb_dq is not None
    if per_joint and args.perturb is not None:
        raise UserError("--perturb excludes --perturb-q / --perturb-dq (give one form)")
    for name, v in (("--perturb", args.perturb), ("--perturb-q", args.perturb_q),
                    ("--perturb-dq", args.perturb_dq)):
        if v is not None and not np.all(np.isfinite(v)):
            raise UserError(f"{name} values must be finite")
    for name, v, kind in (("--perturb", None if args.perturb is None else args.perturb[:1],
                           "angle"),
                          ("--perturb", None if args.perturb is None else args.perturb[1:],
                           "rate"),
                          ("--perturb-q", args.perturb_q, "angle"),
                          ("--perturb-dq", args.perturb_dq, "rate")):
        top, unit = (MAX_ANGLE_ERROR, "rad") if kind == "angle" else (MAX_RATE_ERROR, "rad/s")
        if v is not None and np.max(np.abs(v), initial=0.0) > top:
            raise UserError(f"{name}: {kind} errors must lie within +-{top:.3g} {unit}, got "
                            f"{max(v, key=abs):g}")


def _perturbation(args, nq) -> Perturbation:
    """--perturb Q DQ (every joint), or --perturb-q / --perturb-dq (per joint)."""
    _check_perturbation(args)
    per_joint = args.perturb_q is not None or args.perturb_dq is not None
    if per_joint:
        q = np.zeros(nq) if args.perturb_q is None else np.array(args.perturb_q, float)
        dq = np.zeros(nq) if args.perturb_dq is None else np.array(args.perturb_dq, float)
        for name, v in (("--perturb-q", q), ("--perturb-dq", dq)):
            if v.size != nq:
                raise UserError(f"{name} takes {nq} numbers (one per joint), got {v.size}")
            if not np.all(np.isfinite(v)):
                raise UserError(f"{name} values must be finite")
        return Perturbation(tuple(q), tuple(dq))
    q_err, dq_err = args.perturb if args.perturb is not None else (0.0, 0.0)
    if not (math.isfinite(q_err) and math.isfinite(dq_err)):
        raise UserError("--perturb values must be finite")
    return Perturbation.uniform(nq, q_err, dq_err)


def cmd_simulate(args):
    """``biped simulate``: check the arguments, build the start and the controller,
    simulate, draw, then report (JSON or a table per controller); with a speed profile
    on a gait family, :func:`~analysis.cli.simulate_profile.cmd_profile`."""
    # ---- arguments
    check_m1_values(args.m1)                 # before the gait: finite, within the range
    check_profile_arguments(args)
    _check_numbers(args)
    if args.speeds is not None or args.ramp is not None:     # a speed profile on a family
        return cmd_profile(args, Progress("simulate", quiet=args.json), _perturbation)
    args.steps = 10 if args.steps is None else args.steps
    terrain = _check_arguments(args)
    say = Progress("simulate", quiet=args.json)
    gait = load_gait(args, say)
    model = gait.model
    M1 = parse_m1(args.m1, model.nu, default_zero=True)
    perturbation = _perturbation(args, model.nq)
    gains = Gains(eps=args.eps)
    friction = gait_friction(args, gait)
    opts = SimulationOptions(steps=args.steps, mu=args.mu, jit=args.jit,
                             torque_limit=args.torque_limit)
    q0, dq0 = perturbation.initial_state(gait)

    # ---- simulate
    runs = _run(args, model, gait, M1, gains, q0, dq0, opts, terrain, say)
    res = runs[0]

    # ---- figures
    figures = _figures(args, runs, model, gait, say)

    # ---- report
    if args.json:
        d = res.to_dict()
        d["perturbation"] = perturbation.to_dict()
        d["mu"] = args.mu
        if terrain is not None:
            d["terrain"] = terrain.to_dict()
        d.update(_settling(res))
        if args.compare:
            d["compare"] = dict(runs[1].to_dict(), **_settling(runs[1]))
        if figures:
            d["figures"] = figures
        print_json(d)
        return walked(res)
    _print_report(runs, gait, terrain, figures, friction, default_m1=args.m1 is None)
    return walked(res)



def _settling(run) -> dict:
    """The JSON's verdict on the error: 'ok' (valid, below :data:`CONVERGED` at the
    end), 'not_converged' or the status, and the step it stays below from (or None)."""
    k = run.steps_to_converge(CONVERGED)
    return dict(verdict=run.verdict(CONVERGED), converged_below=CONVERGED,
                steps_to_converge=int(k) if np.isfinite(k) else None)


def _settling_line(run, default_m1: bool) -> str:
    """A valid run's error at the impacts in words: at the first and last step, which way
    it went, and whether it settled below :data:`CONVERGED` ('' for a failed run, whose
    status says how it ended); a growing error under the default M1 = 0 says that it is
    not a design."""
    if not run.ok:
        return ""
    k, e = run.steps_to_converge(CONVERGED), run.unactuated_errors()
    if max(e) < ROUND_OFF or len(e) < 2:
        trend = "round-off"
    else:       # the mean factor per step, from the first error above round-off to the last
        j = next(i for i, x in enumerate(e) if x >= ROUND_OFF)
        j = min(j, len(e) - 2)
        rate = (e[-1] / max(e[j], ROUND_OFF)) ** (1 / (len(e) - 1 - j))
        trend = ("growing" if rate > 1.05 else "falling" if rate < 0.95 else "steady") \
            + f", x{rate:.3g} a step" + (f" from step {j + 1}" if j else "")
    line = (f"  max(|q_u err|, |dq_u err|) {e[0]:.3g} at step 1"
            + (f", {e[-1]:.3g} at step {len(e)} ({trend})" if len(e) > 1 else "") + "; "
            + (f"below {CONVERGED:g} from step {int(k)}" if np.isfinite(k) else
               f"not converged (not below {CONVERGED:g} at the end)"))
    if trend.startswith("growing") and default_m1 and run.controller["controller"] == "tv":
        line += ("\n  M1 = 0 (the default) is not a stable design here: choose M1 with "
                 "'biped m1', check it with 'biped eig --m1 ...'")
    return line


def _check_numbers(args):
    """The controller's and the limits' numbers, and the perturbation (UserError)."""
    if args.controller == "vc" and args.m1 is not None and not args.compare:
        raise UserError("--m1 applies to the time-varying controller (--controller tv, "
                        "or --compare)")
    if args.controller == "vc" and args.rejoin is not None and not args.compare:
        raise UserError("--rejoin applies to the time-varying controller (--controller tv, "
                        "or --compare)")
    if args.schedule is not None and args.rejoin is not None:
        raise UserError("--schedule and --rejoin exclude each other (the schedule gives the "
                        "rejoin time)")
    args.rejoin = 0.5 if args.rejoin is None else args.rejoin
    if args.mu is not None:
        positive(args.mu, "--mu")
    positive(args.eps, "--eps")
    rejoin_fraction(args.rejoin)
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    _check_perturbation(args)


def _check_arguments(args):
    """What else can be checked before the gait is loaded: the terrain (or None)."""
    if not 1 <= args.steps <= MAX_STEPS:
        raise UserError(f"--steps must be between 1 and {MAX_STEPS}, got {args.steps}")
    terrain = None
    if args.terrain is not None:
        h = np.array(args.terrain, float)
        if not np.all(np.isfinite(h)) or np.any(np.abs(h) > MAX_HEIGHT):
            raise UserError(f"--terrain heights must be finite numbers within +-{MAX_HEIGHT} m")
        terrain = Terrain(tuple(h))
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    if args.animate is not None:
        output_file(args.animate, "--animate", suffixes=(".gif",))
    return terrain


def _run(args, model, gait, M1, gains, q0, dq0, opts, terrain, say):
    """The closed loop of the chosen controller (and of the other one with --compare)
    simulated from (q0, dq0): the runs, the chosen controller's first."""
    ctrl = _controller(args.controller, model, gait, M1, gains, args.rejoin)
    if args.controller == "tv":
        check_not_singular(ctrl, M1)
    say(f"simulating {args.steps} step(s)" + (" of each controller" if args.compare else "")
        + (" (compiling the closed loop to C first)" if args.jit else "") + " ...")
    try:
        res = simulate(ctrl, q0, dq0, opts, terrain=terrain)
        runs = [res]
        if args.compare:
            other = "vc" if args.controller == "tv" else "tv"
            runs.append(simulate(_controller(other, model, gait, M1, gains, args.rejoin),
                                 q0, dq0, opts, terrain=terrain))
    except RuntimeError as e:
        if not args.jit:
            raise
        raise UserError(f"--jit: compiling the closed loop failed (is a C compiler "
                        f"installed?): {str(e).strip().splitlines()[0]}") from None
    return runs


def _figures(args, runs, model, gait, say):
    """Figures 5 and 6 (--plot) and the animation of the first run (--animate)."""
    figures = {}
    if args.plot:
        title5 = (f"Fig. 5: error of the unactuated variable at the end of each step "
                  f"({model.params.name})")
        fig5, fig6 = save_figures({"fig5_qu_error": unactuated_error_plot(runs, title=title5),
                                   "fig6_swing_torques": swing_torques_plot(runs, gait)},
                                  args.plot)
        figures.update(fig5=fig5, fig6=fig6)
    if args.animate:
        say(f"writing the animation {args.animate} (about 1 s per simulated step) ...")
        figures["animation"] = walking_animation(runs[0], model, args.animate)
    return figures


def _print_report(runs, gait, terrain, figures, friction: str, default_m1: bool = False):
    """The text report: per run its status, a table of its steps, its peaks (with the
    friction coefficient ``friction``) and whether the error settled, then the files."""
    for r in runs:
        print(f"{r.controller['controller']}: status {r.status}"
              + (f" - {r.message}" if r.message else ""))
        if r.controller["controller"] == "tv":
            print(f"  M1 = {r.controller['M1']}")
        print("  step   t_impact [s]  duration/T   q_u - q_u^d(T)   dq_u - dq_u^d(T)"
              + ("   ground [m]" if terrain is not None else ""))
        for s in r.steps:
            print(f"  {s.index + 1:4d}   {s.t_impact:11.6f}  {s.duration / gait.T:10.6f}"
                  f"   {s.qu_error:+.6e}    {s.dqu_error:+.6e}"
                  + (f"   {s.ground_height:+.4f}" if terrain is not None else ""))
        print(f"  peak |u| {figure_or_na(r.peak_torque, '.1f')} N m, min F_z "
              f"{figure_or_na(r.min_normal_force, '.1f')} N, max |F_x|/F_z "
              f"{figure_or_na(r.max_friction_ratio, '.3f')}, at impact "
              f"{figure_or_na(r.max_impulse_ratio, '.3f')} ({friction})")
        if line := _settling_line(r, default_m1):
            print(line)
    for k, v in figures.items():
        print(f"{k}: {v}")


def register(sub):
    p = sub.add_parser(
        "simulate", help="full-order closed-loop walking (time-varying or virtual constraints)",
        description="Simulate the full-order hybrid closed loop (state q, dq, tau) for N steps "
                    "from the reference state perturbed by Q_ERR rad on every joint and DQ_ERR "
                    "rad/s on every velocity (paper §V-C uses 0.01 0.1). The run stops at the "
                    "first invalid state and says why: status fell, scuffed (swing foot in "
                    "the ground, or the old stance foot not lifting off), slipped (|F_x| > "
                    "mu F_z, in single support or for the impact impulse), "
                    "negative_normal_force (F_z <= 0), torque_limit (|u_i| > U), singular, "
                    "no_impact; 'ok' only when every step was valid (exit code 0; 1 when the "
                    "--controller run stopped; 2 for bad input). With --gait FAMILY.json "
                    "and --speeds V1 V2 ... (or --ramp V1 V2 DV) step k walks the family's "
                    "gait at Vk, the reference switching gait at each impact. --json prints "
                    "{status, "
                    "steps: [{t_impact, qu_error, dqu_error, ...}], peak_torque, "
                    "min_normal_force, max_friction_ratio, max_impulse_ratio, ...} with the "
                    "errors q_u - q_u^d(T), dq_u - dq_u^d(T) just before each impact.")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p, m1_zero=True)
    p.add_argument("--steps", type=int, default=None, metavar="N",
                   help=f"number of steps, 1 to {MAX_STEPS} (10)")
    p.add_argument("--perturb", nargs=2, type=float, default=None,
                   metavar=("Q_ERR", "DQ_ERR"), help="initial error on every joint (rad) and "
                   "every velocity (rad/s), within +-pi rad and +-100 rad/s (default 0 0; the "
                   "paper's: 0.01 0.1)")
    p.add_argument("--perturb-q", nargs="+", type=float, metavar="Q",
                   help="initial error of each joint angle q1..qn, rad (instead of --perturb)")
    p.add_argument("--perturb-dq", nargs="+", type=float, metavar="DQ",
                   help="initial error of each joint velocity, rad/s (instead of --perturb)")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="stop with status torque_limit where some |u_i| exceeds U, N m "
                        "(default: the robot's limit, 150 for RABBIT; for a robot without "
                        "one, the limit its gait was made for)")
    p.add_argument("--terrain", nargs="+", type=float, metavar="H",
                   help="ground heights h1 h2 ... of the steps' footholds above the stance "
                        "foot, m (a step up > 0; flat after the last)")
    p.add_argument("--mu", type=float, help=f"friction coefficient ({MU_HELP})")
    p.add_argument("--eps", type=float, default=0.02,
                   help="epsilon of the output PD, eq. (13), with Kp = 1, Kd = 2 (0.02)")
    p.add_argument("--compare", action="store_true",
                   help="also run the other controller from the same state (Fig. 5/6 overlay)")
    p.add_argument("--jit", action="store_true",
                   help="compile the closed loop to C first (needs a C compiler; faster)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="DIR", help="write Fig. 5 and Fig. 6 (PNG) into DIR; "
                   "with a speed profile, speed_profile.png (speed and errors per step)")
    add_profile_arguments(p)
    p.add_argument("--animate", metavar="FILE.gif", help="write a stick-figure GIF")
    p.set_defaults(func=cmd_simulate)
