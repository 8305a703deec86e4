"""A URDF's tree read at zero joint angles in its torso's frame: poses of links and
joints, inertials, the torso (through a massless root and its floating, planar or fixed
joint), the two legs as chains of rotating joints (hanging from the torso or from its
fixed frames), and the normal of the plane of motion with each joint's sign against it;
the joints held fixed (``lock``: each a fixed joint, its child frame turned by its angle).
The importer (:mod:`biped_casadi.model.urdf`) builds the robot from these."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_ROTATING = ("revolute", "continuous")
_BASE = ("floating", "planar", "fixed")


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
    """(R, p) of a URDF <origin> (identity when absent; a locked joint's exact turn)."""
    if isinstance(origin, _LockedPose):
        return origin.R, origin.xyz
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = np.zeros(3) if origin.xyz is None else np.array(origin.xyz, dtype=float)
    return _rotation(origin.rpy), xyz


@dataclass
class _LockedPose:
    """The origin of a locked joint: its own pose composed with the turn by the lock's
    angle about its axis, kept as a matrix (no round trip through roll-pitch-yaw)."""
    R: np.ndarray
    xyz: np.ndarray


def _turn(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation by ``angle`` about the unit ``axis`` (Rodrigues; exactly I at 0)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def lock_table(lock, lock_off_axis: bool = False, axis=None) -> dict:
    """``lock`` (a mapping name -> angle, or names and (name, angle) pairs) as a dict
    name -> float angle (rad, 0 for a bare name), the options checked.

    Parameters
    ----------
    lock : mapping or iterable or None
        The joints to hold fixed and their angles.
    lock_off_axis : bool
        Whether the joints off the plane's normal are locked too.
    axis : {'x', 'y'} or None
        The plane's normal for ``lock_off_axis`` (torso frame).

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        One line naming the joint: a name that is not a non-empty string, an angle that
        is not a finite number, a joint given twice; an ``axis`` other than 'x' or 'y',
        or without ``lock_off_axis``.
    """
    if axis is not None and axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y' (the torso frame's axis that is the "
                         f"plane's normal; z, vertical at pitch 0, lies in the plane), got "
                         f"{axis!r}")
    if axis is not None and not lock_off_axis:
        raise ValueError("axis chooses the plane's normal for lock_off_axis: give it with "
                         "lock_off_axis=True (--lock-off-axis)")
    if lock is None:
        return {}
    if hasattr(lock, "items"):
        items = list(lock.items())
    elif isinstance(lock, str):
        items = [(lock, 0.0)]
    else:
        items = []
        for x in lock:
            if not isinstance(x, (str, tuple, list)) or (not isinstance(x, str) and len(x) != 2):
                raise ValueError(f"lock: give joint names, (name, angle) pairs or a mapping "
                                 f"name -> angle, got {x!r}")
            items.append((x, 0.0) if isinstance(x, str) else tuple(x))
    out = {}
    for name, angle in items:
        if not isinstance(name, str) or not name:
            raise ValueError(f"lock: joint names must be non-empty strings, got {name!r}")
        if name in out:
            raise ValueError(f"lock: joint {name!r} is locked twice")
        if isinstance(angle, bool) or not isinstance(angle, (int, float, np.floating, np.integer)) \
                or not math.isfinite(angle):
            raise ValueError(f"lock: joint {name!r} needs a finite angle in rad, got {angle!r}")
        out[name] = float(angle)
    return out


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


@dataclass
class _Frame:
    """A link posed at zero joint angles: its rotation and origin in the torso frame."""
    name: str
    R: np.ndarray
    p: np.ndarray


#: rad: joint axes this close to one line are parallel (CAD exporters write angles to
#: 3 to 6 decimals: rpy 1.5708 turns an axis 3.7e-6 rad off pi/2, 1.571 2e-4); the model
#: turns every joint about their mean axis and the notes give the largest deviation
AXIS_TOL = 1e-3


def _parallel(a, b) -> bool:
    """Unit vectors along one line (either sense), within :data:`AXIS_TOL`."""
    return bool(np.linalg.norm(np.cross(a, b)) <= AXIS_TOL)


def _deviation(a, b) -> float:
    """The angle between the lines of two unit vectors, rad."""
    return float(math.atan2(np.linalg.norm(np.cross(a, b)), abs(float(np.dot(a, b)))))


def _child_frame(parent: _Frame, joint) -> _Frame:
    R, p = _pose(joint.origin)
    return _Frame(joint.child, parent.R @ R, parent.p + parent.R @ p)


# ------------------------------------------------------------------ the tree
class _Reader:
    """The URDF's tree, posed at zero joint angles in the torso's frame."""

    def __init__(self, robot, where: str, tol: float):
        self.robot, self.where, self.tol = robot, where, tol
        #: said after every refusal once ``lock_off_axis`` chose by its vote a plane
        #: whose normal is not the torso frame's y
        self.plane_vote = ""
        self._check_names()
        self._check_numbers()
        self.links = {link.name: link for link in robot.links}
        self.children = {}
        for j in robot.joints:
            self.children.setdefault(j.parent, []).append(j)
        self.order = {j.name: i for i, j in enumerate(robot.joints)}
        self.notes = []
        self.planar_axis = None
        #: (the world's z in the torso frame, the links and joints above the torso) when
        #: the torso hangs from a massless root (a world link), else None
        self.world_up = None
        self.locked = {}

    def fail(self, problem: str):
        raise ValueError(f"{self.where}: {problem}{self.plane_vote}")

    def unit_axis(self, joint) -> np.ndarray:
        """A rotating joint's axis as a unit vector in its own frame (x without one)."""
        a = np.array(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), float)
        if not np.linalg.norm(a) > 0:
            self.fail(f"joint {joint.name!r} has a zero axis")
        return a / np.linalg.norm(a)

    def lock(self, lock: dict):
        """Hold the joints of ``lock`` (name -> angle, rad) fixed: each becomes a fixed
        joint whose child frame is its origin turned by the angle about its axis."""
        joints = {j.name: j for j in self.robot.joints}
        for name, angle in lock.items():
            j = joints.get(name)
            if j is None:
                self.fail(f"lock: the file has no joint {name!r}")
            if j.type not in _ROTATING:
                self.fail(f"lock: joint {name!r} is {j.type}: only revolute and continuous "
                          f"joints can be locked")
            R, p = _pose(j.origin)
            j.origin = _LockedPose(R @ _turn(self.unit_axis(j), angle), p)
            j.type = "fixed"
            self.locked[name] = angle
            lim = j.limit
            if lim is not None and lim.lower is not None and lim.upper is not None \
                    and lim.lower < lim.upper and not lim.lower <= angle <= lim.upper:
                self.notes.append(f"joint {name!r} is locked at {angle:g} rad, outside its "
                                  f"range [{lim.lower:g}, {lim.upper:g}]")

    def rotating_axes(self, torso: str) -> list:
        """(joint name, unit axis in the torso frame) of every revolute or continuous
        joint below the torso at zero joint angles, in the file's order."""
        out, todo = [], [_Frame(torso, np.eye(3), np.zeros(3))]
        while todo:
            frame = todo.pop()
            for j in self.children.get(frame.name, []):
                child = _child_frame(frame, j)
                todo.append(child)
                if j.type in _ROTATING:
                    out.append((j.name, child.R @ self.unit_axis(j)))
        return sorted(out, key=lambda na: self.order[na[0]])

    def off_axis(self, torso: str, axis, keep) -> tuple:
        """(n, joints off it, why): the plane's normal for ``lock_off_axis`` and the
        revolute or continuous joints below the torso (but those of ``keep``) whose axis
        at zero joint angles is not parallel to it.  n is the torso frame's ``axis``
        ('x' or 'y'), else the direction across the torso's z that most of the joints
        below the torso turn about (those of ``keep`` too: a robot's locked ankle pitch
        and arm joints vote for its sagittal plane, where a frame turned so that its x is
        lateral would otherwise tie its pitch and roll joints; a tie: the one nearer the
        torso's y, then the first in the file).  A humanoid's hands can outvote its legs
        (JVRC-1: 22 joints about x against 12): the refusals that follow say so."""
        axes = self.rotating_axes(torso)
        if axis is not None:
            n = np.eye(3)[{"x": 0, "y": 1}[axis]]
            why = f"--axis {axis}"
        else:
            across = [a for _, a in axes if abs(a[2]) <= AXIS_TOL]
            if not across:
                self.fail("lock_off_axis: no revolute or continuous joint below the torso "
                          "turns about an axis across its frame's z (the plane's normal)")
            counts = [sum(_parallel(a, b) for _, b in axes) for a in across]
            best = max(range(len(across)),
                       key=lambda i: (counts[i], round(abs(across[i][1]), 9), -i))
            n = across[best]
            why = f"the axis of {counts[best]} of the {len(axes)} joints"
        off = [name for name, a in axes if name not in keep and not _parallel(a, n)]
        return n, off, why

    def _check_names(self):
        """Links and joints defined once; every joint's parent and child defined, and no
        link the child of two joints."""
        for kind, items in (("link", self.robot.links), ("joint", self.robot.joints)):
            seen = set()
            for item in items:
                if item.name in seen:
                    self.fail(f"{kind} {item.name!r} is defined twice")
                seen.add(item.name)
        links = {link.name for link in self.robot.links}
        parents = {}
        for j in self.robot.joints:
            for role, name in (("parent", j.parent), ("child", j.child)):
                if name not in links:
                    self.fail(f"joint {j.name!r} names {role} link {name!r}, which the file "
                              f"does not define")
            if j.child in parents:
                self.fail(f"link {j.child!r} is the child of two joints ({parents[j.child]!r} "
                          f"and {j.name!r}): not a tree")
            parents[j.child] = j.name

    def _check_numbers(self):
        """Every number the model is made from is finite."""
        def check(owner, tag, values):
            if values is None:
                return
            for v in np.atleast_1d(np.asarray(values, dtype=float)):
                if not math.isfinite(v):
                    self.fail(f"{owner}: <{tag}> has a value that is not finite ({v:g})")
        for j in self.robot.joints:
            owner = f"joint {j.name!r}"
            if j.origin is not None:
                check(owner, "origin", list(j.origin.xyz or []) + list(j.origin.rpy or []))
            check(owner, "axis", j.axis)
            if j.limit is not None:
                check(owner, "limit effort", j.limit.effort)
        for link in self.robot.links:
            i = link.inertial
            if i is None:
                continue
            owner = f"link {link.name!r}"
            if i.origin is not None:
                check(owner, "inertial origin", list(i.origin.xyz or []) + list(i.origin.rpy or []))
            check(owner, "mass", i.mass)
            if i.inertia is not None:
                check(owner, "inertia", [i.inertia.ixx, i.inertia.ixy, i.inertia.ixz,
                                         i.inertia.iyy, i.inertia.iyz, i.inertia.izz])

    def torso(self, given: str | None = None) -> str:
        """The torso: ``given``, else the root, or the first link with mass below a chain
        of massless links each joined to the next by the one floating, planar or fixed
        joint."""
        if given is not None:
            return self._given_torso(given)
        kids = {j.child for j in self.robot.joints}
        roots = [name for name in self.links if name not in kids]
        if not roots:
            self.fail("no root link: the joints make a loop (every link is some joint's child)")
        alone = [n for n in roots if n not in self.children and _mass(self.links[n]) == 0.0]
        if len(roots) > 1 and len(roots) - len(alone) == 1:
            self.notes.append(f"ignored: link(s) {', '.join(repr(n) for n in alone)} without "
                              f"mass and joints (not part of the robot's tree)")
            roots = [n for n in roots if n not in alone]
        else:
            alone = []
        if len(roots) != 1:
            self.fail(f"must be one tree of links, found roots {roots}: join them by joints "
                      f"(a fixed joint for a part of one body) or delete the links that are "
                      f"not the robot's")
        name = roots[0]
        reached = self.subtree(name)
        cut = [n for n in self.links if n not in reached and n not in alone]
        if cut:
            self.fail(f"link(s) {', '.join(repr(n) for n in cut[:4])} not connected to the "
                      f"root link {name!r}: the joints make a loop")
        R, above = np.eye(3), []
        while _mass(self.links[name]) == 0.0:
            joints = self.children.get(name, [])
            if len(joints) != 1 or joints[0].type not in _BASE:
                break
            j = joints[0]
            Rj = _pose(j.origin)[0]
            R = R @ Rj
            if not np.allclose(Rj, np.eye(3), rtol=0.0, atol=1e-12):
                above.append(j.name)            # the joints that turn the torso's frame
            self.world_up = (R.T @ np.array([0.0, 0.0, 1.0]), roots[0], above)
            what = {"fixed": "fixes the robot to it"}.get(j.type, "is the robot's base")
            self.notes.append(f"{j.type} joint {j.name!r} from the massless link {name!r}: "
                              f"{what} in the file, not a joint of the model (the stance "
                              f"foot is its base); pitch is the angle of link {j.child!r} "
                              f"in the world")
            if j.type == "planar" and j.axis is not None:
                self.planar_axis = np.array(j.axis, float)     # in the child's frame
            name = j.child
        return name

    def _given_torso(self, name: str) -> str:
        """The link ``name`` as the torso: the links above and beside it (a test rig, a
        boom) are not the robot's; the joints from the root to it hold it in the file."""
        if not isinstance(name, str) or name not in self.links:
            self.fail(f"torso: the file has no link {name!r}")
        parent = {j.child: j for j in self.robot.joints}
        path, at, seen = [], name, {name}
        while at in parent:
            j = parent[at]
            path.insert(0, j)
            at = j.parent
            if at in seen:
                self.fail("no root link: the joints make a loop (every link is some joint's "
                          "child)")
            seen.add(at)
        reached = self.subtree(name)
        if path:
            R, turning = np.eye(3), []
            for j in path:
                Rj = _pose(j.origin)[0]
                R = R @ Rj
                if not np.allclose(Rj, np.eye(3), rtol=0.0, atol=1e-12):
                    turning.append(j.name)
            self.world_up = (R.T @ np.array([0.0, 0.0, 1.0]), at, turning)
            out = [n for n in self.links if n not in reached]
            mass = sum(_mass(self.links[n]) for n in out)
            self.notes.append(
                f"torso {name!r} (torso=): the joint(s) "
                f"{', '.join(f'{j.name!r} ({j.type})' for j in path)} from the root {at!r} "
                f"hold it in the file, not joints of the model (the stance foot is its base); "
                f"the {len(out)} link(s) above and beside it ({mass:g} kg) are not in the "
                f"model; pitch is the angle of link {name!r} in the world")
        return name

    def subtree(self, name: str) -> set:
        """The links at and below link ``name``."""
        reached, todo = {name}, [name]
        while todo:
            for j in self.children.get(todo.pop(), []):
                if j.child not in reached:
                    reached.add(j.child)
                    todo.append(j.child)
        return reached

    def fixed_descendants(self, frame: _Frame) -> list:
        """(joint, frame) of every link hanging from ``frame`` by fixed joints only."""
        out = []
        for j in self.children.get(frame.name, []):
            if j.type == "fixed":
                f = _child_frame(frame, j)
                out.append((j, f))
                out.extend(self.fixed_descendants(f))
        return out

    def moving(self, frame: _Frame) -> list:
        """(joint, parent frame) of the moving joints of a link and of its fixed frames."""
        out = []
        for f in [frame] + [f for _, f in self.fixed_descendants(frame)]:
            for j in self.children.get(f.name, []):
                if j.type == "fixed":
                    continue
                if j.type not in _ROTATING:
                    self.fail(f"joint {j.name!r} is {j.type}: a planar biped's legs are "
                              f"chains of revolute (or continuous) joints")
                out.append((j, f))
        return sorted(out, key=lambda jf: self.order[jf[0].name])


