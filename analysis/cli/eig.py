"""``biped eig``: eigenvalues of the restricted Poincaré map for one output matrix M1."""
from __future__ import annotations

import numpy as np

from analysis.poincare import METHODS, poincare_eigenvalues
from analysis.virtual_constraints import vc_eigenvalue

from .common import UserError, add_robot, load_gait, parse_m1, print_json


def cmd_eig(args):
    if args.controller == "vc" and args.m1 is not None:
        raise UserError("--m1 applies to the time-varying controller (--controller tv)")
    if args.controller == "tv" and args.m1 is None:
        raise UserError("--m1 is required for the time-varying controller (one number per "
                        "torque: 4 for RABBIT)")
    gait = load_gait(args.gait, quiet=args.json, robot_arg=args.robot)
    model = gait.model
    if args.controller == "vc":
        res = vc_eigenvalue(model, gait)
        d = res.to_dict()
        if args.json:
            print_json(res)
        else:
            for k, v in d.items():
                print(f"{k:22s} {v}")
        return 0
    M1 = parse_m1(args.m1, model.nu)
    r = poincare_eigenvalues(model, gait, M1, method=args.method)
    if args.json:
        print_json(r)
        return 0
    print(f"M1 = {M1.tolist()}   status: {r.status}")
    if r.status == "singular":
        print(f"  {r.message}")
        return 0
    print("A^z =")
    print(np.array2string(r.A, precision=8))
    print("eigenvalues: " + ", ".join(f"{e.real:.8g}{e.imag:+.8g}j" for e in r.eigenvalues))
    print(f"max|lambda| = {r.max_abs:.8g}")
    print(f"x* = {r.x_star.tolist()}, impact at tau = {r.tau_impact:.10g} (T = {gait.T:.10g})")
    if args.method == "ad":
        print(f"fixed-point residual |P(x*) - x*| = {r.fixed_point_residual:.2e}")
    return 0


def register(sub):
    p = sub.add_parser(
        "eig", help="eigenvalues of the restricted Poincare map for an output matrix M1",
        description="Exact Jacobian A^z (by algorithmic differentiation) of the restricted "
                    "Poincare map at tau = 0.75 T for outputs v = [M1, I] q, its eigenvalues "
                    "and the SPEC status (stable, unstable, singular, no_impact). With "
                    "--controller vc: the eigenvalue of the virtual-constraint (HZD) "
                    "controller's 1-D map. --json prints {A, eigenvalues (as [re, im] "
                    "pairs), max_abs, status, ...}.")
    p.add_argument("--gait", metavar="FILE", help="gait file from 'biped gait' (default: the "
                   "robot's default gait, optimised once and cached)")
    add_robot(p)
    p.add_argument("--m1", nargs="+", type=float, metavar="M1",
                   help="the components of M1, one per torque (4 for RABBIT, 2 for three_link)")
    p.add_argument("--controller", choices=("tv", "vc"), default="tv",
                   help="tv: time-varying outputs (default); vc: virtual constraints")
    p.add_argument("--method", choices=METHODS, default="variational",
                   help="how A^z is differentiated: the variational equation along the orbit "
                        "(default, < 1 ms) or AD through the whole map (ad, ~0.3 s; also "
                        "prints the fixed-point residual)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_eig)
