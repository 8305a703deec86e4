"""Robots from URDF files: a planar point-foot biped read with ``urdf_parser_py`` (the
ROS URDF parser) and turned into the equivalent :class:`RobotDescription`.

What is read (URDF lengths in m, masses in kg, inertias in kg m^2, efforts in N m):

- the structure: a torso link (the tree's root, or the child of a massless root joined
  by a ``floating`` or ``planar`` joint) with two chains of ``revolute`` (or
  ``continuous``) joints, the legs, whose axes are all parallel: the normal of the
  plane of motion.  At zero joint angles the robot must stand straight (docs: theory §1:
  q = 0 is upright): each leg's joints and foot on one line below the hip;
- per link, from ``<inertial>``: the mass, the centre of mass (its distance from the
  link's proximal joint along the link; off the link's axis in the plane of motion it
  is refused, naming the link) and the inertia about the centre of mass around the
  plane's normal;
- lengths from the joint origins (the last link's from the foot);
- the foot: the origin of the fixed child link (or frame) of each leg's last link, or
  ``foot=(x, y, z)`` in that link's frame;
- the reflected rotor inertia from ``<transmission>``: ``motorInertia`` x
  ``mechanicalReduction``^2 of each joint's actuator (equal for every joint), 0 without
  ``motorInertia``;
- the torque limit from ``<limit effort>`` (the smallest one);
- fixed child links with mass: a point mass at a joint (hip, knee, foot) when the
  inertia is zero and the mass sits on the joint, otherwise merged into the parent.

The torso's length (which only draws the robot) is the top of its visual or collision
geometry above the hip, else twice its centre-of-mass height.  Gravity is 9.81 m/s^2.

Refused, with one ``ValueError`` naming the file and the joint or link: an unparsable
file, non-planar or prismatic joints, a torso without two legs, legs that differ, a leg
joint without actuator (the model's one unactuated degree of freedom is the stance
foot's contact), a link without ``<inertial>``, a centre of mass off its link's axis,
no foot.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from urdf_parser_py import urdf as _urdf
from urdf_parser_py.xml_reflection import core as _xml_core

from ..files import read_text_file
from .description import RobotDescription, description_from_dict, joint_names

__all__ = ["UrdfImport", "import_urdf", "load_urdf", "description_toml", "GEOMETRY_TOL"]

#: m: how far a joint, a foot or a centre of mass may sit off its leg's line in the plane
#: of motion (and how far the two hips may differ) before the file is refused
GEOMETRY_TOL = 1e-9
_ROTATING = ("revolute", "continuous")
_BASE = ("floating", "planar")


@dataclass
class UrdfImport:
    """The robot of a URDF file and how it was read.

    Parameters
    ----------
    description : RobotDescription
        The robot (validated as a description file is).
    torso : str
        The torso link's name.
    legs : tuple of tuple of str
        The two legs' joint names, from the hip down.
    foot : str
        Where the foot came from ('link NAME', or 'foot= argument').
    notes : list of str
        What was assumed or ignored (the torso length's source, unknown tags, ...).
    """

    description: RobotDescription
    torso: str
    legs: tuple
    foot: str
    notes: list = field(default_factory=list)


# ------------------------------------------------------------------ geometry helpers
def _rotation(rpy) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(v) for v in (rpy if rpy is not None else (0, 0, 0)))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), \
        math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _pose(origin):
    """(R, p) of a URDF <origin> (identity when absent)."""
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = np.zeros(3) if origin.xyz is None else np.array(origin.xyz, dtype=float)
    return _rotation(origin.rpy), xyz


class _Reader:
    """The URDF's tree, posed at zero joint angles in the torso's frame."""

    def __init__(self, robot, where: str, tol: float):
        self.robot, self.where, self.tol = robot, where, tol
        self.links = {link.name: link for link in robot.links}
        self.children = {}
        for j in robot.joints:
            self.children.setdefault(j.parent, []).append(j)
        self.notes = []

    def fail(self, problem: str):
        raise ValueError(f"{self.where}: {problem}")

    def torso(self) -> str:
        kids = {j.child for j in self.robot.joints}
        roots = [name for name in self.links if name not in kids]
        if len(roots) != 1:
            self.fail(f"must be one tree of links, found roots {roots}")
        root = roots[0]
        joints = self.children.get(root, [])
        if _mass(self.links[root]) == 0.0 and len(joints) == 1 and joints[0].type in _BASE:
            self.notes.append(f"{joints[0].type} joint {joints[0].name!r} taken as the "
                              f"floating base (not a joint of the model)")
            return joints[0].child
        return root


def _mass(link) -> float:
    return 0.0 if link.inertial is None or link.inertial.mass is None \
        else float(link.inertial.mass)


def _inertia_matrix(inertial) -> np.ndarray:
    i = inertial.inertia
    if i is None:
        return np.zeros((3, 3))
    return np.array([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz], [i.ixz, i.iyz, i.izz]],
                    dtype=float)


@dataclass
class _Body:
    """Mass, centre of mass (torso frame) and inertia tensor about it (torso frame)."""
    mass: float
    com: np.ndarray
    inertia: np.ndarray

    def plus(self, other: "_Body") -> "_Body":
        m = self.mass + other.mass
        c = (self.mass * self.com + other.mass * other.com) / m
        def shifted(b):
            d = b.com - c
            return b.inertia + b.mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
        return _Body(m, c, shifted(self) + shifted(other))


def _body(link, R, p) -> _Body | None:
    """The link's <inertial> in the torso frame (link frame at (R, p)), None without."""
    if link.inertial is None:
        return None
    Ri, pi = _pose(link.inertial.origin)
    Rw = R @ Ri
    return _Body(_mass(link), p + R @ pi, Rw @ _inertia_matrix(link.inertial) @ Rw.T)


# ------------------------------------------------------------------ the tree
@dataclass
class _Frame:
    """A link posed at zero joint angles: its rotation and origin in the torso frame."""
    name: str
    R: np.ndarray
    p: np.ndarray


def _child_frame(parent: _Frame, joint) -> _Frame:
    R, p = _pose(joint.origin)
    return _Frame(joint.child, parent.R @ R, parent.p + parent.R @ p)


def _fixed_descendants(rd: _Reader, frame: _Frame) -> list:
    """(joint, frame) of every link hanging from ``frame`` by fixed joints only."""
    out = []
    for j in rd.children.get(frame.name, []):
        if j.type == "fixed":
            f = _child_frame(frame, j)
            out.append((j, f))
            out.extend(_fixed_descendants(rd, f))
    return out


def _legs(rd: _Reader, torso: _Frame) -> list:
    """The torso's two chains of rotating joints: per leg a list of (joint, frame)."""
    moving = [j for j in rd.children.get(torso.name, []) if j.type != "fixed"]
    for j in moving:
        if j.type not in _ROTATING:
            rd.fail(f"joint {j.name!r} is {j.type}: a planar biped's legs hang from the "
                    f"torso by revolute joints")
    if len(moving) != 2:
        rd.fail(f"the torso {torso.name!r} has {len(moving)} jointed children "
                f"({', '.join(repr(j.name) for j in moving) or 'none'}); a biped has two legs")
    legs = []
    for hip in moving:
        chain, joint, frame = [], hip, torso
        while joint is not None:
            frame = _child_frame(frame, joint)
            chain.append((joint, frame))
            nxt = [j for j in rd.children.get(frame.name, []) if j.type != "fixed"]
            for j in nxt:
                if j.type not in _ROTATING:
                    rd.fail(f"joint {j.name!r} is {j.type}: only revolute joints make "
                            f"a planar biped's legs")
            if len(nxt) > 1:
                rd.fail(f"link {frame.name!r} has {len(nxt)} jointed children: a leg is "
                        f"one chain of links")
            joint = nxt[0] if nxt else None
        legs.append(chain)
    return legs


def _axis(rd: _Reader, legs) -> np.ndarray:
    """The common axis of every leg joint (torso frame, sign: toward +y of the torso)."""
    axes = []
    for chain in legs:
        for joint, frame in chain:
            a = np.array(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), float)
            if not np.linalg.norm(a) > 0:
                rd.fail(f"joint {joint.name!r} has a zero axis")
            axes.append((joint.name, frame.R @ a / np.linalg.norm(a)))
    def parallel(a, b):
        return np.linalg.norm(np.cross(a, b)) <= 1e-9
    n = max((a for _, a in axes), key=lambda a: sum(parallel(a, b) for _, b in axes))
    n = n if n[1] >= 0 else -n
    for name, a in axes:
        if not parallel(a, n):
            rd.fail(f"joint {name!r} turns about {np.round(a, 6).tolist()}, not about the "
                    f"other joints' axis {np.round(n, 6).tolist()}: not a planar robot")
    return n


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


