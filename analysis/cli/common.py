"""What every subcommand shares: the user-error type, JSON output, progress lines, the
``--robot`` option, checks of output paths (made before any long work), loading the
model and the gait named on the command line."""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from analysis.cluster import DASK_CONNECT_TIMEOUT, check_workers, connect
from analysis.tasks import resolve_scheduler
from biped_casadi import robot
from biped_casadi.caching import code_edited
from biped_casadi.control.running import check_running_gait
from biped_casadi.control.output_law import (M1_LIMIT, SECTION, check_M1_range, check_rejoin,
                                             require_regular)
from biped_casadi.results import json_safe
from biped_casadi.simulation.options import DEFAULT_MU, friction_of
from gait_opt import Gait, OpenOrbitWarning, optimize_gait
from gait_opt.running import RunningGait

__all__ = ["UserError", "print_json", "load_model", "load_gait", "load_running_gait", "positive", "add_robot",
           "parse_m1", "check_m1_values", "Progress", "output_file", "output_dir",
           "add_gait_arguments", "add_scheduler", "is_family_file", "require_members",
           "check_inputs", "check_scheduler", "scheduler_and_gait", "not_an_input", "MU_HELP", "gait_friction",
           "friction_source"]

ROBOT_HELP = ("the robot: a built-in name (rabbit, three_link), a description file "
              "(.toml, schema in biped_casadi.model.description) or a URDF file (.urdf)")


class UserError(Exception):
    """An input problem the user can fix; reported as one line, exit code 2."""


def print_json(obj):
    """One JSON object on stdout; non-finite numbers (inf, nan) become null."""
    print(json.dumps(json_safe(obj), allow_nan=False))


# ------------------------------------------------------------------- progress
class Progress:
    """One line on stderr before each wait of more than a couple of seconds.

    Shown only when stderr is a terminal and the output is for a person (not ``--json``);
    a pipe, a log file or ``--json`` keeps stderr for errors only.
    """

    def __init__(self, command: str, quiet: bool = False):
        self.command = command
        self.enabled = not quiet and sys.stderr.isatty()

    def __call__(self, message: str):
        if self.enabled:
            print(f"biped {self.command}: {message}", file=sys.stderr, flush=True)


# --------------------------------------------------------- robot, model, gait
def add_robot(p, with_gait: bool = True):
    """Add ``--robot NAME|FILE`` to a subcommand's parser."""
    default = ("default: the gait file's robot, else rabbit" if with_gait
               else "default: rabbit")
    p.add_argument("--robot", metavar="NAME|FILE", help=f"{ROBOT_HELP}; {default}")


#: the options that name an input (a file, or a robot by name), as the user writes them
INPUT_OPTIONS = {"robot": "--robot", "gait": "--gait", "family": "--family",
                 "import_file": "--import", "plant": "--plant", "schedule": "--schedule",
                 "terrain": "--terrain", "file": "FILE"}


def check_inputs(args):
    """UserError for an input option given an empty value (``--robot ""``, ``--gait ""``
    from an unset shell variable): it meant the default robot or gait before."""
    for dest, option in INPUT_OPTIONS.items():
        v = getattr(args, dest, None)
        if isinstance(v, str) and not v.strip():
            raise UserError(f"{option}: empty name (leave the option out for the default)")


def add_gait_arguments(p, required: bool = False):
    """``--gait FILE`` and ``--allow-open-orbit`` on a subcommand's parser."""
    p.add_argument("--gait", metavar="FILE", required=required,
                   help="gait file from 'biped gait'" + ("" if required else
                        " (default: the robot's default gait, optimised once and cached)"))
    p.add_argument("--allow-open-orbit", action="store_true",
                   help="analyse a gait file that is not a periodic orbit of its robot "
                        "(refused by default; a warning line says by how much it misses)")


def load_model(name_or_path):
    """The robot of ``--robot NAME|FILE`` (default RABBIT); ValueError (exit 2) when the
    name is unknown or the file missing or invalid."""
    try:
        return robot(name_or_path or "rabbit")
    except OSError as e:                  # a name too long, a loop of links, ...
        raise UserError(f"--robot: {_short(name_or_path)}: {e.strerror or e}") from None


