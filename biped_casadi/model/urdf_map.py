"""The map between a URDF's own joint angles and the model's coordinates.

A robot read from a URDF (:mod:`biped_casadi.model.urdf`) keeps, in its description's
``[urdf]`` table, how the file's coordinates become the model's:

- ``pitch``: the root (torso) link's absolute angle about the joints' axis n,
  right-handed about n, zero when the root link's frame is aligned with the world's
  (its z axis vertical, up) -- what a floating or planar root joint measures;
- one entry per URDF leg joint: its ``name``, its ``leg`` (1 or 2, in the order of the
  legs' hip joints in the file), its ``position`` in the leg (1 the hip, 2 the next
  joint down, ...), and ``sign`` and ``offset``: the angle of the joint's child link
  relative to its parent link in the model's sense (absolute angles phi right-handed
  about n, a leg link's up direction from its distal end to its proximal joint, the
  torso's from the hip to its centre of mass) is ``sign * theta + offset``, theta the
  URDF joint angle; ``reduction`` is the joint's transmission ratio (1 without one);
- ``pitch_offset``: the torso's model angle when ``pitch`` is 0 (phi_torso = pitch +
  pitch_offset); ``axis``: n in the root link's frame; ``hip``: the hip joint's position
  in the root link's frame, along the model's forward and up directions at pitch 0, m.

With the stance leg named (its hip joint), the model's coordinates are affine in the
URDF's: the stance leg's joints give the stance leg's relative angles negated (the model
reads the stance leg from the foot up), the swing leg's give the swing leg's, and q1, the
stance leg's lowest link's absolute angle, is phi_torso plus the stance leg's joint
angles:

    q = wrap(A_s x + c_s),   x = (pitch, theta_1, ..., theta_m)   (URDF order)

with ``wrap`` taking every angle to [-pi, pi) (to within pi of the robot's upright pose,
``RobotDescription.upright_q``, for a torso hanging below the hip: its hips are near
+-pi).  Rates follow dq = A_s dx; torques, by
the power they deliver (u . dq_a = tau . dtheta), tau = (A_s' B u) without the pitch
row: each URDF joint's torque is plus or minus one model torque.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["UrdfJoint", "UrdfMap", "urdf_map_from_dict", "wrap_angle"]

_TWO_PI = 2.0 * math.pi


def wrap_angle(a):
    """Angles taken to [-pi, pi) by whole turns: ``a - 2 pi floor((a + pi) / (2 pi))``.

    Parameters
    ----------
    a : float, numpy.ndarray or casadi.SX
        Angles, rad.

    Returns
    -------
    same type as ``a``
    """
    if isinstance(a, (ca.SX, ca.MX, ca.DM)):
        return a - _TWO_PI * ca.floor((a + math.pi) / _TWO_PI)
    return a - _TWO_PI * np.floor((np.asarray(a, dtype=float) + math.pi) / _TWO_PI)


def _apply(A: np.ndarray, x: np.ndarray, c=None) -> np.ndarray:
    """A x (+ c) summed as CasADi's sparse product is: per row, the non-zero terms in
    column order (a +-1 entry a sign, no product), then c when it is not zero -- so
    that numpy's conversion and the generated C agree to the last bit."""
    out = np.empty((A.shape[0],) + x.shape[1:])
    for i in range(A.shape[0]):
        acc = None
        for j in np.flatnonzero(A[i]):
            a = A[i, j]
            term = x[j] if a == 1.0 else (-x[j] if a == -1.0 else a * x[j])
            acc = term if acc is None else acc + term
        acc = np.zeros(x.shape[1:]) if acc is None else acc
        out[i] = acc + c[i] if c is not None and c[i] != 0.0 else acc
    return out


def _continuous(a: np.ndarray, centre=None) -> np.ndarray:
    """Rows of samples (columns over time) made continuous by whole turns, the first
    sample of each row in [-pi, pi) (``centre``: in [centre - pi, centre + pi) per row)."""
    a = np.unwrap(np.asarray(a, dtype=float), axis=-1)
    first = a[..., :1]
    if centre is not None:
        return a + (_wrap_about(first, np.asarray(centre, float)[:, None]) - first)
    return a + (wrap_angle(first) - first)


def _wrap_about(a, centre):
    """Angles taken to [centre - pi, centre + pi) by whole turns."""
    return wrap_angle(a - centre) + centre