def _actuators(rd: _Reader, joints, text: str) -> tuple:
    """(rotor inertia, gear ratio, torque limit) shared by every leg joint."""
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
    efforts = {j.name: (None if j.limit is None else j.limit.effort) for j in joints}
    if rd.robot.transmissions:
        passive = [j.name for j in joints if j.name not in reductions]
    else:
        passive = []
        rd.notes.append("no <transmission>: every leg joint actuated, no rotor inertia")
    passive += [n for n, e in efforts.items() if e is not None and float(e) == 0.0
                and n not in passive]
    if passive:
        rd.fail(f"joint {passive[0]!r} has no actuator (no <transmission>, or effort 0): "
                f"with the passive stance foot that makes more than one unactuated joint, "
                f"which the model does not support")
    rotors = {}
    for j in joints:
        try:
            motor = float(motors.get(j.name, 0.0))
            gear = float(reductions.get(j.name, 1.0))
        except ValueError:
            rd.fail(f"the transmission of joint {j.name!r} has a non-numeric motorInertia "
                    f"or mechanicalReduction")
        rotors[j.name] = (motor, gear)
    values = {n: m * g ** 2 for n, (m, g) in rotors.items()}
    ref = next(iter(values.values()))
    for n, v in values.items():
        if not math.isclose(v, ref, rel_tol=1e-12, abs_tol=0.0):
            rd.fail(f"reflected rotor inertias differ: joint {n!r} {v:g}, joint "
                    f"{next(iter(values))!r} {ref:g} kg m^2 (the model takes one for "
                    f"every joint)")
    given = [float(e) for e in efforts.values() if e is not None]
    if not given:
        rd.fail("no leg joint gives <limit effort=...>: the torque limit is unknown")
    if len(set(given)) > 1:
        rd.notes.append(f"joint efforts differ ({', '.join(f'{v:g}' for v in sorted(set(given)))}"
                        f" N m): the torque limit is the smallest")
    motor, gear = next(iter(rotors.values()))
    return motor, gear, min(given)


