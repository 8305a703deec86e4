"""``biped running``: optimise one periodic running step (stance, takeoff, flight,
landing), check it outside the NLP, save it and optionally draw it; with
``--stability``, close the loop with the tracking controller and give the stride map's
fixed point, its exact eigenvalues and a perturbed run (docs: how-to "Prepare a second
domain"); every computation is in ``gait_opt.running``, ``gait_opt.running_checks``,
``biped_casadi.control.running`` and ``analysis.stability.running_cycle``."""
from __future__ import annotations

import math
import sys

import numpy as np

from analysis.design.running_m1 import choose_running_m1
from analysis.reporting.plots import running_plot, save_figures
from analysis.stability.running_cycle import (FLIGHT_CLOCKS, STEPS_PER_INTERVAL, running_cycle,
                                              running_stability, simulate_running)
from biped_casadi.control.running import RunningController
from biped_casadi.control.running_step import rk4_gain_bounds
from biped_casadi.model.description import torque_bound_text
from gait_opt.running import MU_MARGIN, RunningOptions, optimize_running
from gait_opt.running_checks import check_running
from gait_opt.running_solve import MAX_TIGHTENINGS, STALL_WINDOW, TORQUE_TOL

from .common import Progress, UserError, add_robot, check_m1_values, check_saturation, \
    check_torque_limit, load_model, load_running_gait, output_dir, output_file, print_json
from .simulate import MAX_RATE_ERROR


#: the stability analysis's default design: PD gains and the output's column on q1 that
#: make RABBIT's 1.5 m/s running gait stable (docs: how-to running, "Closing the loop")
DEFAULT_KP, DEFAULT_KD = 400.0, 30.0
DEFAULT_M1 = (0.0, 0.95, 0.95, 0.0)

#: --choose-m1's default bound on a fixed point's distance from the collocated landing
#: state (largest entry, rad or rad/s): farther is another orbit than the gait's
MAX_DISTANCE = 1e-2

#: the closed loop's options and their defaults: given any of them (or --m1), the closed
#: loop is analysed (--stability implied; before, they were ignored without it, and a
#: run with --kp 1e300 optimised the step and exited 0 as if the gain were fine)
CLOSED_LOOP_DEFAULTS = dict(kp=DEFAULT_KP, kd=DEFAULT_KD, law="pd", steps=20, perturb=1e-2,
                            flight_clock="takeoff")

#: the options of the optimisation and their defaults (given or not: refused with --gait)
OPTIMISE_DEFAULTS = dict(speed=1.5, mu=0.6, mu_margin=MU_MARGIN, intervals=(16, 10),
                         out="running.json")

#: at most this many strides in a run (--steps here, --strides and --fit of mujoco-running)
MAX_STRIDES = 5000

#: --choose-m1 solves at most this many fixed points (--max-evaluations; about 0.5 s
#: each at RABBIT's 1.5 m/s step, some 17 minutes; the default is 150)
MAX_EVALUATIONS = 2000

#: a phase's integration departing from its collocation by more than this (the largest
#: entry, rad or rad/s) is said on a note line: the grid is coarse for that robot
COARSE = 1e-3
#: a phase's departure above this many times the largest interval's (each integrated from
#: its own collocated start) is the open loop's growth, not the grid's error alone
GROWN = 10.0


def add_tracking_arguments(p):
    """``--kp``, ``--kd``, ``--m1``, ``--law``: the running controller's design (this
    command's closed loop, and ``biped mujoco-running``)."""
    p.add_argument("--kp", type=float, default=DEFAULT_KP,
                   help=f"proportional gain, N m/rad (default {DEFAULT_KP:g}; 1/s^2 with "
                        "--law computed_torque)")
    p.add_argument("--kd", type=float, default=DEFAULT_KD,
                   help=f"derivative gain, N m s/rad (default {DEFAULT_KD:g}; 1/s with "
                        "--law computed_torque)")
    p.add_argument("--m1", type=float, nargs="+", metavar="M",
                   help="the output's column on q1, one number per torque (default "
                        f"{' '.join(f'{v:g}' for v in DEFAULT_M1)}, stable for RABBIT at "
                        "1.5 m/s; 0 0 0 0 is plain joint tracking)")
    p.add_argument("--law", choices=("pd", "computed_torque"), default="pd",
                   help="feedforward + PD (default) or computed torque on the outputs")


