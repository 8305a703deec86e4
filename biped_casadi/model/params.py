"""Legacy flat parameters of a planar five-link biped (torso + two femur/tibia legs).

Kept so that parameter files and gait files written before robot descriptions
(:mod:`biped_casadi.model.description`) still load: :meth:`RobotParams.to_description` turns
a parameter set into the equivalent :class:`~biped_casadi.model.description.RobotDescription`
(torso, leg = (femur, tibia), torque limit 150 N m), which is what the model uses.
``rabbit(params)`` and ``robot(FILE)`` accept these files and objects.  New robots are
written as description files (any number of links per leg, point masses).
"""
from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..files import read_text_file

from .description import Link, RobotDescription

__all__ = ["RobotParams", "RABBIT", "load_params"]


@dataclass(frozen=True)
class RobotParams:
    """Legacy flat parameters of a five-link biped (RABBIT's layout); defaults: RABBIT.

    Centre-of-mass offsets are measured from the proximal joint of each link: the
    torso's above the hip, the femur's from the hip, the tibia's from the knee.
    Inertias are about each link's own centre of mass.  Every numeric field is checked
    (finite; masses, lengths, inertias, ``g`` and ``torque_limit`` positive).

    Parameters
    ----------
    name : str
        The robot's name.
    m_torso, m_femur, m_tibia : float
        Link masses, kg.
    L_torso, L_femur, L_tibia : float
        Link lengths, m.
    I_torso, I_femur, I_tibia : float
        Link inertias about their centres of mass, kg m^2.
    c_torso, c_femur, c_tibia : float
        Centre-of-mass offsets from the proximal joint, m (at most the link's length).
    rotor_inertia : float
        Reflected rotor inertia (rotor inertia x gear ratio^2, kg m^2) added to the
        diagonal of D for each actuated joint q2..q5; RABBIT: 3.32e-4 x 50^2 = 0.83.
    g : float
        Gravity, m/s^2.
    torque_limit : float
        N m, bound on every actuator torque (gaits and closed-loop runs).
    """

    name: str = "RABBIT"
    m_torso: float = 12.0
    m_femur: float = 6.8
    m_tibia: float = 3.2
    L_torso: float = 0.625
    L_femur: float = 0.4
    L_tibia: float = 0.4
    I_torso: float = 1.33
    I_femur: float = 0.47
    I_tibia: float = 0.20
    c_torso: float = 0.24
    c_femur: float = 0.11
    c_tibia: float = 0.24
    rotor_inertia: float = 3.32e-4 * 50.0**2
    g: float = 9.81
    torque_limit: float = 150.0

    # fields that must be > 0 and those that may be 0 (rotors, offsets)
    _POSITIVE = ("m_torso", "m_femur", "m_tibia", "L_torso", "L_femur", "L_tibia",
                 "I_torso", "I_femur", "I_tibia", "g", "torque_limit")
    _NONNEGATIVE = ("c_torso", "c_femur", "c_tibia", "rotor_inertia")

    def __post_init__(self):
        for f in self._POSITIVE + self._NONNEGATIVE:
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"robot parameter {f!r} must be a number, got {v!r}")
            if not math.isfinite(v):
                raise ValueError(f"robot parameter {f!r} must be finite, got {v!r}")
            if f in self._POSITIVE and v <= 0:
                raise ValueError(f"robot parameter {f!r} must be positive, got {v!r}")
            if f in self._NONNEGATIVE and v < 0:
                raise ValueError(f"robot parameter {f!r} must be non-negative, got {v!r}")
            object.__setattr__(self, f, float(v))
        if self.c_femur > self.L_femur or self.c_tibia > self.L_tibia:
            raise ValueError("robot parameters: a centre-of-mass offset exceeds its link length")
        if not isinstance(self.name, str):
            raise ValueError(f"robot parameter 'name' must be a string, got {self.name!r}")

    @property
    def total_mass(self) -> float:
        """kg: the torso and both legs."""
        return self.m_torso + 2 * (self.m_femur + self.m_tibia)

    def to_dict(self) -> dict:
        """The fields by name (the flat record of older parameter and gait files).

        Returns
        -------
        dict
            Field name -> value.
        """
        return dataclasses.asdict(self)

    def to_description(self) -> RobotDescription:
        """The equivalent robot description (the same numbers, so the same model).

        Returns
        -------
        RobotDescription
        """
        return RobotDescription(
            name=self.name,
            torso=Link("torso", self.m_torso, self.L_torso, self.c_torso, self.I_torso),
            leg=(Link("femur", self.m_femur, self.L_femur, self.c_femur, self.I_femur),
                 Link("tibia", self.m_tibia, self.L_tibia, self.c_tibia, self.I_tibia)),
            point_masses=(), rotor_inertia=self.rotor_inertia, gravity=self.g,
            torque_limit=self.torque_limit)

    @classmethod
    def is_legacy_record(cls, data) -> bool:
        """Whether a mapping is a flat parameter record of this class.

        Such records are written by gait files older than robot descriptions and by
        legacy parameter files.

        Parameters
        ----------
        data : object
            A parsed record (anything; only dicts can qualify).

        Returns
        -------
        bool
            True for a dict without ``torso`` and ``leg`` that names at least one
            numeric field of this class.
        """
        return isinstance(data, dict) and "torso" not in data and "leg" not in data \
            and any(k in data for k in cls.field_names() if k != "name")

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """The names of the fields, in order.

        Returns
        -------
        tuple of str
        """
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_dict(cls, data: dict) -> "RobotParams":
        """Build parameters from a flat mapping that names every numeric field.

        Parameters
        ----------
        data : dict
            Field name -> value; 'name' and 'torque_limit' (default RABBIT's 150 N m)
            may be absent, every other field must be present.

        Returns
        -------
        RobotParams

        Raises
        ------
        ValueError
            Not a mapping, an unknown or missing field, or an invalid value.
        """
        if not isinstance(data, dict):
            raise ValueError("robot parameters must be a table/object of named fields")
        names = cls.field_names()
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f"unknown robot parameter(s): {', '.join(unknown)}")
        # 'name' and 'torque_limit' (added later, RABBIT's 150 N m) may be absent
        missing = [n for n in names if n not in ("name", "torque_limit") and n not in data]
        if missing:
            raise ValueError(f"missing robot parameter(s): {', '.join(missing)}")
        return cls(**data)


