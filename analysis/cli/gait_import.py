"""``biped gait --import FILE``: a gait from another tool (nodes or published virtual
constraints), fitted, closed into an exact orbit of the robot and saved.  Reads top to
bottom; the import is :func:`gait_opt.import_gait`."""
from __future__ import annotations

import math

from analysis.reporting.plots import gait_profiles_plot, gait_stick_plot, save_figures
from gait_opt import IMPORT_TOL, MAX_IMPORT_TOL, GaitOptions, import_gait
from gait_opt.urdf_angles import CSV_ANGLES, require_urdf_map, write_gait_csv

from .common import (UserError, load_gait, load_model, not_an_input, output_dir, output_file,
                     print_json)


#: the units of :meth:`gait_opt.Gait.violations`' amounts, by constraint (the friction
#: cone's is a ratio); the constraints are the gait options' (--mu, --impact-mu,
#: --torque-limit, --clearance, or their defaults)
VIOLATION_UNITS = {"torque limit": " N m", "normal force": " N", "friction cone": " in |F_x|/F_z",
                   "swing foot above ground": " m", "swing-foot clearance": " m",
                   "strike velocity": " m/s", "lift-off velocity": " m/s",
                   "impact impulse cone": " N s", "torso lean": " rad",
                   "stance knee (hyperextension)": " rad",
                   "swing knee (hyperextension)": " rad"}

def add_import_arguments(p):
    """--import, --angles, --stance, --import-tol, --bezier-degree, --export-csv, --gait
    and --nodes on ``biped gait``."""
    p.add_argument("--import", dest="import_file", metavar="FILE",
                   help="import one step from another tool instead of optimising: a CSV "
                        "with header t,q1..qn,dq1..dqn[,ddq1..ddqn], an NPZ or JSON with "
                        "arrays t, q, dq[, ddq], or a JSON with virtual_constraints "
                        "(bezier, theta_plus, theta_minus, phase); with --angles urdf a "
                        "CSV with header t, pitch, the URDF joint names, dpitch, d<joint> "
                        "for each (optionally x, z, dx, dz of the root link: checked)")
    p.add_argument("--angles", choices=CSV_ANGLES, default="relative",
                   help="with --import or --export-csv: the nodes' coordinates, the "
                        "toolkit's relative joint angles (default), absolute link angles "
                        "phi, or the robot's own URDF joint angles and the root link's "
                        "pitch (the robot's URDF map: --robot FILE.urdf, a description "
                        "written by 'biped robot import', or the gait file's robot)")
    p.add_argument("--stance", metavar="HIP_JOINT",
                   help="with --angles urdf: the stance leg, named by its hip joint as the "
                        "URDF names it (--export-csv: default the first leg's)")
    p.add_argument("--export-csv", metavar="FILE",
                   help="write a gait (--gait, default the robot's default gait) as one "
                        "step of nodes in --angles coordinates, a CSV that --import reads "
                        "back, instead of optimising")
    p.add_argument("--gait", metavar="FILE",
                   help="with --export-csv: the gait file to write")
    p.add_argument("--nodes", type=int, default=None, metavar="N",
                   help="with --export-csv: uniform samples from t = 0 to T (default 101)")
    p.add_argument("--import-tol", type=float, default=None, metavar="TOL",
                   help=f"with --import: refuse a trajectory whose fitted orbit misses by "
                        f"more than TOL (rad, rad/s, m; default {IMPORT_TOL:g}, at most "
                        f"{MAX_IMPORT_TOL:g})")
    p.add_argument("--bezier-degree", type=int, default=None, metavar="M",
                   help="with --import: degree of the fitted Bezier polynomials (4 to 20; "
                        "default: chosen by the fit). With --import, --continuation and "
                        "--continuation-shape say how the reference continues past T, and "
                        "--mu, --impact-mu, --torque-limit, --clearance the constraints "
                        "the imported gait is checked against (reported, not enforced)")


