"""Subcommands beyond ``biped model``; each registers itself with the parser."""
from __future__ import annotations

from .cli import _EXTRA_COMMANDS  # noqa: F401
