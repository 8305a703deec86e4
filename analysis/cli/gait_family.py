"""``biped gait --speeds A:B:STEP`` (a gait family by continuation) and ``biped gait
--family FILE --speed V`` (a gait between its members).  Reads top to bottom; the
computation is in :mod:`gait_opt` (``gait_family``, ``GaitFamily.gait_at``), the figures
in :mod:`analysis.gait_metrics` and :mod:`analysis.reporting.plots`.
"""
from __future__ import annotations

import math
import sys

from analysis.gait_metrics import family_figures, lean_from, torso_fall
from analysis.reporting.plots import (gait_family_plot, gait_profiles_plot, gait_stick_plot,
                                      save_figures)
from gait_opt import GaitFamily, GaitOptimizationError, gait_family, parse_speed_range

from .common import (Progress, UserError, load_model, not_an_input, output_dir, output_file,
                     print_json, require_members)

__all__ = ["add_family_arguments", "check_family_arguments", "cmd_family", "cmd_gait_at"]

#: options of ``biped gait`` that define the problem, with their defaults: with
#: --family the family's own options hold, so these must be left alone
PROBLEM_OPTIONS = dict(mu=0.6, torque_limit=None, intervals=30, scheme="legendre",
                       max_iter=None, impact_mu=None, continuation=None,
                       continuation_shape="ramp", clearance=None, torso_lean_max=None)


def add_family_arguments(p):
    """The family options of ``biped gait``."""
    p.add_argument("--speeds", metavar="A:B:STEP",
                   help="a gait family: solve at every speed A, A + STEP, ..., B (m/s) by "
                        "continuation from the neighbour's solution and save all of it to "
                        "--out (default family.json); a rerun with the same arguments "
                        "continues an interrupted one")
    p.add_argument("--family", metavar="FILE",
                   help="with --speed V: the gait at V from this family file (its "
                        "members interpolated and polished to an exact orbit)")
    p.add_argument("--resolve", action="store_true",
                   help="with --family: solve the gait problem at V from the interpolated "
                        "gait (the optimum there, not the interpolant)")
    p.add_argument("--stop-at-fold", action="store_true",
                   help="with --speeds: end the family where the branch followed folds "
                        "(default: continue on the branch the solver lands on)")
    p.add_argument("--fresh", action="store_true",
                   help="with --speeds: replace --out instead of continuing the family in it")


def check_family_arguments(args):
    """Conflicts between the family options and the others (UserError)."""
    if args.speeds is not None and args.family is not None:
        raise UserError("--speeds and --family exclude each other")
    if args.speeds is not None and args.speed is not None:
        raise UserError("--speed and --speeds exclude each other (--speeds A:B:STEP "
                        "gives every speed of the family)")
    if args.family is not None and args.speed is None:
        raise UserError("--family needs --speed V (the speed of the gait wanted)")
    if args.resolve and args.family is None:
        raise UserError("--resolve applies with --family only")
    for flag in ("stop_at_fold", "fresh"):
        if getattr(args, flag) and args.speeds is None:
            raise UserError(f"--{flag.replace('_', '-')} applies with --speeds only")
    if args.family is not None:
        for name, default in PROBLEM_OPTIONS.items():
            if getattr(args, name) != default:
                raise UserError(f"--{name.replace('_', '-')} does not apply with --family "
                                f"(the family's own problem holds)")


def _option(message: str) -> str:
    """gait_opt's 'speeds: ...' and 'path: ...' as the command line's option names."""
    for name, option in (("speeds:", "--speeds:"), ("path:", "--out:")):
        if message.startswith(name):
            return option + message[len(name):]
    return message


def cmd_family(args, options) -> int:
    """``biped gait --speeds A:B:STEP``: the family, saved to --out, and its figures."""
    try:
        speeds = parse_speed_range(args.speeds)
    except ValueError as e:
        raise UserError(_option(str(e))) from None
    out = output_file("family.json" if args.out is None else args.out, "--out", (".json",))
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot)
    say = Progress("gait", quiet=args.json)
    say(f"a gait family of {model.params.name} at {len(speeds)} speeds from {speeds[0]:g} "
        f"to {speeds[-1]:g} m/s (about 0.3 s per speed), saved to {out} as it goes ...")
    try:
        fam = gait_family(model, speeds, options, path=out, resume=not args.fresh,
                          across_folds=not args.stop_at_fold, progress=say)
    except GaitOptimizationError as e:
        raise UserError(f"--speeds: {e}; the family does not exist there (try a range "
                        f"nearer the default 0.75 m/s)") from None
    except ValueError as e:          # another request in --out, a speed out of reach
        raise UserError(_option(str(e)).replace("pass resume=False", "give --fresh")
                        ) from None
    s = fam.to_dict()
    s["file"] = str(out)
    if folder is not None:
        say("the figures: the virtual constraints' eigenvalue of every gait ...")
        s["plots"] = save_figures({"gait_family": gait_family_plot(family_figures(fam))},
                                  folder)
    if args.json:
        print_json(s)
    else:
        _print_family(fam, s)
    if fam.end is not None:
        print(f"biped gait: error: --speeds: the family ends before {fam.end['speed']:g} "
              f"m/s ({fam.end['reason']}); the gaits from {fam.member_speeds[0]:g} to "
              f"{fam.member_speeds[-1]:g} m/s are in {out}", file=sys.stderr)
        return 2
    return 0