def check_tracking_arguments(args):
    """UserError (one line) for a gain of :func:`add_tracking_arguments` that is not a
    finite number >= 0, or an ``--m1`` that is not finite or beyond the model's numerical
    validity (as every command's ``--m1``)."""
    for name in ("kp", "kd"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0):
            raise UserError(f"--{name} must be a finite number >= 0, got {v:g}")
    check_m1_values(args.m1)


def running_controller(args, gait, model, engine: str = "") -> RunningController:
    """The controller of the tracking arguments (``--kp``, ``--kd``, ``--m1``, ``--law``),
    ``--saturate`` and ``--torque-limit`` (the limit: default the robot's; none for a
    robot without one, unless it runs in ``engine``, whose motors need one).

    Parameters
    ----------
    args : argparse.Namespace
        The command's arguments.
    gait : RunningGait
        The step.
    model : BipedModel
        Its robot.
    engine : str
        'MuJoCo' when the controller drives MuJoCo's motors ('' otherwise).

    Returns
    -------
    RunningController

    Raises
    ------
    UserError
        An ``--m1`` of another length, or, for ``engine``, no limit (a robot without
        one, and no ``--torque-limit``).
    """
    M1 = tracking_m1(args, model)
    check_saturation(args, model)
    if engine and args.torque_limit is None \
            and not math.isfinite(model.description.torque_limit):
        raise UserError(f"the robot {model.params.name} has no torque limit, which "
                        f"{engine}'s motors need: give --saturate --torque-limit U")
    return RunningController(model, gait, Kp=args.kp, Kd=args.kd, M1=M1, law=args.law,
                             saturate=args.saturate, torque_limit=args.torque_limit)


def tracking_m1(args, model) -> tuple:
    """``--m1`` (default :data:`DEFAULT_M1`); UserError when not one number per torque."""
    M1 = DEFAULT_M1 if args.m1 is None else tuple(args.m1)
    if len(M1) != model.nu:
        raise UserError(f"--m1 takes {model.nu} numbers for this robot (one per torque), "
                        f"got {len(M1)}")
    return M1


def check_strides_and_perturb(strides, perturb, option: str = "--strides", low: int = 1):
    """UserError for a stride count outside ``low``..:data:`MAX_STRIDES` (``option``), or
    a ``--perturb`` of the velocities that is not finite or beyond +-100 rad/s (as
    ``biped simulate``'s rate errors)."""
    if not low <= strides <= MAX_STRIDES:
        raise UserError(f"{option} must be between {low} and {MAX_STRIDES}, got {strides}")
    if not (math.isfinite(perturb) and abs(perturb) <= MAX_RATE_ERROR):
        raise UserError(f"--perturb must be a finite number within +-{MAX_RATE_ERROR:g} "
                        f"rad/s, got {perturb:g}")


