"""``biped m1``: choose the output matrix M1 minimising max|lambda| (paper §V-B)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from analysis.design import (
    RobustDesignSettings,
    ab_groups,
    optimize_m1,
    robust_design,
)
from analysis.design.codesign import (FIT, QUICK, CodesignError, CodesignSettings, NoDesign,
                                      codesign)
from analysis.design.designs_over_speed import family_designs
from analysis.reporting.plots import family_designs_plot, save_figures
from analysis.design.codesign.method import same_steps
from analysis.robustness import steps_short
from biped_casadi.files import write_bytes_atomic
from biped_casadi.simulation import NOT_CONVERGED
from biped_casadi.simulation.options import friction_of
from gait_opt import GaitFamily
from analysis.sweeps import grid_best

from .common import (
    Progress,
    UserError,
    add_gait_arguments,
    add_robot,
    add_scheduler,
    check_scheduler,
    is_family_file,
    output_dir,
    output_file,
    load_gait,
    load_model,
    not_an_input,
    positive,
    print_json,
)

ROBUST_ONLY = ("--samples", "--starts", "--seed", "--mu", "--scheduler", "--workers", "--out",
               "--plot", "--no-cache", "--method", "--fixed-gait", "--free-gait")


def _robust_defaults(args):
    """Check and default the --robust options (the method's own defaults)."""
    nlp = args.method == "nlp"
    if args.free or args.group:
        raise UserError("--robust chooses M1 itself: it excludes --free and --group")
    if not nlp and args.gait:
        raise UserError("--gait with --robust fixes the gait of the NLP co-design; the "
                        "sampling search (--method search) uses its own gait")
    if args.scheduler is not None and args.workers is not None:
        raise UserError("--workers sets the local cluster's processes; it excludes "
                        "--scheduler (an existing cluster has its own workers)")
    if (args.fixed_gait or args.free_gait) and not (nlp and args.gait):
        raise UserError(f"{'--fixed-gait' if args.fixed_gait else '--free-gait'} says what "
                        "the co-design NLP does with --gait FILE: give one")
    # what the user set (the method's own defaults otherwise)
    args.given = {k: v for k, v in (("samples", args.samples), ("kept", args.starts),
                                    ("seed", args.seed), ("mu", args.mu)) if v is not None}
    args.samples = (2000 if nlp else 40000) if args.samples is None else args.samples
    args.starts = (5 if nlp else 3) if args.starts is None else args.starts
    args.seed = 0 if args.seed is None else args.seed
    args.mu = 0.6 if args.mu is None else args.mu
    if not 100 <= args.samples <= 10_000_000:
        raise UserError(f"--samples must be between 100 and 10000000, got {args.samples}")
    if args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    if not 1 <= args.starts <= 50:
        raise UserError(f"--starts must be between 1 and 50, got {args.starts}")
    positive(args.mu, "--mu")


def cmd_robust_design(args, say):
    """``biped m1 --robust``: the co-design NLP (default) or the sampling search."""
    _robust_defaults(args)
    # --scheduler and the code checked once the inputs are read: a bad file first
    if args.method == "search":
        return _search(args, say)
    if args.gait and is_family_file(args.gait):
        return _family(args, say)
    if args.plot is not None:
        raise UserError("--plot applies to --robust with a gait family (--gait FAMILY.json)")
    out = output_file(args.out, "--out", (".json",)) if args.out is not None \
        else None
    if out is not None:
        not_an_input(out, "--out", {"--gait": args.gait})
    model = load_model(args.robot) if not args.gait else None
    gait = None
    if args.gait:
        gait = load_gait(args, say)
        model = gait.model
        args.given["mu"] = friction_of(gait, args.given.get("mu"))
    check_scheduler(args.scheduler, say)
    if gait is None:
        st = CodesignSettings().replace(free_gait=True, **args.given)
        say(f"robust co-design NLP: gait and M1 from the gait {st.for_model(model).gait}, "
            f"v_c rejoining at {st.rejoin} T; under a minute on 2 cores the first time, "
            "then read from the cache")
    else:
        mode = "fixed" if args.fixed_gait else "free" if args.free_gait else "auto"
        st = FIT.replace(given_gait=mode, **args.given)
        say("robust co-design NLP on the given gait: " + dict(
            fixed="M1 only (the gait fixed)",
            free=f"the gait moved to the robust gait constraints {st.for_model(model).gait} "
                 "near it, then gait and M1 co-designed",
            auto="M1 on the gait as given, the gait moved from it when that misses the "
                 "target")[mode] + "; on 2 cores the first time under a minute for RABBIT's "
            "gaits, a few minutes for other robots")
    try:
        r = codesign(gait if gait is not None else model, st, gait_file=args.gait,
                     progress=say, use_cache=not args.no_cache, scheduler=args.scheduler,
                     workers=args.workers)
    except NoDesign as e:
        return _no_design(args, e.to_dict(), str(e))
    except CodesignError as e:
        raise UserError(str(e)) from None
    if gait is not None:
        why = no_design_reason(r, st)
        if why is not None:
            return _no_design(args, dict(r.to_dict(), status="no_design", success=False,
                                         message=why, design_status=r.status), why)
    if out is not None:
        save_design_gait(r, out)
    if args.json:
        print_json(r)
        return 0
    _print_design(r, st)
    return 0


def save_design_gait(r, out):
    """Write a robust design's gait to ``out`` (a copy of the file it was kept in) and
    point the design's ``gait_file`` and replay arguments at it.

    Parameters
    ----------
    r : CodesignResult or RobustDesignResult
        The design (its ``gait_file`` and ``simulate_args`` are rewritten).
    out : Path
        The file to write (checked writable by :func:`output_file`).
    """
    old = r.gait_file
    write_bytes_atomic(out, Path(old).read_bytes())
    r.gait_file = str(out)
    args = list(r.simulate_args)
    args[args.index("--gait") + 1] = str(out)
    r.simulate_args = args


def no_design_reason(r, st) -> str | None:
    """Why a design on a given gait is not one, in one line (None when it is: it meets
    the target, or its s* is above virtual constraints' on its gait with max|lambda| at
    most theirs); ``st`` the co-design's settings (its protocol's steps)."""
    if r.status == "target_met":
        return None
    if r.max_abs <= r.vc_eigenvalue and r.s_star > r.vc_s_star:
        return None
    b = r.binds or {}
    # b['step'] counts from 1; a run that walked every step but did not converge has none
    where = (f" (in step {b['step']})" if "step" in b and b.get("status") != NOT_CONVERGED
             else "")
    stop = (f"{b.get('binds')}{where}" if b else
            r.check.failure or "nothing within the scales tried")
    lam = ("" if r.max_abs <= r.vc_eigenvalue else
           f", max|lambda| {r.max_abs:.3g} above virtual constraints' {r.vc_eigenvalue:.3g}")
    conv = r.steps_to_converge
    paper = (f"the paper's perturbation below {r.settings['verification']['tol']:g} from "
             f"step {conv}" if conv is not None else
             f"the paper's perturbation: {r.check.paper_status}")
    return (f"no design beats virtual constraints on this gait: the best, M1 "
            f"{np.round(r.design.M1, 3).tolist()} (gait {'moved' if r.gait_free else 'fixed'}"
            f"), reaches s* {r.s_star:.3g}, stopped just above by {stop}{lam}, {paper}; "
            f"virtual constraints reach s* {r.vc_s_star:.3g}"
            + same_steps(r.vc_eigenvalue, st.robustness_settings()))


def _no_design(args, body: dict, line: str) -> int:
    """No design: with --json the reasons as one JSON object on stdout; one line on
    stderr; exit 2."""
    if args.json:
        print_json(body)
    print(f"biped m1: error: {' '.join(line.split())}", file=sys.stderr)
    return 2


def decay_note(r, st) -> str | None:
    """One line when the verification's steps are too few for s* to measure more than the
    convergence rate (:func:`analysis.robustness.decay_steps` above them), naming the
    ``biped robust`` command that measures the design over enough steps; None otherwise."""
    rs = st.robustness_settings()
    n = steps_short(r.vc_eigenvalue, rs)
    if n is None:
        return None
    m1 = " ".join(f"{v:.6g}" for v in r.design.M1)
    return (f"note: at the virtual constraints' rate {abs(r.vc_eigenvalue):.3g} a "
            f"perturbation of scale {rs.s_max:g} cannot fall below {rs.tol:g} in "
            f"{rs.steps} steps, so s* above, the design's and virtual constraints', "
            f"measures how fast each converges; 'biped robust --gait {r.gait_file} --m1 "
            f"{m1} --rejoin {r.design.rejoin:g} --steps auto' walks {n} steps (with "
            f"--controller vc instead of --m1 and --rejoin: virtual constraints' s* there)")


def _print_design(r, st):
    """The human output of a co-design."""
    print(r.message + (" (from the cache)" if r.cached else ""))
    print(f"  M1 = {list(r.design.M1)}, v_c rejoins at {r.design.rejoin} T")
    ch = r.gait_change
    print(f"  gait ({'co-designed' if r.gait_free else 'fixed'}): T {ch['T_start']:.4g} -> "
          f"{ch['T']:.4g} s, largest Bezier change {ch['max_alpha_change']:.3g} rad "
          f"({r.gait_file})")
    if "from_given" in ch and r.gait_free:
        c = ch["from_given"]
        print(f"  moved from the given gait: speed {c['speed'][0]:.4g} -> {c['speed'][1]:.4g} "
              f"m/s, step length {c['step_length'][0]:.4g} -> {c['step_length'][1]:.4g} m, "
              f"period {c['T'][0]:.4g} -> {c['T'][1]:.4g} s, joints by at most "
              f"{c['max_joint_change']:.3g} rad")
    if r.gait_move:
        print(f"  {r.gait_move['message']}")
    print(f"  s* = {r.s_star:.4g} over {r.directions_kept} kept directions"
          + (f" (virtual constraints {r.vc_s_star:.4g}"
             f"{same_steps(r.vc_eigenvalue, st.robustness_settings())})"
             if r.vc_s_star == r.vc_s_star else "") + f"; max|lambda| "
          f"{r.max_abs:.3g} (virtual constraints {r.vc_eigenvalue:.3g}); paper's "
          f"perturbation: {r.check.paper_outcome(st.verification.tol)}; peak torque "
          f"{r.peak_torque:.1f} N m")
    note = decay_note(r, st)
    if note is not None:
        print(f"  {note}")
    if r.alternative:
        print(f"  also tried: {r.alternative.get('message', '')}")
    for k, v in r.verified.items():
        print(f"  full-order check {k.replace('_', ' ')} (s = {v['scale']:.4g}): "
              f"{v['passed']} of {len(v['outcomes'])} directions walk and converge")
    if r.hidden:
        print(f"  hidden sign patterns: {r.hidden.get('message', '')}")
    for a in r.active_constraints[:4]:
        print(f"  binds: {a['constraint']} (multiplier {a['multiplier']:.3g})")
    capped = (" (each solve stops at a set iteration count; the design counts by "
              "the checks above)" if str(r.ipopt['status']).startswith("Maximum_") else "")
    print(f"  IPOPT: {len(r.ipopt['solves'])} solves, {r.ipopt['iterations']} iterations, "
          f"{r.ipopt['evaluations']} evaluations; last status {r.ipopt['status']}{capped}; "
          f"this run took {r.elapsed:.1f} s (kept results are read, not recomputed)")
    print("  replay: biped simulate " + " ".join(r.simulate_args))


def _family(args, say):
    """``biped m1 --robust --gait FAMILY.json``: the designs over a gait family."""
    out = output_file(args.out, "--out", (".json",)) if args.out is not None \
        else None
    if out is not None:
        not_an_input(out, "--out", {"--gait": args.gait})
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    fam = GaitFamily.load(args.gait, load_model(args.robot) if args.robot else None)
    args.given["mu"] = friction_of(fam, args.given.get("mu"))
    check_scheduler(args.scheduler, say)
    say(f"designs over the family: the gait-fixed co-design at each of its {len(fam)} "
        "speeds (side by side), an M1 schedule over speed, one M1 for all; each measured "
        "at every speed (about a minute per speed on 2 cores the first time)")
    # the gait fixed at each speed, the starts fitted to it (those of --gait FILE)
    st = QUICK.replace(starts=FIT.starts, converge_by=FIT.converge_by, **args.given)
    try:
        r = family_designs(fam, st, progress=say, scheduler=args.scheduler,
                           workers=args.workers)
    except NoDesign as e:
        return _no_design(args, e.to_dict(), str(e))
    except CodesignError as e:
        raise UserError(str(e)) from None
    d = r.to_dict()
    if out is not None:
        d["schedule_file"] = str(r.schedule.save(out))
    if folder is not None:
        d["plots"] = save_figures({"family_designs": family_designs_plot(r)}, folder)
    if args.json:
        print_json(d)
        return 0
    print(r.message)
    for rec in r.records:
        if rec["codesign"].get("status") == "no_design":
            print(f"  {rec['speed']:.3g} m/s: no design ({rec['codesign']['message']})")
        if rec["deadbeat"].get("status") == "failed":
            print(f"  {rec['speed']:.3g} m/s: no deadbeat M1 ({rec['deadbeat']['message']})")
        print(f"  {rec['speed']:.3g} m/s: " + "; ".join(
            f"{lab} s* {v['s_star']:.3g}, max|lambda| {v['max_abs']:.3g}" if "s_star" in v
            else f"{lab}: {v['message']}" for lab, v in rec["designs"].items()))
    print(f"  schedule: polynomials of degree {r.fit['degree']} in speed, sampled at the "
          f"family's speeds, v_c rejoining at {r.schedule.rejoin[0]} T"
          + (f" ({d['schedule_file']})" if out is not None else ""))
    print(f"  one M1 for all speeds: {np.round(r.single['M1'], 4).tolist()} (the co-design "
          f"at {r.single['from_speed']:g} m/s)")
    for f in d.get("plots", []):
        print(f"  plot {f}")
    return 0


def _search(args, say):
    """``biped m1 --robust --method search``: the sampling search (the baseline)."""
    model = load_model(args.robot)
    st = RobustDesignSettings(samples=args.samples, starts=args.starts, seed=args.seed,
                              mu=args.mu)
    say(f"robust design by sampling search: gait {st.for_model(model).gait}, v_c rejoining at "
        f"{st.rejoin} T; under a minute on 2 cores the first time, then read from the "
        "cache")
    out = output_file(args.out, "--out", (".json",)) if args.out is not None \
        else None
    if out is not None:
        not_an_input(out, "--out", {"--gait": args.gait})
    if args.plot is not None:
        raise UserError("--plot applies to --robust with a gait family (--gait FAMILY.json)")
    check_scheduler(args.scheduler, say)
    r = robust_design(model, st, progress=say, use_cache=not args.no_cache,
                      scheduler=args.scheduler)
    if out is not None:
        save_design_gait(r, out)
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
        args.method = args.method or "nlp"
        return cmd_robust_design(args, say)
    for name in ROBUST_ONLY:
        value = getattr(args, name.lstrip("-").replace("-", "_"))
        if value is not None and value is not False:       # (0 is given, 0 == False)
            raise UserError(f"{name} applies to --robust")
    gait = load_gait(args, say)
    model = gait.model
    ab = ab_groups(gait)
    valid, why = ab.groups, ab.explanation
    if args.group and args.group not in valid:
        raise UserError(f"--group {args.group}: {why}")
    groups = [None] if args.free else ([args.group] if args.group else (valid or [None]))
    results = []
    for g in groups:
        say(f"optimising M1 {'with all components free' if g is None else f'on group {g}'} "
            "(10-15 s on a loaded 2-core VM) ...")
        results.append(optimize_m1(gait, group=g))
    best = min(results, key=lambda r: r.max_abs)
    say(f"the 9^{model.nu} grid for comparison (once per gait, then cached) ...")
    gb = grid_best(gait)
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
        if r.at_bound:
            print("  " + r.message.split("; ", 1)[1])
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
                   help="instead: the robust time-varying design. By default one NLP "
                        "(CasADi + IPOPT, exact derivatives) co-designs the gait and M1 so "
                        "that perturbation scenarios walk, maximising their scale s, with "
                        "max|lambda| at most the virtual constraints'; with --gait FILE, on "
                        "that gait: M1 alone first, then (when that misses the target: s* >= "
                        "1, max|lambda| at most the virtual constraints', the paper's "
                        f"perturbation below 1e-3 by step {FIT.converge_by}) the gait moved "
                        "from it to the robust gait constraints and co-designed (--fixed-gait, "
                        "--free-gait: one of them only). Ends in a design or in one line "
                        "naming what binds (exit 2). Verified by the protocol of "
                        "'biped robust' (s*, full order, hidden sign patterns). Under a minute "
                        "the first time, cached afterwards")
    p.add_argument("--method", choices=("nlp", "search"), default=None,
                   help="with --robust: 'nlp' (default) the co-design NLP; 'search' the "
                        "sampling search over M1 on a hand-set gait (the baseline, under a "
                        "minute)")
    given = p.add_mutually_exclusive_group()
    given.add_argument("--fixed-gait", action="store_true",
                       help="with --robust --gait FILE: only M1 moves; a design whose s* "
                            "is above the virtual constraints' on the gait, or one line "
                            "naming what binds")
    given.add_argument("--free-gait", action="store_true",
                       help="with --robust --gait FILE: move the gait to the robust gait "
                            "constraints near it and co-design gait and M1 from there "
                            "(the output says how far the gait moved)")
    p.add_argument("--samples", type=int, metavar="N",
                   help="with --robust: random M1 drawn (nlp: 2000 in [-1, 1]^4 for the "
                        "starts, with --gait 20000 in the gait's units; search: 40000 "
                        "screened)")
    p.add_argument("--starts", type=int, metavar="K",
                   help="with --robust: NLP starts from the sampled M1 (nlp: 5) or compass "
                        "searches from the K best samples (search: 3)")
    p.add_argument("--seed", type=int, help="with --robust: seed of the samples (0)")
    p.add_argument("--mu", type=float,
                   help="with --robust: friction coefficient of the verification (default: "
                        "with --gait, the one that gait was optimised for; else 0.6)")
    add_scheduler(p)
    p.add_argument("--out", metavar="FILE",
                   help="with --robust: write the design's gait there (JSON; the replay "
                        "line and --json's gait_file then name it; without --out the gait "
                        "stays in the cache folder); with a gait family (--gait "
                        "FAMILY.json): the M1 schedule over speed (biped simulate "
                        "--schedule reads it)")
    p.add_argument("--plot", metavar="DIR",
                   help="with --robust and a gait family: family_designs.png into DIR "
                        "(max|lambda|, s* and the basin against speed)")
    p.add_argument("--no-cache", action="store_true",
                   help="with --robust: search again instead of reading a cached result")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_m1)