def apply_locks(rd: "_Reader", torso: str, lock: dict, off_axis: bool, axis) -> None:
    """Hold the joints of ``lock`` fixed, and with ``off_axis`` every revolute or
    continuous joint off the plane's normal at 0 (said in the notes)."""
    if off_axis:
        n, off, why = rd.off_axis(torso, axis, lock)
        normal = (np.round(np.where(np.abs(n) < 1e-12, 0.0, n), 6) + 0.0).tolist()
        rd.notes.append(f"lock_off_axis: the plane's normal is {normal} in the torso frame "
                        f"({why}); locked at 0 as off it: {', '.join(off) or 'no joint'}")
        if axis is None and not _parallel(n, np.array([0.0, 1.0, 0.0])):
            # a vote for other than the torso's y (across a frame of x forward, z up) may
            # be the hands' and rolls': every refusal says which plane it took
            rd.plane_vote = (f" (--lock-off-axis took the plane's normal {normal} of the "
                             f"torso frame, {why}: --axis x|y chooses it)")
        lock = {**lock, **dict.fromkeys(off, 0.0)}
    rd.lock(lock)
    if lock:
        names = sorted(lock, key=rd.order.get)
        rd.notes.append(f"locked: {', '.join(f'{k} at {lock[k]:g}' for k in names)} rad: "
                        f"fixed joints of the model, merged into their parent links (the "
                        f"robot must hold them at these angles with its own position loops; "
                        f"the planar model leaves out lateral balance and out-of-plane motion)")


