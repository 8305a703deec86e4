"""Per-joint torque limits: a robot description's ``actuators.torque_limit`` as one number
for every joint or a table with a number per joint of a leg (``{ hip = 150.0, knee =
300.0 }``, the same on both legs: the planar model's legs swap roles every step), and the
bound the toolkit checks and imposes on the torques u1 .. u_nu.

The torques act on q2 .. qn: the stance leg's joints upward, its hip, the swing hip, the
swing leg's joints downward; the per-torque limits are the leg's (hip down) reversed, then
the leg's (:func:`per_torque`).
"""
from __future__ import annotations

import math

__all__ = ["per_torque", "torque_bound_text", "torque_limit_words", "leg_limits_text", "parse_torque_limit",
           "urdf_torque_limit", "placeholder_note", "PLACEHOLDER_RATIO", "joint_names_of"]


def per_torque(leg: tuple) -> tuple:
    """The limits of the torques u1 .. u_nu from those of a leg's joints (hip down).

    Parameters
    ----------
    leg : tuple of float
        N m per joint of a leg, from the hip down.

    Returns
    -------
    tuple of float
        2 len(leg) numbers: ``leg`` reversed (the stance leg upward), then ``leg``.
    """
    return tuple(leg[::-1]) + tuple(leg)


def torque_bound_text(bound, fmt: str = "g") -> str:
    """A torque bound in words (N m): ``'150'``, per torque ``'300/150'``, none ``'none'``.

    An infinite limit (no limit) is written ``'none'``.

    Parameters
    ----------
    bound : float or sequence of float
        :attr:`~biped_casadi.model.description.RobotDescription.torque_bound` (or a
        resolved bound of that form).
    fmt : str
        The format of each number.

    Returns
    -------
    str
    """
    return "/".join(format(v, fmt) if math.isfinite(v) else "none" for v in _entries(bound))


def torque_limit_words(bound) -> str:
    """A torque bound as a phrase: ``'torque limit 150 N m'``, or ``'no torque limit'``.

    Per torque ``'torque limit 300/150 N m'``; ``'no torque limit'`` when every torque's
    is infinite.

    Parameters
    ----------
    bound : float or sequence of float
        As in :func:`torque_bound_text`.

    Returns
    -------
    str
    """
    if not any(math.isfinite(v) for v in _entries(bound)):
        return "no torque limit"
    return f"torque limit {torque_bound_text(bound)} N m"


def _entries(bound) -> tuple:
    """A torque bound's numbers: one, or one per torque."""
    if isinstance(bound, (int, float)) or getattr(bound, "ndim", 1) == 0:
        return (float(bound),)
    return tuple(float(v) for v in bound)


def leg_limits_text(names, limit: float, leg: tuple) -> str:
    """A description's torque limits in words: ``'150 N m'``, ``'hip 150, knee 300 N m'``
    or ``'none (infinite)'``.

    Parameters
    ----------
    names : sequence of str
        The joints of a leg from the hip down.
    limit : float
        The smallest limit (``inf``: none).
    leg : tuple of float
        Per joint of a leg, or empty when they are all ``limit``.

    Returns
    -------
    str
    """
    if not math.isfinite(limit):
        return "none (infinite)"
    if not leg:
        return f"{limit:g} N m"
    return ", ".join(f"{j} {v:g}" for j, v in zip(names, leg)) + " N m"


def parse_torque_limit(check, limit, names) -> tuple:
    """(torque_limit, leg_torque_limits) of a description's ``actuators.torque_limit``.

    Parameters
    ----------
    check : object
        The description's field checker (``number`` and ``table`` methods that raise
        one ``ValueError`` naming the field).
    limit : object
        The value: a number (``inf``: no limit), or a table with a positive finite number
        for each of ``names``.
    names : sequence of str
        The joints of a leg from the hip down.

    Returns
    -------
    tuple
        The smallest limit and the per-joint limits (empty when they are all equal: the
        description of one number).
    """
    field = "actuators.torque_limit"
    if not isinstance(limit, dict):
        return (math.inf if (isinstance(limit, float) and limit == math.inf) else
                check.number(limit, field, strict=True, bounded=False)), ()
    names = tuple(names)
    check.table(limit, field, names, names)
    leg = tuple(check.number(limit[j], f"{field}.{j}", strict=True, bounded=False)
                for j in names)
    return min(leg), (leg if len(set(leg)) > 1 else ())