# ------------------------------------------------------------------ the foot
_FOOT_WORDS = ("foot", "toe", "sole", "contact", "ankle")


def _foot_point(rd: _Reader, last: _Frame, foot) -> tuple:
    """(foot point in the torso frame, where it came from, the foot link or None)."""
    if foot is not None:
        f = np.asarray(foot, dtype=float).ravel()
        return last.p + last.R @ f, "foot= argument", None
    cands = [(j, f) for j, f in _fixed_descendants(rd, last)
             if j.parent == last.name]
    if len(cands) > 1:
        named = [c for c in cands if any(w in c[1].name.lower() for w in _FOOT_WORDS)]
        cands = named if len(named) == 1 else cands
    if len(cands) != 1:
        what = "no child link or fixed frame" if not cands else \
            f"{len(cands)} fixed children ({', '.join(repr(c[1].name) for c in cands)})"
        rd.fail(f"no foot: the last leg link {last.name!r} has {what}; give the foot "
                f"point in its frame (foot=(x, y, z), or 'biped robot import FILE --foot "
                f"X Y Z --out robot.toml')")
    j, f = cands[0]
    return f.p, f"link {f.name!r}", f.name


# ------------------------------------------------------------------ assembly
_SIDES = {"left", "right", "l", "r", "lft", "rgt", "lt", "rt"}


