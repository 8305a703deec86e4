"""``biped m1``: choose the output matrix M1 minimising max|lambda| (paper §V-B)."""
from __future__ import annotations

import numpy as np

from analysis.design import ab_groups, optimize_m1
from analysis.design import ROBUST_GAIT, RobustDesignSettings, robust_design
from analysis.sweeps import grid_best

from .common import (Progress, UserError, add_gait_arguments, add_robot, load_gait, load_model,
                     positive, print_json)


ROBUST_ONLY = ("--samples", "--starts", "--seed", "--mu", "--scheduler", "--no-cache")


def cmd_robust_design(args, say):
    """``biped m1 --robust``: the search of :mod:`analysis.design`."""
    if args.gait or args.free or args.group:
        raise UserError("--robust chooses the gait and M1 itself: it excludes --gait, "
                        "--free and --group")
    args.samples = 40000 if args.samples is None else args.samples
    args.starts = 3 if args.starts is None else args.starts
    args.seed = 0 if args.seed is None else args.seed
    args.mu = 0.6 if args.mu is None else args.mu
    if not 100 <= args.samples <= 10_000_000:
        raise UserError(f"--samples must be between 100 and 10000000, got {args.samples}")
    if not 1 <= args.starts <= 50:
        raise UserError(f"--starts must be between 1 and 50, got {args.starts}")
    positive(args.mu, "--mu")
    model = load_model(args.robot)
    st = RobustDesignSettings(samples=args.samples, starts=args.starts, seed=args.seed,
                              mu=args.mu)
    say(f"robust design: gait {ROBUST_GAIT}, v_c rejoining at {st.rejoin} T; about "
        f"3-5 minutes on 2 cores the first time, then read from the cache")
    r = robust_design(model, st, progress=say, use_cache=not args.no_cache,
                      scheduler=args.scheduler)
    if args.json:
        print_json(r)
        return 0
    print(r.message + (" (from the cache)" if r.cached else ""))
    print(f"  M1 = {r.design['M1']}, v_c rejoins at {r.design['rejoin']} T")
    print(f"  gait: impact_mu {r.gait_options.get('impact_mu')}, continuation "
          f"{r.gait_options.get('continuation')}, clearance {r.gait_options.get('clearance')} "
          f"({r.gait_file})")
    for k, v in r.verified.items():
        print(f"  full-order check {k.replace('_', ' ')} (s = {v['scale']:.4g}): "
              f"{v['passed']} of {len(v['outcomes'])} directions walk and converge")
    print("  replay: biped simulate " + " ".join(r.simulate_args))
    return 0


def cmd_m1(args):
    say = Progress("m1", quiet=args.json)
    if args.robust:
        return cmd_robust_design(args, say)
    for name in ROBUST_ONLY:
        if getattr(args, name.lstrip("-").replace("-", "_")) not in (None, False):
            raise UserError(f"{name} applies to --robust")
    gait = load_gait(args, say)
    model = gait.model
    ab = ab_groups(model, gait)
    valid, why = ab.groups, ab.explanation
    if args.group and args.group not in valid:
        raise UserError(f"--group {args.group}: {why}")
    groups = [None] if args.free else ([args.group] if args.group else (valid or [None]))
    results = []
    for g in groups:
        say(f"optimising M1 {'with all components free' if g is None else f'on group {g}'} "
            "(10-15 s on a loaded 2-core VM) ...")
        results.append(optimize_m1(model, gait, group=g))
    best = min(results, key=lambda r: r.max_abs)
    say(f"the 9^{model.nu} grid for comparison (once per gait, then cached) ...")
    gb = grid_best(model, gait)
    out = dict(best.to_dict(), grid_best=gb)
    if len(results) > 1:
        out["groups"] = {str(r.group): r.to_dict() for r in results}
    if args.json:
        print_json(out)
        return 0
    for r in results:
        label = "all components free" if r.group is None and args.free or not valid \
            else f"group {r.group}"
        print(f"{label}: M1 = {np.array2string(r.M1, precision=6)}  max|lambda| = "
              f"{r.max_abs:.3g} (+- {r.eigenvalue_uncertainty:.1g})  a = {r.a:.2g}, "
              f"b = {r.b:.2g}  [{r.solve_time:.1f} s, {r.starts} starts]")
    if not valid and not args.free:
        print(f"a = b = 0: {why}; all components free instead")
    print(f"best of the 9^{model.nu} grid: " + ("no stable point" if gb["M1"] is None else
                                               f"M1 = {gb['M1']}  max|lambda| = "
                                               f"{gb['max_abs']:.4g}"))
    return 0


def register(sub):
    p = sub.add_parser(
        "m1", help="choose M1 minimising max|lambda| (a = b = 0 groups, or free)",
        description="Second NLP of the toolkit: choose the output matrix M1 minimising the "
                    "spectral radius of A^z, on the solution groups of the swing-height "
                    "conditions a = b = 0 (paper eq. 27-28), or with all components free "
                    "(--free). For a robot with two torques (three_link) the groups are the "
                    "solutions of a = b = 0 themselves (isolated points, or a line: group 1). "
                    "Exact derivatives of A^z in M1 by AD; several starts; the result is "
                    "verified by the full-AD Poincare map and compared with the best stable "
                    "point of the 9^nu grid.")
    add_gait_arguments(p)
    add_robot(p)
    where = p.add_mutually_exclusive_group()
    where.add_argument("--free", action="store_true", help="all components of M1 free")
    where.add_argument("--group", type=int, choices=(1, 2),
                       help="only this a = b = 0 group (default: every group, the best is "
                            "reported)")
    p.add_argument("--robust", action="store_true",
                   help="instead: the time-varying design (gait, M1, v_c rejoin time) that "
                        "survives the largest perturbation s* with max|lambda| at most the "
                        "virtual constraints' (see 'biped robust'); 3-5 min the first time, "
                        "cached afterwards")
    p.add_argument("--samples", type=int, metavar="N",
                   help="with --robust: random M1 screened (40000)")
    p.add_argument("--starts", type=int, metavar="K",
                   help="with --robust: compass searches from the K best samples (3)")
    p.add_argument("--seed", type=int, help="with --robust: seed of the samples (0)")
    p.add_argument("--mu", type=float,
                   help="with --robust: friction coefficient (0.6)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="with --robust: run the bisections on a Dask cluster "
                        "(tcp://host:port), each worker building the walker once")
    p.add_argument("--no-cache", action="store_true",
                   help="with --robust: search again instead of reading a cached result")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_m1)
