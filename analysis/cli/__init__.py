"""The ``biped`` command line (:mod:`analysis.cli.app`).  Each subcommand reads top to
bottom and calls the library.

Importing this package loads nothing else: :mod:`analysis.cli.app` and what it needs
(a second or two) load on first use of a name, so that ``python -m analysis.cli``, like
``biped``, loads them where a Ctrl-C ends the command with one line and exit code 130
(:mod:`biped_cli`) rather than a traceback of the imports.
"""
from importlib import import_module

__all__ = ["main", "build_parser", "UserError"]


def __getattr__(name: str):
    """A name of :mod:`analysis.cli.app` (``main``, ``build_parser``, ``UserError``, ...)."""
    if not name.startswith("__"):
        try:
            return getattr(import_module(".app", __name__), name)
        except AttributeError:
            pass
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