def load_running_gait(args):
    """The running step of ``--gait FILE`` and its robot: ``--robot``, else the one the
    file names (UserError, exit 2: a file that cannot be read, a robot that is not
    built in without ``--robot FILE``, a ``--robot`` that is another robot).

    Returns
    -------
    tuple
        (RunningGait, BipedModel).
    """
    try:
        gait = RunningGait.load(args.gait)
    except (ValueError, OSError) as e:
        kind = gait_file_kind(args.gait)
        if kind in ("gait", "family"):
            raise UserError(f"--gait: {_short(args.gait)} is a walking gait"
                            f"{' family' if kind == 'family' else ''} (from 'biped gait'), "
                            "not a running step: make one with 'biped running --out FILE'"
                            ) from None
        raise UserError(f"--gait: {e}") from None
    if args.robot is None:
        try:
            model = robot(gait.robot)
        except (ValueError, OSError):
            raise UserError(f"--gait: {args.gait} is a step of {gait.robot}, not a built-in "
                            "robot: give its description with --robot FILE") from None
    else:
        model = load_model(args.robot)
    if model.description.name != gait.robot:
        raise UserError(f"--gait: {args.gait} is a step of {gait.robot}, not of "
                        f"{model.description.name}")
    try:
        check_running_gait(gait, model, name=None)
    except ValueError as e:
        raise UserError(f"--gait: {args.gait}: not a running step of {gait.robot}: {e}") \
            from None
    return gait, model


def load_gait(args, progress: Progress):
    """The gait of ``args.gait``, or the robot's default gait (optimised once, then
    cached).

    With ``args.robot`` (``--robot``) and a file, the file must have been made for that
    robot (GaitFileError, exit 2, otherwise).  Without a file, ``progress`` announces the
    optimisation of the default gait (a few seconds) when it is not cached yet.  With
    ``args.allow_open_orbit``, a gait that is not a periodic orbit is loaded and one
    warning line goes to stderr (always: it qualifies every result that follows).  A robot
    without a torque limit (a URDF without effort limits) gets the command's
    ``--torque-limit`` for its default gait too."""
    robot_arg = getattr(args, "robot", None)
    if not args.gait:
        model, limit = load_model(robot_arg), getattr(args, "torque_limit", None)
        if math.isfinite(model.description.torque_limit):
            return optimize_gait(model, progress=progress, cache=True)
        if limit is None:
            how = "--torque-limit N" if hasattr(args, "torque_limit") else \
                "--gait FILE, made by 'biped gait --robot ... --torque-limit N --out FILE'"
            raise UserError(f"--robot: {_short(robot_arg)} has no torque limit (its URDF "
                            f"gives no effort limits) and its default gait needs one: "
                            f"give {how}")
        return optimize_gait(model, progress=progress, cache=True, torque_limit=float(limit))
    if is_family_file(args.gait):
        raise UserError(_family_where_one_gait(args.gait, progress.command))
    model = load_model(robot_arg) if robot_arg else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OpenOrbitWarning)
        try:
            gait = Gait.load(args.gait, model=model,
                             allow_open_orbit=getattr(args, "allow_open_orbit", False))
        except ValueError:
            if gait_file_kind(args.gait) == "running":
                raise UserError(f"--gait: {_short(args.gait)} is a running step (from 'biped "
                                "running'), not a walking gait: 'biped running --gait' and "
                                "'biped mujoco-running --gait' take it") from None
            raise
    for w in caught:
        if issubclass(w.category, OpenOrbitWarning):
            print(f"biped {progress.command}: warning: {w.message}", file=sys.stderr,
                  flush=True)
        else:                                         # not ours: pass it on
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return gait


#: how each command that also takes a family takes it
_FAMILY_USE = {"simulate": "; or walk it with --speeds V1 V2 ... or --ramp V1 V2 DV",
               "m1": "; 'biped m1 --robust' designs over a family"}


def _family_where_one_gait(path, command: str) -> str:
    """The one line for a gait family file given where one gait is taken."""
    return (f"--gait: {_short(path)} is a gait family file, not one gait: take one with "
            f"'biped gait --family {_short(path)} --speed V --out gait.json'"
            + _FAMILY_USE.get(command, ""))


def require_members(family, path, option: str):
    """UserError naming ``option`` when the family ``family`` read from ``path`` holds no
    gait yet (a family solve interrupted before its first speed)."""
    if not len(family):
        raise UserError(f"{option}: {_short(path)} holds no gait yet (its 'biped gait "
                        f"--speeds' run stopped before the first speed: rerun it to "
                        f"continue)")


#: the largest gait file whose kind is looked at (a gait file is tens of kilobytes)
_KIND_BYTES = 50_000_000


