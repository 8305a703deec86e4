"""A robot description as a TOML file (:func:`description_toml`): the schema of
:mod:`biped_casadi.model.description`, numbers written exactly."""
from __future__ import annotations

import math

__all__ = ["description_toml"]


def description_toml(d, header: str = "") -> str:
    """A description file (TOML) that loads back to a description equal to ``d``.

    The schema of :mod:`biped_casadi.model.description`; the URDF joint map, when
    there is one, is the ``[urdf]`` table with one ``[[urdf.joints]]`` table per joint.

    Parameters
    ----------
    d : ~biped_casadi.model.description.RobotDescription
        The robot.
    header : str
        Comment lines to put first (``#`` added).

    Returns
    -------
    str
        TOML text; numbers written with ``repr`` (exact round trip).
    """
    def table(t):
        return "\n".join(f"{k} = {_value(v)}" for k, v in t.items()
                         if not isinstance(v, list) or not v or not isinstance(v[0], dict))
    dd = d.to_dict()
    out = [f"# {line}" for line in header.splitlines()]
    out += [f"name = {_q(dd['name'])}", f"gravity = {dd['gravity']!r}"]
    if "torso_upright" in dd:
        out += [f"torso_upright = {_value(dd['torso_upright'])}"]
    out += ["", "[actuators]", table(dd["actuators"]), "", "[torso]", table(dd["torso"])]
    for link in dd["leg"]:
        out += ["", "[[leg]]", table(link)]
    if dd["point_masses"]:
        out += ["", "[point_masses]", table(dd["point_masses"])]
    if "urdf" in dd:
        out += ["", "[urdf]", table(dd["urdf"])]
        for j in dd["urdf"]["joints"]:
            out += ["", "[[urdf.joints]]", table(j)]
    return "\n".join(out) + "\n"


def _value(v) -> str:
    """A TOML value: floats exactly (repr; inf as TOML's inf), ints, strings, lists,
    inline tables."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "inf" if v == math.inf else ("-inf" if v == -math.inf else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):                     # an inline table (per-joint torque limits)
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    return _q(v)


def _q(s: str) -> str:
    """A TOML basic string."""
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'
