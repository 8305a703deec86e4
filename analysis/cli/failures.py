"""A computation that fails on the command line: one line on stderr and exit code 2.

The subcommands turn the errors they expect into :class:`~analysis.cli.common.UserError`
themselves; whatever else reaches :func:`analysis.cli.main` -- a failed task of the
engine (:class:`analysis.tasks.TaskError`, which carries its task's error as text), a
solver that did not converge (:class:`gait_opt.GaitOptimizationError`, CasADi's
``RuntimeError``), or an error nobody expected -- is said here in one line, never as a
traceback.  ``BIPED_DEBUG=1`` in the environment lets the traceback through instead
(for a bug report).
"""
from __future__ import annotations

import os
import re

from gait_opt import GaitOptimizationError

from ..tasks import TaskError

__all__ = ["failure_line", "debugging", "DEBUG_ENV"]

#: set (to anything but '' or '0') to see the traceback of a failure
DEBUG_ENV = "BIPED_DEBUG"

#: the ``Type: `` prefix of an error carried as text
_TYPE = re.compile(r"^([A-Za-z_][\w.]*): ")

#: errors of the code itself (a bug), not of the computation: said as internal errors
_BUGS = ("KeyError", "IndexError", "AttributeError", "TypeError", "NameError",
         "AssertionError", "ZeroDivisionError", "UnboundLocalError", "NotImplementedError",
         "RecursionError")

#: at most this many characters of a message (a solver's can be pages long)
MAX_CHARS = 600

#: Dask's words for the tasks it drops when the run loses its scheduler or workers (the
#: future's CancelledError, or its text inside a flow's TaskError)
_DROPPED = re.compile(r"cancelled for reason: ([^.\s]+)")


def _one_line(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_CHARS else text[:MAX_CHARS - 3] + "..."


def debugging() -> bool:
    """Whether ``BIPED_DEBUG`` asks for tracebacks.

    Returns
    -------
    bool
    """
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def failure_line(error: BaseException) -> str | None:
    """The one line that reports ``error``, or None to let it through.

    Parameters
    ----------
    error : BaseException
        What reached the command line's top level.

    Returns
    -------
    str or None
        None for what is not a failure of the computation (an interrupt, an exit) and
        for everything while ``BIPED_DEBUG`` is set.
    """
    if not isinstance(error, Exception) or debugging():
        return None
    dropped = _DROPPED.search(str(error.message if isinstance(error, TaskError) else error))
    if dropped:
        return (f"the Dask cluster dropped the run's tasks ({dropped.group(1)}): start its "
                "scheduler and workers again and run the same command (it resumes from the "
                "results kept so far)")
    if isinstance(error, TaskError):
        text = str(error.message)
        m = _TYPE.match(text)
        name = m.group(1).rsplit(".", 1)[-1] if m else ""
        if name not in _BUGS:      # its text is written for the user (no type: the engine's)
            return _one_line(text[m.end():] if m else text)
        return _one_line(f"task {error.origin.rsplit('.', 1)[-1]} failed: {text} (an internal "
                         f"error: {DEBUG_ENV}=1 shows its traceback)")
    if isinstance(error, GaitOptimizationError):
        return _one_line(str(error))
    if isinstance(error, RuntimeError):                # CasADi's solvers and functions
        return _one_line(f"{error} ({DEBUG_ENV}=1 shows the traceback)")
    return _one_line(f"internal error: {type(error).__name__}: {error} ({DEBUG_ENV}=1 shows "
                     "the traceback)")
