"""What every subcommand shares: the user-error type, JSON output, the ``--robot``
option, loading the model and the gait named on the command line."""
from __future__ import annotations

import json
import math
import sys

import numpy as np

from biped_casadi import robot
from biped_casadi.results import json_safe
from gait_opt import Gait, default_gait

__all__ = ["UserError", "print_json", "load_model", "load_gait", "positive", "add_robot",
           "parse_m1"]

ROBOT_HELP = ("the robot: a built-in name (rabbit, three_link) or a description file "
              "(.toml, schema in biped_casadi.description)")


class UserError(Exception):
    """An input problem the user can fix; reported as one line, exit code 2."""


def print_json(obj):
    """One JSON object on stdout; non-finite numbers (inf, nan) become null."""
    print(json.dumps(json_safe(obj), allow_nan=False))


def add_robot(p, with_gait: bool = True, params_alias: bool = False):
    """Add ``--robot NAME|FILE`` to a subcommand's parser (and the older ``--params
    FILE`` as an alias where it existed)."""
    default = ("default: the gait file's robot, else rabbit" if with_gait
               else "default: rabbit")
    p.add_argument("--robot", metavar="NAME|FILE", help=f"{ROBOT_HELP}; {default}")
    if params_alias:
        p.add_argument("--params", dest="robot", metavar="FILE", help="same as --robot FILE "
                       "(also reads the older flat parameter files)")


def load_model(name_or_path):
    """The robot of ``--robot NAME|FILE`` (default RABBIT); ValueError (exit 2) when the
    name is unknown or the file missing or invalid."""
    return robot(name_or_path or "rabbit")


def load_gait(path, quiet: bool = False, robot_arg=None):
    """The gait of ``--gait FILE``, or the robot's default gait (optimised once, then
    cached).

    With ``robot_arg`` (``--robot``) and a file, the file must have been made for that
    robot (GaitFileError, exit 2, otherwise).  Without a file, a note goes to stderr
    when the default gait must be optimised (a few seconds), unless ``quiet``."""
    if path:
        return Gait.load(path, model=load_model(robot_arg) if robot_arg else None)
    return default_gait(load_model(robot_arg), progress=None if quiet else _note)


def parse_m1(values, nu: int, default_zero: bool = False):
    """``--m1`` as a vector of the robot's nu components (UserError otherwise)."""
    if values is None:
        if default_zero:
            return np.zeros(nu)
        raise UserError(f"--m1 takes {nu} numbers (one per torque)")
    M1 = np.array(values, dtype=float)
    if M1.shape != (nu,):
        raise UserError(f"--m1 takes {nu} numbers for this robot (one per torque), "
                        f"got {M1.size}")
    if not np.all(np.isfinite(M1)):
        raise UserError("--m1 values must be finite")
    return M1


def _note(message: str):
    if sys.stderr.isatty():
        print(message, file=sys.stderr, flush=True)


def positive(value, name):
    """``value`` if it is a positive finite number, else a UserError naming ``name``."""
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{name} must be a positive number, got {value!r}")
    return value