def urdf_torque_limit(notes: list, pairs, efforts: dict, all_zero: bool, torque_limit):
    """A URDF's torque limit (:func:`~biped_casadi.model.urdf.import_urdf`), said in
    ``notes``.

    Parameters
    ----------
    notes : list of str
        The import's notes (appended to).
    pairs : sequence of (str, str)
        The two legs' joints, pair by pair from the hips down.
    efforts : dict
        Joint name -> ``<limit effort>`` (N m), None where the file gives none.
    all_zero : bool
        Every joint gave ``effort="0"`` (exporters' "unknown": ``efforts`` all None).
    torque_limit : float or None
        The one limit given for every joint, N m, instead of the file's.

    Returns
    -------
    float or dict
        ``torque_limit``; ``inf`` without any effort; the smallest effort when the joints'
        are equal; else a table by joint name (hip down) of the smaller of its two legs'
        efforts (a joint without one takes the smallest of the others').
    """
    given = sorted({e for e in efforts.values() if e is not None})
    unlimited = [n for n, e in efforts.items() if e is None]
    if torque_limit is not None:
        notes.append(f"torque limit {torque_limit:g} N m from torque_limit (--torque-limit)"
                     + (f"; the file's efforts: {', '.join(f'{v:g}' for v in given)} N m"
                        if given else ""))
        return float(torque_limit)
    if not given:
        notes.append(("every leg joint gives <limit effort=\"0\"> (what exporters write "
                      "when they know no limit)" if all_zero else
                      "no leg joint gives <limit effort=...> (continuous joints, no <limit>)")
                     + ": the robot has no torque limit (infinite); commands that need one "
                     "say so; set one with --torque-limit N (torque_limit=)")
        return math.inf
    smallest = given[0]
    if unlimited:
        notes.append(f"joints without an effort limit ({', '.join(unlimited)}) take the "
                     f"others' smallest, {smallest:g} N m")
    if len(given) == 1:
        return smallest
    names = joint_names_of(len(pairs))
    limit = {n: min(smallest if efforts[j] is None else efforts[j] for j in pair)
             for n, pair in zip(names, pairs)}
    notes.append("joint efforts differ: each joint's torque limit is the smaller of its two "
                 f"legs' ({', '.join(f'{n} {v:g}' for n, v in limit.items())} N m)")
    return limit


#: a file's effort this many times the robot's weight times its leg's length (the torque
#: that holds the whole robot out on one straight leg) reads as an exporter's placeholder
PLACEHOLDER_RATIO = 20.0


def placeholder_note(notes: list, description) -> None:
    """Say in ``notes`` when a URDF's efforts look like a placeholder: the smallest limit
    at least :data:`PLACEHOLDER_RATIO` times m g L (a 1.25 kg robot with legs of 0.4 m and
    ``effort="1000"``: 203 times 4.92 N m).  Real actuators give about 0.2 to 2 times.

    Parameters
    ----------
    notes : list of str
        The import's notes (appended to).
    description : RobotDescription
        The imported robot, its limits from the file's efforts.
    """
    weight = description.total_mass * description.gravity * description.leg_length
    smallest = min(description.torque_limits) if description.has_torque_limit else math.inf
    if math.isfinite(smallest) and weight > 0 and smallest >= PLACEHOLDER_RATIO * weight:
        notes.append(f"the file's effort limits ({smallest:g} N m and up) are "
                     f"{smallest / weight:.0f} times the robot's weight times its leg's "
                     f"length ({weight:.3g} N m): they look like an exporter's placeholder, "
                     "not the actuators'; give the real limit with --torque-limit N "
                     "(torque_limit=)")


def joint_names_of(k: int) -> tuple:
    """The joints of a leg of ``k`` links from the hip down: ``'hip'``, then ``'knee'``
    when k = 2, else ``'joint1'`` ... (a description's ``torque_limit`` table's keys)."""
    return ("hip",) + (("knee",) if k == 2 else tuple(f"joint{j}" for j in range(1, k)))