def register(sub):
    p = sub.add_parser(
        "running", help="optimise a periodic running step (stance + flight) and, with "
                        "--stability, the stability of its tracking controller",
        description="Optimise one periodic running step of a robot with legs of two links "
                    "(RABBIT by default): single support, takeoff where the ground's normal "
                    "force reaches zero, flight, the swing foot's landing with the legs "
                    "relabelled (Hermite-Simpson collocation on both phases + IPOPT), then "
                    "measure it outside the NLP: the phases integrated by an ODE solver, "
                    "the step map through the exact takeoff and landing, the ground force "
                    "and the feet on a dense grid.  With --stability (or --gait FILE), track "
                    "it with a controller in stance and flight and give the stride map's "
                    "fixed point, exact eigenvalues and a perturbed run.")
    p.add_argument("--speed", type=float, metavar="V",
                   help="average speed, m/s (default 1.5)")
    p.add_argument("--mu", type=float, help="friction coefficient (default 0.6)")
    p.add_argument("--mu-margin", type=float, metavar="M",
                   help="kept below --mu in every friction cone of the optimised step (stance "
                        f"force, landing impulse), 0 <= M < mu (default {MU_MARGIN:g}: room "
                        "for a perturbed closed loop's landing)")
    p.add_argument("--torque-limit", type=float, default=None, metavar="U",
                   help="|u| bound in N m (default: the robot's, 150 for RABBIT): the "
                        "optimised step's and its closed loop's (a run stops beyond it, or "
                        "with --saturate clips at it); with --gait only the limit --saturate "
                        "clips at")
    p.add_argument("--intervals", type=int, nargs=2, metavar=("STANCE", "FLIGHT"),
                   help="Hermite-Simpson intervals of each phase, 2 to 200 (default 16 10)")
    p.add_argument("--max-iter", type=int, default=None, metavar="K",
                   help="IPOPT iteration limit (default 3000); giving it also turns off the "
                        "stop of a search whose constraint violation did not halve over "
                        f"{STALL_WINDOW} iterations (with it an unreachable speed fails in "
                        "about 30 s): the long search")
    p.add_argument("--no-cache", action="store_true",
                   help="solve again even when a step of the same robot, options and code "
                        "is kept in the cache ($BIPED_CACHE_DIR or ~/.cache/biped-casadi)")
    add_robot(p, with_gait=False)
    p.add_argument("--out", metavar="FILE",
                   help="where to save the step (default running.json; "
                        "gait_opt.running.RunningGait.load reads it)")
    p.add_argument("--plot", metavar="DIR",
                   help="write running_step.png into DIR (poses, joint angles, torques)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_closed_loop_arguments(p)
    p.set_defaults(func=cmd_running)


def _add_closed_loop_arguments(p):
    """The options of ``--stability`` (the closed loop), in their own group."""
    st = p.add_argument_group(
        "closed loop (--stability)",
        "track the step with u = u_d(t) + Kp (v_d - v) + Kd (dv_d - dv), v = [M1, I] q, in "
        "stance and in flight (t restarts in each phase, see --flight-clock); find the stride "
        "map's fixed point (landing state), the eigenvalues of its exact Jacobian and run "
        "STEPS strides from the fixed point with PERTURB added to every velocity; exit code 1 "
        "when the closed loop fails (no fixed point, or the perturbed run stops); any option "
        "of this group implies --stability")
    st.add_argument("--stability", action="store_true",
                    help="analyse the closed loop of the step (optimised, or --gait FILE)")
    st.add_argument("--gait", metavar="FILE",
                    help="a running step saved by 'biped running' (no optimisation, nothing "
                         "written); implies --stability")
    add_tracking_arguments(st)
    st.add_argument("--steps", type=int, default=20, metavar="N",
                    help=f"strides of the perturbed run, 0 to {MAX_STRIDES} (default 20; 0: "
                         "none)")
    st.add_argument("--perturb", type=float, default=1e-2, metavar="DQ",
                    help="added to every velocity of the fixed point, rad/s, within +-100 "
                         "(default 0.01)")
    st.add_argument("--saturate", action="store_true",
                    help="clip the law's torques at the robot's limit or --torque-limit "
                         "(the motors give their maximum) instead of stopping the run where "
                         "the law asks for more; "
                         "the report gives each stride's time saturated; implies "
                         "--stability")
    st.add_argument("--flight-clock", choices=FLIGHT_CLOCKS, default="takeoff",
                    help="the flight reference's clock: restarted at 0 at the takeoff "
                         "(default) or the stance's continued through it (t - T_stance, t "
                         "since landing), which keeps the law's torque continuous through a "
                         "takeoff earlier or later than the reference's")
    st.add_argument("--choose-m1", action="store_true",
                    help="choose M1 first: minimise the stride map's spectral radius over "
                         "M1 (Nelder-Mead on the exact radius, about 0.5 s an evaluation) "
                         "from --m1 (the start; default the design above), then analyse "
                         "the chosen M1; implies --stability")
    p.set_defaults(**{k: None for k in CLOSED_LOOP_DEFAULTS})     # given or not
    st.add_argument("--max-evaluations", type=int, default=None, metavar="N",
                    help="with --choose-m1: fixed points solved at most, 1 to "
                         f"{MAX_EVALUATIONS} (default 150)")
    st.add_argument("--tune-gains", action="store_true",
                    help="with --choose-m1: search Kp and Kd too (log scale, from --kp, --kd)")
    st.add_argument("--max-distance", type=float, default=None, metavar="D",
                    help="with --choose-m1: a fixed point farther than D from the collocated "
                         "landing state (largest entry, rad or rad/s) is another orbit than "
                         "the gait's, infeasible (default 0.01; a coarse grid for the robot "
                         "may need more)")


def _check_closed_loop(args):
    """The closed-loop options (UserError, one line, before any work)."""
    check_tracking_arguments(args)
    check_strides_and_perturb(args.steps, args.perturb, "--steps", low=0)
    if not args.choose_m1:
        for opt, given in (("--max-evaluations", args.max_evaluations is not None),
                           ("--tune-gains", args.tune_gains),
                           ("--max-distance", args.max_distance is not None)):
            if given:
                raise UserError(f"{opt} is an option of --choose-m1 (add --choose-m1)")
    elif args.max_evaluations is not None and not 1 <= args.max_evaluations <= MAX_EVALUATIONS:
        raise UserError(f"--max-evaluations must be between 1 and {MAX_EVALUATIONS}, got "
                        f"{args.max_evaluations}")
    if args.max_distance is not None and not (math.isfinite(args.max_distance)
                                              and args.max_distance > 0):
        raise UserError(f"--max-distance must be a positive number, got {args.max_distance:g}")
    if args.tune_gains and (args.kp <= 0 or args.kd <= 0):
        raise UserError("--tune-gains searches Kp and Kd on a log scale: --kp and --kd must "
                        "be > 0")


def _grid_notes(report: dict, opts) -> list:
    """The note on a phase that departs from its collocation by more than COARSE: the
    grid's error (a finer grid cuts it) or the open loop's growth of it (it need not)."""
    worst = max(report["stance_end_error"], report["flight_end_error"])
    if worst <= COARSE:
        return []
    local, finer = report["interval_error"], f"--intervals {2 * opts.n_stance} {2 * opts.n_flight}"
    head = (f"the phases integrated from their collocated starts depart from the "
            f"collocation by {worst:.1e} (more than {COARSE:g})")
    if worst <= GROWN * local:
        return [f"{head}: the grid is coarse for this robot; {finer} cuts that about 16-fold"]
    return [f"{head}, one interval from its own collocated start by at most {local:.1e}: "
            f"the open-loop phase grows the grid's error {worst / max(local, 1e-300):.2g}-fold "
            f"(it is unstable), so {finer} cuts the intervals' error about 16-fold but need "
            f"not cut the phase's; the closed loop (--stability) is the check"]


def _violation_notes(violations: list) -> list:
    """The note on path constraints violated between the collocation points."""
    if not violations:
        return []
    unit = {"torque limit": "N m", "feet above the ground in flight": "m",
            "swing foot above the ground in stance": "m"}
    return ["between the collocation points (dense grid) VIOLATED " + "; ".join(
        f"{name} by {v:.2g} {unit.get(name, 'N')}" for name, v in violations) +
        " (the NLP bounds them at its points only, a torque's bound lowered by its excess, "
        "a foot that dips bounded at the dense grid's samples, and the step solved again "
        f"up to {MAX_TIGHTENINGS} times; a finer --intervals need not cut it)"]


def cmd_running(args):
    given = args.m1 is not None or any(getattr(args, k) is not None
                                       for k in CLOSED_LOOP_DEFAULTS)
    for k, v in CLOSED_LOOP_DEFAULTS.items():
        setattr(args, k, v if getattr(args, k) is None else getattr(args, k))
    if args.gait is not None or args.choose_m1 or args.saturate or given:
        args.stability = True
    _check_closed_loop(args)
    if args.gait is not None:
        return _stability_of_file(args)
    for k, v in OPTIMISE_DEFAULTS.items():
        setattr(args, k, v if getattr(args, k) is None else getattr(args, k))
    for name in ("speed", "mu", "torque_limit"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"--{name.replace('_', '-')} must be a positive number, got {v:g}")
    if args.max_iter is not None and args.max_iter < 1:
        raise UserError(f"--max-iter must be >= 1, got {args.max_iter}")
    try:
        opts = RunningOptions(speed=args.speed, mu=args.mu, mu_margin=args.mu_margin,
                              torque_limit=args.torque_limit,
                              n_stance=args.intervals[0], n_flight=args.intervals[1],
                              ipopt={} if args.max_iter is None else {"max_iter": args.max_iter},
                              stall_window=STALL_WINDOW if args.max_iter is None else None)
    except ValueError as e:
        raise UserError(str(e).replace("RunningOptions.n_stance", "--intervals STANCE")
                        .replace("RunningOptions.n_flight", "--intervals FLIGHT")
                        .replace("RunningOptions.mu_margin", "--mu-margin")) from None
    out = output_file(args.out, "--out", (".json",))          # before the solve
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot)
    if model.nq != 5:
        links = f"{model.k} link" + ("s" if model.k != 1 else "")
        raise UserError(f"--robot: {model.params.name} has legs of {links}; the running "
                        "step's built-in guess needs legs of two links (RABBIT's)")
    if args.stability:
        check_gains_for_steps(args, model, opts)
    say = Progress("running", quiet=args.json)
    gait = optimize_running(model, opts, cache=not args.no_cache, progress=say)
    reused = gait.solver_stats.get("cache") == "hit"
    if not gait.success:
        raise UserError(failure(args.speed, gait.solver_stats))
    say("checking it outside the NLP (about 2 s) ...")
    check = check_running(model, gait)
    report = check.as_dict()
    s = dict(robot=model.params.name, speed=gait.speed, T_stance=gait.T_stance,
             T_flight=gait.T_flight, step_length=gait.step_length, cost=gait.cost,
             solver=gait.solver_stats, checks=report, file=str(gait.save(out)))
    s["dense_grid_violations"] = [list(v) for v in check.violations(gait.options.limit(model))]
    s["notes"] = _grid_notes(report, opts) + _violation_notes(s["dense_grid_violations"])
    if folder is not None:
        s["plots"] = save_figures({"running_step": running_plot(model, gait)}, folder)
    if args.stability:
        say("closing the loop: fixed point, eigenvalues, perturbed run (about 10 s) ...")
        s["stability"] = closed_loop(model, gait, args)
    if args.json:
        print_json(s)
        return loop_exit_code(s.get("stability"))
    if reused:
        print(f"reused the running step kept in {gait.solver_stats['cache_file']} (same "
              "robot, options and code; --no-cache solves it again)")
    _print(s, gait, gait.options.limit(model))
    if args.stability:
        _print_stability(s["stability"])
    return loop_exit_code(s.get("stability"))