def _common_name(a: str, b: str, default: str) -> str:
    """'femur' from 'femur_left' / 'femur_right', 'l_femur' / 'r_femur', ..."""
    def tokens(s):
        return [t for t in re.split(r"[_\-\s.]+", s) if t and t.lower() not in _SIDES]
    ta, tb = tokens(a), tokens(b)
    if ta and ta == tb:
        return "_".join(ta)
    i = 0
    while i < min(len(a), len(b)) and a[i] == b[i]:
        i += 1
    return a[:i].strip("_- .") or default


def _in_plane(d, n) -> float:
    """The length of ``d`` in the plane of motion (normal ``n``)."""
    return float(np.linalg.norm(d - np.dot(d, n) * n))


class _Leg:
    """One leg read in the plane: joint points, link bodies, point masses."""

    def __init__(self, rd: _Reader, chain, foot_p, foot_link):
        self.rd = rd
        self.joints = [j for j, _ in chain]
        self.frames = [f for _, f in chain]
        self.points = [f.p for f in self.frames] + [foot_p]
        self.foot_link = foot_link

    def body(self, i: int, up, fwd, pm: dict) -> dict:
        """Link i (from the hip) in the schema: mass, length, com, inertia; point masses
        found on it are added to ``pm`` (joint name -> kg)."""
        rd, frame = self.rd, self.frames[i]
        link = rd.links[frame.name]
        body = _body(link, frame.R, frame.p)
        if body is None or body.mass <= 0:
            rd.fail(f"link {link.name!r} has no <inertial> with a positive mass")
        k = len(self.frames)
        names = joint_names(k)
        ends = {0: self.points[i], 1: self.points[i + 1]}
        for j, f in _fixed_descendants(rd, frame):
            extra = _body(rd.links[f.name], f.R, f.p)
            if extra is None or extra.mass == 0.0:
                continue
            at = [e for e, pt in ends.items() if _in_plane(extra.com - pt, rd.n) <= rd.tol]
            if at and not np.any(extra.inertia):
                joint = names[i + at[0]]
                pm[joint] = pm.get(joint, 0.0) + extra.mass
            else:
                body = body.plus(extra)
                rd.notes.append(f"fixed link {f.name!r} merged into {link.name!r}")
        top, bottom = self.points[i], self.points[i + 1]
        length = float(np.dot(top - bottom, up))
        off = float(np.dot(body.com - top, fwd))
        if abs(off) > rd.tol:
            rd.fail(f"link {link.name!r}: its centre of mass is {off:.3g} m off the link's "
                    f"axis in the plane of motion (off-axis centres of mass are not "
                    f"supported)")
        n = np.cross(fwd, up)
        return dict(name=link.name, mass=body.mass, length=length,
                    com=float(np.dot(top - body.com, up)), inertia=float(n @ body.inertia @ n))


def _check_line(rd: _Reader, legs, up, fwd):
    """Every joint and foot of both legs on the line below the hip (at zero angles)."""
    hip = legs[0].points[0]
    for leg in legs:
        for pt, name in zip(leg.points, [f.name for f in leg.frames] + ["foot"]):
            off = float(np.dot(pt - hip, fwd)), float(np.dot(pt - hip, up))
            if abs(off[0]) > rd.tol:
                rd.fail(f"at zero joint angles the leg is not straight below the hip: the "
                        f"{'foot' if name == 'foot' else f'joint of link {name!r}'} is "
                        f"{off[0]:.3g} m in front of it (q = 0 must be upright)")
        if abs(float(np.dot(leg.points[0] - hip, up))) > rd.tol:
            rd.fail("the two hip joints are not at the same height")
        steps = np.diff([float(np.dot(p - hip, up)) for p in leg.points])
        if np.any(steps >= 0):
            rd.fail(f"leg {leg.joints[0].name!r}: its joints and foot must go down from "
                    f"the hip, one link after the other")


