"""The ``biped`` command line.  Each subcommand reads top to bottom and calls the library.

A user error (bad file, bad numbers, infeasible option) prints one line on stderr and
exits with code 2; ``--json`` prints exactly one JSON object on stdout.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


class UserError(Exception):
    """An input problem the user can fix; reported as one line, exit code 2."""


def _print_json(obj):
    """One JSON object on stdout; non-finite numbers (inf, nan) become null."""
    print(json.dumps(json_safe(obj), indent=None, default=_json_default, allow_nan=False))


def json_safe(o):
    """Plain JSON types for ``o``: numpy scalars and arrays unpacked, non-finite numbers
    as None, paths as strings, dict keys as strings."""
    if isinstance(o, dict):
        return {str(k): json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, Path):
        return str(o)
    return o


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, complex):
        return [o.real, o.imag]
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _load_model(path):
    from . import rabbit
    from .params import load_params
    return rabbit(load_params(path) if path else None)


# ----------------------------------------------------------------------- model
def cmd_model(args):
    model = _load_model(args.params)
    q = np.zeros(5) if args.q is None else np.array(args.q, dtype=float)
    if q.shape != (5,):
        raise UserError(f"--q takes 5 numbers (q1..q5), got {q.size}")
    if not np.all(np.isfinite(q)):
        raise UserError("--q values must be finite")
    s = model.summary(q)
    if args.json:
        _print_json(s)
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

    for register in _EXTRA_COMMANDS:
        register(sub)
    return ap


#: subcommand registrars contributed by other modules: f(subparsers) -> None
_EXTRA_COMMANDS: list = []


def _register_extras():
    if not _EXTRA_COMMANDS:
        from . import cli_commands  # noqa: F401  (registers the remaining subcommands)


def main(argv=None) -> int:
    _register_extras()
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
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