def check_gains_for_steps(args, model, opts):
    """UserError (before the optimisation) for ``--kp`` or ``--kd`` that make the closed
    loop's RK4 diverge at any step the optimisation can give (the shortest phase it
    allows, over its intervals of :data:`STEPS_PER_INTERVAL` RK4 steps, or longer):
    :func:`~biped_casadi.control.running_step.rk4_gain_bounds`.  The gains within are
    checked at the optimised step's own steps and nodes after it."""
    for phase, bounds, n in (("stance", opts.stance_time_bounds, opts.n_stance),
                             ("flight", opts.flight_time_bounds, opts.n_flight)):
        h = bounds[0] / (n * STEPS_PER_INTERVAL)
        kp, kd = rk4_gain_bounds(model, phase, h, args.law, tracking_m1(args, model))
        bad = [f"--{name} {v:g} (above {top:.2g})" for name, v, top in
               (("kp", args.kp, kp), ("kd", args.kd, kd)) if v > top]
        if bad:
            raise UserError(
                f"{' and '.join(bad)} make{'s' if len(bad) == 1 else ''} the {phase}'s "
                f"output error grow at every RK4 step of the closed loop, whatever step is "
                f"optimised: a step is at least {h:.2g} s (the shortest {phase} allowed, "
                f"{bounds[0]:g} s, over {n} intervals of {STEPS_PER_INTERVAL} steps); "
                f"lower {'it' if len(bad) == 1 else 'them'} (gains below are checked at "
                "the optimised step's own RK4 steps)")