def _torso(rd: _Reader, frame: _Frame, hip, up, fwd, pm: dict) -> dict:
    link = rd.links[frame.name]
    body = _body(link, frame.R, frame.p)
    if body is None or body.mass <= 0:
        rd.fail(f"link {link.name!r} (the torso) has no <inertial> with a positive mass")
    for j, f in _fixed_descendants(rd, frame):
        extra = _body(rd.links[f.name], f.R, f.p)
        if extra is None or extra.mass == 0.0:
            continue
        if _in_plane(extra.com - hip, rd.n) <= rd.tol and not np.any(extra.inertia):
            pm["hip"] = pm.get("hip", 0.0) + extra.mass
        else:
            body = body.plus(extra)
            rd.notes.append(f"fixed link {f.name!r} merged into the torso")
    off = float(np.dot(body.com - hip, fwd))
    if abs(off) > rd.tol:
        rd.fail(f"link {link.name!r} (the torso): its centre of mass is {off:.3g} m off "
                f"the torso's axis in the plane of motion (off-axis centres of mass are "
                f"not supported)")
    com = float(np.dot(body.com - hip, up))
    n = np.cross(fwd, up)
    return dict(name=link.name, mass=body.mass, length=_torso_length(rd, link, frame, hip, up, com),
                com=com, inertia=float(n @ body.inertia @ n))


def _torso_length(rd: _Reader, link, frame: _Frame, hip, up, com: float) -> float:
    """The top of the torso's geometry above the hip (else 2 com)."""
    tops = []
    for g in list(link.visuals or []) + list(link.collisions or []):
        R, p = _pose(g.origin)
        R, p = frame.R @ R, frame.p + frame.R @ p
        u = R.T @ up                         # up in the geometry's frame
        geo = g.geometry
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
    rd.notes.append("the torso has no box, cylinder or sphere geometry: its length (for "
                    "drawings) is twice its centre-of-mass height")
    return 2.0 * com if com > 0 else 1e-3


# ------------------------------------------------------------------ entry points
def _parse(text: str, where: str):
    """The parsed robot and the parser's complaints (unknown tags are not errors)."""
    said = []
    keep = _xml_core.on_error
    _xml_core.on_error = said.append
    try:
        robot = _urdf.URDF.from_xml_string(text.encode())
    except Exception as e:       # noqa: BLE001 - lxml, assertions and KeyErrors of the parser
        raise ValueError(f"{where}: cannot parse the URDF ({' '.join(str(e).split()) or type(e).__name__})"
                         ) from None
    finally:
        _xml_core.on_error = keep
    return robot, said