def gait_file_kind(path) -> str | None:
    """'running' (a step of 'biped running'), 'family', 'gait' (a walking gait) or None,
    from a regular file's JSON, without validating it (for the message of a file given
    where the other kind is taken)."""
    if is_family_file(path):
        return "family"
    try:
        if not os.path.isfile(path) or os.path.getsize(path) > _KIND_BYTES:
            return None
        body = json.loads(Path(path).read_text())
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(body, dict):
        return None
    if body.get("kind") == "running gait":
        return "running"
    return "gait" if body.get("format") == "biped-casadi-gait" else None


def is_family_file(path) -> bool:
    """Whether ``path`` looks like a gait family file (its format field), without
    validating it (the loader does, with its own errors).  Only a regular file is
    opened: reading a named pipe (a FIFO) waited for a writer forever."""
    try:
        if not os.path.isfile(path):
            return False
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", "ignore")
    except OSError:
        return False
    return '"biped-casadi-gait-family"' in head


def check_not_singular(controller, M1, where: str = "the reference step"):
    """Refuse (UserError) a time-varying controller singular on its step (eq. 24;
    :func:`biped_casadi.control.output_law.require_regular`)."""
    try:
        require_regular(controller, M1, where)
    except ValueError as e:
        raise UserError(str(e)) from None


def figure_or_na(x, fmt) -> str:
    """A figure of a run: 'inf' for a friction ratio where F_z <= 0, 'n/a' when the run
    never produced it (no impact: None or NaN)."""
    if x is None:
        return "n/a"
    return format(x, fmt) if math.isfinite(x) else "inf" if x == math.inf else "n/a"


def check_m1_values(values):
    """What can be checked of ``--m1`` before the robot is known: finite, and within the
    model's numerical validity (UserError otherwise)."""
    if values is None:
        return
    M1 = np.array(values, dtype=float)
    if not np.all(np.isfinite(M1)):
        raise UserError("--m1 values must be finite")
    try:
        check_M1_range(M1, "--m1")
    except ValueError as e:
        raise UserError(str(e)) from None


def m1_required(nu: int | None = None) -> UserError:
    """The error of a time-varying design without ``--m1`` (with the robot's count when
    it is known)."""
    count = f": {nu} for this robot" if nu else ""
    return UserError(f"--m1 is required for the time-varying controller (one number per "
                     f"torque{count})")


def parse_m1(values, nu: int, default_zero: bool = False):
    """``--m1`` as a vector of the robot's nu components (UserError otherwise)."""
    if values is None:
        if default_zero:
            return np.zeros(nu)
        raise m1_required(nu)
    M1 = np.array(values, dtype=float)
    if M1.shape != (nu,):
        raise UserError(f"--m1 takes {nu} numbers for this robot (one per torque), "
                        f"got {M1.size}")
    check_m1_values(M1)
    return M1


def positive(value, name):
    """``value`` if it is a positive finite number, else a UserError naming ``name``."""
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{name} must be a positive number, got {value!r}")
    return value


def check_torque_limit(args, clip_only: bool = False):
    """``--torque-limit``: a positive number; where it is only the limit ``--saturate``
    clips at (``clip_only``), ``--saturate`` too (UserError, one line).

    Parameters
    ----------
    args : argparse.Namespace
        With ``torque_limit`` and ``saturate``.
    clip_only : bool
        The command gives ``--torque-limit`` no other meaning.
    """
    if args.torque_limit is None:
        return
    positive(args.torque_limit, "--torque-limit")
    if clip_only and not args.saturate:
        raise UserError("--torque-limit is the limit --saturate clips at (add --saturate)")


def check_saturation(args, model):
    """``--saturate`` needs a limit to clip at: the robot's, or ``--torque-limit``
    (UserError, one line, naming the robot).

    Parameters
    ----------
    args : argparse.Namespace
        With ``torque_limit`` and ``saturate``.
    model : BipedModel
        The robot.
    """
    if args.saturate and args.torque_limit is None \
            and not math.isfinite(model.description.torque_limit):
        raise UserError(f"--saturate: the robot {model.params.name} has no torque limit to "
                        "clip at: give --torque-limit U")


#: --help of --mu in the commands that judge a gait: its default
MU_HELP = (f"default: the one the gait was optimised for, its 'biped gait --mu'; "
           f"{DEFAULT_MU:g} for a gait that records none")