def loop_exit_code(s: dict | None) -> int:
    """1 when the closed loop of ``s`` (the ``stability`` report, or None) failed: no fixed
    point, or a perturbed run that stopped, said in one line on stderr (as ``biped
    mujoco-running``'s run that stops: exit 1 for a stage or run that failed); else 0.
    An unstable fixed point whose run completes is a result, 0.  With the foot pinned to
    its takeoff (``sliding`` False), a pushing foot below the ground in flight is said to
    come from the tangential force it left with (a sliding foot leaves without one)."""
    if not s:
        return 0
    sim = s.get("simulation")
    if s.get("status") == "failed":
        why = s.get("message", "")
    elif sim and sim.get("status") not in (None, "ok"):
        why = f"the perturbed run stopped at {sim.get('message', '')}"
    else:
        return 0
    if "domain 'flight': other foot height" in why and s.get("sliding") is False:
        why += ("; the foot that pushed off went below the ground in flight: it left with a "
                "tangential ground force where the normal force vanished (within the friction "
                "cone's slack near takeoff), which starts it downward")
    print(f"biped running: the closed loop failed: {why}", file=sys.stderr)
    return 1


def failure(speed: float, stats: dict) -> str:
    """The one line of a running step that did not converge.

    How the search ended and what its last iterate says: the torques at their limit and
    the constraints violated most (:mod:`gait_opt.running_solve`).

    Parameters
    ----------
    speed : float
        The speed asked, m/s.
    stats : dict
        The step's ``solver_stats``.

    Returns
    -------
    str
    """
    n = stats.get("iterations")
    if stats.get("return_status") == "Stalled":
        how = (f"stalled: its constraint violation did not halve over "
               f"{stats['stall_window']} iterations, stopped after {n}; --max-iter K "
               "searches on up to K iterations")
    else:
        how = f"IPOPT: {stats.get('return_status')} after {n} iterations"
    said = []
    limit = stats.get("torque_at_limit") or []
    if limit and len({d["limit"] for d in limit}) == 1:
        said.append(f"torques at their {limit[0]['limit']:g} N m limit (" + ", ".join(
            f"{d['joint']} at {d['count']} points" for d in limit) + ")")
    elif limit:                                     # the joints' limits differ
        said.append("torques at their limits (" + ", ".join(
            f"{d['joint']} at {d['count']} points of its {d['limit']:g} N m" for d in limit)
            + ")")
    for d in stats.get("violated") or []:
        said.append(f"{d['name']} violated by {d['violation']:.2g}"
                    + (f" {d['unit']}" if d["unit"] else ""))
    last = f"; at the last iterate: {'; '.join(said)}" if said else ""
    return f"the running step did not converge at {speed:g} m/s ({how}){last}; nothing written"


