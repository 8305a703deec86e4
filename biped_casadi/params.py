"""Physical parameters of a planar five-link biped (torso + two femur/tibia legs).

RABBIT (SPEC section 1) is the default.  Parameters load from TOML or JSON and are
validated field by field, so another planar five-link robot is one file away.
"""
from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

__all__ = ["RobotParams", "RABBIT", "load_params"]


@dataclass(frozen=True)
class RobotParams:
    """Masses (kg), lengths (m), inertias about each link's own centre of mass (kg m^2).

    Centre-of-mass offsets are measured from the proximal joint of each link: the
    torso's above the hip, the femur's from the hip, the tibia's from the knee.
    ``torque_limit`` (N m) bounds every actuator torque (gaits and closed-loop runs).
    ``rotor_inertia`` is the reflected rotor inertia added to the diagonal of D for
    each actuated joint q2..q5 (rotor inertia x gear ratio^2).
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
        return self.m_torso + 2 * (self.m_femur + self.m_tibia)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_dict(cls, data: dict) -> "RobotParams":
        """Build from a mapping that names every numeric field ('name' and
        'torque_limit' optional)."""
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
    """Read parameters from a ``.toml`` or ``.json`` file (all numeric fields required).

    A TOML file may hold the fields at top level or under a ``[robot]`` table.
    """
    path = Path(path)
    try:
        if not path.exists():
            raise ValueError(f"parameter file not found: {path}")
        if not path.is_file():
            raise ValueError(f"parameter file {path} is " + (
                "a folder, not a file" if path.is_dir() else "not a regular file"))
        if path.stat().st_size > 1_000_000:
            raise ValueError(f"parameter file {path} is too large to be a parameter file")
        text = path.read_bytes().decode("utf-8")
    except OSError as e:
        raise ValueError(f"parameter file {path} cannot be read: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise ValueError(f"parameter file {path} is not a text (TOML or JSON) file") from None
    try:
        if path.suffix.lower() == ".toml":
            data = tomllib.loads(text)
        elif path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            raise ValueError(f"parameter file must end in .toml or .json: {path}")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise ValueError(f"cannot parse parameter file {path}: {e}") from None
    if isinstance(data, dict) and "robot" in data and isinstance(data["robot"], dict):
        data = data["robot"]
    try:
        return RobotParams.from_dict(data)
    except (TypeError, ValueError) as e:
        raise ValueError(f"parameter file {path}: {e}") from None
