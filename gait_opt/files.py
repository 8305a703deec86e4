"""The gait file: a self-describing JSON record of a reference gait, and its validation.

A file holds ``format``, ``version``, ``robot`` (the robot description), ``options``
(:class:`~gait_opt.GaitOptions`), ``solution`` (T, alpha, x0), optionally
``solver_stats``, and ``sha256``, the :func:`biped_casadi.caching.digest` of the rest.
:func:`read_gait_file` reads and checks the envelope; :func:`gait_parts` validates the
robot, options and solution of a file's body or of a gait's
:meth:`~gait_opt.Gait.definition` (what is sent to sweep and Monte Carlo workers), so
:meth:`Gait.load <gait_opt.Gait.load>` and :meth:`Gait.from_dict <gait_opt.Gait.from_dict>`
read the same way.  Every problem is a :class:`GaitFileError` naming the file and the
reason.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from biped_casadi import RobotParams, description_from_dict, robot
from biped_casadi.caching import digest
from biped_casadi.files import read_text_file

from .options import GaitOptions

__all__ = ["GaitFileError", "OpenOrbitWarning", "FORMAT", "FORMAT_VERSION", "read_gait_file",
           "gait_body", "gait_parts", "checksum_error"]

FORMAT = "biped-casadi-gait"
FORMAT_VERSION = 1
#: a gait file larger than this is not one this toolkit wrote
MAX_FILE_BYTES = 20_000_000
#: RK4 steps per step (``polish_steps``) and Bezier degree a readable file may ask for
MAX_POLISH_STEPS = 1_000_000
MAX_BEZIER_DEGREE = 40
#: the keys of a gait file (``solver_stats`` optional)
_KEYS = ("format", "version", "robot", "options", "solution", "sha256")


class GaitFileError(ValueError):
    """A gait file that cannot be used; the message names the file and the reason.

    Missing, not a file, unreadable, corrupted, other format or version, malformed
    contents, made for other robot parameters, or not a periodic orbit of its robot
    (:data:`ORBIT_TOL`).  A ``ValueError``.
    """


class OpenOrbitWarning(UserWarning):
    """Warning: a gait read with ``allow_open_orbit=True`` is not a periodic orbit.

    Issued by ``Gait.load(..., allow_open_orbit=True)``: results computed from such a
    gait (fixed points, eigenvalues) are not those of a walking cycle.
    """


def read_gait_file(path: Path) -> dict:
    """The body of a gait file, its envelope checked: format, version, checksum, keys.

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    dict
        The body without the checksum.

    Raises
    ------
    GaitFileError
        Naming the file and what is wrong.
    """
    try:
        body = _read_json(path)
    except GaitFileError as e:
        raise GaitFileError(_another_input(path) or str(e)) from None
    if not (isinstance(body, dict) and body.get("format") == FORMAT):
        hint = _another_input(path, body)
        if hint:
            raise GaitFileError(hint)
    return gait_body(body, f"gait file {path}", str(path))


#: the suffixes of the toolkit's other inputs: a sampled step to import, a robot
_STEP_SUFFIXES = (".csv", ".npz")
_ROBOT_SUFFIXES = (".toml", ".urdf")


def _another_input(path: Path, body=None) -> str:
    """The message for a file given as a gait file that is one of the toolkit's other
    inputs (a sampled step, which becomes a gait by import; a robot description), by its
    suffix or its JSON ``body``; '' for anything else (the reader's own message)."""
    path = Path(path)
    try:
        if not path.is_file():
            return ""
    except OSError:                       # a name too long, say: the reader's own line
        return ""
    keys = set(body) if isinstance(body, dict) else set()
    if path.suffix.lower() in _STEP_SUFFIXES or {"t", "q", "dq"} <= keys \
            or "virtual_constraints" in keys:
        return (f"{path} is a sampled step, not a gait file: make a gait of it with "
                f"gait_opt.import_gait (on the command line 'biped gait --import {path} "
                f"--out gait.json', then --gait gait.json)")
    if path.suffix.lower() in _ROBOT_SUFFIXES or {"torso", "leg"} <= keys:
        return (f"{path} is a robot description, not a gait file: load it with "
                f"biped_casadi.robot (on the command line --robot {path})")
    return ""


def gait_body(body, where: str, name: str | None = None) -> dict:
    """A gait file's parsed JSON, its envelope checked: format, version, checksum, keys.

    Parameters
    ----------
    body : object
        The parsed JSON (a gait file's, or a member of a gait family file).
    where : str
        What it is, for the messages ('gait file PATH').
    name : str, optional
        How the messages about the format name it (default ``where``).

    Returns
    -------
    dict
        A copy of the body without the checksum.

    Raises
    ------
    GaitFileError
        Naming ``where`` and what is wrong.
    """
    name = where if name is None else name
    if not isinstance(body, dict) or body.get("format") != FORMAT:
        raise GaitFileError(f"{name} is not a {FORMAT} file")
    if body.get("version") != FORMAT_VERSION:
        raise GaitFileError(f"{name} has format version {body.get('version')!r}; this "
                            f"toolkit reads version {FORMAT_VERSION}")
    body = dict(body)
    checksum = body.pop("sha256", None)
    if checksum != digest(body):
        raise checksum_error(where, checksum)
    missing = [k for k in _KEYS if k != "sha256" and k not in body]
    unknown = sorted(set(body) - set(_KEYS) - {"solver_stats"})
    if missing or unknown:
        raise GaitFileError(f"{where}: " + "; ".join(
            ([f"missing key(s): {', '.join(missing)}"] if missing else [])
            + ([f"unknown key(s): {', '.join(unknown)}"] if unknown else [])))
    return body


def checksum_error(where: str, checksum) -> GaitFileError:
    """The error of a file whose ``sha256`` is missing (``checksum`` None) or is not the
    digest of the rest: what happened, and what to do instead of editing it."""
    what = ("has no 'sha256' checksum" if checksum is None else
            "is corrupted or was edited (checksum mismatch)")
    return GaitFileError(f"{where} {what}: only the numbers the toolkit wrote are read; "
                         f"write the file again, or import a step edited by hand "
                         f"(gait_opt.import_gait, 'biped gait --import')")


def gait_parts(body: dict, model, where: str):
    """The validated parts of a gait's record: (model, options, (alpha, x0, T), stats).

    Parameters
    ----------
    body : dict
        ``robot``, ``options``, ``solution`` and optionally ``solver_stats``.
    model : BipedModel or None
        The robot the record must describe (None: its own).
    where : str
        What the record is, for the messages.

    Returns
    -------
    tuple
        (model, GaitOptions, (alpha, x0, T), solver statistics dict).

    Raises
    ------
    GaitFileError
        Naming ``where`` and what is wrong.
    """
    if not isinstance(body, dict):
        raise GaitFileError(f"{where}: must be an object, got {type(body).__name__}")
    missing = [k for k in ("robot", "options", "solution") if k not in body]
    if missing:
        raise GaitFileError(f"{where}: missing key(s): {', '.join(missing)}")
    model = _robot_from_file(body["robot"], model, where)
    opts = _options_from_file(body["options"], where)
    solution = _solution_from_file(body["solution"], opts, model.nu, where)
    stats = body.get("solver_stats", {})
    if not isinstance(stats, dict):
        raise GaitFileError(f"{where}: 'solver_stats' must be an object, got "
                            f"{type(stats).__name__}")
    return model, opts, solution, stats


def _read_json(path: Path):
    """The parsed JSON of a gait file, or GaitFileError naming the file and the reason."""
    try:
        text = read_text_file(path, "gait file", MAX_FILE_BYTES)
    except ValueError as e:
        raise GaitFileError(str(e).replace("is not a text file", "is not a text (JSON) file")
                            ) from None
    if not text.strip():
        raise GaitFileError(f"gait file {path} is empty")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as e:
        raise GaitFileError(f"gait file {path} is not valid JSON (truncated or "
                            f"corrupted?): {e}") from None


def _robot_from_file(record, model, where: str):
    """The model a gait file describes (its ``robot`` record: a robot description, or the
    flat parameters of files written before descriptions), checked against ``model``
    when given.  The one place that reads the robot part of a gait file."""
    try:
        if RobotParams.is_legacy_record(record):
            params = RobotParams.from_dict(record).to_description()
        else:
            params = description_from_dict(record, where=f"{where}: 'robot'")
    except (KeyError, TypeError, ValueError) as e:
        msg = str(e)
        raise GaitFileError(msg if msg.startswith(where) else
                            f"{where}: invalid 'robot': {msg}") from None
    if model is None:
        return robot(params)
    if model.params != params:
        mine, theirs = _flat(model.params.to_dict()), _flat(params.to_dict())
        diff = [f"{k} ({theirs.get(k)!r} in the file, {mine.get(k)!r} in the model)"
                for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)]
        more = f", and {len(diff) - 3} more" if len(diff) > 3 else ""
        raise GaitFileError(f"{where} was made for other robot parameters "
                            f"(robot {params.name!r}, the model is {model.params.name!r}; "
                            f"differ in: {', '.join(diff[:3])}{more})")
    return model