def _legs(rd: _Reader, torso: _Frame) -> list:
    """The torso's two chains of rotating joints: per leg a list of (joint, frame)."""
    below = _jointed(rd, torso)
    if len(below) == 1:
        _held(rd, torso, below[0])
    hips = rd.moving(torso)
    if len(hips) != 2:
        rd.fail(f"the torso {torso.name!r} has {len(hips)} jointed children "
                f"({', '.join(repr(j.name) for j, _ in hips) or 'none'}); a biped has two legs"
                + (" (lock the joints of the others, e.g. arms: 'biped robot import FILE "
                   "--lock NAME', lock=)"
                   + _off_plane_hint(rd, torso, hips) if len(hips) > 2 else ""))
    legs = []
    for hip, parent in hips:
        chain, item = [], (hip, parent)
        while item is not None:
            joint, parent = item
            if getattr(joint, "mimic", None) is not None:
                rd.fail(f"joint {joint.name!r} mimics joint {joint.mimic.joint!r} (<mimic>): "
                        f"its angle is not free, and every leg joint of the model is an "
                        f"independent, actuated one; a sagittal model that holds it fixed "
                        f"locks it ('biped robot import FILE --lock {joint.name}[=RAD]', "
                        f"lock={{{joint.name!r}: 0}})")
            frame = _child_frame(parent, joint)
            chain.append((joint, frame))
            nxt = rd.moving(frame)
            if len(nxt) > 1:
                rd.fail(f"link {frame.name!r} has {len(nxt)} jointed children "
                        f"({', '.join(repr(j.name) for j, _ in nxt)}): a leg is one chain "
                        f"of links (lock the joints of the others: 'biped robot import "
                        f"FILE --lock NAME', lock=; a "
                        f"closed linkage cut open in the file, as a four-bar leg, is not one "
                        f"and locking a branch makes another robot)")
            item = nxt[0] if nxt else None
        legs.append(chain)
    return legs


