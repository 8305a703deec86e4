"""The physical scales that carry the co-design's RABBIT-sized margins to another robot.

The margins were set on RABBIT (legs 0.8 m, 32 kg, torque limit 150 N m).  On another
robot each follows the quantity it is made of: a length the leg length
(:func:`gait_opt.leg_scale`), a speed sqrt(g leg) (the Froude scaling of
:func:`gait_opt.reference_speed`), an impulse the mass times that speed, a torque the
robot's torque limit (a robot without one: its weight times its leg length).  Every
factor is a ratio to RABBIT's own numbers computed by the same formula (its description
read from the package), so that on RABBIT each is exactly 1.0 and its filled settings
are the constants bit for bit.
"""
from __future__ import annotations

import math
from functools import lru_cache

from biped_casadi import find_description
from gait_opt import leg_scale

__all__ = ["physical_scales"]


@lru_cache(maxsize=1)
def _rabbit():
    """RABBIT's description, the robot the margins were set on."""
    return find_description("rabbit")


def _speed(d) -> float:
    """sqrt(g leg), m/s."""
    return math.sqrt(float(d.gravity) * float(d.leg_length))


def _weight_leg(d) -> float:
    """Weight times leg length, N m."""
    return float(d.total_mass) * float(d.gravity) * float(d.leg_length)


def physical_scales(model) -> dict:
    """The robot's factors on RABBIT's margins, by kind.

    Parameters
    ----------
    model : BipedModel or RobotDescription
        The robot.

    Returns
    -------
    dict
        ``length``: leg length / RABBIT's; ``speed``: sqrt(g leg) / RABBIT's; ``impulse``:
        total mass x sqrt(g leg) / RABBIT's; ``torque``: the robot's torque limit /
        RABBIT's (without a finite limit: weight x leg length / RABBIT's; where the
        joints' limits differ, the smallest: a margin in N m is one number, kept below
        every joint's limit).  On RABBIT every one is exactly 1.0.
    """
    d, r = getattr(model, "description", model), _rabbit()
    speed = _speed(d) / _speed(r)
    mass = float(d.total_mass) / float(r.total_mass)
    limit = float(d.torque_limit)
    torque = (limit / float(r.torque_limit) if math.isfinite(limit)
              else _weight_leg(d) / _weight_leg(r))
    return dict(length=leg_scale(d), speed=speed, impulse=mass * speed, torque=torque)
