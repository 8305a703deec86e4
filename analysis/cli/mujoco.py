"""``biped mujoco``: a design walked in MuJoCo with the exported C law in the loop, and
MuJoCo's stride map beside the exact eigenvalues."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from biped_casadi import Design, Gains
from biped_casadi.control.compiled import CompilerError
from biped_casadi.control.export import exported_law
from biped_casadi.mujoco import (BOUNCE_TOLERANCE, LAWS, SETTLE, STEP_STARTS, TOUCHDOWNS,
                                 MujocoLoop, check_contact, check_timestep, layout,
                                 stride_map)
from analysis.in_mujoco import exact_eigenvalues
from analysis.reporting.plots import mujoco_animation, mujoco_steps_plot, save_figures

from .common import (Progress, UserError, add_design_arguments, add_gait_arguments, add_robot,
                     check_m1_values, load_gait, output_dir, parse_m1, positive, print_json,
                     rejoin_fraction)
from .mujoco_options import (AUTO, add_mujoco_settings, cone_text as _cone, gait_settings,
                             mujoco_settings, settings_error)
from .simulate import MAX_STEPS, _check_perturbation, _perturbation


#: the steps ``--plot``'s animation shows (in real time; a longer walk's axes would leave
#: the robot a dot, and its GIF take minutes and tens of MB)
ANIMATED_STEPS = 10


def friction_needed(gait, mu: float) -> dict:
    """The friction ``gait`` needs, and a warning when ``mu`` is below it.

    Parameters
    ----------
    gait : Gait
        The gait (its dense check, :meth:`gait_opt.Gait.check`).
    mu : float
        The floor's friction coefficient in MuJoCo.

    Returns
    -------
    dict
        ``stance`` (the largest |F_x| / F_z over its stance), ``impact`` (|F_x| / F_z of
        its impact impulse), ``mu``, and ``warning``: one line when ``mu`` is below
        either, else ''.  Not a refusal: MuJoCo's friction is soft and its impact lasts
        a few time steps, so a walk below them can still walk (docs/howto/mujoco.md).
    """
    c = gait.check()
    stance, impact = float(c["max_friction_ratio"]), float(c["impact_friction_ratio"])
    needs = (f"|F_x| / F_z up to {stance:.3g} in its stance and {impact:.3g} in its impact "
             "impulse")
    if mu < stance:
        warning = (f"--mu {mu:g} is below the friction the gait needs ({needs}): expect its "
                   "stance foot to slide and the walk to slow down or fail")
    elif mu < impact:
        warning = (f"--mu {mu:g} is below the friction the gait's rigid impact needs "
                   f"({needs}): MuJoCo's soft impact may still hold, or the landing foot "
                   "slide")
    else:
        warning = ""
    return dict(stance=stance, impact=impact, mu=float(mu), warning=warning)


def _check(args):
    """Everything that can be checked before the gait is loaded; the settings."""
    check_m1_values(args.m1)
    if args.controller == "vc" and (args.m1 is not None or args.rejoin is not None):
        raise UserError("--m1 and --rejoin apply to the time-varying controller "
                        "(--controller tv)")
    if args.rejoin is not None:
        rejoin_fraction(args.rejoin)
    positive(args.eps, "--eps")
    if not 1 <= args.steps <= MAX_STEPS:
        raise UserError(f"--steps must be between 1 and {MAX_STEPS}, got {args.steps}")
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    positive(args.max_slip, "--max-slip")
    _check_perturbation(args)
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    return mujoco_settings(args)


def _design(args, gait) -> Design:
    gains = Gains(eps=args.eps)
    if args.controller == "vc":
        d = Design.vc(gait, gains)
    else:
        M1 = parse_m1(args.m1, gait.model.nu, default_zero=True)
        d = Design.tv(gait, M1, 0.5 if args.rejoin is None else args.rejoin, gains)
    try:
        exported_law(d)
    except ValueError as e:
        what = "--m1" if args.controller == "tv" else "--controller vc"
        raise UserError(f"{what}: {str(e).split(': ', 1)[-1]}") from None
    return d


def cmd_mujoco(args):
    # ---- arguments, the gait, the design, the loop
    settings = _check(args)
    say = Progress("mujoco", quiet=args.json)
    gait = load_gait(args, say)
    settings = gait_settings(args, settings, gait)
    friction = friction_needed(gait, settings.mu)
    if friction["warning"]:                     # before the walk: it qualifies all below
        print(f"biped mujoco: warning: {friction['warning']}", file=sys.stderr, flush=True)
    model = gait.model
    design = _design(args, gait)
    perturbation = _perturbation(args, model.nq)
    q0, dq0 = perturbation.initial_state(gait)
    if args.law == "c":
        say("compiling the exported C law (once; kept in the cache) ...")
    try:
        loop = MujocoLoop(design, settings, args.law, args.torque_limit, args.step_start,
                          args.max_slip, touchdown=args.touchdown)
    except CompilerError as e:
        raise UserError(f"--law c: {e} (or use --law python)") from None
    except ValueError as e:
        raise settings_error(e) from None

    # ---- walk, MuJoCo's stride map
    say(f"walking {args.steps} step(s) in MuJoCo ...")
    w = loop.run(q0, dq0, args.steps, log=args.plot is not None)
    if not w.success:
        say("the same walk at finer time steps and with softer contacts (is the time step "
            "or the contact the cause?) ...")
    check = check_timestep(loop, q0, dq0, args.steps, w, refine=args.timestep == AUTO)
    contact = check_contact(loop, q0, dq0, args.steps, w, check)
    chosen = chosen_solref = None
    if args.timestep == AUTO and check.status == "too_coarse":
        # --timestep auto: the walk, the figures and the stride map at the time step that
        # walked with its landings resolved (the walk again, for its log); it keeps the
        # contact asked for, so it comes before --solref auto
        chosen = check.suggested_timestep
        say(f"--timestep auto: walking at {chosen:g} s ...")
        loop = loop.at_timestep(chosen)
    elif args.solref == AUTO and contact.status == "too_stiff":
        chosen_solref = contact.suggested_solref
        say(f"--solref auto: walking with solref {chosen_solref:g} s ...")
        loop = loop.with_settings(solref=chosen_solref)
    if chosen is not None or chosen_solref is not None:
        w = loop.run(q0, dq0, args.steps, log=args.plot is not None)
    eig = None
    if not args.no_eig:
        say("MuJoCo's limit cycle and stride map (rollouts) ...")
        sm = stride_map(design, loop.settings, args.law, loop=loop)
        ex = exact_eigenvalues(design)
        known = sm.status != "undetermined"     # else the fit's are not MuJoCo's
        eig = dict(status=sm.status, reason=sm.reason,
                   mujoco=sm.eigenvalues if known else [],
                   mujoco_max_abs=sm.max_abs if known else math.nan,
                   exact=ex, exact_max_abs=max(abs(e) for e in ex),
                   relative_residual=sm.relative_residual, stride_map=sm.to_dict())

    figures = _figures(args.plot, design, w, say) if args.plot else {}

    # ---- report
    d = w.to_dict()
    d["perturbation"] = perturbation.to_dict()
    d["friction_needed"] = friction
    d["steps_per_second"] = w.steps_per_second
    d["timestep_check"] = check.to_dict()
    d["timestep_check"]["auto_timestep"] = chosen
    d["contact_check"] = contact.to_dict()
    d["contact_check"]["auto_solref"] = chosen_solref
    if eig is not None:
        d["eigenvalues"] = eig
    if figures:
        d["figures"] = figures
    if args.json:
        print_json(d)
    else:
        _print(w, eig, figures, check, chosen, contact, chosen_solref)
    return 0 if w.success else 1


def _figures(plot: str, design, w, say) -> dict:
    """``--plot DIR``: the figure of the steps and the animation of the walk; their paths."""
    say("drawing the figure and the animation ...")
    folder, figures = Path(plot), {}
    title = f"In MuJoCo, {design.label()}:\nspeed, step duration and error at each touchdown"
    figures["steps"] = save_figures({"mujoco_steps": mujoco_steps_plot([w], title=title)},
                                    folder)[0]
    if w.t.size:
        figures["animation"] = mujoco_animation(w, layout(design.gait.model),
                                                folder / "mujoco_walk.gif",
                                                max_steps=ANIMATED_STEPS)
    return figures


def _pct(x) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:+.2f} %"


def _ev(ev) -> str:
    return "[" + ", ".join(f"{e.real:.3g}" if abs(e.imag) < 1e-12 else
                           f"{e.real:.3g}{e.imag:+.3g}j" for e in ev) + "]"


def _auto_line(check, chosen: float) -> str:
    """``--timestep auto``'s line: why the walk below is not at the time step asked for."""
    c, mm = check.walk, lambda x: f"{1e3 * x:.3g} mm"
    why = (f"({c['message']})" if c["status"] != "walked" else
           f"but its landings moved the new stance foot up to {mm(c['landing_travel'])} "
           f"(more than {mm(check.bounce_limit)}, {100 * BOUNCE_TOLERANCE:g} % of the step)")
    r = next(t for t in check.tried if t["timestep"] == chosen)
    still = "" if not r["landing_travel"] > check.bounce_limit else (
        f" (the finest time step tried: its landings still move the foot up to "
        f"{mm(r['landing_travel'])}, not the time step alone: the friction?)")
    return (f"--timestep auto: at {check.timestep:g} s the walk {c['status']} {why}; the walk "
            f"below is at {chosen:g} s{still}")


