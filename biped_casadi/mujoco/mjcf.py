"""A robot description as a MuJoCo model (MJCF), and the map between MuJoCo's coordinates
and the toolkit's.

The MJCF (:func:`mjcf`) is generated from the description the toolkit reads (a TOML
file or a URDF read by :mod:`biped_casadi.model.urdf`): MuJoCo's own URDF loader welds
the torso to the world, ignores the rotor inertia and makes no actuators.

- A planar floating base at the hip: slide joints ``x`` and ``z`` (the hip's world
  position) and the hinge ``pitch`` (the torso's absolute angle phi from the vertical,
  positive leaning forward: a rotation about MuJoCo's +y axis).
- Two legs ``a`` and ``b`` of hinges about y, from the hip down (``hip_a``, ``knee_a``,
  ... the angle of each link relative to the one above it), with the reflected rotor
  inertia as ``armature``, and one ``motor`` per hinge limited to the torque limit
  (``ctrlrange``).
- Each link's mass, centre of mass (with ``Link.com_offset`` when the description has
  one: forward of the link's line) and inertia about the centre of mass; point masses
  as massive bodies without joints at their joints.  A link of zero inertia (a point
  mass) gets :data:`MIN_INERTIA`, the smallest inertia MuJoCo accepts for a moving body.
- A sphere foot of radius ``foot_radius`` centred on each leg's point foot; only the
  feet collide (with the floor).  ``contact='stiff'`` gives feet and floor
  ``solref = (solref, 1)`` (default :data:`STIFF`: 4 ms); ``'default'`` keeps MuJoCo's
  (0.02 s).
- Friction: the sliding coefficient ``mu`` in MuJoCo's default contact (``condim`` 3,
  so the torsional and rolling coefficients of the ``friction`` triple are unused) and
  pyramidal cone.  MuJoCo regularises the cone's four edges with
  ``2 mu_r^2 (1 + mu^2) R_n`` (``R_n`` the regulariser of a frictionless contact,
  ``mu_r = mu / sqrt(impratio)``), so the normal direction's, a quarter of that, is
  ``R_n`` at mu = 1 and grows as mu^4 above: RABBIT's stance foot sank 18 mm at mu 5
  (1.1 mm at 0.6, stiff contact) and its walk scuffed in the first step at mu 10; at mu
  1000 a resting ball sinks metres.  Above mu = 1 the option ``impratio`` is
  ``mu^2 (1 + mu^2) / 2``, which holds the normal at ``R_n`` and leaves the friction
  cone as it is: a larger mu then only makes slipping harder.  At mu <= 1 the MJCF has
  no ``impratio`` (MuJoCo's 1), so there the normal is still mu's: mu^2 (1 + mu^2) / 2
  ``R_n`` (0.245 ``R_n`` at the default 0.6, 0.049 at 0.3), and the friction's
  regulariser, ``(1 + mu^2) R_n``, depends on mu at every mu.
- ``cone='elliptic'`` (MuJoCo's elliptic cone) instead regularises the normal with
  ``R_n`` and the friction with ``R_n / impratio``, neither depending on mu: mu then
  only bounds the friction force.  The MJCF leaves ``impratio`` at MuJoCo's 1 there.

:class:`Layout` maps MuJoCo's ``qpos``/``qvel`` (x, z, pitch, leg a from the hip down,
leg b) to the toolkit's q, dq (docs: theory §1) with either leg as the stance leg, and
the toolkit's torques u to MuJoCo's ``ctrl``.  :func:`floating_base_inertia` is the
toolkit's mass matrix in MuJoCo's coordinates (from the impact map's extended
coordinates), the one MuJoCo's ``mj_fullM`` must equal.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from xml.sax.saxutils import quoteattr

import casadi as ca
import numpy as np

from ..caching import cached
from ..model.biped import BipedModel, resolve_robot, robot as _robot
from ..model.description import RobotDescription

__all__ = ["mjcf", "ContactSettings", "STIFF", "MUJOCO_DEFAULT", "MIN_INERTIA", "Layout",
           "layout", "floating_base_inertia", "CONTACTS", "MIN_TIMESTEP", "MAX_TIMESTEP",
           "MAX_MU", "MAX_SOLREF", "CONES"]

#: kg m^2: the inertia given to a link that is a point mass (MuJoCo refuses a moving body
#: whose inertia is below mjMINVAL = 1e-15); its effect on D is below 1e-13
MIN_INERTIA = 1e-14
#: the contact kinds of :func:`mjcf`
CONTACTS = ("stiff", "default")
#: MuJoCo's friction cones (the first, MuJoCo's default, is the MJCF's)
CONES = ("pyramidal", "elliptic")
#: s: the time steps a run takes (a smaller one would run for hours, a larger one misses
#: the step's dynamics: a step lasts a few tenths of a second, walking (0.4 to 1 s for the
#: robots measured) or running (RABBIT at 1.5 m/s: 0.36 s stance, 0.10 s flight))
MIN_TIMESTEP, MAX_TIMESTEP = 1e-5, 0.05
#: s: the softest contact a run takes: a time constant longer than a step, walking or
#: running, leaves the stance foot still sinking when the step ends
MAX_SOLREF = 1.0
#: the largest friction coefficient (any real contact is below about 2; near 1e200
#: MuJoCo's contact solver overflows and the state is NaN at the first contact)
MAX_MU = 1e6


def _impratio(mu: float) -> float:
    """MuJoCo's ``impratio`` that keeps the pyramidal cone's normal impedance at a
    frictionless contact's (module docstring).

    Parameters
    ----------
    mu : float
        The friction coefficient (> 0).

    Returns
    -------
    float
        ``max(1, mu^2 (1 + mu^2) / 2)``: 1 (MuJoCo's default) for mu <= 1.
    """
    mu = float(mu)
    return max(1.0, mu * mu * (1.0 + mu * mu) / 2.0)


@dataclass(frozen=True)
class ContactSettings:
    """The simulation settings of a MuJoCo run that the MJCF carries.

    Parameters
    ----------
    timestep : float
        MuJoCo's time step, s (:data:`MIN_TIMESTEP` to :data:`MAX_TIMESTEP`; MuJoCo's
        default 0.002).
    solref : float or None
        The contact's time constant, s (``solref = (solref, 1)`` on feet and floor);
        None: MuJoCo's default (0.02 s, critically damped).  MuJoCo silently raises a
        time constant below two time steps to two (a softer contact than asked: its
        'refsafe' flag, on by default), so that is refused, as is one above
        :data:`MAX_SOLREF`.
    foot_radius : float
        Radius of the sphere feet, m (> 0).
    mu : float
        Friction coefficient of feet and floor (> 0).
    integrator : str
        MuJoCo's integrator ('Euler', 'implicitfast', 'implicit' or 'RK4'; default
        MuJoCo's, 'Euler').
    cone : str
        MuJoCo's friction cone: 'pyramidal' (MuJoCo's default), whose normal and
        friction softness depend on mu, or 'elliptic', whose do not (module docstring).
    """

    timestep: float = 0.002
    solref: float | None = 0.004
    foot_radius: float = 0.005
    mu: float = 0.6
    integrator: str = "Euler"
    cone: str = "pyramidal"

    def __post_init__(self):
        for name in ("timestep", "foot_radius", "mu"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.mu > MAX_MU:
            raise ValueError(f"mu must be at most {MAX_MU:g}, got {self.mu!r}")
        if self.timestep > MAX_TIMESTEP:
            raise ValueError(f"timestep must be at most {MAX_TIMESTEP:g} s (a step, walking "
                             f"or running, lasts a few tenths of a second), got "
                             f"{self.timestep!r}")
        if self.timestep < MIN_TIMESTEP:
            raise ValueError(f"timestep must be at least {MIN_TIMESTEP:g} s (half a second "
                             f"of walking or running would take {0.5 / self.timestep:.2g} "
                             f"MuJoCo steps), got {self.timestep!r}")
        if self.solref is not None:
            v = self.solref
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v <= 0:
                raise ValueError(f"solref must be a positive time constant (s), got {v!r}")
            if v > MAX_SOLREF:
                raise ValueError(f"solref must be at most {MAX_SOLREF:g} s (longer than a "
                                 f"step, walking or running), got {v!r}")
            if v < 2 * self.timestep:
                raise ValueError(f"solref must be at least two time steps ({2 * self.timestep:g}"
                                 f" s): MuJoCo would silently raise {v!r} s to that")
        if self.integrator not in ("Euler", "implicitfast", "implicit", "RK4"):
            raise ValueError(f"integrator must be Euler, implicitfast, implicit or RK4, got "
                             f"{self.integrator!r}")
        if self.cone not in CONES:
            raise ValueError(f"cone must be one of {', '.join(CONES)}, got {self.cone!r}")

    @classmethod
    def of(cls, contact: str = "stiff", **changes) -> "ContactSettings":
        """The stiff settings or MuJoCo's defaults, with some fields changed.

        Parameters
        ----------
        contact : {'stiff', 'default'}
            'stiff': dt 2 ms, solref 4 ms, 5 mm feet, mu 0.6 (:data:`STIFF`);
            'default': MuJoCo's contact (solref 0.02 s) with the same feet and friction.
        **changes
            Fields to change (None values are ignored).

        Returns
        -------
        ContactSettings
        """
        if contact not in CONTACTS:
            raise ValueError(f"contact must be one of {', '.join(CONTACTS)}, got {contact!r}")
        base = STIFF if contact == "stiff" else MUJOCO_DEFAULT
        return replace(base, **{k: v for k, v in changes.items() if v is not None})

    @property
    def contact(self) -> str:
        """'default' (MuJoCo's own contact), 'stiff' (:data:`STIFF`'s solref) or 'custom'."""
        if self.solref is None:
            return "default"
        return "stiff" if self.solref == STIFF.solref else "custom"

    def to_dict(self) -> dict:
        """The settings by name.

        Returns
        -------
        dict
        """
        return dict(asdict(self), contact=self.contact)


#: the recommended stiff settings: dt 2 ms, solref 4 ms, 5 mm feet, mu 0.6
STIFF = ContactSettings()
#: MuJoCo's default contact (solref 0.02 s) and time step, with 5 mm feet and mu 0.6
MUJOCO_DEFAULT = ContactSettings(solref=None)


# ================================================================ coordinates
def _description(robot_or_model) -> RobotDescription:
    if isinstance(robot_or_model, BipedModel):
        return robot_or_model.description
    return resolve_robot(robot_or_model)


@dataclass(frozen=True)
class Layout:
    """MuJoCo's coordinates of a robot and their map to the toolkit's.

    ``qpos`` = ``qvel`` = (x, z, pitch, leg a's k hinges from the hip down, leg b's):
    n = 3 + 2 k numbers; ``ctrl`` = leg a's k torques, then leg b's.  The toolkit's
    q (docs: theory §1) with leg ``s`` (0: a, 1: b) as the stance leg is
    ``q = A[s] @ qpos[2:]`` (the relation is linear: every toolkit angle is a sum of
    MuJoCo's), ``dq = A[s] @ qvel[2:]``; the toolkit's torques u act on MuJoCo's hinges
    as ``ctrl = G[s] @ u`` (equal virtual work).

    Parameters
    ----------
    k : int
        Links per leg.
    lengths : tuple of float
        The leg's link lengths from the hip down, m.
    torso_length : float
        m.
    A, A_inv, G : tuple of numpy.ndarray
        Per stance leg: q from (pitch, hinges), its inverse, and ctrl from u.
    """

    k: int
    lengths: tuple
    torso_length: float
    A: tuple = field(repr=False)
    A_inv: tuple = field(repr=False)
    G: tuple = field(repr=False)

    @property
    def nq(self) -> int:
        """The toolkit's joints, 2 k + 1."""
        return 2 * self.k + 1

    @property
    def n(self) -> int:
        """MuJoCo's qpos size, 3 + 2 k."""
        return 3 + 2 * self.k

    def hinge(self, leg: int, j: int) -> int:
        """Index in ``qpos`` of leg ``leg``'s hinge ``j`` (0: the hip).

        Parameters
        ----------
        leg : int
            0 (a) or 1 (b).
        j : int
            0 .. k - 1, from the hip down.

        Returns
        -------
        int
        """
        return 3 + leg * self.k + j

    def to_toolkit(self, qpos, qvel, stance: int) -> tuple:
        """(q, dq) of the toolkit with leg ``stance`` as the stance leg.

        Parameters
        ----------
        qpos, qvel : array_like
            MuJoCo's (n,) each.
        stance : int
            0 (leg a) or 1 (leg b).

        Returns
        -------
        tuple of numpy.ndarray
        """
        A = self.A[stance]
        return A @ np.asarray(qpos, float)[2:], A @ np.asarray(qvel, float)[2:]

    def angles(self, q, stance: int) -> np.ndarray:
        """MuJoCo's (pitch, hinges) of the toolkit's q (or dq) with leg ``stance`` down.

        Parameters
        ----------
        q : array_like
            (nq,).
        stance : int
            0 or 1.

        Returns
        -------
        numpy.ndarray
            (nq,).
        """
        return self.A_inv[stance] @ np.asarray(q, float)

    def from_toolkit(self, q, dq, stance: int, foot=(0.0, 0.0)) -> tuple:
        """MuJoCo's (qpos, qvel) of the toolkit's state with the stance foot pinned.

        Parameters
        ----------
        q, dq : array_like
            The toolkit's state, rad and rad/s.
        stance : int
            The stance leg, 0 or 1.
        foot : tuple of float
            World (x, z) of the stance foot's point (the foot sphere's centre), m.

        Returns
        -------
        tuple of numpy.ndarray
            (qpos, qvel), (n,) each: the hip placed above the stance foot, moving with
            the stance foot at rest.
        """
        q, dq = np.asarray(q, float), np.asarray(dq, float)
        ang, dang = self.angles(q, stance), self.angles(dq, stance)
        phi, dphi = self._stance_phi(ang, stance), self._stance_phi(dang, stance)
        L = np.asarray(self.lengths)
        hip = np.array(foot, float) + np.array([np.sum(L * np.sin(phi)),
                                                np.sum(L * np.cos(phi))])
        dhip = np.array([np.sum(L * np.cos(phi) * dphi), -np.sum(L * np.sin(phi) * dphi)])
        return np.r_[hip, ang], np.r_[dhip, dang]

    def _stance_phi(self, ang, stance):
        """Absolute angles of the stance leg's links, from the hip down."""
        i = 1 + stance * self.k
        return ang[0] + np.cumsum(ang[i:i + self.k])

    def feet(self, qpos) -> np.ndarray:
        """World (x, z) of both point feet (the sphere centres), m.

        Parameters
        ----------
        qpos : array_like
            (n,) or (N, n).

        Returns
        -------
        numpy.ndarray
            (..., 2, 2): leg, (x, z).
        """
        P = self.points(qpos)
        return P[..., [self.k + 1, 2 * self.k + 2], :]

    def points(self, qpos) -> np.ndarray:
        """World (x, z) of the joints for drawing, m.

        Parameters
        ----------
        qpos : array_like
            (n,) or (N, n).

        Returns
        -------
        numpy.ndarray
            (..., 2 k + 3, 2): torso top, hip, leg a's joints from the knee down to its
            foot, hip again, leg b's joints down to its foot.
        """
        qp = np.asarray(qpos, float)
        hip = qp[..., :2]
        pitch = qp[..., 2]
        up = lambda a: np.stack([np.sin(a), np.cos(a)], axis=-1)   # noqa: E731
        out = [hip + self.torso_length * up(pitch)]
        for leg in (0, 1):
            p = hip
            out.append(p)
            phi = pitch
            for j in range(self.k):
                phi = phi + qp[..., self.hinge(leg, j)]
                p = p - self.lengths[j] * up(phi)
                out.append(p)
        return np.stack(out, axis=-2)


@cached(maxsize=8)
def _layout(d: RobotDescription) -> Layout:
    k, nq = d.k, d.nq
    A, A_inv, G = [], [], []
    B = np.vstack([np.zeros((1, nq - 1)), np.eye(nq - 1)])
    S = np.eye(nq) - np.eye(nq, k=-1)
    for stance in (0, 1):
        # absolute angles phi (toolkit order) from (pitch, hinges a, hinges b)
        Phi = np.zeros((nq, nq))
        legs = {stance: "st", 1 - stance: "sw"}
        for leg, role in legs.items():
            for j in range(k):                  # link j from the hip down
                row = (k - 1 - j) if role == "st" else (k + 1 + j)
                Phi[row, 0] = 1.0
                Phi[row, 1 + leg * k:1 + leg * k + j + 1] = 1.0
        Phi[k, 0] = 1.0                          # the torso
        Am = S @ Phi
        A.append(Am)
        A_inv.append(np.linalg.inv(Am))
        G.append((Am.T @ B)[1:])                 # the pitch row is zero
    return Layout(k=k, lengths=tuple(link.length for link in d.leg),
                  torso_length=d.torso.length, A=tuple(A), A_inv=tuple(A_inv), G=tuple(G))


def layout(robot_or_model) -> Layout:
    """The map between MuJoCo's coordinates and the toolkit's for a robot.

    Parameters
    ----------
    robot_or_model : BipedModel, RobotDescription or str
        The robot.

    Returns
    -------
    Layout
    """
    return _layout(_description(robot_or_model))


@cached(maxsize=8)
def _inertia_function(d: RobotDescription) -> ca.Function:
    model = _robot(d)
    lay = _layout(d)
    n, k = lay.n, d.k
    qm = ca.SX.sym("qpos", n)
    q = ca.mtimes(ca.DM(lay.A[0]), qm[2:])                 # leg a on the ground
    phi = [qm[2] + sum(qm[lay.hinge(0, i)] for i in range(j + 1)) for j in range(k)]
    foot = qm[:2]
    for j in range(k):
        foot = foot - d.leg[j].length * ca.vertcat(ca.sin(phi[j]), ca.cos(phi[j]))
    qe = ca.vertcat(q, foot)                              # the impact map's coordinates
    J = ca.jacobian(qe, qm)
    De = model.D_extended(q)
    return ca.Function("floating_base_inertia", [qm], [ca.mtimes([J.T, De, J])],
                       ["qpos"], ["M"])


def floating_base_inertia(robot_or_model, qpos) -> np.ndarray:
    """The toolkit's mass matrix of the free robot, in MuJoCo's coordinates.

    The kinetic energy of the robot with both feet free is the impact map's (extended
    coordinates (q, stance foot x, z): ``BipedModel.D_extended``); with qe(qpos) the
    coordinates of that map (leg a as the stance leg), MuJoCo's mass matrix must be
    J' De J, J = d qe / d qpos.

    Parameters
    ----------
    robot_or_model : BipedModel, RobotDescription or str
        The robot.
    qpos : array_like
        MuJoCo's (3 + 2 k,) coordinates.

    Returns
    -------
    numpy.ndarray
        (3 + 2 k, 3 + 2 k).
    """
    d = _description(robot_or_model)
    qpos = np.asarray(qpos, float).ravel()
    if qpos.size != 3 + 2 * d.k:
        raise ValueError(f"qpos must have {3 + 2 * d.k} numbers for {d.name}, got {qpos.size}")
    return np.array(_inertia_function(d)(qpos))


# ======================================================================= MJCF
def _num(x) -> str:
    return repr(float(x))


def _vec(*xs) -> str:
    return " ".join(_num(x) for x in xs)


def _inertial(mass, com_x, com_z, inertia) -> str:
    i = max(float(inertia), MIN_INERTIA)
    return (f'<inertial pos="{_vec(com_x, 0, com_z)}" mass="{_num(mass)}" '
            f'diaginertia="{_vec(i, i, i)}"/>')


def _point_mass(name, mass, z) -> str:
    return (f'<body name="{name}" pos="{_vec(0, 0, z)}"><inertial pos="0 0 0" '
            f'mass="{_num(mass)}" diaginertia="0 0 0"/></body>')


def torque_limit_of(d: RobotDescription, torque_limit=None):
    """The motors' limit: ``torque_limit`` or the robot's, checked finite and positive.

    Parameters
    ----------
    d : RobotDescription
        The robot.
    torque_limit : float or tuple of float, optional
        N m (a tuple: one per torque u1 .. u_nu); default the robot's
        (:attr:`RobotDescription.torque_bound`).

    Returns
    -------
    float or tuple of float
        One limit for every motor, or the robot's per torque u1 .. u_nu where its joints'
        limits differ.

    Raises
    ------
    ValueError
        Naming ``torque_limit`` when neither is a finite positive number.
    """
    u = d.torque_bound if torque_limit is None else torque_limit
    many = isinstance(u, (tuple, list)) and len(u) == d.nu
    for v in (u if many else (u,)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise ValueError(f"torque_limit must be a positive number, got {u!r}")
        if not math.isfinite(v):
            raise ValueError(f"torque_limit: {d.name} has no finite torque limit and MuJoCo's "
                             "motors need one (--torque-limit U on the command line)")
    if many and tuple(u[:d.k]) != tuple(u[d.k:])[::-1]:
        raise ValueError(f"torque_limit: a joint's motor has one limit on both legs (u1 .. "
                         f"u{d.k} the reverse of u{d.k + 1} .. u{d.nu}), got {u!r}")
    return tuple(float(v) for v in u) if many else float(u)


def mjcf(robot, settings: ContactSettings = STIFF, torque_limit=None) -> str:
    """The MJCF text of a robot (module docstring).

    Parameters
    ----------
    robot : BipedModel, RobotDescription or str
        The robot (a built-in name, a description file or a URDF file).
    settings : ContactSettings
        Time step, contact, feet and friction (default :data:`STIFF`).
    torque_limit : float or tuple of float, optional
        The motors' limit, N m (default the robot's: each joint's own); a tuple: one per
        torque u1 .. u_nu (:func:`torque_limit_of`), the same for the joint on both legs.

    Returns
    -------
    str
        An MJCF document (``mujoco.MjModel.from_xml_string`` reads it).

    Raises
    ------
    ValueError
        Naming ``torque_limit`` when the robot has no finite limit and none is given,
        ``settings`` of another type, ``foot_radius`` when the foot is not smaller than
        the leg's last link.
    """
    d = _description(robot)
    if not isinstance(settings, ContactSettings):
        raise ValueError(f"settings must be ContactSettings, got {type(settings).__name__}")
    U = torque_limit_of(d, torque_limit)
    # per joint of a leg from the hip down: the swing leg's torques u_{k+1} .. u_2k
    leg_U = [U] * d.k if np.ndim(U) == 0 else list(U[d.k:])
    s = settings
    if s.foot_radius >= d.leg[-1].length:
        raise ValueError(f"foot_radius must be smaller than the leg's last link "
                         f"({d.leg[-1].length:g} m; a sphere foot is the point foot rounded "
                         f"off), got {s.foot_radius!r}")
    pm = dict(d.point_masses)
    inner = ["knee"] if d.k == 2 else [f"joint{j}" for j in range(1, d.k)]
    solref = "" if s.solref is None else f' solref="{_vec(s.solref, 1)}"'
    friction = f'friction="{_vec(s.mu, 0.005, 0.0001)}"'
    ratio = ' cone="elliptic"' if s.cone == "elliptic" else \
        "" if s.mu <= 1.0 else f' impratio="{_num(_impratio(s.mu))}"'
    t = d.torso
    off = lambda link: link.com_offset                         # noqa: E731
    lines = [f"<mujoco model={quoteattr(d.name)}>",
             f"  <!-- generated by biped-casadi from the robot description {d.name!r}: "
             "planar floating base at the hip, sphere feet -->",
             '  <compiler angle="radian" autolimits="true"/>',
             f'  <option timestep="{_num(s.timestep)}" gravity="{_vec(0, 0, -d.gravity)}" '
             f'integrator="{s.integrator}"{ratio}/>',
             "  <visual><global offwidth=\"640\" offheight=\"480\"/></visual>",
             "  <worldbody>",
             f'    <geom name="floor" type="plane" size="0 0 1" contype="0" conaffinity="1" '
             f'{friction}{solref}/>',
             '    <body name="torso" pos="0 0 0">',
             '      <joint name="x" type="slide" axis="1 0 0"/>',
             '      <joint name="z" type="slide" axis="0 0 1"/>',
             '      <joint name="pitch" type="hinge" axis="0 1 0"/>',
             f"      {_inertial(t.mass, off(t), t.com, t.inertia)}",
             f'      <geom name="torso" type="capsule" fromto="0 0 0 0 0 {_num(t.length)}" '
             'size="0.02" contype="0" conaffinity="0" mass="0"/>']
    if "hip" in pm:
        lines.append(f"      {_point_mass('hip_mass', pm['hip'], 0.0)}")
    for leg in "ab":
        indent = "      "
        for j, link in enumerate(d.leg):
            joint = "hip" if j == 0 else inner[j - 1]
            z0 = 0.0 if j == 0 else -d.leg[j - 1].length
            lines.append(f'{indent}<body name="{link.name}_{leg}" pos="{_vec(0, 0, z0)}">')
            indent += "  "
            lines.append(f'{indent}<joint name="{joint}_{leg}" type="hinge" axis="0 1 0" '
                         f'armature="{_num(d.rotor_inertia)}"/>')
            lines.append(f"{indent}{_inertial(link.mass, off(link), -link.com, link.inertia)}")
            lines.append(f'{indent}<geom name="{link.name}_{leg}" type="capsule" '
                         f'fromto="0 0 0 0 0 {_num(-link.length)}" size="0.015" contype="0" '
                         'conaffinity="0" mass="0"/>')
            if j < d.k - 1 and inner[j] in pm:
                lines.append(f"{indent}{_point_mass(f'{inner[j]}_mass_{leg}', pm[inner[j]], -link.length)}")
        last = d.leg[-1]
        if "foot" in pm:
            lines.append(f"{indent}{_point_mass(f'foot_mass_{leg}', pm['foot'], -last.length)}")
        lines.append(f'{indent}<geom name="foot_{leg}" type="sphere" '
                     f'pos="{_vec(0, 0, -last.length)}" size="{_num(s.foot_radius)}" '
                     f'contype="1" conaffinity="0" {friction}{solref}/>')
        for j in range(d.k):
            indent = indent[:-2]
            lines.append(f"{indent}</body>")
    lines += ["    </body>", "  </worldbody>", "  <actuator>"]
    for leg in "ab":
        for j in range(d.k):
            joint = "hip" if j == 0 else inner[j - 1]
            lines.append(f'    <motor name="{joint}_{leg}" joint="{joint}_{leg}" '
                         f'ctrlrange="{_vec(-leg_U[j], leg_U[j])}"/>')
    lines += ["  </actuator>", "</mujoco>", ""]
    return "\n".join(lines)
