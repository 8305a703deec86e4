"""``biped eig``: eigenvalues of the restricted Poincaré map for one output matrix M1."""
from __future__ import annotations

import numpy as np

from .cli import UserError, _print_json


def load_gait_arg(path):
    """The gait of ``--gait FILE``, or the default gait (optimised once, then cached)."""
    from gait_opt import Gait
    if path:
        return Gait.load(path)
    import gait_opt
    return gait_opt.default_gait()


def cmd_eig(args):
    gait = load_gait_arg(args.gait)
    model = gait.model
    if args.controller == "vc":
        if args.m1 is not None:
            raise UserError("--m1 applies to the time-varying controller (--controller tv)")
        from analysis.virtual_constraints import vc_eigenvalue
        res = vc_eigenvalue(model, gait)
        d = res.to_dict()
        if args.json:
            _print_json(d)
        else:
            for k, v in d.items():
                print(f"{k:22s} {v}")
        return 0
    if args.m1 is None:
        raise UserError("--m1 A B C D is required for the time-varying controller")
    M1 = np.array(args.m1, dtype=float)
    if M1.shape != (4,):
        raise UserError(f"--m1 takes 4 numbers, got {M1.size}")
    if not np.all(np.isfinite(M1)):
        raise UserError("--m1 values must be finite")
    from analysis import poincare_eigenvalues
    r = poincare_eigenvalues(model, gait, M1)
    if args.json:
        _print_json(dict(A=r.A.tolist(), eigenvalues=[[e.real, e.imag] for e in r.eigenvalues],
                         max_abs=r.max_abs, status=r.status, M1=M1.tolist(),
                         x_star=r.x_star.tolist(), tau_impact=r.tau_impact,
                         fixed_point_residual=r.fixed_point_residual,
                         min_denominator=r.min_denominator))
        return 0
    print(f"M1 = {M1.tolist()}   status: {r.status}")
    if r.status == "singular":
        print(f"  {r.message}")
        return 0
    print("A^z =")
    print(np.array2string(r.A, precision=8))
    print("eigenvalues: " + ", ".join(f"{e.real:.8g}{e.imag:+.8g}j" for e in r.eigenvalues))
    print(f"max|lambda| = {r.max_abs:.8g}")
    print(f"x* = {r.x_star.tolist()}, impact at tau = {r.tau_impact:.10g} (T = {gait.T:.10g}), "
          f"fixed-point residual {r.fixed_point_residual:.2e}")
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
                   "default RABBIT gait, optimised once and cached)")
    p.add_argument("--m1", nargs="+", type=float, metavar="M1", help="the 4 components of M1")
    p.add_argument("--controller", choices=("tv", "vc"), default="tv",
                   help="tv: time-varying outputs (default); vc: virtual constraints")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_eig)