def _print(w, eig, figures, check=None, chosen=None, contact=None, chosen_solref=None):
    s = w.settings
    if chosen is not None:
        print(_auto_line(check, chosen))
    if chosen_solref is not None:
        print(f"--solref auto: with solref {contact.solref:g} s the walk "
              f"{check.walk['status']} ({check.walk['message']}); the walk below is with "
              f"solref {chosen_solref:g} s")
    print(f"MuJoCo ({s['contact']} contact: solref "
          f"{s['solref'] if s['solref'] is not None else 'MuJoCo default 0.02'} s, dt "
          f"{s['timestep']:g} s, feet {s['foot_radius']:g} m, mu {s['mu']:g}{_cone(s)}), "
          f"{w.law} law, "
          f"step start from the {w.step_start}: {w.status}"
          + (f" - {w.message}" if w.message else ""))
    if chosen is None and chosen_solref is None:
        for c in (check, contact):
            if c is not None and c.message:
                print(f"  {c.message}")
    over = (f"over steps {SETTLE + 1}-{w.steps_walked}" if w.steps_walked > 2 * SETTLE
            else "over all steps")
    print(f"  {w.steps_walked} of {w.n_steps} steps; speed error {_pct(w.speed_error)}, period "
          f"error {_pct(w.period_error)} ({over}); worst error after step {SETTLE}: "
          + (f"{w.worst_qu_error:.3g} rad, {w.worst_dqu_error:.3g} rad/s"
             if w.steps_walked > SETTLE else "none (the walk ended first)"
             if w.steps_walked < w.n_steps else
             f"none: it needs more than {SETTLE} steps (--steps {2 * SETTLE + 10})"))
    print("  step  period [s]  speed [m/s]  q_u err [rad]  dq_u err [rad/s]  peak |u| "
          "cmd/applied [N m]  clipped [s]  slip [mm]")
    for r in w.steps:
        print(f"  {r.index + 1:4d}  {r.period:10.4f}  {r.speed:11.4f}  {r.qu_error:+13.4e}  "
              f"{r.dqu_error:+16.4e}  {r.peak_commanded:8.1f} / {r.peak_applied:6.1f}        "
              f"{r.clipped_time:8.3f}  {1e3 * r.slip:8.3f}")
    print(f"  {w.mujoco_steps} MuJoCo steps in {w.wall_time:.2f} s ({w.steps_per_second:.0f} "
          "steps/s with the law in the loop)")
    if eig is not None:
        c = eig["stride_map"]["cycle"]
        if eig["status"] == "undetermined":
            print(f"MuJoCo's stride map on tau = 0.75 T: not determined by its rollouts "
                  f"({eig['reason']}); exact {_ev(eig['exact'])}")
            if math.isfinite(c["approach"]):
                s0, s1 = c["approach_steps"]
                print(f"  MuJoCo's walk approached its cycle by a factor {c['approach']:.3g} "
                      f"a step (steps {s0}-{s1}): its slowest multiplier, unperturbed")
        elif len(eig["mujoco"]):
            print(f"MuJoCo's stride map on tau = 0.75 T: eigenvalues {_ev(eig['mujoco'])} (fit "
                  f"residual {eig['relative_residual']:.2g} of the deviations); exact "
                  f"{_ev(eig['exact'])}")
        else:
            print(f"MuJoCo's stride map on tau = 0.75 T: none (no cycle to fit it on); exact "
                  f"{_ev(eig['exact'])}")
        print(f"  {c['message']}")
        if eig["exact_max_abs"] > 1:
            print(f"  the design is unstable (exact max|lambda| {eig['exact_max_abs']:.3g} > 1): "
                  "choose M1 with 'biped m1' (--m1 defaults to all zero)")
    for k, v in figures.items():
        print(f"{k}: {v}")