def friction_source(gait, mu=None) -> str:
    """Where the friction coefficient of a run on ``gait`` comes from
    (:func:`~biped_casadi.simulation.options.friction_of`): '--mu' (``mu`` given), "the
    gait's" (the one it was optimised for) or 'default' (0.6)."""
    if mu is not None:
        return "--mu"
    if getattr(getattr(gait, "options", None), "mu", None) is not None:
        return "the gait's"
    return "default"


def gait_friction(args, gait) -> str:
    """Set ``args.mu`` to the friction coefficient the run is held to: ``--mu``, else the
    one ``gait`` was optimised for, else 0.6 (as the simulators do without ``--mu``).

    Returns
    -------
    str
        The coefficient and where it came from, for the command's output.
    """
    source = friction_source(gait, args.mu)
    args.mu = friction_of(gait, args.mu)
    return f"mu {args.mu:g}, {source}"


def add_design_arguments(p, m1_zero: bool = False, rejoin_default=None,
                         m1_default: str = "all zero"):
    """--controller, --m1 and --rejoin: which controller, and a time-varying design.

    ``m1_zero``: --m1 has a default, ``m1_default`` in words (else --controller tv
    needs it); ``rejoin_default``: the parsed default of --rejoin (None: the command's
    own, 0.5)."""
    p.add_argument("--controller", choices=("tv", "vc"), default="tv",
                   help="tv: time-varying outputs [M1, I] q (default" +
                        ("" if m1_zero else ", needs --m1") + "); vc: virtual constraints")
    p.add_argument("--m1", nargs="+", type=float, metavar="M1",
                   help="the components of M1 for --controller tv, one per torque" +
                        (f", each within +-{M1_LIMIT:.0e} (default {m1_default})" if m1_zero
                         else ""))
    p.add_argument("--rejoin", type=float, metavar="R", default=rejoin_default,
                   help=f"time at which v_c rejoins the reference, fraction of T in "
                        f"(0, {SECTION}] (default 0.5, the paper's)")


def rejoin_fraction(value) -> float:
    """``--rejoin`` checked (:func:`biped_casadi.control.output_law.check_rejoin`), else a
    UserError."""
    try:
        return check_rejoin(value, "--rejoin")
    except ValueError as e:
        raise UserError(str(e)) from None


# ---------------------------------------------------------------- output paths
def _nearest_existing(path: Path) -> Path:
    """The deepest existing ancestor of ``path`` (as the user wrote it, when possible)."""
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path.cwd()


def _probe(folder: Path, option: str, shown: Path):
    """UserError unless a file can be created in ``folder`` (tried, then removed: the
    permission bits alone do not say it for root or a read-only file system)."""
    try:
        fd, name = tempfile.mkstemp(prefix=".biped-write-test-", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as e:
        raise UserError(f"{option}: cannot write in {shown} ({e.strerror or e})") from None


def _checked(fn):
    """An OS error while looking at a path (a name too long, a loop of links) is a user
    error naming the option too."""
    def wrapper(path, option, *args, **kwargs):
        try:
            return fn(path, option, *args, **kwargs)
        except OSError as e:
            raise UserError(f"{option}: {_short(path)}: {e.strerror or e}") from None
    wrapper.__doc__, wrapper.__name__ = fn.__doc__, fn.__name__
    return wrapper


def _short(path) -> str:
    """A path for a one-line message (very long ones abbreviated)."""
    s = str(path)
    return s if len(s) <= 160 else f"{s[:100]}...{s[-40:]}"


@_checked
def output_dir(path, option: str) -> Path:
    """Check, before any long work, that ``path`` is (or can be created as) a folder we
    may write in.  Nothing is created here: the command creates the folder when it
    writes its first file.

    Raises
    ------
    UserError
        Naming ``option`` when ``path`` is empty, is a file, lies under a file, or is
        (or would be created in) a folder we cannot write in.
    """
    if path is None or str(path).strip() == "":
        raise UserError(f"{option}: empty folder name")
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise UserError(f"{option}: {p} is a file, not a folder")
        _probe(p, option, p)
        return p
    _creatable(p, option, f"cannot create folder {p}")
    return p


def _creatable(folder: Path, option: str, what: str):
    """UserError unless the missing ``folder`` can be created: its deepest existing
    ancestor is a folder we may write in (``what`` begins the message otherwise)."""
    anc = _nearest_existing(folder)
    if not anc.is_dir():
        raise UserError(f"{option}: {what}: {anc} is a file, not a folder")
    _probe(anc, option, anc)


@_checked
def output_file(path, option: str, suffixes: tuple = ()) -> Path:
    """Check, before any long work, that a file can be written at ``path``: not a folder
    or a device, its folder writable or (when missing) creatable, and (if ``suffixes``)
    its suffix is one of them.  Nothing is created here: the file's missing folders are
    created when it is written (:func:`biped_casadi.files.atomic_path`), as an output
    folder's (:func:`output_dir`).

    Raises
    ------
    UserError
        Naming ``option`` and the reason.
    """
    if path is None or str(path).strip() == "":
        raise UserError(f"{option}: empty file name")
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{option}: {p} is a folder; give a file name")
    if p.exists() and not p.is_file():
        raise UserError(f"{option}: {p} exists and is not a regular file")
    if suffixes and p.suffix.lower() not in suffixes:
        raise UserError(f"{option}: the file name must end in {' or '.join(suffixes)}, "
                        f"got {str(path)!r}")
    folder = p.parent
    if not folder.exists():
        _creatable(folder, option, f"cannot write {p}")
        return p
    if not folder.is_dir():
        raise UserError(f"{option}: cannot write {p}: {folder} is a file, not a folder")
    _probe(folder, option, folder)
    return p


#: --workers of a local cluster: processes, each of which builds its own CasADi functions
MAX_WORKERS = 64


def not_an_input(out, option: str, inputs: dict):
    """UserError when the output ``out`` of ``option`` is one of the command's input files
    (``inputs``: option -> path or None): writing it replaced the input (a gait family
    given with --family and --out was overwritten by the one gait taken from it)."""
    for name, path in inputs.items():
        if path is None:
            continue
        try:
            same = Path(out).resolve() == Path(path).resolve() or (
                Path(out).exists() and os.path.samefile(out, path))
        except (OSError, RuntimeError):
            same = False
        if same:
            raise UserError(f"{option}: {_short(out)} is the {name} file; writing there "
                            f"would replace it (give another file name)")


def _workers(text) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if not 1 <= n <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_WORKERS}, got {n}")
    return n