def _off_plane_hint(rd: _Reader, torso: _Frame, hips) -> str:
    """'; ... --lock-off-axis' when some of the torso's jointed children turn out of the
    plane most joints below it turn in (a 3-D robot), else ''."""
    try:
        _, off, _ = rd.off_axis(torso.name, None, ())
    except ValueError:                    # no joint turns across the torso's z
        return ""
    off = [j.name for j, _ in hips if j.name in off]
    return (f"; {', '.join(map(repr, off))} turn(s) out of the plane most joints turn in: "
            f"a 3-D robot's sagittal model locks every such joint with 'biped robot "
            f"import FILE --lock-off-axis' (lock_off_axis=True)") if off else ""


def _jointed(rd: _Reader, frame: _Frame) -> list:
    """(joint, parent frame) of the joints of any type but fixed below a link and its
    fixed frames."""
    return [(k, f) for f in [frame] + [g for _, g in rd.fixed_descendants(frame)]
            for k in rd.children.get(f.name, []) if k.type != "fixed"]


def _held(rd: _Reader, torso: _Frame, joint) -> None:
    """Refuse a torso whose one moving joint leads to the link the legs hang from: the
    joints above that link hold the robot (a test rig, a boom, a pin to the world)."""
    j, parent = joint
    above = [j]
    while True:
        frame = _child_frame(parent, j)
        nxt = _jointed(rd, frame)
        if len(nxt) != 1:
            break
        j, parent = nxt[0]
        above.append(j)
    if len(nxt) == 2:
        names = ", ".join(f"{k.name!r} ({k.type})" for k in above)
        rd.fail(f"the legs hang from link {frame.name!r}, held by the joint(s) {names} "
                f"from {torso.name!r} (a test rig, a boom, a pin?): not joints of "
                f"a free biped; name the torso ('biped robot import FILE --torso "
                f"{frame.name}', torso={frame.name!r}: what is above it is left out) or make "
                f"{frame.name!r} the file's root link")