def import_urdf(path, foot=None, tol: float = GEOMETRY_TOL) -> UrdfImport:
    """Read a planar biped from a URDF file (what is read: the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.urdf`` file.
    foot : sequence of 3 floats, optional
        The foot point in the frame of each leg's last link, m; needed when that link
        has no fixed child link (frame) to mark the foot.
    tol : float
        m: how far joints, feet and centres of mass may be off the legs' lines.

    Returns
    -------
    UrdfImport
        The description, the links and joints found, and notes.

    Raises
    ------
    ValueError
        One message naming the file and what is wrong (module docstring).
    """
    path = Path(path)
    where = f"URDF file {path}"
    if foot is not None:
        f = np.asarray(foot, dtype=float).ravel()
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ValueError(f"foot must be 3 finite numbers (x, y, z in m), got {foot!r}")
    text = read_text_file(path, "URDF file", 20_000_000)
    robot, said = _parse(text, where)
    rd = _Reader(robot, where, tol)
    torso = _Frame(rd.torso(), np.eye(3), np.zeros(3))
    chains = _legs(rd, torso)
    n = rd.n = _axis(rd, chains)
    feet = [_foot_point(rd, chain[-1][1], foot) for chain in chains]
    legs = [_Leg(rd, chain, p, link) for chain, (p, _, link) in zip(chains, feet)]
    if len(legs[0].frames) != len(legs[1].frames):
        rd.fail(f"legs differ: {len(legs[0].frames)} and {len(legs[1].frames)} links")
    hip = legs[0].points[0]
    down = legs[0].points[-1] - hip
    down = down - np.dot(down, n) * n
    if not np.linalg.norm(down) > 0:
        rd.fail("the foot is at the hip")
    up = -down / np.linalg.norm(down)
    fwd = np.cross(n, up)
    _check_line(rd, legs, up, fwd)
    motor, gear, effort = _actuators(rd, [j for leg in legs for j in leg.joints], text)
    pm_legs = [dict(), dict()]
    links = [[leg.body(i, up, fwd, pm) for i in range(len(leg.frames))]
             for leg, pm in zip(legs, pm_legs)]
    _same_legs(rd, links, pm_legs)
    pm = {"hip": 0.0}
    torso_d = _torso(rd, torso, hip, up, fwd, pm)
    pm["hip"] += pm_legs[0].pop("hip", 0.0) + pm_legs[1].pop("hip", 0.0)
    pm.update(pm_legs[0])
    if pm["hip"] == 0.0:
        del pm["hip"]
    for i, (a, b) in enumerate(zip(*links)):
        a["name"] = _common_name(a["name"], b["name"], f"link{i + 1}")
    data = dict(name=robot.name or path.stem, gravity=9.81,
                actuators=dict(torque_limit=effort, rotor_inertia=motor, gear_ratio=gear),
                torso=torso_d, leg=links[0], point_masses=pm)
    rd.notes += [f"ignored: {s}" for s in said if "motorInertia" not in s]
    d = description_from_dict(data, where=where, source=str(path))
    return UrdfImport(d, torso.name, tuple(tuple(j.name for j in leg.joints) for leg in legs),
                      feet[0][1], rd.notes)


def _same_legs(rd: _Reader, links, pms):
    for a, b in zip(*links):
        for key in ("mass", "length", "com", "inertia"):
            if not math.isclose(a[key], b[key], rel_tol=1e-9, abs_tol=rd.tol):
                rd.fail(f"legs differ: link {a['name']!r} has {key} {a[key]:.6g}, link "
                        f"{b['name']!r} {b[key]:.6g}")
    if set(pms[0]) - {"hip"} != set(pms[1]) - {"hip"} or any(
            not math.isclose(pms[0][k], pms[1][k], rel_tol=1e-9) for k in pms[0] if k != "hip"):
        rd.fail(f"legs differ in their point masses: {pms[0]} and {pms[1]}")


def load_urdf(path, foot=None) -> RobotDescription:
    """The robot description of a URDF file (:func:`import_urdf` without the notes).

    Parameters
    ----------
    path : str or Path
        The ``.urdf`` file.
    foot : sequence of 3 floats, optional
        The foot point in the last leg link's frame, m.

    Returns
    -------
    RobotDescription

    Raises
    ------
    ValueError
        Naming the file and what is wrong.
    """
    return import_urdf(path, foot).description


def description_toml(d: RobotDescription, header: str = "") -> str:
    """A description file (TOML) that loads back to a description equal to ``d``.

    The schema is that of :mod:`biped_casadi.model.description`.

    Parameters
    ----------
    d : RobotDescription
        The robot.
    header : str
        Comment lines to put first (``#`` added).

    Returns
    -------
    str
        TOML text; numbers written with ``repr`` (exact round trip).
    """
    def table(t):
        return "\n".join(f"{k} = {v!r}" if isinstance(v, float) else f"{k} = {_q(v)}"
                         for k, v in t.items())
    dd = d.to_dict()
    out = [f"# {line}" for line in header.splitlines()]
    out += [f"name = {_q(dd['name'])}", f"gravity = {dd['gravity']!r}", "",
            "[actuators]", table(dd["actuators"]), "", "[torso]", table(dd["torso"])]
    for link in dd["leg"]:
        out += ["", "[[leg]]", table(link)]
    if dd["point_masses"]:
        out += ["", "[point_masses]", table(dd["point_masses"])]
    return "\n".join(out) + "\n"


def _q(s: str) -> str:
    """A TOML basic string."""
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'