def check_scheduler(scheduler, say=None):
    """``--scheduler``: not empty, and a scheduler given by address answers (UserError
    otherwise), before any work: a run of tasks on an address that does not answer
    reported every stage's failure and left its output folder behind.  And this
    process's own code: a file of it changed on disk since the command imported the
    toolkit failed the flows and the tasks the command runs itself, one by one
    (:mod:`analysis.tasks`).  The code's digest, read here, is needed by the first task
    anyway: the check adds a stat per file (some 0.3 ms)."""
    if edited := code_edited():
        raise UserError(f"stale code: {edited} changed on disk after this command started "
                        "(it imported the toolkit); restart the command")
    if scheduler is None:
        return
    if not scheduler.strip():
        raise UserError("--scheduler: empty address")
    scheduler = resolve_scheduler(scheduler)          # the engine's spellings
    if scheduler in ("synchronous", "local"):
        return
    if say is not None:
        say(f"connecting to the Dask scheduler at {scheduler} (up to "
            f"{DASK_CONNECT_TIMEOUT}) ...")
    try:
        client = connect(scheduler)[0]
        try:
            check_workers(client)                  # a stale worker: one line, no report
        finally:
            client.close()
    except ValueError as e:
        raise UserError(f"--{e}") from None


def scheduler_and_gait(args, say):
    """:func:`check_scheduler` and :func:`load_gait` in the order that refuses bad input
    before any work: a gait file (``--gait``), or else the robot (``--robot``), is read
    first (a missing one waited for the code's digest and the scheduler's answer before
    its one line), the robot's default gait after the check (optimising it is work).

    Parameters
    ----------
    args : argparse.Namespace
        With ``gait`` and ``scheduler`` (and what :func:`load_gait` reads).
    say : Progress
        The command's progress lines.

    Returns
    -------
    Gait
    """
    gait = load_gait(args, say) if args.gait else load_model(getattr(args, "robot", None))
    check_scheduler(args.scheduler, say)
    return gait if args.gait else load_gait(args, say)


def add_scheduler(p):
    """``--scheduler ADDRESS`` and ``--workers N``: where the tasks run, the same meaning
    for every command (:func:`analysis.tasks.resolve_scheduler`)."""
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the tasks on an existing Dask cluster (tcp://host:8786; start "
                        "one with 'dask scheduler' and 'dask worker tcp://host:8786'); "
                        "default: a local cluster of one worker process per core")
    p.add_argument("--workers", type=_workers, metavar="N",
                   help="worker processes of the local cluster (default: the cores; 1: "
                        "everything in this process)")
