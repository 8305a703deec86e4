"""The ``biped`` command line (:mod:`analysis.cli` names it; loaded on first use).  Each
subcommand reads top to bottom and calls the library.

A user error (bad option or number, missing, unreadable or malformed file, an output
path that cannot be written, conflicting options, a request outside the model's
validity) prints one line on stderr naming the argument or file and exits with code 2,
without a traceback; output paths are checked before any long work.  ``--json`` prints
exactly one JSON object on stdout.  Numerical warnings of numpy are not printed: a
condition worth knowing is a status of the result, or one line on stderr.
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import warnings

import numpy as np

import biped_casadi
from biped_casadi.numerics import NotCompiledWarning
from biped_cli import interrupted

from . import (eig, export, export_running, gait, m1, mujoco, mujoco_running, reproduce,
               robot, robust, running, simulate, sweep, terrain, view)
from .common import UserError, add_robot, check_inputs, load_model, print_json
from .failures import debugging, failure_line
from .stdout import named_stdout

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
          f"{nq} joints, {model.nu} torques (limit {d.torque_limit_text}), g = {d.gravity:g}")
    for link in (d.torso,) + d.leg:
        print(f"  {link.name:8s} mass {link.mass:g} kg, length {link.length:g} m, "
              f"com {link.com:g} m" + (f" (off its line by {link.com_offset:g} m)"
                                   if link.com_offset else "")
              + f", inertia {link.inertia:g} kg m^2")
    for joint, m in d.point_masses:
        print(f"  point mass {m:g} kg at the {joint}" + ("" if joint == "hip" else " (each leg)"))
    print(f"  rotor inertia {d.rotor_inertia:g} kg m^2 on each actuated joint")
    print("joints: " + ", ".join(f"q{i + 1} {n}" for i, n in enumerate(model.joint_names)))
    print(f"q = {np.array2string(q, precision=4)}")
    print("D(q) =")
    print(np.array2string(np.array(s["D"]), precision=6, suppress_small=True))
    print("H(q, 0) = G(q) =")
    print(np.array2string(np.array(s["H"]), precision=6, suppress_small=True))


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``biped eig: error: ... (see --help)``), and
    negative numbers in any notation taken as values (``--range -1e6 1e6``,
    ``--perturb-q -1e-3 ...``, ``--m1 -inf ...``, ``--speeds -1:1:0.5``), not as unknown
    options."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(
            r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$"
            r"|^-[\d.]+[eE0-9+-]*:[^ ]*$", re.IGNORECASE)     # and -A:B:STEP ranges

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {_one_line(message)} (see '{self.prog} "
                     f"--help')\n")


def _one_line(text) -> str:
    return " ".join(str(text).split())


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(
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
    add_robot(p, with_gait=False)
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configuration q1..qn in rad (RABBIT: 5 numbers; default: upright, "
                        "q = 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_model)

    for command in (robot, gait, running, eig, sweep, m1, robust, simulate, terrain, export,
                    export_running, mujoco, mujoco_running, reproduce, view):
        command.register(sub)
    return ap


def main(argv=None) -> int:
    """Run ``biped`` with ``argv`` (default: the process's arguments); returns the exit
    code: 0 done, 1 a stage or run failed, 2 a user error or a failed computation (one
    line, :mod:`analysis.cli.failures`), 130 interrupted."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:        # argparse already printed its one-line usage error
        return int(e.code or 0)
    except KeyboardInterrupt:      # building the parser takes some 20 ms
        return interrupted(argv)
    ctrl_c = _CtrlC()
    try:
        with warnings.catch_warnings(record=True) as caught, ctrl_c, named_stdout():
            warnings.simplefilter("default")
            check_inputs(args)
            rc = args.func(args)
        _note_warnings(args.command, caught)
    except Exception:
        if not ctrl_c:
            return _failed(args, sys.exc_info()[1])
        print(f"biped {args.command}: interrupted", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"biped {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


class _CtrlC:
    """Whether Ctrl-C was pressed while a command ran: an error that follows it (a
    library may turn the KeyboardInterrupt into its own error, e.g. CasADi's SystemError
    inside a task) is the interruption, not a failure.  Python's handler is kept (it
    raises KeyboardInterrupt); it is only observed, from the main thread.

    Python raises it wherever the main thread runs, and there it can vanish: in a
    weakref's callback or a finalizer it is printed ("Exception ignored in ...") and
    dropped; in Python code that a library calls it may be cleared (CasADi's operators
    call ``shape`` while they choose an overload, and go on with the next one).  The
    command then ran on to its end.  So the main thread is sent SIGINT again, later and
    later, until the command has ended: raised again unless an error is already on its
    way out (the interruption's, met in the command's clean-up)."""

    #: after a Ctrl-C, the main thread is sent SIGINT again this much later, s (then
    #: twice as late each time, at most 1 s)
    AGAIN = 0.05

    def __init__(self):
        self.pressed, self._old, self._hook, self._thread = False, None, None, None
        self._wake, self._ended = threading.Event(), threading.Event()

    def __bool__(self):
        return self.pressed

    def __enter__(self):
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
            self._old = signal.default_int_handler
            signal.signal(signal.SIGINT, self._handler)
            self._hook, sys.unraisablehook = sys.unraisablehook, self._dropped
            # started here: a thread started in the handler could wait for a lock the
            # interrupted code holds
            self._thread = threading.Thread(target=self._again, daemon=True)
            self._thread.start()
        return self

    def _handler(self, signum, frame):
        if self._ended.is_set() or (self.pressed and sys.exc_info()[1] is not None):
            return
        self.pressed = True
        self._wake.set()
        signal.default_int_handler(signum, frame)

    def _again(self):
        """A thread: once Ctrl-C is pressed, SIGINT to the main thread, later and later."""
        delay, main = self.AGAIN, threading.main_thread().ident
        self._wake.wait()
        while not self._ended.wait(delay):
            signal.pthread_kill(main, signal.SIGINT)
            delay = min(2 * delay, 1.0)

    def _dropped(self, unraisable):
        """sys.unraisablehook: a dropped Ctrl-C is not printed (it is raised again)."""
        if not (self.pressed and issubclass(unraisable.exc_type, KeyboardInterrupt)):
            self._hook(unraisable)

    def __exit__(self, *exc):
        self._ended.set()
        if self._thread is not None:
            self._wake.set()
            self._thread.join()
            signal.signal(signal.SIGINT, self._old)   # (after a SIGINT sent meanwhile)
            sys.unraisablehook = self._hook
        return False


def _failed(args, e: BaseException) -> int:
    """The exit code and one line for an error of a command (not an interruption)."""
    try:
        raise e
    except (UserError, ValueError) as e:           # GaitFileError, SweepStoreError, ...
        if not isinstance(e, UserError) and debugging():
            raise                                  # a library's: where it came from
        print(f"biped {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except BrokenPipeError:        # output piped into `head` and the like
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:                           # a file or folder we cannot use
        where = f"{e.filename}: " if e.filename else ""
        print(f"biped {args.command}: error: {where}{_one_line(e.strerror or e)}",
              file=sys.stderr)
        return 2
    except Exception as e:           # a failed task or solver (analysis.cli.failures)
        line = failure_line(e)
        if line is None:
            raise
        print(f"biped {args.command}: error: {line}", file=sys.stderr)
        return 2


def _note_warnings(command: str, caught):
    """Numerical warnings (numpy's RuntimeWarning) become at most one line; the result's
    status already says whether the computation failed.  Others (deprecations of the
    libraries underneath) are not the user's business and are dropped; compiled code
    that could not be built is a note of its own (the run is slower)."""
    for text in dict.fromkeys(str(w.message) for w in caught
                              if issubclass(w.category, NotCompiledWarning)):
        print(f"biped {command}: note: {text}", file=sys.stderr)
    numeric = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    if numeric:
        print(f"biped {command}: note: {len(numeric)} numerical warning(s) during the "
              f"computation (first: {_one_line(numeric[0].message)}); check the status "
              "of the results", file=sys.stderr)
