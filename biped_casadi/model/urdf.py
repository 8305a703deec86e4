"""Robots from URDF files: a planar point-foot biped read with ``urdf_parser_py`` (the
ROS URDF parser) and turned into the equivalent :class:`RobotDescription`, with the map
between the file's own joint angles and the model's coordinates
(:class:`~biped_casadi.model.urdf_map.UrdfMap`, the description's ``[urdf]`` table).

What is read (URDF lengths in m, masses in kg, inertias in kg m^2, efforts in N m):

- the structure: a torso link (the tree's root, or reached from a massless root, a
  ``world`` link, through one ``floating``, ``planar`` or ``fixed`` joint, or named by
  ``torso=``: a robot on a test rig or a boom, whose joints above it and the links above
  and beside it are left out) with two
  chains of ``revolute`` or ``continuous`` joints, the legs, listed in any order, whose
  axes are all parallel, +n or -n per joint: n, the normal of the plane of motion (axes
  within ``AXIS_TOL``, 1e-3 rad, as a CAD export's rounded angles leave them, are
  parallel: n is their mean, the notes give the largest deviation).  Fixed
  frames (sensors, an IMU, feet) may hang anywhere; moving joints may hang from them.
  Pitch, the torso's absolute angle, is right-handed about n, with n oriented toward +y
  of the torso's frame (toward the planar root joint's axis when there is one); the
  torso frame's z axis, vertical at pitch 0, must lie in the plane of motion;
- any zero pose: the model's geometry is found from the tree at zero joint angles.  The
  torso's up direction goes from the hip toward its centre of mass (toward the centre of
  its visual and collision geometry when the centre of mass is at the hip, along its
  frame's z when that is at the hip too: a pelvis with its mass on the hip); each leg
  link's goes from the next joint down (the foot, for the last link) to its own joint.
  The angle between a link's up direction and its parent's at zero is the joint's
  ``offset``, the orientation of its axis against n its ``sign`` (printed on import); a
  torso whose centre of mass is at or below the hip's height (its up direction at pitch 0
  at least a quarter turn from z) stands upright at the model angle ``pitch_offset``
  (pi for one hanging straight below): the description's ``torso_upright``;
- per link, from ``<inertial>``, with fixed child links merged in (they may carry all of
  it: a massless ``base_link`` with the legs and a fixed inertial child): the mass, the centre
  of mass anywhere in the plane (``com`` along the link's line from its proximal joint,
  ``com_offset`` across it, positive forward when upright) and the inertia about the
  centre of mass around n; a fixed child link with mass and no inertia sitting on the
  hip, a joint between leg links or the foot is a point mass there;
- the foot: the origin of the fixed child link (or frame) of each leg's last link
  (one named like a foot when there are several; of several, the one named like a sole
  or contact; a top-level ``<frame name link xyz rpy/>``, Drake's and FROST's extension,
  is such a frame), or ``foot=(x, y, z)`` in that link's
  frame; when that child hangs by a locked joint (a 3-D robot's ankle), the one fixed
  frame below it named like a sole or contact point, else the ankle: the lowest of the
  locked joints down from there that turn in the plane (a spring, a tarsus and a toe
  locked below a knee: the toe's joint), said in the notes (``foot=`` then gives the
  point that touches the ground);
- a 3-D robot, as its sagittal-plane model: ``lock={name: angle}`` holds joints fixed
  (each becomes a fixed joint, its child frame turned by the angle about its axis, so
  its child links merge into its parent: hip yaw and roll links into the torso, a foot
  into the shin, arms into the torso), ``lock_off_axis=True`` every revolute or
  continuous joint off the plane's normal at 0; out-of-plane offsets (hips apart along
  n, lateral centres of mass, products of inertia) do not enter the planar model, so
  mirror-image legs are the same legs;
- the reflected rotor inertia from ``<transmission>``: ``motorInertia`` x
  ``mechanicalReduction``^2 of each joint's actuator (equal for every joint), 0 without
  ``motorInertia``; each joint's ``mechanicalReduction`` is kept in the map (the motor
  side of an exported law);
- the torque limits: per joint of a leg the smaller ``<limit effort>`` of its two legs' (none:
  the others' smallest); without any (``continuous`` joints, no ``<limit>``, or ``effort="0"``
  every one: exporters' "unknown") none (infinite, in the notes) unless ``torque_limit=``.

Joint ``<dynamics>`` (damping, friction) is not in the model (rigid, frictionless joints),
nor is a revolute joint's range ``<limit lower upper>`` narrower than a turn (no gait or
walk is held to it): the notes list both.

The torso's length (which only draws the robot) is the top of its visual or collision
geometry above the hip along its up direction, else twice its centre-of-mass height.
Gravity is 9.81 m/s^2 along -z of the world.

Refused, with one ``ValueError`` naming the file and the joint or link: an unparsable
file, a xacro file (macros, ``${...}``: expand it with xacro first), a file without
links (a fragment that a xacro file includes), links in several trees (a link without
mass and joints beside the tree, as an unused ``world``, is ignored), links or joints
defined twice, a joint naming a link the file does not define, a loop of joints, a
number that is not finite, a negative mass, a leg longer than :data:`MAX_LEG` (a file in
mm), non-planar or prismatic joints, a torso without two legs (held by a rig: a pin or a
boom above the link the legs hang from, the refusal suggests ``torso=`` that link), a
last leg link without length in the plane (an ankle at the foot: lock it, or give the
foot), a torso hung from a massless root by joints whose origins turn the root's z (the
world's vertical) out of the legs' plane (a file written with y up), legs that differ
(links, masses, centres of mass, point masses), the hips at two places in the plane, a
leg joint without actuator (the model's one unactuated degree of freedom is the stance
foot's contact; effort 0 beside others' positive efforts), a ``<mimic>`` leg joint, a
link without ``<inertial>`` (its own or a fixed child's), no foot (legs and hips agree
within ``match_tol`` of the leg's size, default identical; the model's leg is their
mean); in ``lock``, a joint the file does not define, one that is not revolute or
continuous, an angle that is not finite, a joint given twice. A non-planar joint's
refusal names it and its axis, and how to lock it.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from urdf_parser_py import urdf as _urdf

from ..files import read_text_file
from .description import RobotDescription, description_from_dict, description_toml, joint_names
from .torque_limits import placeholder_note, urdf_torque_limit
from .urdf_map import UrdfJoint, UrdfMap, wrap_angle
from .urdf_legs import (MATCH_TOL, MAX_MATCH_TOL, _beyond, _check_foot, check_match_tol,
                        _foot_point, _same_legs, _unequal_legs, _wider)
from .urdf_text import _parse, xacro_refusal
from .urdf_tree import _axis, _body, _Frame, _legs, _pose, _Reader, apply_locks, lock_table

__all__ = ["UrdfImport", "import_urdf", "load_urdf", "description_toml", "xacro_refusal",
           "GEOMETRY_TOL",
           "MATCH_TOL", "MAX_MATCH_TOL",
           "MAX_LEG"]

#: m: a longer leg is refused as a file in other units (URDF lengths are in metres)
MAX_LEG = 10.0
#: m: how far the two hips may be apart in the plane of motion, and how far from the hip
#: a centre of mass (or geometry) must be to give the torso's direction
GEOMETRY_TOL = 1e-9


@dataclass
class UrdfImport:
    """The robot of a URDF file and how it was read.

    Parameters
    ----------
    description : RobotDescription
        The robot (validated as a description file is), with its URDF joint map
        (``description.urdf``).
    torso : str
        The torso link's name.
    legs : tuple of tuple of str
        The two legs' joint names, from the hip down (leg 1 first: the file's order of
        the hips).
    foot : str
        Where the foot came from ('link NAME', or 'foot= argument').
    notes : list of str
        What was assumed or ignored (the torso's direction and length, the torque limit,
        the root joint, merged links, locked joints, unknown tags, ...).
    locked : dict
        The joints held fixed (``lock``, ``lock_off_axis``): name -> angle, rad, in the
        file's order.
    """

    description: RobotDescription
    torso: str
    legs: tuple
    foot: str
    notes: list = field(default_factory=list)
    locked: dict = field(default_factory=dict)

    @property
    def urdf_map(self) -> UrdfMap:
        """The map between the file's joint angles and the model's q."""
        return self.description.urdf


# ------------------------------------------------------------------ actuators
def _motor_inertias(text: str) -> dict:
    """joint name -> motorInertia of its transmission's actuator (the one element of a
    transmission the parser does not know)."""
    out = {}
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return out
    for t in root.iter("transmission"):
        joints = [j.get("name") for j in t.findall("joint")]
        if not joints and t.find("joint") is not None:
            joints = [t.find("joint").text]
        node = t.find("actuator/motorInertia")
        if node is None:
            node = t.find("motorInertia")
        if node is not None and node.text is not None:
            for name in joints:
                out[name] = node.text.strip()
    return out


def _actuators(rd: _Reader, legs, text: str, torque_limit) -> tuple:
    """(rotor inertia, gear ratio, torque limit or per-joint table, reduction per joint)."""
    joints = [j for leg in legs for j in leg.joints]
    reductions = {}
    for t in rd.robot.transmissions:
        if isinstance(t, _urdf.PR2Transmission):
            reductions[t.joint] = t.mechanicalReduction
            continue
        red = next((a.mechanicalReduction for a in t.actuators
                    if a.mechanicalReduction is not None), 1.0)
        for j in t.joints:
            reductions[j.name] = red
    motors = _motor_inertias(text)
    efforts = {j.name: (None if j.limit is None or j.limit.effort is None
                        else float(j.limit.effort)) for j in joints}
    # effort="0" on every leg joint is what exporters write when they know no limit (a
    # robot with every joint passive is no robot to control): no limit, not no actuator
    all_zero = all(e == 0.0 for e in efforts.values())
    if all_zero:
        efforts = dict.fromkeys(efforts)
    if rd.robot.transmissions:
        passive = [j.name for j in joints if j.name not in reductions]
    else:
        passive = []
        rd.notes.append("no <transmission>: every leg joint actuated, no rotor inertia")
    passive += [n for n, e in efforts.items() if e is not None and e == 0.0
                and n not in passive]
    if passive:
        rd.fail(f"joint {passive[0]!r} has no actuator (no <transmission>, or effort 0): "
                f"with the passive stance foot that makes more than one unactuated joint, "
                f"which the model does not support; a passive joint held still (a stiff "
                f"spring) is locked ('biped robot import FILE --lock {passive[0]}[=RAD]', "
                f"lock={{{passive[0]!r}: 0}}), or its actuator is missing from the file")
    rotors = {}
    for j in joints:
        try:
            motor = float(motors.get(j.name, 0.0))
            gear = float(reductions.get(j.name, 1.0))
        except ValueError:
            rd.fail(f"the transmission of joint {j.name!r} has a non-numeric motorInertia "
                    f"or mechanicalReduction")
        if not math.isfinite(motor):
            rd.fail(f"the transmission of joint {j.name!r} has motorInertia {motor:g}: it must "
                    f"be a finite number")
        if not (math.isfinite(gear) and gear > 0):
            rd.fail(f"the transmission of joint {j.name!r} has mechanicalReduction {gear:g}: "
                    f"it must be positive")
        rotors[j.name] = (motor, gear)
    values = {n: m * g ** 2 for n, (m, g) in rotors.items()}
    ref = next(iter(values.values()))
    for n, v in values.items():
        if not math.isclose(v, ref, rel_tol=1e-12, abs_tol=0.0):
            rd.fail(f"reflected rotor inertias differ: joint {n!r} {v:.12g}, joint "
                    f"{next(iter(values))!r} {ref:.12g} kg m^2 (apart by {abs(v - ref):.2g}; "
                    f"the model takes one for every joint)")
    pairs = list(zip(*([j.name for j in leg.joints] for leg in legs)))
    limit = urdf_torque_limit(rd.notes, pairs, efforts, all_zero, torque_limit)
    motor, gear = next(iter(rotors.values()))
    return motor, gear, limit, {n: g for n, (_, g) in rotors.items()}


# ------------------------------------------------------------------ the plane
_SIDES = {"left", "right", "l", "r", "lft", "rgt", "lt", "rt"}


def _common_name(a: str, b: str, default: str) -> str:
    """'femur' from 'femur_left' / 'femur_right', 'l_femur' / 'r_femur', 'Thigh' from
    'LeftThigh' / 'RightThigh', 'UPPER_LEG' from 'FL_UPPER_LEG' / 'FR_UPPER_LEG'; the
    common prefix else, or ``default``."""
    def tokens(s):
        return [t for t in re.split(r"[_\-\s.]+|(?<=[a-z])(?=[A-Z])", s)
                if t and t.lower() not in _SIDES]
    ta, tb = tokens(a), tokens(b)
    if ta and ta == tb:
        return "_".join(ta)
    if len(ta) == len(tb):         # 'FL_UPPER_LEG' / 'FR_UPPER_LEG': the side is the token
        same = [x for x, y in zip(ta, tb) if x == y]      # that differs
        if same and len(same) == len(ta) - 1:
            return "_".join(same)
    i = 0
    while i < min(len(a), len(b)) and a[i] == b[i]:
        i += 1
    return a[:i].strip("_- .") or default


class _Plane:
    """The plane of motion in the torso frame at pitch 0: normal n, up U (the torso
    frame's z), forward F = n x U; angles right-handed about n from U."""

    def __init__(self, n):
        self.n = n
        self.U = np.array([0.0, 0.0, 1.0])
        self.F = np.cross(n, self.U)

    def flat(self, v) -> np.ndarray:
        """The part of ``v`` in the plane (3-vector)."""
        return v - np.dot(v, self.n) * self.n

    def angle(self, v) -> float:
        """The angle of an in-plane vector from U, right-handed about n."""
        return math.atan2(float(np.dot(v, self.F)), float(np.dot(v, self.U)))

    def normal(self, u) -> np.ndarray:
        """The forward normal f = n x u of a link's up direction u."""
        return np.cross(self.n, u)


def _merged(rd: _Reader, frame: _Frame, ends: dict, owner: str, pm: dict, plane: _Plane):
    """A link's body with its fixed child links merged in; those with mass and no
    inertia that sit on one of ``ends`` (joint name -> point) become point masses in
    ``pm``."""
    link = rd.links[frame.name]
    body = _body(link, frame.R, frame.p)
    if body is not None and body.mass < 0:
        rd.fail(f"link {link.name!r}{owner} has a negative mass ({body.mass:g} kg)")
    if body is not None and body.mass == 0.0:
        body = None                   # a massless link: its fixed children may carry it
    for _, f in rd.fixed_descendants(frame):
        extra = _body(rd.links[f.name], f.R, f.p)
        if extra is not None and extra.mass < 0:
            rd.fail(f"link {f.name!r} (fixed to {link.name!r}) has a negative mass "
                    f"({extra.mass:g} kg)")
        if extra is None or extra.mass == 0.0:
            continue
        at = [name for name, pt in ends.items()
              if np.linalg.norm(plane.flat(extra.com - pt)) <= rd.tol]
        if at and not np.any(extra.inertia):
            pm[at[0]] = pm.get(at[0], 0.0) + extra.mass
        else:
            body = extra if body is None else body.plus(extra)
            rd.notes.append(f"fixed link {f.name!r} merged into {link.name!r}")
    if body is None or not body.mass > 0:
        rd.fail(f"link {link.name!r}{owner} has no <inertial> with a positive mass (nor "
                f"fixed child links with one)")
    return body


class _Leg:
    """One leg read in the plane: joint points, link directions, link bodies."""

    def __init__(self, rd: _Reader, chain, foot_p, plane: _Plane):
        self.rd, self.plane = rd, plane
        self.joints = [j for j, _ in chain]
        self.frames = [f for _, f in chain]
        self.points = [f.p for f in self.frames] + [foot_p]
        self.up, self.lengths = [], []
        for i, f in enumerate(self.frames):
            d = plane.flat(self.points[i] - self.points[i + 1])
            length = float(np.linalg.norm(d))
            if not length > rd.tol:
                j = self.joints[i].name
                if i == len(self.frames) - 1:
                    what = "the foot"
                    todo = (f"for a point foot lock that joint, an ankle ('biped robot import "
                            f"FILE --lock {j}', lock={{{j!r}: 0}}: {f.name!r} merges into the "
                            f"link above), or give the foot point (--foot X Y Z in the frame "
                            f"of {f.name!r}, foot=)")
                else:
                    what = f"joint {self.joints[i + 1].name!r}"
                    todo = f"lock one of them (--lock {j}, lock=)"
                rd.fail(f"link {f.name!r} has no length in the plane of motion: its joint "
                        f"{j!r} and {what} are at the same place; {todo}")
            self.up.append(d / length)
            self.lengths.append(length)

    def body(self, i: int, pm: dict) -> dict:
        """Link i (from the hip) in the schema; point masses found on it go to ``pm``
        (joint name -> kg)."""
        rd, frame, plane = self.rd, self.frames[i], self.plane
        names = joint_names(len(self.frames))
        ends = {names[i]: self.points[i], names[i + 1]: self.points[i + 1]}
        body = _merged(rd, frame, ends, "", pm, plane)
        top, u = self.points[i], self.up[i]
        rel = plane.flat(body.com - top)
        return dict(name=rd.links[frame.name].name, mass=body.mass,
                    length=_clean(self.lengths[i]), com=_clean(-np.dot(rel, u)),
                    com_offset=_clean(np.dot(rel, plane.normal(u)), rd.tol),
                    inertia=_clean(plane.n @ body.inertia @ plane.n))


def _torso(rd: _Reader, frame: _Frame, hip, plane: _Plane, pm: dict) -> tuple:
    """(the torso's table, its up direction)."""
    link = rd.links[frame.name]
    body = _merged(rd, frame, {"hip": hip}, " (the torso)", pm, plane)
    rel = plane.flat(body.com - hip)
    if np.linalg.norm(rel) > rd.tol:
        up = rel / np.linalg.norm(rel)
        rd.notes.append(f"the torso's up direction: from the hip toward its centre of mass "
                        f"(at {_fmt(plane.angle(up))} rad from z of {link.name!r})")
    else:
        centre = _geometry_centre(rd, link, frame)
        g = None if centre is None else plane.flat(centre - hip)
        if g is None or not np.linalg.norm(g) > rd.tol:
            up = plane.flat(np.array([0.0, 0.0, 1.0]))
            up = up / np.linalg.norm(up)
            rd.notes.append(f"the torso's centre of mass is at the hip, and so is the centre "
                            f"of its geometry{'' if g is not None else ' (it has none)'}: "
                            f"its up direction is z of {link.name!r} (upright at pitch 0); "
                            f"it only sets where the torso's angle is measured from (a pelvis "
                            f"whose mass sits on the hip)")
        else:
            up = g / np.linalg.norm(g)
            rd.notes.append(f"the torso's centre of mass is at the hip: its up direction "
                            f"goes toward the centre of its geometry "
                            f"({_fmt(plane.angle(up))} rad from z of {link.name!r})")
    com = _clean(np.dot(rel, up))
    table = dict(name=link.name, mass=body.mass,
                 length=_clean(_torso_length(rd, link, frame, hip, up, com)),
                 com=com, com_offset=_clean(np.dot(rel, plane.normal(up)), rd.tol),
                 inertia=_clean(plane.n @ body.inertia @ plane.n))
    return table, up


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def _clean(v: float, tol: float = 0.0) -> float:
    """A length, inertia or angle found through turned frames without the round-off of
    the turns: 15 significant digits (0.39999999999999997 -> 0.4), 0 within ``tol``."""
    v = float(v)
    return 0.0 if abs(v) <= tol else float(f"{v:.15g}")


def _clean_angle(a: float) -> float:
    """An angle within 1e-12 of a multiple of pi/2 is that multiple (else unchanged)."""
    k = round(a / (math.pi / 2))
    return float(wrap_angle(k * (math.pi / 2))) if abs(a - k * math.pi / 2) <= 1e-12 else float(a)


def _geometries(link, frame: _Frame):
    """(geometry, R, p) of a link's visuals and collisions, in the torso frame."""
    for g in list(link.visuals or []) + list(link.collisions or []):
        R, p = _pose(g.origin)
        yield g.geometry, frame.R @ R, frame.p + frame.R @ p


def _geometry_centre(rd: _Reader, link, frame: _Frame):
    """The mean of the torso's geometry origins (None without geometry)."""
    pts = [p for _, _, p in _geometries(link, frame)]
    for _, f in rd.fixed_descendants(frame):
        pts += [p for _, _, p in _geometries(rd.links[f.name], f)]
    return np.mean(pts, axis=0) if pts else None


def _torso_length(rd: _Reader, link, frame: _Frame, hip, up, com: float) -> float:
    """The top of the torso's geometry above the hip along ``up`` (else 2 com)."""
    tops = []
    for geo, R, p in _geometries(link, frame):
        u = R.T @ up                         # up in the geometry's frame
        if isinstance(geo, _urdf.Box):
            half = 0.5 * float(np.abs(u) @ np.abs(np.array(geo.size, float)))
        elif isinstance(geo, _urdf.Cylinder):
            half = 0.5 * geo.length * abs(u[2]) + geo.radius * math.sqrt(max(0.0, 1 - u[2]**2))
        elif isinstance(geo, _urdf.Sphere):
            half = geo.radius
        else:
            continue
        tops.append(float(np.dot(p - hip, up)) + half)
    if tops and max(tops) > 0:
        return max(tops)
    rd.notes.append(("the torso's box, cylinder or sphere geometry does not reach above the "
                     "hip along its up direction (toward its centre of mass)" if tops else
                     "the torso has no box, cylinder or sphere geometry")
                    + ": its length (for drawings) is twice its centre-of-mass height")
    return 2.0 * com if com > 0 else 1e-3


# ------------------------------------------------------------------ entry points
def _check_torque_limit(torque_limit):
    if torque_limit is None:
        return None
    if isinstance(torque_limit, bool) or not isinstance(torque_limit, (int, float, np.floating)) \
            or not math.isfinite(torque_limit) or not torque_limit > 0:
        raise ValueError(f"torque_limit must be a positive number (N m), got {torque_limit!r}")
    return float(torque_limit)


def _joint_notes(rd: _Reader, joints) -> None:
    """Notes on the leg joints' <dynamics> and ranges (not in the model)."""
    damped = []
    for j in joints:
        terms = [f"{k} {getattr(j.dynamics, k):g}" for k in ("damping", "friction")
                 if j.dynamics is not None and getattr(j.dynamics, k, None)]
        if terms:
            damped.append(f"{j.name} ({', '.join(terms)})")
    if damped:
        rd.notes.append(f"ignored: joint <dynamics> of {', '.join(damped)}: the model's joints "
                        f"are frictionless (the torques it computes are the rigid body's)")
    ranged = [f"{j.name} [{j.limit.lower:g}, {j.limit.upper:g}]" for j in joints
              if j.type == "revolute" and j.limit is not None
              and j.limit.lower is not None and j.limit.upper is not None
              and j.limit.upper - j.limit.lower < 2 * math.pi - 0.01]     # narrower than a turn
    if ranged:
        rd.notes.append(f"not held to: the joint ranges (rad, the URDF's angles) of "
                        f"{', '.join(ranged)}: gaits and walks are not constrained by them "
                        f"(compare a gait's angles: biped gait --export-csv --angles urdf)")


def import_urdf(path, foot=None, tol: float = GEOMETRY_TOL,
                torque_limit: float | None = None, lock=None, lock_off_axis: bool = False,
                axis: str | None = None, match_tol: float = MATCH_TOL,
                foot_beyond: float = 0.0, torso: str | None = None) -> UrdfImport:
    """Read a planar biped from a URDF file (what is read: the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.urdf`` file.
    foot : sequence of 3 floats, optional
        The foot point in the frame of each leg's last link, m; needed when that link
        has no fixed child link (frame) to mark the foot.
    tol : float
        m: how far the hips may be apart in the plane, and how far a centre of mass must
        be from the hip to give the torso's direction.
    torque_limit : float, optional
        N m: the robot's torque limit, instead of the file's effort limits (needed for a
        limit when the file gives none).
    lock : mapping or iterable, optional
        Joints held fixed: name -> angle (rad), or names (angle 0) and (name, angle)
        pairs.  Each revolute or continuous joint named becomes a fixed joint whose child
        frame is its origin turned by the angle about its axis, before the rest of the
        import (so its child link merges into its parent): a 3-D robot's sagittal model.
    lock_off_axis : bool
        Also lock at 0 every revolute or continuous joint below the torso whose axis, at
        the file's zero joint angles, is not parallel to the plane's normal n (a joint
        named in ``lock`` keeps its angle there): n is the torso frame's ``axis``, else
        the direction across the torso frame's z that most of the joints below the torso
        turn about (a tie: the one nearer the torso's y, then the first in the file).
    axis : {'x', 'y'}, optional
        The plane's normal for ``lock_off_axis``, in the torso's frame.
    match_tol : float
        How closely the two legs must agree, relative to the leg's size (masses to its
        mass, lengths and centres of mass to its length, inertias to mass x length^2),
        and the hips in the plane (to its length); within it the model's leg is the mean
        of the two (the notes give the largest difference).  Default :data:`MATCH_TOL`
        (identical legs); a CAD export's mirrored legs differ by about 1e-4.
    foot_beyond : float
        m: the foot (the point that touches the ground) this far beyond the foot point
        found or given, along the last link's line (the sole below a locked ankle, for
        legs whose last links' frames differ, where one ``foot`` point cannot serve
        both).
    torso : str, optional
        The torso link's name, when the robot hangs in the file from a test rig or a boom
        (joints of any type above it): the joints from the root to it hold it in the
        file, and the links above and beside it are left out of the model (the notes
        give their mass).  Default: found as the module docstring says.

    Returns
    -------
    UrdfImport
        The description (with its joint map), the links and joints found, and notes.

    Raises
    ------
    ValueError
        One message naming the file and what is wrong (module docstring).
    """
    path = Path(path)
    where = f"URDF file {path}"
    _check_foot(foot)
    if isinstance(foot_beyond, bool) or not isinstance(foot_beyond, (int, float, np.floating)) \
            or not 0 <= foot_beyond <= MAX_LEG:
        raise ValueError(f"foot_beyond must be a number of metres in [0, {MAX_LEG:g}], got "
                         f"{foot_beyond!r}")
    torque_limit = _check_torque_limit(torque_limit)
    match_tol = check_match_tol(match_tol)
    lock = lock_table(lock, lock_off_axis, axis)
    text = read_text_file(path, "URDF file", 20_000_000)
    robot, said, framed, text = _parse(text, where, path.name)   # text as parsed
    rd = _Reader(robot, where, tol)
    rd.notes += framed
    torso = _Frame(rd.torso(torso), np.eye(3), np.zeros(3))
    apply_locks(rd, torso.name, lock, lock_off_axis, axis)
    chains = _legs(rd, torso)
    if len(chains[0]) != len(chains[1]):          # before the feet: a leg's own checks
        _unequal_legs(rd, torso.name, chains)     # would blame the longer leg's links
    n, signs = _axis(rd, chains)
    plane = _Plane(n)
    feet = [_foot_point(rd, chain[-1][1], foot, n, [j.name for j, _ in chain])
            for chain in chains]
    if foot_beyond:
        feet = [_beyond(rd, chain, f, foot_beyond, plane) for chain, f in zip(chains, feet)]
    legs = [_Leg(rd, chain, p, plane) for chain, (p, _, _) in zip(chains, feet)]
    span = sum(legs[0].lengths)
    if span > MAX_LEG:
        rd.fail(f"the leg of {legs[0].joints[0].name!r} is {span:.4g} m long: URDF lengths are "
                f"in metres (a file in millimetres?)")
    hip = legs[0].points[0]
    apart = float(np.linalg.norm(plane.flat(legs[1].points[0] - hip)))
    hips = apart / span if apart > tol else 0.0
    all_joints = [j for leg in legs for j in leg.joints]
    pm_legs = [dict(), dict()]
    links = [[leg.body(i, pm) for i in range(len(leg.frames))]
             for leg, pm in zip(legs, pm_legs)]
    worst = _same_legs(rd, links, pm_legs, legs, match_tol, hips)
    if apart > tol + match_tol * span:
        rd.fail(f"the hip joints {legs[0].joints[0].name!r} and {legs[1].joints[0].name!r} "
                f"are {apart:.3g} m apart in the plane of motion: the model's legs share "
                f"one hip{_wider(max(hips, worst), match_tol, 'accepts them')}")
    if apart > tol:
        rd.notes.append(f"the hips are {apart:.2g} m apart in the plane of motion (match_tol "
                        f"{match_tol:g}): the model's hip is that of {legs[0].joints[0].name!r}")
    _joint_notes(rd, all_joints)
    motor, gear, limit, reductions = _actuators(rd, legs, text, torque_limit)
    pm = {"hip": 0.0}
    torso_d, torso_up = _torso(rd, torso, hip, plane, pm)
    pm["hip"] += pm_legs[0].pop("hip", 0.0) + pm_legs[1].pop("hip", 0.0)
    pm.update(pm_legs[0])
    if pm["hip"] == 0.0:
        del pm["hip"]
    names = [_common_name(a["name"], b["name"], f"link{i + 1}")
             for i, (a, b) in enumerate(zip(*links))]
    for i, a in enumerate(links[0]):       # names that coincide: the links' positions
        a["name"] = names[i] if names.count(names[i]) == 1 else f"link{i + 1}"
        if a["com_offset"] == 0.0:
            del a["com_offset"]
    if torso_d["com_offset"] == 0.0:
        del torso_d["com_offset"]
    urdf_map = _joint_map(rd, legs, torso_up, plane, signs, reductions, torso.name, hip)
    data = dict(name=robot.name or path.stem, gravity=9.81,
                **_torso_upright(rd, plane, torso_up, urdf_map))
    data.update(actuators=dict(torque_limit=limit, rotor_inertia=motor, gear_ratio=gear),
                torso=torso_d, leg=links[0], point_masses=pm, urdf=urdf_map.to_dict())
    rd.notes += [f"ignored: {s}" for s in said if "motorInertia" not in s]
    d = description_from_dict(data, where=where, source=str(path))
    if torque_limit is None:
        placeholder_note(rd.notes, d)
    locked = {k: rd.locked[k] for k in sorted(rd.locked, key=rd.order.get)}
    return UrdfImport(d, torso.name, tuple(tuple(j.name for j in leg.joints) for leg in legs),
                      feet[0][1], rd.notes, locked)


def _torso_upright(rd: _Reader, plane: _Plane, torso_up, urdf_map: UrdfMap) -> dict:
    """``{'torso_upright': pitch_offset}`` for a torso whose centre of mass is at or below
    the hip's height (the model's torso, up toward it, points down when the file's torso
    stands upright, at pitch 0), said in the notes; else ``{}`` (upright at 0)."""
    if abs(plane.angle(torso_up)) < math.pi / 2:
        return {}
    rd.notes.append(f"the torso's centre of mass is not above the hip: the model's torso "
                    f"points down at pitch 0, so it stands upright at torso angle "
                    f"{_fmt(urdf_map.pitch_offset)} rad (torso_upright; falls and leans "
                    f"are judged from there)")
    return {"torso_upright": urdf_map.pitch_offset}


def _joint_map(rd: _Reader, legs, torso_up, plane: _Plane, signs: dict, reductions: dict,
               root: str, hip) -> UrdfMap:
    """The map of the module docstring: per joint, the angle between its child link's
    up direction and its parent's at zero (offset) and its axis against n (sign)."""
    beta = plane.angle(torso_up)
    joints = []
    for number, leg in enumerate(legs, start=1):
        parent = beta
        for i, j in enumerate(leg.joints):
            gamma = plane.angle(leg.up[i])
            joints.append(UrdfJoint(j.name, number, i + 1, signs[j.name],
                                    _clean_angle(wrap_angle(gamma - parent)),
                                    float(reductions[j.name])))
            parent = gamma
    joints.sort(key=lambda j: rd.order[j.name])
    return UrdfMap(joints=tuple(joints), pitch_offset=_clean_angle(wrap_angle(beta)), root=root,
                   axis=tuple(float(v) for v in plane.n),
                   hip=(_clean(np.dot(hip, plane.F), 1e-15), _clean(np.dot(hip, plane.U), 1e-15)))


def load_urdf(path, foot=None, torque_limit: float | None = None, lock=None,
              lock_off_axis: bool = False, axis: str | None = None,
              match_tol: float = MATCH_TOL) -> RobotDescription:
    """The robot description of a URDF file (:func:`import_urdf` without the notes).

    Parameters
    ----------
    path : str or Path
        The ``.urdf`` file.
    foot : sequence of 3 floats, optional
        The foot point in the last leg link's frame, m.
    torque_limit : float, optional
        N m, instead of the file's effort limits.
    lock : mapping or iterable, optional
        Joints held fixed at the angles given (:func:`import_urdf`).
    lock_off_axis : bool
        Also lock at 0 every joint off the plane's normal (:func:`import_urdf`).
    axis : {'x', 'y'}, optional
        The plane's normal for ``lock_off_axis``.
    match_tol : float
        How closely the legs must agree; within it the model's leg is their mean
        (:func:`import_urdf`).

    Returns
    -------
    RobotDescription
        With its URDF joint map (``urdf``).

    Raises
    ------
    ValueError
        Naming the file and what is wrong.
    """
    return import_urdf(path, foot, torque_limit=torque_limit, lock=lock,
                       lock_off_axis=lock_off_axis, axis=axis, match_tol=match_tol).description
