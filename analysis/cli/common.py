"""What every subcommand shares: the user-error type, JSON output, loading the model and
the gait named on the command line."""
from __future__ import annotations

import json
import math
import sys

from biped_casadi import load_params, rabbit
from biped_casadi.results import json_safe
from gait_opt import Gait, default_gait

__all__ = ["UserError", "print_json", "load_model", "load_gait", "positive"]


class UserError(Exception):
    """An input problem the user can fix; reported as one line, exit code 2."""


def print_json(obj):
    """One JSON object on stdout; non-finite numbers (inf, nan) become null."""
    print(json.dumps(json_safe(obj), allow_nan=False))


def load_model(path):
    """The robot of ``--params FILE`` (default RABBIT)."""
    return rabbit(load_params(path) if path else None)


def load_gait(path, quiet: bool = False):
    """The gait of ``--gait FILE``, or the default gait (optimised once, then cached).

    Without a file, a note goes to stderr when the default gait must be optimised
    (about 3 s), unless ``quiet``."""
    if path:
        return Gait.load(path)
    return default_gait(progress=None if quiet else _note)


def _note(message: str):
    if sys.stderr.isatty():
        print(message, file=sys.stderr, flush=True)


def positive(value, name):
    """``value`` if it is a positive finite number, else a UserError naming ``name``."""
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{name} must be a positive number, got {value!r}")
    return value
