"""``biped gait``: optimise the reference gait (docs: theory §2), print its figures, save
it, and optionally draw it.  Reads top to bottom; every computation is in ``gait_opt``.
"""
from __future__ import annotations

import math

from analysis.gait_metrics import lean_from, torso_fall
from analysis.reporting.plots import gait_profiles_plot, gait_stick_plot, save_figures
from biped_casadi.model.description import torque_bound_text
from gait_opt import GaitOptimizationError, GaitOptions, optimize_gait
from gait_opt.options import SMOOTH_CONTINUATION_MAX

from .common import (Progress, UserError, add_robot, load_model, output_dir, output_file,
                     print_json)
from .gait_family import add_family_arguments, check_family_arguments, cmd_family, cmd_gait_at
from .gait_import import add_import_arguments, check_export_arguments, cmd_export_csv, cmd_import

#: --intervals beyond this make an NLP that takes minutes per iteration
MAX_INTERVALS = 400


def register(sub):
    p = sub.add_parser(
        "gait", help="optimise, check and save the cyclic reference gait",
        description="Optimise the cyclic reference step (direct collocation + IPOPT, then "
                    "the exact periodic orbit), check it on a dense grid, print its "
                    "figures and save it to a self-describing JSON file.  With --speeds: "
                    "a family of gaits over a range of speeds, by continuation; with "
                    "--family and --speed: a gait between a family's members.")
    p.add_argument("--speed", type=float, default=None, metavar="V",
                   help="average speed in m/s (default 0.75)")
    p.add_argument("--mu", type=float, default=0.6, help="friction coefficient (default 0.6)")
    p.add_argument("--torque-limit", type=float, default=None, metavar="U",
                   help="|u| bound in N m (default: the robot's, 150 for RABBIT)")
    p.add_argument("--intervals", type=int, default=30, metavar="N",
                   help=f"collocation intervals, 4 to {MAX_INTERVALS} (default 30)")
    p.add_argument("--scheme", choices=("legendre", "radau"), default="legendre",
                   help="collocation points (default legendre)")
    p.add_argument("--max-iter", type=int, default=None, metavar="K",
                   help="IPOPT iteration limit (default 500)")
    p.add_argument("--impact-mu", type=float, default=None, metavar="MU",
                   help="bound on the impact impulse's |F_x|/F_z (default: --mu); the "
                        "robust design's gait uses 0.15")
    p.add_argument("--continuation", type=float, default=None, metavar="C",
                   help="continue the reference past T by an acceleration ramp over C T "
                        "(default: the Bezier polynomials themselves; the robust design's "
                        "gait uses 0.03)")
    p.add_argument("--continuation-shape", choices=("ramp", "smooth"), default="ramp",
                   help="with --continuation: 'ramp' (default), or 'smooth': the "
                        "acceleration decays exponentially over C T, matching the jerk at "
                        f"T (no kink where late impacts land; C at most "
                        f"{SMOOTH_CONTINUATION_MAX:g})")
    p.add_argument("--clearance", type=float, default=None, metavar="H",
                   help="mid-step swing-foot clearance, m (default scaled with leg length: "
                        "0.0375 x leg, 0.03 for RABBIT; the robust design's gait uses "
                        "0.0625 x leg, 0.05 for RABBIT; the step length is bounded to "
                        "0.25-1.0 x leg, the lower bound shrinking with the speed below "
                        "0.75 m/s x sqrt(leg / 0.8 m), recorded in the gait's options)")
    p.add_argument("--torso-lean-max", type=float, default=None, metavar="RAD",
                   help="bound on the torso's lean from upright at every node, rad, "
                        "between 0 and pi (default: none; unbounded, RABBIT's optimum "
                        "leans past the simulator's fall bound pi/2 from about 1.2 m/s)")
    add_robot(p, with_gait=False)
    add_family_arguments(p)
    p.add_argument("--out", metavar="FILE.json", default=None,
                   help="where to save the gait, a name ending in .json as every --out "
                        "file names its format (default gait.json; with --speeds, the "
                        "family: default family.json)")
    p.add_argument("--plot", metavar="DIR",
                   help="write gait_stick.png and gait_profiles.png into DIR (with "
                        "--speeds: gait_family.png, the figures against speed)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_import_arguments(p)
    p.set_defaults(func=cmd_gait)


def cmd_gait(args):
    if args.clearance is not None and not (math.isfinite(args.clearance)
                                           and args.clearance >= 0):
        raise UserError(f"--clearance must be a number >= 0 (m), got {args.clearance:g}")
    check_family_arguments(args)
    check_export_arguments(args)
    for name in ("speed", "mu", "torque_limit", "impact_mu", "continuation"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"--{name.replace('_', '-')} must be a positive number, got {v:g}")
    lean = args.torso_lean_max
    if lean is not None and not (math.isfinite(lean) and 0 < lean < math.pi):
        raise UserError(f"--torso-lean-max must be a number of rad between 0 and pi (both "
                        f"excluded), got {lean:g}")
    if args.continuation_shape == "smooth" and not (
            args.continuation is not None and args.continuation <= SMOOTH_CONTINUATION_MAX):
        raise UserError(f"--continuation-shape smooth needs --continuation C, at most "
                        f"{SMOOTH_CONTINUATION_MAX:g} (the decay time, in T)"
                        + ("" if args.continuation is None else
                           f", got {args.continuation:g}"))
    if not 4 <= args.intervals <= MAX_INTERVALS:
        raise UserError(f"--intervals must be between 4 and {MAX_INTERVALS}, got "
                        f"{args.intervals}")
    if args.max_iter is not None and args.max_iter < 1:
        raise UserError(f"--max-iter must be >= 1, got {args.max_iter}")
    if args.export_csv is not None:
        return cmd_export_csv(args, Progress("gait", quiet=args.json))
    if args.import_file is not None:
        if args.speeds is not None or args.family is not None:
            raise UserError("--import brings in one gait: it excludes --speeds and --family")
        if args.speed is not None:
            raise UserError("--speed: an imported gait walks at its data's speed (its step "
                            "length over T, printed); the option applies to an optimised gait")
        args.out = "gait.json" if args.out is None else args.out
        return cmd_import(args)
    if args.family is not None:
        return cmd_gait_at(args)
    speed = 0.75 if args.speed is None else args.speed
    options = GaitOptions(speed=speed, mu=args.mu, torque_limit=args.torque_limit,
                          n_intervals=args.intervals, scheme=args.scheme,
                          ipopt={} if args.max_iter is None else {"max_iter": args.max_iter},
                          impact_mu=args.impact_mu, continuation=args.continuation,
                          continuation_shape=args.continuation_shape,
                          torso_lean_max=args.torso_lean_max,
                          **({} if args.clearance is None else {"clearance": args.clearance}))
    if args.speeds is not None:
        return cmd_family(args, options)
    out = output_file("gait.json" if args.out is None else args.out, "--out", (".json",))  # before the solve
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot)

    say = Progress("gait", quiet=args.json)
    say(f"optimising the gait at {speed:g} m/s (about 6 s on a loaded 2-core VM) ...")
    try:
        gait = optimize_gait(model, options)
    except GaitOptimizationError as e:
        raise UserError(str(e)) from None
    s = gait.summary()
    s["max_torso_lean"], past, bound = torso_fall(gait)
    s["file"] = str(gait.save(out))
    if folder is not None:
        s["plots"] = save_figures({"gait_stick": gait_stick_plot(gait),
                                   "gait_profiles": gait_profiles_plot(gait)}, folder)

    if args.json:
        print_json(s)
        return 0
    _print_gait(s, gait, model, out, args.mu, past, bound)
    return 0


