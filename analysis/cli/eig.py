"""``biped eig``: eigenvalues of the restricted Poincaré map for one output matrix M1."""
from __future__ import annotations

import numpy as np

from analysis.gait_metrics import torso_fall
from analysis.stability import METHODS, poincare_eigenvalues
from analysis.stability import vc_eigenvalue
from analysis.reporting.text import eigenvalues_text, number_text
from biped_casadi.control.output_law import M1_LIMIT, SECTION

from .common import (Progress, UserError, add_gait_arguments, add_robot, check_m1_values,
                     load_gait, parse_m1, print_json, rejoin_fraction)


def cmd_eig(args):
    if args.controller == "vc" and args.m1 is not None:
        raise UserError("--m1 applies to the time-varying controller (--controller tv)")
    if args.controller == "vc" and args.method is not None:
        raise UserError("--method applies to the time-varying controller (--controller tv)")
    if args.controller == "vc" and args.rejoin is not None:
        raise UserError("--rejoin applies to the time-varying controller (--controller tv)")
    rejoin = 0.5 if args.rejoin is None else rejoin_fraction(args.rejoin)
    method = args.method or "variational"
    check_m1_values(args.m1)                 # before the gait: finite, within the range
    say = Progress("eig", quiet=args.json)
    gait = load_gait(args, say)
    model = gait.model
    if args.controller == "vc":
        say("fitting the virtual constraints to the gait (a few seconds) ...")
        res = vc_eigenvalue(gait)
        d = res.to_dict()
        if args.json:
            print_json(res)
        else:
            for k, v in d.items():
                print(f"{k:22s} {v}")
            _fall_note(gait)
        return 0
    M1 = parse_m1(args.m1, model.nu)      # after the gait: its file's errors come first
    if method == "ad":
        say("AD through the whole Poincare map (builds it once, a few seconds) ...")
    r = poincare_eigenvalues(gait, M1, method=method, rejoin=rejoin)
    if args.json:
        print_json(r)
        return 0
    when = "" if rejoin == 0.5 else f", v_c rejoins at {rejoin:g} T"
    print(f"M1 = {M1.tolist()}{when}   status: {r.status}")
    if not r.success:                    # singular, no_impact or open_orbit
        print(f"  {r.message}")
        return 0
    print("A^z =")
    print(np.array2string(r.A, precision=8))
    print(f"eigenvalues: {eigenvalues_text(r.eigenvalues)}")
    print(f"max|lambda| = {number_text(r.max_abs)}")
    print(f"x* = {r.x_star.tolist()}, impact at tau = {r.tau_impact:.10g} (T = {gait.T:.10g})")
    print(f"fixed-point residual |P(x*) - x*| = {r.fixed_point_residual:.2e}")
    _fall_note(gait)
    return 0


def _fall_note(gait):
    """One line when the gait's torso leans past the simulator's fall bound: the map's
    eigenvalues are those of an orbit every walk of which is a fall."""
    lean, past, bound = torso_fall(gait)
    if past:
        print(f"note: the gait's torso leans {lean:.4g} rad, PAST the simulator's fall bound "
              f"({bound:.4g} rad): the eigenvalues are the orbit's, but every walk of this "
              "gait is a fall (biped simulate, terrain, mujoco); a lower speed keeps the "
              "torso up")


def register(sub):
    p = sub.add_parser(
        "eig", help="eigenvalues of the restricted Poincare map for an output matrix M1",
        description="Exact Jacobian A^z (by algorithmic differentiation) of the restricted "
                    "Poincare map at tau = 0.75 T for outputs v = [M1, I] q, its eigenvalues "
                    "and the status (stable, unstable, singular, no_impact). With "
                    "--controller vc: the eigenvalue of the virtual-constraint (HZD) "
                    "controller's 1-D map. --json prints {A, eigenvalues (as [re, im] "
                    "pairs), max_abs, status, ...}.")
    add_gait_arguments(p)
    add_robot(p)
    p.add_argument("--m1", nargs="+", type=float, metavar="M1",
                   help=f"the components of M1, one per torque (4 for RABBIT, 2 for "
                        f"three_link), each within +-{M1_LIMIT:.0e}")
    p.add_argument("--controller", choices=("tv", "vc"), default="tv",
                   help="tv: time-varying outputs (default); vc: virtual constraints")
    p.add_argument("--rejoin", type=float, metavar="R", default=None,
                   help=f"time at which v_c rejoins the reference, fraction of T in "
                        f"(0, {SECTION}] (default 0.5, the paper's); A^z depends on it, as "
                        f"in biped simulate")
    p.add_argument("--method", choices=METHODS, default=None,
                   help="how A^z is differentiated: the variational equation along the orbit "
                        "(default, ~1 ms) or AD through the whole map (ad, ~0.3 s); both "
                        "check the fixed point (status open_orbit when the gait is not one)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_eig)