def _flat(d, prefix: str = "") -> dict:
    """{'torso.mass': 12.0, 'leg[1].length': 0.4, ...} from a nested record."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        elif isinstance(v, list) and all(isinstance(x, dict) for x in v):
            for i, x in enumerate(v):
                out.update(_flat(x, f"{prefix}{k}[{i + 1}]."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _options_from_file(options, where: str) -> GaitOptions:
    if not isinstance(options, dict):
        raise GaitFileError(f"{where}: 'options' must be an object, got "
                            f"{type(options).__name__}")
    try:
        opts = GaitOptions.from_dict(options)
    except (TypeError, ValueError) as e:
        raise GaitFileError(f"{where}: invalid 'options': {e}") from None
    if opts.polish_steps > MAX_POLISH_STEPS or opts.bezier_degree > MAX_BEZIER_DEGREE:
        raise GaitFileError(f"{where}: 'options' asks for polish_steps "
                            f"{opts.polish_steps} and bezier_degree {opts.bezier_degree} "
                            f"(at most {MAX_POLISH_STEPS} and {MAX_BEZIER_DEGREE})")
    return opts


def _finite_number(v):
    """``v`` as a finite float if it is a JSON number (not a boolean), else None."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        f = float(v)
    except OverflowError:           # an integer beyond the float range
        return None
    return f if math.isfinite(f) else None