def register(sub):
    p = sub.add_parser(
        "mujoco", help="walk a design in MuJoCo with the exported C law in the loop",
        description="Walk the controller of 'biped simulate' (the same design options; "
                    "'biped m1 --robust' prints them as simulate_args) in MuJoCo: the robot's "
                    "MJCF ('biped robot mjcf'), the law of 'biped export' compiled once "
                    "and called every MuJoCo step (--law python: the same law in Python), "
                    "touchdown from MuJoCo's contacts once the old stance foot has lifted "
                    "off, the legs relabelled, each step's law state from the rigid impact "
                    "map applied to the state at touchdown (--step-start contact: from "
                    "MuJoCo's state, which is still mid-impact). Prints per step the period, "
                    "speed, pre-impact error, peak torque commanded and applied, clipping "
                    "time and stance-foot slip, and how the walk ended (walked, fell, "
                    "scuffed, slipped, ...); then MuJoCo's limit cycle and its stride-map "
                    "eigenvalues (a least-squares fit of rollouts) beside the exact ones. "
                    "A walk that fails is walked again at a half and a quarter of the time "
                    "step: one line says whether the time step is the likely cause and which "
                    "--timestep to use (JSON: timestep_check); a walk that walks but whose "
                    "landings bounce (move the new stance foot more than 1 % of the step) "
                    "is named there too (--timestep auto walks it at the finer time step "
                    "that resolves them); and again at the same time step "
                    "with a contact 1.5 and 2 times softer: a second line says whether a "
                    "softer contact walks, which --solref to use and what it costs (speed "
                    "error, feet' depth into the floor; JSON: contact_check). Exit 0 when the "
                    "walk walked its steps, 1 otherwise.")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p, m1_zero=True)
    p.add_argument("--eps", type=float, default=0.02,
                   help="epsilon of the output PD, eq. (13), with Kp = 1, Kd = 2 (0.02)")
    p.add_argument("--steps", type=int, default=10, metavar="N",
                   help=f"steps to walk, 1 to {MAX_STEPS} (10)")
    p.add_argument("--perturb", nargs=2, type=float, default=None,
                   metavar=("Q_ERR", "DQ_ERR"), help="initial error on every joint (rad) and "
                   "every velocity (rad/s), within +-pi rad and +-100 rad/s (default 0 0; the "
                   "paper's: 0.01 0.1)")
    p.add_argument("--perturb-q", nargs="+", type=float, metavar="Q",
                   help="initial error of each joint angle q1..qn, rad (instead of --perturb)")
    p.add_argument("--perturb-dq", nargs="+", type=float, metavar="DQ",
                   help="initial error of each joint velocity, rad/s (instead of --perturb)")
    p.add_argument("--law", choices=LAWS, default="c",
                   help="c: the exported C law through ctypes (default); python: the same "
                        "law in Python (slower)")
    p.add_argument("--step-start", choices=STEP_STARTS, default="impact",
                   help="each step's law state from the rigid impact map at touchdown "
                        "(default) or from MuJoCo's state one time step later")
    p.add_argument("--touchdown", choices=TOUCHDOWNS, default="grid",
                   help="the touchdown's time and state: MuJoCo's first state in contact "
                        "(default), or interpolated to where the swing foot meets the floor")
    add_mujoco_settings(p, auto=True)
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="the motors' limit, N m (default the robot's, or for a robot without one "
                        "the limit its gait was made for); torques beyond it are clipped by "
                        "MuJoCo and the time clipped is reported")
    p.add_argument("--max-slip", type=float, default=0.05, metavar="M",
                   help="a stance foot sliding more than M in single support ends the walk "
                        "as slipped (0.05 m; MuJoCo's soft friction creeps about 0.5 mm a "
                        "step at stiff contact, 12 mm at MuJoCo's default)")
    p.add_argument("--no-eig", action="store_true",
                   help="skip MuJoCo's stride map (a second or two of rollouts)")
    p.add_argument("--plot", metavar="DIR",
                   help="write DIR/mujoco_steps.png (speed, period and errors per step) and "
                        f"DIR/mujoco_walk.gif (the walk, its first {ANIMATED_STEPS} steps)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_mujoco)