def _stability_of_file(args):
    """``--gait FILE``: the closed loop of a saved step."""
    check_torque_limit(args, clip_only=True)
    given = ["--" + dest.replace("_", "-")
             for dest in (*OPTIMISE_DEFAULTS, "max_iter", "plot", "no_cache")
             if getattr(args, dest) not in (None, False)]
    if given:
        raise UserError(f"--gait analyses a saved step; {', '.join(given)} "
                        f"{'is' if len(given) == 1 else 'are'} for optimising one (leave "
                        "--gait out for that)")
    if args.robot is not None and not str(args.robot).strip():
        raise UserError("--robot: empty name (leave the option out for the default)")
    if not str(args.gait).strip():
        raise UserError("--gait: empty name (leave the option out for the default)")
    gait, model = load_running_gait(args)
    say = Progress("running", quiet=args.json)
    say("closing the loop: fixed point, eigenvalues, perturbed run (about 10 s) ...")
    s = dict(robot=model.params.name, file=str(args.gait), speed=gait.speed,
             T_stance=gait.T_stance, T_flight=gait.T_flight,
             stability=closed_loop(model, gait, args))
    if args.json:
        print_json(s)
    else:
        print(f"running step of {s['robot']} from {s['file']}: {gait.speed:.4f} m/s, stance "
              f"{gait.T_stance:.4f} s, flight {gait.T_flight:.4f} s")
        _print_stability(s["stability"])
    return loop_exit_code(s["stability"])