def _numbers(value, shape: tuple, what: str, where: str) -> np.ndarray:
    """``value`` (nested JSON lists) as a finite float array of ``shape``."""
    def ok(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    rows = value if len(shape) == 2 else [value]
    n_rows, n_cols = (shape if len(shape) == 2 else (1, shape[0]))
    expect = (f"{n_rows} rows of {n_cols} numbers" if len(shape) == 2
              else f"a list of {n_cols} numbers")
    if (not isinstance(value, list) or len(rows) != n_rows
            or not all(isinstance(r, list) and len(r) == n_cols for r in rows)):
        raise GaitFileError(f"{where}: solution.{what} must be {expect}")
    if not all(ok(v) for r in rows for v in r):
        raise GaitFileError(f"{where}: solution.{what} must hold only numbers")
    try:
        a = np.array(rows, dtype=float).reshape(shape)
    except OverflowError:
        a = np.full(shape, np.inf)
    if not np.all(np.isfinite(a)):
        raise GaitFileError(f"{where}: solution.{what} holds a non-finite number "
                            f"(NaN or infinity)")
    return a


def _solution_from_file(sol, opts: GaitOptions, nu: int, where: str):
    """(alpha, x0, T) of the ``solution`` entry, every field checked."""
    if not isinstance(sol, dict):
        raise GaitFileError(f"{where}: 'solution' must be an object with T, alpha, x0, "
                            f"got {type(sol).__name__}")
    missing = [k for k in ("T", "alpha", "x0") if k not in sol]
    unknown = sorted(set(sol) - {"T", "alpha", "x0"})
    if missing or unknown:
        raise GaitFileError(f"{where}: 'solution' " + "; ".join(
            ([f"lacks {', '.join(missing)}"] if missing else [])
            + ([f"has unknown key(s) {', '.join(unknown)}"] if unknown else [])))
    T = _finite_number(sol["T"])
    if T is None or T <= 0:
        raise GaitFileError(f"{where}: solution.T must be a positive finite number, "
                            f"got {sol['T']!r:.40}")
    alpha = _numbers(sol["alpha"], (nu, opts.bezier_degree + 1),
                     f"alpha (Bezier degree {opts.bezier_degree})", where)
    x0 = _numbers(sol["x0"], (2,), "x0", where)
    return alpha, x0, float(T)
