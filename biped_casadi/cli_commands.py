"""Subcommands beyond ``biped model``.  Each module listed here defines
``register(subparsers)``; one line per module keeps additions independent."""
from __future__ import annotations

import importlib

from .cli import _EXTRA_COMMANDS

MODULES = [
    "cli_simulate",
    "cli_gait",
    "cli_sweep",
    "cli_analysis",
    "cli_design",
    "cli_reproduce",
]

for _name in MODULES:
    _EXTRA_COMMANDS.append(importlib.import_module(f"biped_casadi.{_name}").register)
