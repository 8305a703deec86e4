"""The ``biped`` command line.  Each subcommand reads top to bottom and calls the library.

A user error (bad file, bad numbers, infeasible option) prints one line on stderr and
exits with code 2; ``--json`` prints exactly one JSON object on stdout.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import biped_casadi

from . import eig, gait, m1, reproduce, simulate, sweep
from .common import UserError, add_robot, load_model, print_json

__all__ = ["main", "build_parser", "UserError"]


# ----------------------------------------------------------------------- model
def cmd_model(args):
    model = load_model(args.robot)
    nq = model.nq
    q = np.zeros(nq) if args.q is None else np.array(args.q, dtype=float)
    if q.shape != (nq,):
        raise UserError(f"--q takes {nq} numbers (q1..q{nq}) for this robot, got {q.size}")
    if not np.all(np.isfinite(q)):
        raise UserError("--q values must be finite")
    s = model.describe(q)
    if args.json:
        print_json(s)
        return
    d = model.description
    print(f"robot {d.name}: total mass {s['total_mass']:.4g} kg, {d.k} link(s) per leg, "
          f"{nq} joints, {model.nu} torques (limit {d.torque_limit:g} N m), g = {d.gravity:g}")
    for link in (d.torso,) + d.leg:
        print(f"  {link.name:8s} mass {link.mass:g} kg, length {link.length:g} m, "
              f"com {link.com:g} m, inertia {link.inertia:g} kg m^2")
    for joint, m in d.point_masses:
        print(f"  point mass {m:g} kg at the {joint}" + ("" if joint == "hip" else " (each leg)"))
    print(f"  rotor inertia {d.rotor_inertia:g} kg m^2 on each actuated joint")
    print("joints: " + ", ".join(f"q{i + 1} {n}" for i, n in enumerate(model.joint_names)))
    print(f"q = {np.array2string(q, precision=4)}")
    print("D(q) =")
    print(np.array2string(np.array(s["D"]), precision=6, suppress_small=True))
    print("H(q, 0) = G(q) =")
    print(np.array2string(np.array(s["H"]), precision=6, suppress_small=True))


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="biped",
        description="Time-varying control of underactuated planar bipeds (RABBIT by default, "
                    "any point-foot biped from a description file with --robot): model, "
                    "reference gait, exact Poincare analysis, output selection "
                    "(Wang & Chevallereau).")
    ap.add_argument("--version", action="version",
                    version=f"biped-casadi {biped_casadi.__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("model", help="print the robot parameters, D(q) and H(q, 0)",
                       description="Print the robot parameters, total mass, and the mass "
                                   "matrix D(q) and H(q, 0) = G(q) at a configuration.")
    add_robot(p, with_gait=False, params_alias=True)
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configuration q1..qn in rad (RABBIT: 5 numbers; default: upright, "
                        "q = 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_model)

    for command in (gait, eig, sweep, m1, simulate, reproduce):
        command.register(sub)
    return ap


def main(argv=None) -> int:
    """Run ``biped`` with ``argv`` (default: the process's arguments); returns the exit
    code: 0 done, 1 a stage or run failed, 2 a user error, 130 interrupted."""
    ap = build_parser()
    try:
        args = ap.parse_args(argv)
    except SystemExit as e:        # argparse already printed its one-line usage error
        return int(e.code or 0)
    try:
        rc = args.func(args)
    except (UserError, ValueError, FileNotFoundError) as e:
        print(f"biped {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"biped {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:        # output piped into `head` and the like
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