def _print_gait(s: dict, gait, model, out, mu: float, past: bool, bound: float):
    """``biped gait``'s report of one gait (``s``: its summary)."""
    print(f"reference gait of {model.params.name}, saved to {out}")
    hit = {n: (side, b) for n, side, b in s.get("bounds_hit", [])}

    def on_bound(name, unit):
        if name not in hit:
            return ""
        side, b = hit[name]
        return (f"   (on its {side} bound {b:g} {unit}, GaitOptions.{name}: the optimum lies "
                "beyond it; set other bounds in Python, gait_opt.GaitOptions)")
    print(f"  step time T          {s['T']:.6f} s" + on_bound("step_time_bounds", "s"))
    lo, hi = gait.options.step_length_bounds
    print(f"  step length          {s['step_length']:.6f} m"
          + (on_bound("step_length_bounds", "m") or f"   (bounds {lo:.4g} to {hi:.4g} m)"))
    print(f"  speed                {s['speed']:.6f} m/s")
    print(f"  cost                 {s['cost']:.6f} N^2 m s (int u'u dt / step length)")
    print(f"  peak torque          {s['peak_torque']:.3f} N m   (limit "
          f"{torque_bound_text(gait.options.torque_limit)})")
    print(f"  min normal force     {s['min_normal_force']:.3f} N")
    lean_max = gait.options.torso_lean_max
    print(f"  torso lean           {s['max_torso_lean']:.4f} rad {lean_from(model)} at most"
          + (f": PAST the simulator's fall bound ({bound:.4g} rad), so every walk of this "
             f"gait is a fall; a lower speed, or --torso-lean-max RAD (below {bound:.4g}), "
             "keeps the torso up" if past else "")
          + (f"   (bound {lean_max:g} rad, --torso-lean-max)" if lean_max is not None
             else ""))
    print(f"  max friction ratio   {s['max_friction_ratio']:.4f}   (mu {mu:g}); "
          f"at impact {s['impact_friction_ratio']:.4f}")
    print(f"  swing foot           min height inside the step {s['min_swing_height_inside']:.2e} m, "
          f"strike {s['strike_velocity']:.3f} m/s, lift-off {s['liftoff_velocity']:.3f} m/s")
    print(f"  dense-grid check     {s['dense_grid_points']} points: "
          + ("all constraints hold" if not s["dense_grid_violations"] else
             "VIOLATED " + "; ".join(f"{n} by {v:.3g}" for n, v in s["dense_grid_violations"])))
    print("  consistency")
    print(f"    periodicity q      {s['periodicity_q']:.2e} rad")
    print(f"    periodicity dq     {s['periodicity_dq']:.2e} rad/s")
    print(f"    z_sw(T)            {s['swing_height_at_T']:.2e} m")
    print(f"    unactuated row     {s['reintegration_error']:.2e} rad (independent reintegration)")
    print(f"  solve time           {s['solve_time']:.2f} s, IPOPT {s['ipopt_iterations']} "
          f"iterations ({s['ipopt_status']})")
    for p in s.get("plots", []):
        print(f"  plot                 {p}")
