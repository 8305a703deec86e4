"""The gait family file: one JSON file holding a family's members and records.

A file holds ``format`` ('biped-casadi-gait-family'), ``version``, ``robot`` (the robot
description), ``options`` (the :class:`~gait_opt.GaitOptions` of the problem without
its speed), ``speeds`` (the requested grid), the family's ``status``, ``message``,
``events``, ``end``, ``total_time``, ``build_time``, one ``records`` entry per member,
``members`` (each a complete gait file body, its own ``sha256`` included: a member
written out alone is a gait file) and ``sha256``, the
:func:`biped_casadi.caching.digest` of the rest.  Reading checks all of it and every
member as :meth:`Gait.load <gait_opt.Gait.load>` checks a gait file (checksum, robot,
options, solution, a periodic orbit); every problem is a :class:`GaitFileError` naming
the file and the reason.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from biped_casadi.caching import digest
from biped_casadi.files import read_text_file, write_text_atomic

from .files import GaitFileError, checksum_error, gait_body
from .gait import Gait
from .options import GaitOptions

__all__ = ["FAMILY_FORMAT", "FAMILY_VERSION", "family_body", "write_family",
           "read_family_file", "options_record", "RECORD_FIELDS"]

FAMILY_FORMAT = "biped-casadi-gait-family"
FAMILY_VERSION = 1
#: a family file larger than this is not one this toolkit wrote
MAX_FAMILY_BYTES = 500_000_000
#: the fields of a member's record (:class:`gait_opt.speed_family.MemberRecord`)
RECORD_FIELDS = ("speed", "status", "iterations", "substeps", "failed_steps", "time", "T",
                 "step_length", "cost", "orbit_residual", "polish_residual",
                 "polish_change", "active", "margins", "violations", "branch")
STATUSES = ("complete", "ended", "violates", "partial")
_KEYS = ("format", "version", "robot", "options", "speeds", "status", "message", "events",
         "end", "total_time", "build_time", "records", "members", "sha256")


def options_record(options: GaitOptions) -> dict:
    """The options as a family file records them: without the speed."""
    d = options.to_dict()
    d.pop("speed", None)
    return d


def family_body(robot: dict, options: GaitOptions, speeds, meta: dict, records: list,
                gaits: list) -> dict:
    """The content of a family file, its checksum included.

    Parameters
    ----------
    robot : dict
        The robot description's record.
    options : GaitOptions
        The problem (its speed left out).
    speeds : sequence of float
        The requested speeds.
    meta : dict
        ``status``, ``message``, ``events``, ``end``, ``total_time``, ``build_time``.
    records : list of dict
        One per member (:data:`RECORD_FIELDS`).
    gaits : list of Gait
        The members.

    Returns
    -------
    dict
    """
    members = []
    for g in gaits:
        m = g.to_dict()
        m["sha256"] = digest(m)
        members.append(m)
    body = dict(format=FAMILY_FORMAT, version=FAMILY_VERSION, robot=robot,
                options=options_record(options), speeds=[float(v) for v in speeds],
                **{k: meta[k] for k in ("status", "message", "events", "end", "total_time",
                                        "build_time")},
                records=records, members=members)
    body = json.loads(json.dumps(body, default=_plain))
    body["sha256"] = digest(body)
    return body


def _plain(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"not JSON: {type(o).__name__}")


def write_family(path, body: dict) -> Path:
    """Write a family file's content atomically (complete or absent).

    Parameters
    ----------
    path : str or Path
    body : dict
        From :func:`family_body`.

    Returns
    -------
    Path
    """
    # Infinity as in a gait file (a robot without a torque limit: its URDF gives none)
    return write_text_atomic(Path(path), json.dumps(body, indent=1))


def read_family_file(path, model=None) -> dict:
    """Read and validate a family file.

    Parameters
    ----------
    path : str or Path
    model : BipedModel, optional
        The robot the members must be of (default: the file's).

    Returns
    -------
    dict
        ``options`` (GaitOptions, speed of the first member), ``speeds``, ``status``,
        ``message``, ``events``, ``end``, ``total_time``, ``build_time``, ``records``
        (list of dict) and ``gaits`` (list of Gait).

    Raises
    ------
    GaitFileError
        Naming the file and what is wrong.
    """
    path = Path(path)
    where = f"gait family file {path}"
    try:
        text = read_text_file(path, "gait family file", MAX_FAMILY_BYTES)
        body = json.loads(text) if text.strip() else None
    except (json.JSONDecodeError, RecursionError) as e:
        raise GaitFileError(f"{where} is not valid JSON (truncated or corrupted?): {e}") \
            from None
    except ValueError as e:
        raise GaitFileError(str(e)) from None
    if body is None:
        raise GaitFileError(f"{where} is empty")
    _envelope(body, where, path)
    if not isinstance(body["options"], dict):
        raise GaitFileError(f"{where}: 'options' must be an object")
    try:
        opts = GaitOptions.from_dict(body["options"])
    except (TypeError, ValueError) as e:
        raise GaitFileError(f"{where}: invalid 'options': {e}") from None
    speeds = _speeds(body["speeds"], where)
    records = _records(body["records"], where)
    got = [float(r["speed"]) for r in records]
    if len(got) > len(speeds) or any(abs(a - b) > 1e-9 for a, b in zip(got, speeds)):
        raise GaitFileError(f"{where}: the records' speeds are not the first of 'speeds'")
    members = body["members"]
    if not isinstance(members, list) or len(members) != len(records):
        raise GaitFileError(f"{where}: 'members' must be a list of one gait per record "
                            f"({len(records)})")
    gaits = [_member(m, i, r, model, opts, body["robot"], where)
             for i, (m, r) in enumerate(zip(members, records))]
    if gaits:
        opts = gaits[0].options
    _events(body["events"], where)
    _end(body["end"], where)
    if body["status"] not in STATUSES:
        raise GaitFileError(f"{where}: unknown status {body['status']!r}")
    status = ("ended" if body["end"] is not None else
              "partial" if len(records) < len(speeds) else
              "violates" if any(r["violations"] for r in records) else "complete")
    if body["status"] != status:
        raise GaitFileError(f"{where}: status {body['status']!r} does not match its "
                            f"contents ({len(records)} of {len(speeds)} speeds solved, "
                            f"{'an' if body['end'] is not None else 'no'} end: {status!r})")
    if not isinstance(body["message"], str):
        raise GaitFileError(f"{where}: 'message' must be a string")
    for k in ("total_time", "build_time"):
        if not _is_number(body[k]):
            raise GaitFileError(f"{where}: {k!r} must be a number")
    return dict(options=opts, speeds=speeds, records=records, gaits=gaits,
                **{k: body[k] for k in ("status", "message", "events", "end", "total_time",
                                        "build_time")})


def _envelope(body, where, path):
    """Format, version, checksum and keys of a family file."""
    if not isinstance(body, dict) or body.get("format") != FAMILY_FORMAT:
        raise GaitFileError(f"{path} is not a {FAMILY_FORMAT} file")
    if body.get("version") != FAMILY_VERSION:
        raise GaitFileError(f"{path} has format version {body.get('version')!r}; this "
                            f"toolkit reads version {FAMILY_VERSION}")
    rest = {k: v for k, v in body.items() if k != "sha256"}
    if body.get("sha256") != digest(rest):
        raise checksum_error(where, body.get("sha256"))
    missing = [k for k in _KEYS if k not in body]
    unknown = sorted(set(body) - set(_KEYS))
    if missing or unknown:
        raise GaitFileError(f"{where}: " + "; ".join(
            ([f"missing key(s): {', '.join(missing)}"] if missing else [])
            + ([f"unknown key(s): {', '.join(unknown)}"] if unknown else [])))


def _speeds(speeds, where):
    ok = (isinstance(speeds, list) and len(speeds) >= 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
        for v in speeds) and all(b > a for a, b in zip(speeds, speeds[1:])))
    if not ok:
        raise GaitFileError(f"{where}: 'speeds' must be at least two increasing positive "
                            f"numbers")
    return [float(v) for v in speeds]


def _is_number(v) -> bool:
    """A JSON number (not a boolean); NaN and infinity included (a figure that was not
    computed)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


#: the type of each field of a record, as (check, what it must be); the speed is a
#: finite number, checked apart
_RECORD_TYPES = dict(
    status=(lambda v: v in ("ok", "violates"), "'ok' or 'violates'"),
    **{k: (_is_count, "a count (an integer >= 0)")
       for k in ("iterations", "substeps", "failed_steps", "branch")},
    **{k: (_is_number, "a number")
       for k in ("time", "cost", "orbit_residual", "polish_residual", "polish_change")},
    **{k: (lambda v: _is_number(v) and math.isfinite(v) and v > 0, "a positive number")
       for k in ("T", "step_length")},
    active=(lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
            "a list of constraint names"),
    margins=(lambda v: isinstance(v, dict), "an object"),
    violations=(lambda v: isinstance(v, list) and all(
        isinstance(x, list) and len(x) == 2 and isinstance(x[0], str) and _is_number(x[1])
        for x in v), "a list of [constraint, amount] pairs"),
)


def _records(records, where):
    """The records, every field of the type the family's solve writes (GaitFileError)."""
    if not isinstance(records, list):
        raise GaitFileError(f"{where}: 'records' must be a list")
    for i, r in enumerate(records):
        if not isinstance(r, dict) or set(r) != set(RECORD_FIELDS):
            raise GaitFileError(f"{where}: record {i + 1} must have the fields "
                                f"{', '.join(RECORD_FIELDS)}")
        if not _is_number(r["speed"]) or not math.isfinite(r["speed"]):
            raise GaitFileError(f"{where}: record {i + 1}: 'speed' must be a number")
        for k, (ok, what) in _RECORD_TYPES.items():
            if not ok(r[k]):
                raise GaitFileError(f"{where}: record {i + 1}: {k!r} must be {what}, got "
                                    f"{r[k]!r:.40}")
    return records


#: what an event says changed at its speed
EVENT_CHANGES = ("branch", "active", "inactive")


def _events(events, where):
    """The events: objects with a speed, a change, the constraint (None for a change of
    branch) and a detail in words (GaitFileError)."""
    if not isinstance(events, list):
        raise GaitFileError(f"{where}: 'events' must be a list")
    for i, e in enumerate(events):
        ok = (isinstance(e, dict) and _is_number(e.get("speed"))
              and e.get("change") in EVENT_CHANGES
              and isinstance(e.get("detail", ""), str)
              and (e.get("constraint") is None if e.get("change") == "branch"
                   else isinstance(e.get("constraint"), str)))
        if not ok:
            raise GaitFileError(f"{where}: event {i + 1} must be an object with a 'speed', "
                                f"a 'change' ({', '.join(EVENT_CHANGES)}), the 'constraint' "
                                f"and a 'detail'")


def _end(end, where):
    """The family's end: null, or an object with the speed and the reason (GaitFileError)."""
    if end is None:
        return
    if not (isinstance(end, dict) and _is_number(end.get("speed"))
            and isinstance(end.get("reason"), str)):
        raise GaitFileError(f"{where}: 'end' must be null or an object with the 'speed' "
                            f"and the 'reason'")


def _member(body, i, record, model, opts, robot, where):
    """Member ``i``: a gait file body, checked as a gait file, of the family's robot,
    options and the record's speed."""
    here = f"{where}: member {i + 1}"
    inner = gait_body(body, here)
    if inner.get("robot") != robot:
        raise GaitFileError(f"{here} is of another robot than the family")
    gait = Gait.from_record(inner, model, where=here)
    if options_record(gait.options) != options_record(opts.for_model(gait.model)):
        raise GaitFileError(f"{here} was made with other options than the family's")
    if abs(gait.options.speed - float(record["speed"])) > 1e-12:
        raise GaitFileError(f"{here} is at {gait.options.speed:g} m/s, its record at "
                            f"{record['speed']:g} m/s")
    return gait