def _axis(rd: _Reader, legs) -> tuple:
    """The plane's normal n (torso frame, oriented as the module docstring says) and the
    sign of every leg joint's axis against it."""
    axes = [(joint.name, frame.R @ rd.unit_axis(joint)) for chain in legs
            for joint, frame in chain]
    n = max((a for _, a in axes), key=lambda a: sum(_parallel(a, b) for _, b in axes))
    n = _mean_axis(rd, n, axes)
    for name, a in axes:
        if not _parallel(a, n):
            turned = " (turned by the locked joints' angles)" if any(rd.locked.values()) \
                else ""
            rd.fail(f"joint {name!r} turns about {np.round(a, 6).tolist()}{turned}, not about "
                    f"the other joints' axis {np.round(n, 6).tolist()} (torso frame): not a "
                    f"planar robot; for its sagittal model lock it ('biped robot import "
                    f"FILE --lock {name}', lock={{{name!r}: 0}}) or every joint off that "
                    f"axis (--lock-off-axis)")
    if rd.planar_axis is not None and _parallel(rd.planar_axis, n):
        n = n if np.dot(rd.planar_axis, n) > 0 else -n
    elif abs(n[1]) > 1e-9:
        n = n if n[1] > 0 else -n
    else:
        n = n if n[int(np.argmax(np.abs(n)))] > 0 else -n
    n = n + 0.0                                       # -0.0 (of a flipped n) is 0.0
    if abs(n[2]) > AXIS_TOL:
        rd.fail(f"the joints turn about {np.round(n, 6).tolist()} (torso frame): the torso "
                f"frame's z axis, vertical at pitch 0, must lie in the plane of motion")
    if rd.world_up is not None and abs(float(np.dot(rd.world_up[0], n))) > AXIS_TOL:
        up, root, above = rd.world_up
        rd.fail(f"the world's vertical (z of the root link {root!r}) is "
                f"{(np.round(up, 6) + 0.0).tolist()} in the torso's frame, turned by the "
                f"origin of {', '.join(repr(a) for a in above)} above it: not in the plane of "
                f"the legs (normal {(np.round(n, 6) + 0.0).tolist()}), so gravity would act "
                f"across it (a file written with another axis up?); the importer takes z of "
                f"the torso's frame as vertical: write the file with the torso's up along the "
                f"world's z")
    if abs(n[2]) > 1e-9:            # within the tolerance: the plane holds z exactly
        rd.notes.append(f"the joints' mean axis is {abs(math.asin(n[2])):.2g} rad off the "
                        f"plane across the torso frame's z (rounded angles in the file): the "
                        f"model's plane holds z")
    if n[2] != 0.0:
        n = np.array([n[0], n[1], 0.0]) / math.hypot(n[0], n[1])
    return n, {name: (1.0 if np.dot(a, n) > 0 else -1.0) for name, a in axes}


def _mean_axis(rd: _Reader, n, axes) -> np.ndarray:
    """The mean of the axes parallel to ``n`` (each turned to n's sense), round-off
    cleaned; the notes give the largest deviation when it is above round-off."""
    near = [a if np.dot(a, n) > 0 else -a for _, a in axes if _parallel(a, n)]
    m = np.sum(near, axis=0)
    m = np.where(np.abs(m) < 1e-12 * len(near), 0.0, m)     # round-off of turned frames
    m = m / np.linalg.norm(m)
    worst = max(_deviation(a, m) for a in near)
    if worst > 1e-9:
        rd.notes.append(f"the leg joints' axes are parallel within {worst:.2g} rad (rounded "
                        f"angles in the file): the model turns every joint about their mean "
                        f"axis")
    return m