def closed_loop(model, gait, args) -> dict:
    """The stride map of ``gait`` under the tracking controller of ``args``: fixed point,
    eigenvalues, perturbed run, as a dict (the ``stability`` field of ``--json``)."""
    c = running_controller(args, gait, model)
    M1 = tuple(float(v) for v in c.M1)
    cyc = running_cycle(c, flight_clock=args.flight_clock)
    c = cyc.controller
    choice = None
    if getattr(args, "choose_m1", False):
        say = Progress("running", quiet=args.json)
        dist = MAX_DISTANCE if args.max_distance is None else args.max_distance
        ch = choose_running_m1(cyc, tune_gains=args.tune_gains,
                               max_evaluations=args.max_evaluations or 150,
                               max_distance=dist, progress=say)
        if ch.status == "failed":          # as a solver that did not converge: one line
            far = "collocated landing state" in ch.message
            raise UserError(f"--choose-m1: {ch.message}" + (
                f"; the grid may be coarse for the robot (a step optimised with a finer "
                f"--intervals), or give a larger --max-distance than {dist:g}" if far else ""))
        choice = dict(ch.to_dict(), start_M1=list(M1))
        cyc = cyc.retuned(Kp=ch.Kp, Kd=ch.Kd, M1=ch.M1)
        c = cyc.controller
        M1 = tuple(float(v) for v in ch.M1)
    r = running_stability(cyc)
    kp = float(c.Kp[0]) if np.ptp(c.Kp) == 0 else c.Kp.tolist()
    kd = float(c.Kd[0]) if np.ptp(c.Kd) == 0 else c.Kd.tolist()
    out = dict(law=args.law, Kp=kp, Kd=kd, M1=list(M1), flight_clock=args.flight_clock,
               sliding=cyc.sliding, clipped_at=c.clipped_at, status=r.status,
               message=r.message, stable=r.stable,
               fixed_point=r.fixed_point.tolist(), fixed_point_residual=r.residual,
               fixed_point_distance=r.distance, spectral_radius=r.spectral_radius,
               eigenvalues=[[float(e.real), float(e.imag)] for e in r.eigenvalues],
               eigenvalue_moduli=np.abs(r.eigenvalues).tolist(),
               durations=r.durations.tolist())
    if choice is not None:
        out["choice"] = choice
    if r.status == "failed" or args.steps == 0:
        out["simulation"] = None
        return out
    x = r.fixed_point.copy()
    x[model.nq:] += args.perturb
    run = simulate_running(cyc, r.fixed_point, x, args.steps)
    d = run.deviations
    n = d.size - 1
    rate = float((d[-1] / d[1]) ** (1.0 / (n - 1))) if n >= 2 and d[1] > 0 else None
    margins = {}
    if run.strides:
        st = run.strides
        margins = dict(fz_min=min(s.fz_min for s in st),
                       friction_ratio_max=max(s.friction_ratio_max for s in st),
                       friction_excess_max=max(s.friction_excess_max for s in st),
                       torque_max=max(s.torque_max for s in st),
                       saturated_time=sum(s.saturated_time for s in st),
                       swing_foot_min=min(s.swing_min for s in st),
                       landing_impulse_ratio_max=max(s.landing_impulse_ratio for s in st),
                       slip_max=max(s.slip for s in st),
                       restick_max=max(s.restick for s in st),
                       slide_max=max(abs(s.slide) for s in st))
    out["simulation"] = dict(steps=args.steps, perturb=args.perturb, status=run.status,
                             message=run.message, strides=len(run.strides),
                             deviations=d.tolist(), contraction=run.contraction.tolist(),
                             mean_contraction=rate, mu=cyc.mu,
                             friction_slack=cyc.friction_slack, sliding=cyc.sliding,
                             torque_limit=c.torque_limit, saturate=c.saturate,
                             saturated_time=[s.saturated_time for s in run.strides],
                             torque_max=[s.torque_max for s in run.strides], margins=margins)
    return out


def _exact(values) -> str:
    """Numbers as they round-trip (Python's shortest repr, "0.95", "0" for 0.0): a gain
    printed so is the gain analysed, and gives back the printed radius when passed to
    ``--m1`` (the spectral radius at a chosen M1 is not smooth: three decimals of the
    M1 can move it in the second)."""
    return " ".join(repr(float(v)).removesuffix(".0") for v in values)


def _print_stability(s: dict):
    """The closed loop's report."""
    ch = s.get("choice")
    if ch is not None:
        print(f"choice of M1 ({ch['method']}, {ch['n_evaluations']} evaluations, "
              f"{ch['n_infeasible']} infeasible, {ch['seconds']:.1f} s): {ch['status']}")
        rad0 = ch["start_radius"]
        print("  start                M1 " + _exact(ch["start_M1"])
              + (f", spectral radius {rad0:.4f}" if rad0 is not None
                 else f" ({ch['start_status']})"))
        print("  chosen               M1 " + _exact(ch["M1"])
              + (f", Kp {_exact([ch['Kp']])}, Kd {_exact([ch['Kd']])}"
                 if ch["tune_gains"] else "")
              + f", spectral radius {ch['spectral_radius']:.4f}")
    def gain(v):
        return _exact([v] if isinstance(v, float) else v)
    clock = "" if s.get("flight_clock", "takeoff") == "takeoff" else \
        f", flight clock {s['flight_clock']}"
    if s.get("clipped_at") is not None:
        clock += f", torques clipped at {torque_bound_text(s['clipped_at'])} N m"
    print(f"closed loop ({s['law']}, Kp {gain(s['Kp'])}, Kd {gain(s['Kd'])}, M1 "
          f"{_exact(s['M1'])}{clock}): {s['status']}")
    if s["status"] == "failed":
        print(f"  {s['message']}")
        return
    print(f"  fixed point          residual {s['fixed_point_residual']:.1e}, "
          f"{s['fixed_point_distance']:.1e} from the collocated landing state")
    print(f"  spectral radius      {s['spectral_radius']:.4f} "
          f"({'stable' if s['stable'] else 'unstable'})")
    print("  |eigenvalues|        " + " ".join(f"{v:.3g}" for v in s["eigenvalue_moduli"]))
    sim = s.get("simulation")
    if not sim:
        return
    print(f"  perturbed run        {sim['perturb']:g} rad/s on every velocity: "
          f"{sim['message']} ({sim['status']})")
    print("  per-stride contraction " + " ".join(f"{v:.3g}" for v in sim["contraction"]))
    if sim["mean_contraction"] is not None:
        print(f"  mean contraction     {sim['mean_contraction']:.4f} per stride after the "
              f"first (spectral radius {s['spectral_radius']:.4f})")
    mg = sim["margins"]
    if mg:
        print(f"  margins              Fz >= {mg['fz_min']:.3g} N before takeoff; |Fx| - mu Fz "
              f"<= {mg['friction_excess_max']:.3g} N"
              + (f" (slack {sim['friction_slack']:.3g}); " if not sim.get("sliding", False)
                 else "; ") +
              f"|u| {'asked ' if sim.get('saturate') else ''}<= {mg['torque_max']:.1f} N m "
              f"(limit {torque_bound_text(sim['torque_limit'])})")
    if mg and sim.get("sliding"):
        print(f"  sliding near takeoff up to {1e3 * mg['slip_max']:.3g} ms and "
              f"{1e3 * mg['slide_max']:.3g} mm a stride (friction on the cone's edge)"
              + (f", stuck again up to {1e3 * mg['restick_max']:.3g} ms"
                 if mg.get("restick_max", 0.0) > 0 else ""))
    if sim.get("saturate"):
        n = sum(1 for v in sim["saturated_time"] if v > 0)
        print(f"  saturation           torques clipped at {torque_bound_text(sim['torque_limit'])}"
              f" N m in {n} of "
              f"{len(sim['saturated_time'])} strides, {1e3 * mg.get('saturated_time', 0.0):.1f}"
              " ms in all; per stride (ms) "
              + " ".join(f"{1e3 * v:.1f}" for v in sim["saturated_time"]))