def cmd_import(args):
    args.import_tol = IMPORT_TOL if args.import_tol is None else args.import_tol
    if not (math.isfinite(args.import_tol) and args.import_tol > 0):
        raise UserError(f"--import-tol must be a positive number, got {args.import_tol:g}")
    if args.import_tol > MAX_IMPORT_TOL:
        raise UserError(f"--import-tol must be at most {MAX_IMPORT_TOL:g} (rad, rad/s, m: a "
                        f"larger residual is not close to an orbit), got {args.import_tol:g}")
    if args.bezier_degree is not None and not 4 <= args.bezier_degree <= 20:
        raise UserError(f"--bezier-degree must be from 4 to 20, got {args.bezier_degree}")
    out = output_file(args.out, "--out", (".json",))
    not_an_input(out, "--out", {"--import": args.import_file})
    folder = output_dir(args.plot, "--plot") if args.plot is not None else None
    model = load_model(args.robot)
    if args.angles == "urdf":
        umap = require_urdf_map(model, "--angles urdf")
        if args.stance is None:
            raise UserError(f"--angles urdf needs --stance HIP_JOINT: the stance leg's hip "
                            f"joint ({' or '.join(umap.hips)})")
        _check_stance(umap, args.stance)
    # recorded with the gait: how it continues past T (a late impact), and the
    # constraints its figures are compared with (reported, not enforced)
    options = GaitOptions(mu=args.mu, torque_limit=args.torque_limit, impact_mu=args.impact_mu,
                          continuation=args.continuation,
                          continuation_shape=args.continuation_shape,
                          **({} if args.clearance is None else {"clearance": args.clearance}))
    r = import_gait(model, args.import_file, angles=args.angles, stance=args.stance,
                    bezier_degree=args.bezier_degree, tol=args.import_tol, options=options)
    s = r.to_dict()
    s["file"] = str(r.gait.save(out))
    if folder is not None:
        s["plots"] = save_figures({"gait_stick": gait_stick_plot(r.gait),
                                   "gait_profiles": gait_profiles_plot(r.gait)}, folder)
    if args.json:
        print_json(s)
        return 0
    print(f"imported gait of {model.params.name} from {args.import_file} ({r.kind}), saved "
          f"to {out}")
    print(f"  nodes fitted         {r.n_nodes}, Bezier degree {r.bezier_degree}")
    if args.angles == "urdf":
        spread = r.info.get("stance_foot_spread")
        print(f"  URDF angles          stance leg of {r.info['stance']}"
              + ("" if spread is None else
                 f"; the base columns keep its foot within {spread:.2e} m"))
    print(f"  fit error            {r.fit_error_q:.2e} rad, {r.fit_error_dq:.2e} rad/s")
    print(f"  data through impact  {r.data_impact_residual:.2e}   unactuated drift "
          f"{r.unactuated_drift:.2e} rad")
    print(f"  orbit residual       {r.orbit_residual_before:.2e} -> {r.orbit_residual_after:.2e}"
          f" (parameters moved by at most {r.parameter_change:.2e})")
    print(f"  step time T          {r.T:.6f} s, length {r.step_length:.6f} m, speed "
          f"{r.speed:.6f} m/s")
    print(f"  peak torque          {r.peak_torque:.3f} N m")
    print(f"  friction ratio       {r.max_friction_ratio:.4f} (impact {r.impact_friction_ratio:.4f})")
    print(f"  swing-foot clearance {r.min_swing_height:.3e} m (lowest inside the step)")
    for name, v in r.violations:
        print(f"  note: violates the gait constraint '{name}' by {v:.3g}"
              f"{VIOLATION_UNITS.get(name, '')} (reported, not enforced)")
    for p in s.get("plots", []):
        print(f"  plot                 {p}")
    return 0


def _check_stance(umap, stance):
    try:
        umap.stance_leg(stance)
    except ValueError as e:
        raise UserError(f"--{e}") from None


#: the options of an optimised gait that an imported one does not have, with their defaults
SOLVER_OPTIONS = dict(intervals=30, scheme="legendre", max_iter=None, torso_lean_max=None)


def check_export_arguments(args):
    """--export-csv excludes the other modes; --stance belongs to --angles urdf; the
    options of --import and --export-csv are refused without them (they were ignored:
    '--nodes 0' on an optimisation said nothing), the solver's with --import."""
    if args.stance is not None and args.angles != "urdf":
        raise UserError("--stance names the stance leg of --angles urdf")
    if args.import_file is None:
        for name in ("import_tol", "bezier_degree"):
            if getattr(args, name) is not None:
                raise UserError(f"--{name.replace('_', '-')} applies with --import only")
    if args.import_file is not None or args.export_csv is not None:
        for name, default in SOLVER_OPTIONS.items():
            if getattr(args, name) != default:
                raise UserError(f"--{name.replace('_', '-')} does not apply with "
                                f"{'--import' if args.import_file else '--export-csv'} (no "
                                f"gait is optimised: it is fitted to the nodes, or read)")
    if args.import_file is None and args.export_csv is None and args.angles != "relative":
        raise UserError("--angles applies with --import or --export-csv")
    if args.export_csv is None:
        if args.gait is not None:
            raise UserError("--gait FILE is the gait --export-csv writes (give --export-csv)")
        if args.nodes is not None:
            raise UserError("--nodes applies with --export-csv only")
        return
    args.nodes = 101 if args.nodes is None else args.nodes
    if args.import_file is not None or args.speeds is not None or args.family is not None:
        raise UserError("--export-csv writes a gait: it excludes --import, --speeds and "
                        "--family")
    if not 5 <= args.nodes <= 100_000:
        raise UserError(f"--nodes must be from 5 to 100000, got {args.nodes}")


def cmd_export_csv(args, progress):
    """``biped gait --export-csv FILE``: a gait as nodes in the chosen coordinates."""
    out = output_file(args.export_csv, "--export-csv", (".csv",))
    gait = load_gait(args, progress)
    if args.angles == "urdf":
        umap = require_urdf_map(gait.model, "--angles urdf")
        if args.stance is not None:
            _check_stance(umap, args.stance)
    path = write_gait_csv(gait, out, args.angles, args.stance, args.nodes)
    stance = None
    if args.angles == "urdf":
        stance = args.stance or gait.model.description.urdf.hips[0]
    s = dict(file=str(path), angles=args.angles, stance=stance, nodes=args.nodes, T=gait.T,
             robot=gait.model.params.name, gait=args.gait)
    if args.json:
        print_json(s)
        return 0
    where = f" (stance leg of {stance})" if stance else ""
    print(f"wrote {path}: one step of {gait.model.params.name} as {args.nodes} nodes in "
          f"{args.angles} angles{where}, T = {gait.T:.6f} s")
    return 0