RABBIT = RobotParams()


def load_params(path: str | Path) -> RobotParams:
    """Read legacy flat parameters from a ``.toml`` or ``.json`` file.

    A TOML file may hold the fields at top level or under a ``[robot]`` table; every
    numeric field is required ('name' and 'torque_limit' optional, as
    :meth:`RobotParams.from_dict`).

    Parameters
    ----------
    path : str or Path
        A ``.toml`` or ``.json`` file.

    Returns
    -------
    RobotParams

    Raises
    ------
    ValueError
        Naming the file: missing, unreadable, another suffix, unparsable, or a field
        missing, unknown or invalid.
    """
    path = Path(path)
    text = read_text_file(path, "parameter file", 1_000_000)
    try:
        if path.suffix.lower() == ".toml":
            data = tomllib.loads(text)
        elif path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            raise ValueError(f"parameter file must end in .toml or .json: {path}")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise ValueError(f"cannot parse parameter file {path}: {e}") from None
    kind = data.get("format") if isinstance(data, dict) else None
    if isinstance(kind, str) and kind.startswith("biped-casadi-gait"):
        raise ValueError(f"{path} is a {kind} file, not a robot description: a gait "
                         f"file carries its robot (read it with Gait.load, on the command "
                         f"line with --gait)")
    if isinstance(data, dict) and "robot" in data and isinstance(data["robot"], dict):
        data = data["robot"]
    try:
        return RobotParams.from_dict(data)
    except (TypeError, ValueError) as e:
        raise ValueError(f"parameter file {path}: {e}") from None
