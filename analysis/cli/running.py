"""``biped running``: optimise one periodic running step (stance, takeoff, flight,
landing), check it outside the NLP, save it and optionally draw it.  A first step
toward running (docs: how-to "Prepare a second domain"); every computation is in
``gait_opt.running`` and ``gait_opt.running_checks``."""
from __future__ import annotations

import math

from analysis.reporting.plots import running_plot, save_figures
from gait_opt.running import RunningOptions, optimize_running
from gait_opt.running_checks import check_running

from .common import Progress, UserError, add_robot, load_model, output_dir, output_file, \
    print_json


#: a phase's integration departing from its collocation by more than this (the largest
#: entry, rad or rad/s) is said on a note line: the grid is coarse for that robot
COARSE = 1e-3


def register(sub):
    p = sub.add_parser(
        "running", help="optimise a periodic running step (stance + flight; no controller "
                        "yet)",
        description="Optimise one periodic running step of a robot with legs of two links "
                    "(RABBIT by default): single support, takeoff where the ground's normal "
                    "force reaches zero, flight, the swing foot's landing with the legs "
                    "relabelled (Hermite-Simpson collocation on both phases + IPOPT), then "
                    "measure it outside the NLP: the phases integrated by an ODE solver, "
                    "the step map through the exact takeoff and landing, the ground force "
                    "and the feet on a dense grid.  An open-loop reference: no controller "
                    "tracks it yet.")
    p.add_argument("--speed", type=float, default=1.5, metavar="V",
                   help="average speed, m/s (default 1.5)")
    p.add_argument("--mu", type=float, default=0.6, help="friction coefficient (default 0.6)")
    p.add_argument("--torque-limit", type=float, default=None, metavar="U",
                   help="|u| bound in N m (default: the robot's, 150 for RABBIT)")
    p.add_argument("--intervals", type=int, nargs=2, default=(16, 10),
                   metavar=("STANCE", "FLIGHT"),
                   help="Hermite-Simpson intervals of each phase, 2 to 200 (default 16 10)")
    p.add_argument("--max-iter", type=int, default=None, metavar="K",
                   help="IPOPT iteration limit (default 3000)")
    p.add_argument("--no-cache", action="store_true",
                   help="solve again even when a step of the same robot, options and code "
                        "is kept in the cache ($BIPED_CACHE_DIR or ~/.cache/biped-casadi)")
    add_robot(p, with_gait=False)
    p.add_argument("--out", metavar="FILE", default="running.json",
                   help="where to save the step (default running.json; "
                        "gait_opt.running.RunningGait.load reads it)")
    p.add_argument("--plot", metavar="DIR",
                   help="write running_step.png into DIR (poses, joint angles, torques)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_running)


def cmd_running(args):
    for name in ("speed", "mu", "torque_limit"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"--{name.replace('_', '-')} must be a positive number, got {v:g}")
    if args.max_iter is not None and args.max_iter < 1:
        raise UserError(f"--max-iter must be >= 1, got {args.max_iter}")
    try:
        opts = RunningOptions(speed=args.speed, mu=args.mu, torque_limit=args.torque_limit,
                              n_stance=args.intervals[0], n_flight=args.intervals[1],
                              ipopt={} if args.max_iter is None else {"max_iter": args.max_iter})
    except ValueError as e:
        raise UserError(str(e).replace("RunningOptions.n_stance", "--intervals STANCE")
                        .replace("RunningOptions.n_flight", "--intervals FLIGHT")) from None
    out = output_file(args.out, "--out", (".json",))          # before the solve
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot)
    if model.nq != 5:
        links = f"{model.k} link" + ("s" if model.k != 1 else "")
        raise UserError(f"--robot: {model.params.name} has legs of {links}; the running "
                        "step's built-in guess needs legs of two links (RABBIT's)")
    say = Progress("running", quiet=args.json)
    gait = optimize_running(model, opts, cache=not args.no_cache, progress=say)
    reused = gait.solver_stats.get("cache") == "hit"
    if not gait.success:
        raise UserError(f"the running step did not converge at {args.speed:g} m/s (IPOPT: "
                        f"{gait.solver_stats.get('return_status')} after "
                        f"{gait.solver_stats.get('iterations')} iterations); nothing written")
    say("checking it outside the NLP (about 2 s) ...")
    report = check_running(model, gait).as_dict()
    s = dict(robot=model.params.name, speed=gait.speed, T_stance=gait.T_stance,
             T_flight=gait.T_flight, step_length=gait.step_length, cost=gait.cost,
             solver=gait.solver_stats, checks=report, file=str(gait.save(out)))
    worst = max(report["stance_end_error"], report["flight_end_error"])
    s["notes"] = [] if worst <= COARSE else [
        f"the phases integrated from their collocated starts depart from the collocation "
        f"by {worst:.1e} (more than {COARSE:g}): the grid is coarse for this robot; "
        f"--intervals {2 * opts.n_stance} {2 * opts.n_flight} cuts that about 16-fold"]
    if folder is not None:
        s["plots"] = save_figures({"running_step": running_plot(model, gait)}, folder)
    if args.json:
        print_json(s)
        return 0
    if reused:
        print(f"reused the running step kept in {gait.solver_stats['cache_file']} (same "
              "robot, options and code; --no-cache solves it again)")
    _print(s, gait, gait.options.limit(model))
    return 0


def _print(s: dict, gait, limit: float):
    """``biped running``'s report."""
    c = s["checks"]
    print(f"running step of {s['robot']}, saved to {s['file']} (open loop: no controller "
          "tracks it yet)")
    print(f"  stance / flight      {s['T_stance']:.4f} s / {s['T_flight']:.4f} s")
    print(f"  step length          {s['step_length']:.4f} m at {s['speed']:.4f} m/s")
    print(f"  cost                 {s['cost']:.1f} N^2 m s (int u'u dt / step length)")
    print(f"  peak torque          {c['torque_max_dense']:.1f} N m (dense grid; limit "
          f"{limit:g})")
    print(f"  ground force         Fz at takeoff {c['fz_takeoff']:.2g} N, smallest "
          f"{c['fz_min_dense']:.2g} N (dense); |Fx|/Fz at most {c['friction_ratio_max']:.3f}"
          f" (mu {gait.options.mu:g})")
    print(f"  flight               feet at least {c['feet_min_flight']:.2g} m up; lands at "
          f"{c['strike_velocity']:.2f} m/s, the other foot leaves at "
          f"{c['other_foot_velocity']:.2f} m/s; impulse |Fx|/Fz {c['impulse_ratio']:.3f}")
    print(f"  consistency          periodicity through the exact edges "
          f"{c['periodicity_collocated']:.1e}; phases integrated (DOP853): stance end "
          f"{c['stance_end_error']:.1e}, step map {c['step_map_residual']:.1e}")
    print(f"  solve                {s['solver'].get('iterations')} IPOPT iterations, "
          f"{s['solver'].get('wall_s', 0.0):.1f} s")
    for p in s.get("plots", []):
        print(f"  plot                 {p}")
    for n in s["notes"]:
        print(f"note: {n}")