def _resolves(solver: dict) -> str:
    """What the re-solves of the step's loop fixed between the points ('' for none)."""
    again = solver.get("tightenings", [])
    if not again:
        return ""
    over, dips = max(again[0]["excess"]), again[0].get("dips", [])
    why = ([f"a torque peaked above its limit by {over:.2g} N m, its bound lowered by "
            "that"] if over > TORQUE_TOL else [])
    if dips:
        why.append(f"a foot dipped {max(d['depth'] for d in dips):.2g} m below its bound, "
                   "held above it at the dense grid's samples")
    return f" ({1 + len(again)} solves: between the points {' and '.join(why)})"


def _print(s: dict, gait, limit):
    """``biped running``'s report."""
    c = s["checks"]
    print(f"running step of {s['robot']}, saved to {s['file']} (the checks below are open "
          "loop; --stability closes it)")
    print(f"  stance / flight      {s['T_stance']:.4f} s / {s['T_flight']:.4f} s")
    print(f"  step length          {s['step_length']:.4f} m at {s['speed']:.4f} m/s")
    print(f"  cost                 {s['cost']:.1f} N^2 m s (int u'u dt / step length)")
    print(f"  peak torque          {c['torque_max_dense']:.1f} N m (dense grid; limit "
          f"{torque_bound_text(limit)})")
    print(f"  ground force         Fz at takeoff {c['fz_takeoff']:.2g} N, smallest "
          f"{c['fz_min_dense']:.2g} N (dense); |Fx|/Fz at most {c['friction_ratio_max']:.3f}"
          f" (mu {gait.options.mu:g}, optimised with {gait.options.mu_margin:g} below it)")
    print(f"  flight               feet at least {c['feet_min_flight']:.2g} m up; lands at "
          f"{c['strike_velocity']:.2f} m/s, the other foot leaves at "
          f"{c['other_foot_velocity']:.2f} m/s; impulse |Fx|/Fz {c['impulse_ratio']:.3f}")
    print(f"  consistency          periodicity through the exact edges "
          f"{c['periodicity_collocated']:.1e}; phases integrated (DOP853): stance end "
          f"{c['stance_end_error']:.1e}, one interval {c['interval_error']:.1e}, step map "
          f"{c['step_map_residual']:.1e}")
    print(f"  solve                {s['solver'].get('iterations')} IPOPT iterations, "
          f"{s['solver'].get('wall_s', 0.0):.1f} s" + _resolves(s["solver"]))
    for p in s.get("plots", []):
        print(f"  plot                 {p}")
    for n in s["notes"]:
        print(f"note: {n}")