def _centre(centre):
    """None for no centre (all zeros): the plain wrap to [-pi, pi)."""
    if centre is None or not np.any(np.asarray(centre, dtype=float)):
        return None
    return np.asarray(centre, dtype=float)


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF leg joint in the map.

    Parameters
    ----------
    name : str
        The joint's name in the URDF.
    leg : int
        1 or 2: the leg it belongs to (the legs' order of their hips in the file).
    position : int
        1 for the hip, 2 for the next joint down the leg, ...
    sign : float
        +1 or -1: the child link turns by ``sign * theta`` about the model's axis.
    offset : float
        rad: the child link's angle relative to its parent (model sense) at theta = 0.
    reduction : float
        The transmission's reduction (motor turns per joint turn; 1 without one).
    """

    name: str
    leg: int
    position: int
    sign: float
    offset: float
    reduction: float = 1.0

    def to_dict(self) -> dict:
        """The entry as in the ``[[urdf.joints]]`` tables.

        Returns
        -------
        dict
            ``name``, ``leg``, ``position``, ``sign``, ``offset``, ``reduction``.
        """
        return dict(name=self.name, leg=self.leg, position=self.position, sign=self.sign,
                    offset=self.offset, reduction=self.reduction)


@dataclass(frozen=True)
class UrdfMap:
    """How a URDF's joint angles (and the root link's pitch) map to the model's q.

    The module docstring gives the definitions.

    Parameters
    ----------
    joints : tuple of UrdfJoint
        Every leg joint, in the order of the URDF file.
    pitch_offset : float
        rad: the torso's model angle at pitch = 0.
    root : str
        The root (torso) link's name.
    axis : tuple of float
        The joints' axis n in the root link's frame (pitch is right-handed about it).
    hip : tuple of float
        The hip joint in the root link's frame: (forward, up) at pitch 0, m.
    """

    joints: tuple
    pitch_offset: float = 0.0
    root: str = ""
    axis: tuple = (0.0, 1.0, 0.0)
    hip: tuple = (0.0, 0.0)

    # ------------------------------------------------------------- structure
    @property
    def k(self) -> int:
        """Links (joints) per leg."""
        return len(self.joints) // 2

    @property
    def nq(self) -> int:
        """Coordinates: pitch and the joints (2 k + 1, the model's nq)."""
        return len(self.joints) + 1

    @property
    def names(self) -> tuple:
        """The URDF joint names, in the file's order."""
        return tuple(j.name for j in self.joints)

    @property
    def hips(self) -> tuple:
        """The hip joints' names of leg 1 and leg 2."""
        return tuple(next(j.name for j in self.joints if j.leg == leg and j.position == 1)
                     for leg in (1, 2))

    def stance_leg(self, hip_joint) -> int:
        """The leg (1 or 2) whose hip joint is named ``hip_joint``.

        Parameters
        ----------
        hip_joint : str or int
            A hip joint's URDF name (or the leg number itself, 1 or 2).

        Returns
        -------
        int

        Raises
        ------
        ValueError
            Naming ``stance`` when it is neither a hip joint of the map nor 1 or 2.
        """
        if isinstance(hip_joint, (int, np.integer)) and not isinstance(hip_joint, bool) \
                and int(hip_joint) in (1, 2):
            return int(hip_joint)
        hips = self.hips
        if hip_joint in hips:
            return hips.index(hip_joint) + 1
        other = [j.name for j in self.joints if j.name == hip_joint]
        why = (f"{hip_joint!r} is not a hip joint" if other else
               f"the URDF has no leg joint {hip_joint!r}")
        raise ValueError(f"stance: {why}; the stance leg is named by its hip joint: "
                         f"{' or '.join(hips)}")

    # ------------------------------------------------------------- the affine map
    def matrices(self, stance) -> tuple:
        """(A, c) of q = wrap(A x + c) for the stance leg given.

        Parameters
        ----------
        stance : str or int
            The stance leg's hip joint (or leg number).

        Returns
        -------
        tuple
            A (nq, nq) with entries 0 and +-1, c (nq,) rad.
        """
        s = self.stance_leg(stance)
        k, n = self.k, self.nq
        A, c = np.zeros((n, n)), np.zeros(n)
        A[0, 0], c[0] = 1.0, self.pitch_offset
        for i, j in enumerate(self.joints):
            if j.leg == s:
                A[0, 1 + i] = j.sign
                c[0] += j.offset
                row = k + 1 - j.position
                A[row, 1 + i], c[row] = -j.sign, -j.offset
            else:
                row = k + j.position
                A[row, 1 + i], c[row] = j.sign, j.offset
        return A, c

    def to_model(self, x, dx, stance, continuous: bool = False, centre=None) -> tuple:
        """The model's (q, dq) from the URDF's (pitch, joint angles) and their rates.

        Parameters
        ----------
        x, dx : array_like
            (nq,) or (nq, N): pitch then the joint angles in URDF order, rad; rates, rad/s.
        stance : str or int
            The stance leg's hip joint.
        continuous : bool
            For (nq, N) samples of a motion: angles continuous along the samples (whole
            turns added as needed), the first sample's in [-pi, pi); otherwise every
            angle in [-pi, pi).
        centre : array_like, optional
            (nq,) rad: each angle within pi of its entry instead of 0 (the robot's
            :attr:`~biped_casadi.model.description.RobotDescription.upright_q`: a torso
            hanging below the hip puts the hips near +-pi).

        Returns
        -------
        tuple
            q, dq of the same shape.
        """
        A, c = self.matrices(stance)
        x, dx = np.asarray(x, dtype=float), np.asarray(dx, dtype=float)
        raw = _apply(A, x, c)
        centre = _centre(centre)
        if centre is None:
            q = _continuous(raw) if continuous and x.ndim == 2 else wrap_angle(raw)
        elif continuous and x.ndim == 2:
            q = _continuous(raw, centre)
        else:
            q = _wrap_about(raw, centre if raw.ndim == 1 else centre[:, None])
        return q, _apply(A, dx)

    def from_model(self, q, dq, stance, continuous: bool = False) -> tuple:
        """The URDF's (pitch, joint angles) and rates from the model's (q, dq).

        Parameters
        ----------
        q, dq : array_like
            (nq,) or (nq, N), rad and rad/s.
        stance : str or int
            The stance leg's hip joint.
        continuous : bool
            As :meth:`to_model`.

        Returns
        -------
        tuple
            x, dx: pitch then the joint angles in URDF order (angles in [-pi, pi), or
            continuous), and their rates.
        """
        A, c = self.matrices(stance)
        Ai = np.round(np.linalg.inv(A))        # integer entries (0, +-1)
        q, dq = np.asarray(q, dtype=float), np.asarray(dq, dtype=float)
        raw = Ai @ (q - (c if q.ndim == 1 else c[:, None]))
        x = _continuous(raw) if continuous and q.ndim == 2 else wrap_angle(raw)
        return x, Ai @ dq

    def torque_matrix(self, stance, motor_side: bool = False) -> np.ndarray:
        """T of tau = T u: the URDF joints' torques from the model's u.

        T = (A_s' B) without the pitch row, each row times 1 / reduction on the motor side:
        one entry +-1 (or +-1/reduction) per row.

        Parameters
        ----------
        stance : str or int
            The stance leg's hip joint.
        motor_side : bool
            Divide by each joint's reduction.

        Returns
        -------
        numpy.ndarray
            (nu, nu).
        """
        A, _ = self.matrices(stance)
        T = A.T[1:, 1:].copy()                   # B = [0; I]: the pitch column drops out
        if motor_side:
            T *= (1.0 / np.array([j.reduction for j in self.joints]))[:, None]
        return T

    def torques(self, u, stance, motor_side: bool = False) -> np.ndarray:
        """The URDF joints' torques (file order, the file's sign) from the model's u.

        Parameters
        ----------
        u : array_like
            (nu,) or (nu, N): torques on q2..qn, N m.
        stance : str or int
            The stance leg's hip joint.
        motor_side : bool
            Divide each by its joint's ``reduction`` (the motor's torque).

        Returns
        -------
        numpy.ndarray
            (nu,) or (nu, N), N m.
        """
        return _apply(self.torque_matrix(stance, motor_side), np.asarray(u, dtype=float))

    # ------------------------------------------------------------- records
    def to_dict(self) -> dict:
        """The map as in a description's ``[urdf]`` table.

        Returns
        -------
        dict
            ``root``, ``axis``, ``pitch_offset``, ``hip`` and ``joints`` (a list of
            :meth:`UrdfJoint.to_dict`).
        """
        return dict(root=self.root, axis=list(self.axis), pitch_offset=self.pitch_offset,
                    hip=list(self.hip), joints=[j.to_dict() for j in self.joints])

    def describe(self) -> list:
        """One line per URDF joint: how its angle enters the model (for printing).

        Returns
        -------
        list of str
        """
        out = [f"pitch: the {self.root or 'root'} link's angle about "
               f"[{', '.join(f'{v:.6g}' for v in self.axis)}] (right-handed); torso "
               f"angle = pitch {_signed(self.pitch_offset)}"]
        for j in self.joints:
            where = "hip" if j.position == 1 else f"joint {j.position} from the hip"
            out.append(f"{j.name}: leg {j.leg} {where}, model angle = "
                       f"{'' if j.sign > 0 else '-'}theta {_signed(j.offset)}"
                       + ("" if j.reduction == 1.0 else f", reduction {j.reduction:g}"))
        return out


def _signed(v: float) -> str:
    return f"{'+' if v >= 0 else '-'} {abs(v):.12g} rad"


def urdf_map_from_dict(data, k: int, where: str = "robot description") -> UrdfMap:
    """Validate a description's ``[urdf]`` table.

    Parameters
    ----------
    data : dict
        ``root``, ``axis``, ``pitch_offset``, ``hip`` and ``joints`` (a list of tables:
        ``name``, ``leg``, ``position``, ``sign``, ``offset``, optional ``reduction``).
    k : int
        Links per leg of the description.
    where : str
        Names the source in messages.

    Returns
    -------
    UrdfMap

    Raises
    ------
    ValueError
        One message naming ``where`` and the field.
    """
    def fail(name, problem):
        raise ValueError(f"{where}: urdf.{name} {problem}")

    def number(v, name, positive=False):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail(name, f"must be a finite number, got {v!r}")
        if positive and not v > 0:
            fail(name, f"must be positive, got {v!r}")
        return float(v)

    if not isinstance(data, dict):
        fail("", f"must be a table, got {type(data).__name__}")
    known = ("root", "axis", "pitch_offset", "hip", "joints")
    unknown = [key for key in data if key not in known]
    if unknown:
        fail(unknown[0], f"is not a known key (known: {', '.join(known)})")
    if "joints" not in data:
        fail("joints", "is missing")
    root = data.get("root", "")
    if not isinstance(root, str):
        fail("root", f"must be a string, got {root!r}")
    axis = data.get("axis", [0.0, 1.0, 0.0])
    if not isinstance(axis, (list, tuple)) or len(axis) != 3:
        fail("axis", f"must be 3 numbers, got {axis!r}")
    axis = tuple(number(v, "axis") for v in axis)
    if not abs(math.hypot(*axis) - 1.0) <= 1e-9:
        fail("axis", f"must be a unit vector, got {list(axis)}")
    hip = data.get("hip", [0.0, 0.0])
    if not isinstance(hip, (list, tuple)) or len(hip) != 2:
        fail("hip", f"must be 2 numbers (forward, up), got {hip!r}")
    hip = tuple(number(v, "hip") for v in hip)
    pitch_offset = number(data.get("pitch_offset", 0.0), "pitch_offset")
    rows = data["joints"]
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        fail("joints", "must be an array of tables ([[urdf.joints]])")
    if len(rows) != 2 * k:
        fail("joints", f"has {len(rows)} entries; a robot with {k} link(s) per leg has "
                       f"{2 * k} leg joints")
    fields = ("name", "leg", "position", "sign", "offset", "reduction")
    joints = []
    for i, r in enumerate(rows, start=1):
        bad = [key for key in r if key not in fields]
        if bad:
            fail(f"joints[{i}].{bad[0]}", f"is not a known key (known: {', '.join(fields)})")
        missing = [key for key in fields[:5] if key not in r]
        if missing:
            fail(f"joints[{i}].{missing[0]}", "is missing")
        name = r["name"]
        if not isinstance(name, str) or not name.strip():
            fail(f"joints[{i}].name", f"must be a non-empty string, got {name!r}")
        leg, pos = r["leg"], r["position"]
        if isinstance(leg, bool) or leg not in (1, 2):
            fail(f"joints[{i}].leg", f"must be 1 or 2, got {leg!r}")
        if isinstance(pos, bool) or not isinstance(pos, int) or not 1 <= pos <= k:
            fail(f"joints[{i}].position", f"must be an integer from 1 to {k}, got {pos!r}")
        sign = number(r["sign"], f"joints[{i}].sign")
        if sign not in (1.0, -1.0):
            fail(f"joints[{i}].sign", f"must be 1 or -1, got {r['sign']!r}")
        joints.append(UrdfJoint(name, int(leg), int(pos), sign,
                                number(r["offset"], f"joints[{i}].offset"),
                                number(r.get("reduction", 1.0), f"joints[{i}].reduction",
                                       positive=True)))
    names = [j.name for j in joints]
    if len(set(names)) != len(names):
        fail("joints", f"names must differ, got {names}")
    for leg in (1, 2):
        got = sorted(j.position for j in joints if j.leg == leg)
        if got != list(range(1, k + 1)):
            fail("joints", f"leg {leg} must have one joint at each position 1..{k}, got "
                           f"positions {got}")
    return UrdfMap(joints=tuple(joints), pitch_offset=pitch_offset, root=root, axis=axis,
                   hip=hip)
