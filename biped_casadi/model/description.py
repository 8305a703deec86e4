"""Robot descriptions: any planar point-foot biped with one degree of underactuation,
from one TOML file.

A description holds a torso and two identical legs of k links each (k = 1: the classic
three-link biped; k = 2: RABBIT's femur and tibia), every joint between them actuated
and the stance foot a passive point contact.  The schema (SI units throughout)::

    name = "RABBIT"            # any non-empty string; recorded in gait files
    gravity = 9.81             # m/s^2, > 0
    torso_upright = 0.0        # optional, rad, finite (default 0): the torso's angle phi
                               # when it stands upright (module docstring)

    [actuators]
    torque_limit = 150.0       # N m, > 0: bound on every joint torque (the gait's default);
                               # inf: no limit (a command that needs one says so); or one
                               # per joint of a leg, the same on both legs:
                               # torque_limit = { hip = 150.0, knee = 300.0 }
                               # (every joint of joint_names: hip, knee or joint1 ..)
    rotor_inertia = 3.32e-4    # kg m^2, >= 0: rotor inertia of each actuated joint ...
    gear_ratio = 50.0          # optional (default 1), > 0: ... reflected through the gear
                               # as rotor_inertia * gear_ratio^2 on the joint's diagonal
                               # entry of D (joints q2..qn, not q1)

    [torso]                    # the torso, from the hip up
    mass = 12.0                # kg, > 0
    length = 0.625             # m, > 0
    com = 0.24                 # m, centre of mass above the hip (along the torso's line)
    com_offset = 0.0           # optional, m: its distance off that line, positive forward
                               # when the robot stands upright (q = 0)
    inertia = 1.33             # kg m^2 about the centre of mass, >= 0 (0: a point mass)

    [[leg]]                    # the links of one leg, from the hip down to the foot
    name = "femur"             # optional (default link1, link2, ...)
    mass = 6.8                 # kg, > 0
    length = 0.4               # m, > 0
    com = 0.11                 # m, from the link's upper (proximal) joint down the link
    com_offset = 0.0           # optional, m: off the link's line, positive forward upright
    inertia = 0.47             # kg m^2 about the centre of mass, >= 0

    [[leg]]
    name = "tibia"
    ...

    [point_masses]             # optional: kg at joints, >= 0
    hip = 15.0                 # "hip" (one mass), "foot" (one on each leg), and the
                               # joints between leg links: "knee" when k = 2, or
                               # "joint1" .. "joint{k-1}" counted from the hip (one on
                               # each leg)

    [urdf]                     # optional: written by 'biped robot import'; how the URDF's
                               # own joint angles map to q (biped_casadi.model.urdf_map)

A centre of mass may lie anywhere in the plane of motion: ``com`` (along the link's line,
from its proximal joint; negative or beyond ``length`` is allowed) and ``com_offset``
(across it).  With a link's upward unit vector u = (sin phi, cos phi) and its forward
normal f = (cos phi, -sin phi): torso COM = hip + com u + com_offset f; a leg link's COM
= its proximal joint - com u + com_offset f (u points up the leg).

The torso's angle phi is that of its up direction, from the hip toward its centre of mass
(``com`` > 0) or along its line.  A torso whose centre of mass hangs below the hip (a URDF
import puts ``com`` on the line from the hip toward it) stands upright at phi = pi, not 0:
``torso_upright`` says where (:func:`torso_lean`).  Every judgement of the torso's
posture -- the simulators' fall checks, a gait's largest lean, the gait problem's start --
takes the lean wrap(phi - torso_upright) in [-pi, pi); with the default 0 the lean is phi
itself.  It changes no dynamics.

Coordinates (docs: theory §1, generalised): q1 is the absolute angle of the stance
leg's lowest link, then the relative angles up the stance leg, the torso relative to
the stance leg's top link, the swing leg's top link relative to the torso, and the
relative angles down the swing leg: n = 2 k + 1 joints, n - 1 torques.

:func:`load_description` reads and validates a file, raising one ``ValueError`` that
names the file and the field for each kind of problem (missing or unknown key, wrong
type, negative mass, no leg link, ...).  The toolkit ships ``rabbit`` and
``three_link`` (:data:`BUILTIN`); :func:`find_description` resolves a name or a path.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from ..files import file_path, read_text_file
from .toml_text import description_toml
from .torque_limits import (joint_names_of, leg_limits_text, parse_torque_limit, per_torque,
                            torque_bound_text)
from .urdf_map import UrdfMap, urdf_map_from_dict, wrap_angle

__all__ = ["Link", "RobotDescription", "load_description", "find_description",
           "description_from_dict", "description_toml", "BUILTIN", "builtin_path",
           "torso_lean", "torque_bound_text"]

#: descriptions shipped with the toolkit (package data, biped_casadi/model/robots/NAME.toml)
BUILTIN = ("rabbit", "three_link")

_TOP = ("name", "gravity", "torso_upright", "actuators", "torso", "leg", "point_masses",
        "urdf")
_TWO_PI = 2.0 * math.pi
#: the largest magnitude of a number of a description (SI units: m, kg, kg m^2, m/s^2);
#: beyond, the mass matrix overflows (a leg 1e300 m long gave D full of inf) -- a file
#: in other units.  The torque limit may be larger (or inf: none).
MAX_VALUE = 1e6


def torso_lean(phi, upright: float = 0.0):
    """The torso's lean from upright: wrap(phi - upright) in [-pi, pi).

    Parameters
    ----------
    phi : float, numpy.ndarray or casadi.SX
        The torso's angle in the model (phi of the torso; its up direction), rad.
    upright : float
        The torso's angle when it stands upright
        (:attr:`RobotDescription.torso_upright`), rad.

    Returns
    -------
    same type as ``phi``
        ``phi`` itself (the same object) when ``upright`` is 0, as the toolkit has always
        judged a torso; else the wrapped difference.
    """
    if upright == 0.0:
        return phi
    return wrap_angle(phi - upright)
_ACTUATORS = ("torque_limit", "rotor_inertia", "gear_ratio")
_LINK = ("name", "mass", "length", "com", "inertia", "com_offset")


@dataclass(frozen=True)
class Link:
    """One rigid link of a robot description (the torso or one link of a leg).

    Parameters
    ----------
    name : str
        The link's name ('torso', 'femur', 'tibia', 'link1', ...).
    mass : float
        kg, > 0.
    length : float
        m, > 0: from the proximal joint to the distal end.
    com : float
        m: the centre of mass along the link's line, measured from the link's proximal
        joint (the hip for the torso and for the top link of a leg, the joint above it
        for the other leg links), up the torso and down a leg.
    inertia : float
        kg m^2 about the centre of mass, >= 0 (0: a point mass).
    com_offset : float
        m: the centre of mass's signed distance from the link's line in the plane of
        motion, positive forward (+x) when the robot stands upright at q = 0 (module
        docstring); 0 for a centre of mass on the line.
    """

    name: str
    mass: float
    length: float
    com: float
    inertia: float
    com_offset: float = 0.0

    def __repr__(self):
        # the fields of a link on its line as before com_offset existed: digests of
        # descriptions (cache keys) stay the same
        extra = f", com_offset={self.com_offset!r}" if self.com_offset != 0.0 else ""
        return (f"Link(name={self.name!r}, mass={self.mass!r}, length={self.length!r}, "
                f"com={self.com!r}, inertia={self.inertia!r}{extra})")

    def to_dict(self) -> dict:
        """The fields by name, as in a description file's link table.

        Returns
        -------
        dict
            ``name``, ``mass``, ``length``, ``com``, ``inertia``, and ``com_offset``
            when it is not zero.
        """
        d = dict(name=self.name, mass=self.mass, length=self.length, com=self.com,
                 inertia=self.inertia)
        if self.com_offset != 0.0:
            d["com_offset"] = self.com_offset
        return d


@dataclass(frozen=True)
class RobotDescription:
    """A planar point-foot biped: torso, two identical legs of ``k`` links, point masses.

    Build one with :func:`load_description` (a TOML file) or
    :func:`description_from_dict`; both validate every field (the constructor itself
    does not).  Equal descriptions give equal models (a gait records its description and
    refuses another robot).

    Parameters
    ----------
    name : str
        The robot's name, recorded in gait files.
    torso : Link
        The torso, from the hip up.
    leg : tuple of Link
        One leg's links from the hip down to the foot (k = ``len(leg)`` links).
    point_masses : tuple of (str, float)
        Joint name ('hip', 'knee', 'joint1', ..., 'foot') and mass (kg), sorted by joint
        name; every joint but the hip carries one on each leg.
    rotor_inertia : float
        Reflected rotor inertia (kg m^2, already times the gear ratio squared) added to
        the diagonal entry of D of every actuated joint (q2..qn).
    gravity : float
        m/s^2.
    torque_limit : float
        N m, the smallest joint's torque limit: a bound every joint's torque may reach (the
        limit of every joint when they are equal); ``inf`` when the robot has none (a URDF
        without effort limits).  The bounds the toolkit checks and imposes are
        :attr:`torque_bound`.
    leg_torque_limits : tuple of float
        N m per joint of a leg from the hip down (hip, knee or joint1 ..), the same on both legs (the legs swap roles every step); empty (the default)
        when every joint has ``torque_limit``.  When given, ``torque_limit`` is their
        smallest (:func:`description_from_dict` sets both).
    source : str
        Where the description was read from (a file name; for messages, not compared).
    urdf : UrdfMap or None
        For a robot read from a URDF: how the file's joint angles map to q
        (:mod:`biped_casadi.model.urdf_map`).  Not compared (it changes no dynamics),
        but part of :attr:`cache_key`.
    torso_upright : float
        rad: the torso's angle phi when it stands upright (0 for a torso whose centre of
        mass is above the hip; pi or -pi for one hanging below it, set by the URDF
        import); judgements of the torso's posture take :func:`torso_lean`.  Not
        compared (it changes no dynamics), but part of :attr:`cache_key` when not 0.
    """

    name: str
    torso: Link
    leg: tuple
    point_masses: tuple = ()
    rotor_inertia: float = 0.0
    gravity: float = 9.81
    torque_limit: float = 150.0
    leg_torque_limits: tuple = field(default=(), repr=False)
    source: str = field(default="", compare=False, repr=False)
    urdf: UrdfMap | None = field(default=None, compare=False, repr=False)
    torso_upright: float = field(default=0.0, compare=False, repr=False)

    # --------------------------------------------------------------- sizes
    @property
    def k(self) -> int:
        """Links per leg."""
        return len(self.leg)

    @property
    def nq(self) -> int:
        """Joints (generalised coordinates): 2 k + 1."""
        return 2 * self.k + 1

    @property
    def nu(self) -> int:
        """Torques: 2 k."""
        return 2 * self.k

    @property
    def torque_limits(self) -> tuple:
        """N m, the limit of each torque u1 .. u_nu (:func:`~.torque_limits.per_torque`)."""
        return per_torque(self.leg_torque_limits or (self.torque_limit,) * self.k)

    @property
    def torque_bound(self):
        """The bound on the torques as the toolkit checks and imposes it.

        ``torque_limit`` (a float) when every joint has the same limit, else
        :attr:`torque_limits` (a tuple of nu floats, one per torque u_i); every check,
        bound and clip (the gait's bounds, the simulators' checks and saturation, the C
        export's clip, MuJoCo's ctrlrange) takes either.
        """
        return self.torque_limit if not self.leg_torque_limits else self.torque_limits

    @property
    def leg_length(self) -> float:
        """Hip-to-foot length of a straight leg, m."""
        return sum(link.length for link in self.leg)

    @property
    def joint_masses(self) -> dict:
        """Point masses by joint name (kg)."""
        return dict(self.point_masses)

    @property
    def total_mass(self) -> float:
        """kg: torso, both legs and every point mass."""
        M = self.torso.mass + 2 * sum(link.mass for link in self.leg)
        for joint, m in self.point_masses:
            M += m if joint == "hip" else 2 * m
        return M

    @property
    def cache_key(self):
        """What a model built from the description depends on (with the URDF map, if any).

        The torso's upright angle joins it when it is not 0, the joints' torque limits when
        they differ (existing keys unchanged).
        """
        key = (self.name, self.torso, self.leg, self.point_masses, self.rotor_inertia,
               self.gravity, self.torque_limit)
        if self.leg_torque_limits:                  # equal limits: the keys as before
            key += (("leg_torque_limits", self.leg_torque_limits),)
        key = key if self.urdf is None else key + (self.urdf,)
        return key if self.torso_upright == 0.0 else key + (("torso_upright",
                                                              self.torso_upright),)

    @property
    def upright_q(self) -> tuple:
        """The configuration q of the robot standing straight upright (rad, nq numbers).

        Zeros but the hips when :attr:`torso_upright` is not 0: the stance hip (torso
        relative to the stance leg) at torso_upright, the swing hip at -torso_upright.
        Angles of the model are taken within pi of it where they are wrapped (URDF angles,
        the gait problem's joint bounds).
        """
        q = [0.0] * self.nq
        if self.torso_upright != 0.0:
            q[self.k], q[self.k + 1] = self.torso_upright, -self.torso_upright
        return tuple(q)

    def torso_lean(self, phi):
        """The torso's lean from upright, :func:`torso_lean` with :attr:`torso_upright`.

        Parameters
        ----------
        phi : float, numpy.ndarray or casadi.SX
            The torso's angle in the model, rad.

        Returns
        -------
        same type as ``phi``
            wrap(phi - torso_upright) in [-pi, pi); ``phi`` itself when torso_upright is 0.
        """
        return torso_lean(phi, self.torso_upright)

    # --------------------------------------------------------------- dicts
    def to_dict(self) -> dict:
        """The description in the file's schema, as recorded in gait files.

        Returns
        -------
        dict
            ``name``, ``gravity``, ``torso_upright`` when it is not 0, ``actuators``
            (the reflected rotor inertia with gear_ratio 1; ``torque_limit`` a number, or
            a table by joint name where the joints' limits differ), ``torso``, ``leg`` (a list
            of link tables), ``point_masses`` and, for a robot read from a URDF,
            ``urdf`` (the joint map); :func:`description_from_dict` reads it back to an
            equal description.
        """
        d = dict(name=self.name, gravity=self.gravity)
        if self.torso_upright != 0.0:
            d["torso_upright"] = self.torso_upright
        limit = self.torque_limit if not self.leg_torque_limits else \
            dict(zip(joint_names_of(self.k), self.leg_torque_limits))
        d.update(actuators=dict(torque_limit=limit,
                                rotor_inertia=self.rotor_inertia, gear_ratio=1.0),
                 torso=self.torso.to_dict(), leg=[link.to_dict() for link in self.leg],
                 point_masses=dict(self.point_masses))
        if self.urdf is not None:
            d["urdf"] = self.urdf.to_dict()
        return d

    @property
    def has_torque_limit(self) -> bool:
        """Whether the robot has a (finite) torque limit."""
        return math.isfinite(self.torque_limit)

    @property
    def torque_limit_text(self) -> str:
        """The torque limits in words (:func:`~.torque_limits.leg_limits_text`)."""
        return leg_limits_text(joint_names_of(self.k), self.torque_limit,
                               self.leg_torque_limits)

    def without_urdf(self) -> "RobotDescription":
        """The same robot without its URDF joint map (the model of its dynamics alone).

        Returns
        -------
        RobotDescription
        """
        return dataclasses.replace(self, urdf=None)

    def __str__(self):
        return (f"{self.name}: planar biped, {self.k} link(s) per leg, {self.nq} joints, "
                f"total mass {self.total_mass:g} kg")

    def scaled(self, mass: float = 1.0, inertia: float = 1.0, length: float = 1.0,
               torso_mass: float = 1.0) -> "RobotDescription":
        """The same robot with its parameters scaled (a plant with a model error).

        Parameters
        ----------
        mass : float
            Factor on every link's mass and every point mass.
        inertia : float
            Factor on every link's inertia.
        length : float
            Factor on every link's length and centre-of-mass position (and offset).
        torso_mass : float
            Further factor on the torso's mass.

        Returns
        -------
        RobotDescription
            Validated; its name says the factors.

        Raises
        ------
        ValueError
            A factor that is not a positive finite number (named).
        """
        f = dict(mass=mass, inertia=inertia, length=length, torso_mass=torso_mass)
        for name, v in f.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v <= 0:
                raise ValueError(f"{name} scale must be a positive number, got {v!r}")
        d = self.to_dict()

        def link(t, m=1.0):
            t = dict(t)
            t["mass"] *= mass * m
            t["inertia"] *= inertia
            t["length"] *= length
            t["com"] *= length
            if "com_offset" in t:
                t["com_offset"] *= length
            return t

        d.pop("urdf", None)                 # a plant with other parameters: no file map
        d["torso"] = link(d["torso"], torso_mass)
        d["leg"] = [link(t) for t in d["leg"]]
        d["point_masses"] = {k: v * mass for k, v in d["point_masses"].items()}
        tag = ", ".join(f"{k} x{v:g}" for k, v in f.items() if v != 1.0)
        if tag:
            d["name"] = f"{self.name} ({tag})"
        return description_from_dict(d, where="scaled robot")


def joint_names(k: int) -> tuple:
    """Names a point mass may be attached to, for legs of ``k`` links.

    Parameters
    ----------
    k : int
        Links per leg.

    Returns
    -------
    tuple of str
        ``'hip'``, the joints between leg links (``'knee'`` when k = 2, else
        ``'joint1'`` ...), ``'foot'``.
    """
    return joint_names_of(k) + ("foot",)


# ------------------------------------------------------------------ validation
class _Checker:
    """Field-by-field validation with one clear message per problem."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, field_name: str, problem: str):
        raise ValueError(f"{self.where}: {field_name} {problem}")

    def table(self, data, name: str, keys: tuple, required: tuple) -> dict:
        if not isinstance(data, dict):
            self.fail(name, f"must be a table of fields, got {type(data).__name__}")
        unknown = [k for k in data if k not in keys]
        if unknown:
            self.fail(f"{name}.{unknown[0]}" if name else unknown[0],
                      f"is not a known key (known: {', '.join(keys)})")
        for k in required:
            if k not in data:
                self.fail(f"{name}.{k}" if name else k, "is missing")
        return data

    def number(self, value, name: str, lo: float = 0.0, strict: bool = False,
               hi: float | None = None, hi_name: str = "", bounded: bool = True) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(name, f"must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            self.fail(name, f"must be finite, got {value!r}")
        if strict and not v > lo:
            self.fail(name, f"must be positive, got {value!r}")
        if not strict and not v >= lo:
            self.fail(name, f"must be non-negative, got {value!r}")
        if hi is not None and v > hi:
            self.fail(name, f"must not exceed {hi_name} ({hi:g}), got {value!r}")
        if bounded:
            self.bounded(v, name)
        return v

    def bounded(self, v: float, name: str):
        if abs(v) > MAX_VALUE:
            self.fail(name, f"must be at most {MAX_VALUE:g} in magnitude (SI units: m, kg, "
                            f"kg m^2; a file in other units?), got {v!r}")

    def text(self, value, name: str) -> str:
        if not isinstance(value, str) or not value.strip():
            self.fail(name, f"must be a non-empty string, got {value!r}")
        return value

    def real(self, value, name: str) -> float:
        """Any finite number (a signed distance)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(name, f"must be a number, got {value!r}")
        if not math.isfinite(value):
            self.fail(name, f"must be finite, got {value!r}")
        self.bounded(float(value), name)
        return float(value)

    def link(self, data, name: str, default_name: str) -> Link:
        self.table(data, name, _LINK, ("mass", "length", "com", "inertia"))
        length = self.number(data["length"], f"{name}.length", strict=True)
        return Link(name=self.text(data.get("name", default_name), f"{name}.name"),
                    mass=self.number(data["mass"], f"{name}.mass", strict=True),
                    length=length,
                    com=self.real(data["com"], f"{name}.com"),
                    inertia=self.number(data["inertia"], f"{name}.inertia"),
                    com_offset=self.real(data.get("com_offset", 0.0), f"{name}.com_offset"))


def description_from_dict(data: dict, where: str = "robot description",
                          source: str = "") -> RobotDescription:
    """Validate a description given as a mapping in the file's schema.

    Parameters
    ----------
    data : dict
        The parsed TOML (or a gait file's ``robot`` record).
    where : str
        Names the source in error messages (a file name).
    source : str
        Where the description came from (kept for messages, not compared).

    Returns
    -------
    RobotDescription
        With the rotor inertia reflected through the gear (rotor_inertia *
        gear_ratio^2).

    Raises
    ------
    ValueError
        One message naming ``where`` and the field, for the first problem found.
    """
    c = _Checker(where)
    if isinstance(data, dict) and "leg" not in data:
        c.fail("leg", "is missing: a leg needs at least one link (one [[leg]] table per "
                      "link, k >= 1)")
    c.table(data, "", _TOP, ("name", "gravity", "actuators", "torso", "leg"))
    name = c.text(data["name"], "name")
    gravity = c.number(data["gravity"], "gravity", strict=True)
    upright = c.real(data.get("torso_upright", 0.0), "torso_upright")
    if abs(upright) > _TWO_PI:
        c.fail("torso_upright", f"must be an angle in rad within [-2 pi, 2 pi] (pi for a "
                                f"torso hanging below the hip), got {data['torso_upright']!r}")
    act = c.table(data["actuators"], "actuators", _ACTUATORS, ("torque_limit", "rotor_inertia"))
    rotor = c.number(act["rotor_inertia"], "actuators.rotor_inertia")
    gear = c.number(act.get("gear_ratio", 1.0), "actuators.gear_ratio", strict=True)
    torso = c.link(data["torso"], "torso", "torso")
    legs = data["leg"]
    if isinstance(legs, dict):
        legs = [legs]
    if not isinstance(legs, list):
        c.fail("leg", f"must be an array of tables ([[leg]]), got {type(legs).__name__}")
    if not legs:
        c.fail("leg", "has no links: a leg needs at least one link (k >= 1)")
    leg = tuple(c.link(d, f"leg[{i + 1}]", f"link{i + 1}") for i, d in enumerate(legs))
    names = [link.name for link in leg]
    if len(set(names)) != len(names):
        c.fail("leg", f"link names must differ, got {names}")
    torque_limit, leg_limits = parse_torque_limit(c, act["torque_limit"],
                                                  joint_names_of(len(leg)))
    pm = data.get("point_masses", {})
    allowed = joint_names(len(leg))
    c.table(pm, "point_masses", allowed, ())
    masses = tuple(sorted((j, c.number(m, f"point_masses.{j}")) for j, m in pm.items()))
    urdf = urdf_map_from_dict(data["urdf"], len(leg), where) if "urdf" in data else None
    # rotor_inertia * gear_ratio ** 2: the same operations as RobotParams' default
    return RobotDescription(name=name, torso=torso, leg=leg, point_masses=masses,
                            rotor_inertia=rotor * gear**2,
                            gravity=gravity, torque_limit=torque_limit,
                            leg_torque_limits=leg_limits, source=source,
                            urdf=urdf, torso_upright=upright + 0.0)


def load_description(path) -> RobotDescription:
    """Read and validate a robot description file (TOML, schema in the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.toml`` file.

    Returns
    -------
    RobotDescription
        Validated; ``source`` is the file name.

    Raises
    ------
    ValueError
        File missing or unparsable, or a field missing, unknown or out of range (the
        message names the file and the field).
    """
    path = file_path(path)
    text = read_text_file(path, "robot description file", 1_000_000)
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"cannot parse robot description {path}: {e}") from None
    return description_from_dict(data, where=str(path), source=str(path))


def builtin_path(name: str) -> Path:
    """The packaged file of a built-in description.

    Parameters
    ----------
    name : str
        ``'rabbit'`` or ``'three_link'``.

    Returns
    -------
    Path
        ``biped_casadi/model/robots/NAME.toml`` inside the installed package.

    Raises
    ------
    ValueError
        When ``name`` is not one of :data:`BUILTIN`.
    """
    if name not in BUILTIN:
        raise ValueError(f"robot: no built-in robot {name!r} (built-in: {', '.join(BUILTIN)})")
    return Path(str(resources.files("biped_casadi.model") / "robots" / f"{name}.toml"))


def find_description(name_or_path) -> RobotDescription:
    """A built-in robot by name (case-insensitive) or a description file by path.

    Parameters
    ----------
    name_or_path : str or Path
        ``'rabbit'``, ``'three_link'`` or the path of a ``.toml`` file (a
        :class:`RobotDescription` is returned as it is).

    Returns
    -------
    RobotDescription
        Validated.

    Raises
    ------
    ValueError
        Neither a built-in name nor a readable, valid description file.
    """
    if isinstance(name_or_path, RobotDescription):
        return name_or_path
    if not isinstance(name_or_path, (str, Path)) or not str(name_or_path).strip():
        raise ValueError(f"robot must be a built-in name ({', '.join(BUILTIN)}) or a "
                         f"description file, got {name_or_path!r}")
    text = str(name_or_path)
    key = text.strip().lower().replace("-", "_")
    if key in BUILTIN and not Path(text).is_file():
        return load_description(builtin_path(key))
    if not text.lower().endswith(".toml") and not Path(text).is_file():
        raise ValueError(f"robot: {text!r} is neither a built-in robot "
                         f"({', '.join(BUILTIN)}) nor a description file (.toml)")
    return load_description(text)
