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
from .common import UserError, load_model, print_json

__all__ = ["main", "build_parser", "UserError"]


# ----------------------------------------------------------------------- model
def cmd_model(args):
    model = load_model(args.params)
    q = np.zeros(5) if args.q is None else np.array(args.q, dtype=float)
    if q.shape != (5,):
        raise UserError(f"--q takes 5 numbers (q1..q5), got {q.size}")
    if not np.all(np.isfinite(q)):
        raise UserError("--q values must be finite")
    s = model.describe(q)
    if args.json:
        print_json(s)
        return
    p = s["params"]
    print(f"robot {p['name']}: total mass {s['total_mass']:.4g} kg")
    for k, v in p.items():
        if k != "name":
            print(f"  {k:14s} {v:g}")
    print(f"q = {np.array2string(q, precision=4)}")
    print("D(q) =")
    print(np.array2string(np.array(s["D"]), precision=6, suppress_small=True))
    print("H(q, 0) = G(q) =")
    print(np.array2string(np.array(s["H"]), precision=6, suppress_small=True))


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="biped",
        description="Time-varying control of the planar five-link biped RABBIT: model, "
                    "reference gait, exact Poincare analysis, output selection "
                    "(Wang & Chevallereau).")
    ap.add_argument("--version", action="version",
                    version=f"biped-casadi {biped_casadi.__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("model", help="print the robot parameters, D(q) and H(q, 0)",
                       description="Print the robot parameters, total mass, and the mass "
                                   "matrix D(q) and H(q, 0) = G(q) at a configuration.")
    p.add_argument("--params", metavar="FILE", help="robot parameters (.toml or .json); "
                   "default: RABBIT")
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configuration q1..q5 in rad (default: upright, q = 0)")
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