def _print_family(fam: GaitFamily, s: dict):
    print(f"gait family of {fam.robot}: {fam.message}; saved to {s['file']}")
    print(f"  {'speed':>6} {'T s':>8} {'step m':>8} {'cost':>10} {'iter':>5} "
          f"{'orbit resid':>11} {'torso rad':>9}  active constraints")
    falls = []
    for r, g in zip(fam.records, fam.gaits):
        tag = f"  branch {r.branch + 1}" if fam.records[-1].branch else ""
        lean, past, bound = torso_fall(g)
        if past:
            falls.append(f"{r.speed:g}")
        print(f"  {r.speed:6.3f} {r.T:8.5f} {r.step_length:8.5f} {r.cost:10.2f} "
              f"{r.iterations:5d} {r.orbit_residual:11.1e} {lean:9.3f}  "
              f"{', '.join(r.active) or '-'}" + tag
              + (f"  VIOLATES {r.violations}" if r.violations else "")
              + ("  TORSO PAST THE FALL BOUND" if past else ""))
    if falls:
        print(f"  at {', '.join(falls)} m/s the torso leans past the simulator's fall bound "
              f"({bound:.4g} rad): every walk of those gaits is a fall; --torso-lean-max RAD "
              f"(below {bound:.4g}) bounds the lean")
    for e in fam.events:
        what = e["detail"] if e["change"] == "branch" else \
            f"{e['constraint']} becomes {e['change']}"
        print(f"  at {e['speed']:g} m/s: {what}")
    print(f"  {sum(r.iterations for r in fam.records)} IPOPT iterations, "
          f"{fam.total_time:.1f} s")
    for p in s.get("plots", []):
        print(f"  plot {p}")


def cmd_gait_at(args) -> int:
    """``biped gait --family FILE --speed V``: the gait at V, saved to --out."""
    if not math.isfinite(args.speed):
        raise UserError(f"--speed must be a finite number, got {args.speed:g}")
    out = output_file("gait.json" if args.out is None else args.out, "--out", (".json",))
    not_an_input(out, "--out", {"--family": args.family})
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot) if args.robot else None
    fam = GaitFamily.load(args.family, model)
    require_members(fam, args.family, "--family")
    lo, hi = fam.member_speeds[0], fam.member_speeds[-1]
    if not lo - 1e-9 <= args.speed <= hi + 1e-9:
        raise UserError(f"--speed {args.speed:g} m/s is outside the family in "
                        f"{args.family} ({lo:g} to {hi:g} m/s)")
    r = fam.gait_at(args.speed, resolve=args.resolve)
    if r.gait is None or r.status == "failed":
        print(f"biped gait: {r.message}", file=sys.stderr)
        return 1
    s = r.to_dict()
    s["file"] = str(r.gait.save(out))
    s["T"], s["step_length"] = r.gait.T, r.gait.step_length
    lean, past, bound = torso_fall(r.gait)
    s["max_torso_lean"], s["torso_past_fall_bound"] = lean, past
    if folder is not None:
        s["plots"] = save_figures({"gait_stick": gait_stick_plot(r.gait),
                                   "gait_profiles": gait_profiles_plot(r.gait)}, folder)
    if args.json:
        print_json(s)
        return 0
    print(f"gait at {args.speed:g} m/s from the family in {args.family}, saved to {out}")
    print(f"  {r.message}")
    print(f"  neighbours           {r.neighbours[0]:g} and {r.neighbours[1]:g} m/s")
    if math.isfinite(r.interpolant_residual):
        print(f"  interpolant residual {r.interpolant_residual:.2e} (orbit "
              f"{r.interpolant_orbit_residual:.2e}) before the polish; parameters changed "
              f"by {r.parameter_change:.2e} (T by {r.T_change:.2e} s)")
    else:
        print("  interpolant          none (the gait was solved at this speed)")
    print(f"  orbit residual       {r.orbit_residual:.1e}")
    print(f"  step time T          {r.gait.T:.6f} s, step length {r.gait.step_length:.6f} m")
    if past:
        print(f"  torso lean           {lean:.4f} rad {lean_from(r.gait.model)} at most: "
              f"PAST the simulator's fall bound ({bound:.4g} rad), so every walk of this gait is a "
              f"fall (a family solved with --torso-lean-max RAD keeps the torso up)")
    if r.violations:
        print(f"  VIOLATED on the dense grid: {r.violations} (--resolve gives the optimal "
              f"gait at this speed)")
    for path in s.get("plots", []):
        print(f"  plot                 {path}")
    return 0
