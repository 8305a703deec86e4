"""Figures of a gait family against speed (docs/theory.md, "Gait families").

:func:`family_figures` computes, for every member of a :class:`gait_opt.GaitFamily`:
the mechanical cost of transport, the step length, the period T, the peak torque, the
impact impulse ratio ``|F_x| / F_z``, the largest friction ratio along the step, the
objective and the eigenvalue of the virtual constraints' restricted Poincaré map
(:func:`analysis.vc_eigenvalue`).  The figures are drawn by
:func:`analysis.reporting.plots.gait_family_plot`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import SimulationOptions
from biped_casadi.control.reference import require_reference
from biped_casadi.results import Result

from .stability import vc_eigenvalue

__all__ = ["FamilyFigures", "family_figures", "torso_fall", "lean_from", "cost_of_transport",
           "actuator_work"]


def actuator_work(gait, n: int = 4001, absolute: bool = True) -> float:
    """Work of the actuators over one step, J.

    Parameters
    ----------
    gait : Gait
        The reference step.
    n : int
        Trapezoid points on [0, T].
    absolute : bool
        The integral of sum_i ``|u_i dq_{a,i}|`` (what the actuators spend when negative
        work costs too), else of sum_i u_i dq_{a,i} (the signed work, which equals the
        change of the mechanical energy along the step).

    Returns
    -------
    float
    """
    require_reference(gait)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n (trapezoid points) must be an integer >= 2, got {n!r}")
    t = np.linspace(0.0, gait.T, n)
    _, dq, _ = gait.evaluate(t)
    power = gait.u(t) * dq[1:]
    power = np.sum(np.abs(power) if absolute else power, axis=0)
    return float(np.sum((power[1:] + power[:-1]) / 2) * (t[1] - t[0]))


def cost_of_transport(gait, n: int = 4001) -> float:
    """Mechanical cost of transport of a gait: absolute actuator work per weight and distance.

    COT = (integral over the step of sum_i ``|u_i dq_{a,i}|`` dt) / (m g L), with u the
    reference torques, q_a the actuated joints, m the robot's mass, g gravity and L the
    step length (dimensionless; no regeneration: negative work costs too).

    Parameters
    ----------
    gait : Gait
        The reference step.
    n : int
        Trapezoid points on [0, T] (the integrand has kinks where a joint power
        changes sign; on RABBIT's 0.75 m/s gait 4001 points are within 1.2e-7 relative
        of 16001).

    Returns
    -------
    float
    """
    d = require_reference(gait).model.description
    return actuator_work(gait, n) / (gait.model.params.total_mass * d.gravity
                                     * gait.step_length)


@dataclass
class FamilyFigures(Result):
    """Per-member figures of a gait family, in order of speed.

    ``success``: computed for every member (the virtual constraints' eigenvalue may
    still be 'unstable' or 'singular': see ``vc_status``).

    Parameters
    ----------
    status : str
        'ok'.
    message : str
    robot : str
    speed : list of float
        m/s.
    cost_of_transport : list of float
        :func:`cost_of_transport` (dimensionless).
    step_length, period : list of float
        m, s.
    peak_torque : list of float
        max ``|u_i|`` over the step, N m.
    impact_impulse_ratio : list of float
        ``|F_x| / F_z`` of the impact impulse.
    friction_ratio : list of float
        max ``|F_x| / F_z`` along the step.
    cost : list of float
        The objective, integral of u'u dt / step length (N^2 m s).
    vc_eigenvalue : list of float
        Eigenvalue of the virtual constraints' 1-D restricted Poincaré map.
    vc_status : list of str
        Its status ('stable', 'unstable', 'singular', 'no_impact').
    branch : list of int
        The members' branches (:class:`gait_opt.MemberRecord`).
    events : list of dict
        The family's events (active-set changes, folds).
    torso_lean : list of float
        The torso's largest lean from upright (:meth:`gait_opt.Gait.torso_lean`: from the
        vertical, or from the robot's ``torso_upright`` angle), rad.
    fall_bound : float
        The simulator's fall bound on that lean (past it every walk is a fall), rad.
    torque_limit, mu, impact_mu : float
        The bounds of the problem (for the figures' reference lines; the torque limit of
        a robot whose joints' limits differ is the largest, the bound on the peak ``|u|``).
    """

    status: str
    message: str
    robot: str
    speed: list
    cost_of_transport: list
    step_length: list
    period: list
    peak_torque: list
    impact_impulse_ratio: list
    friction_ratio: list
    cost: list
    vc_eigenvalue: list
    vc_status: list
    branch: list
    events: list = field(default_factory=list)
    torso_lean: list = field(default_factory=list)
    fall_bound: float = math.pi / 2
    torque_limit: float = float("nan")
    mu: float = float("nan")
    impact_mu: float = float("nan")

    SUCCESS = ("ok",)


def torso_fall(gait) -> tuple:
    """The torso's largest lean on a gait against the simulator's fall bound.

    The lean is :meth:`gait_opt.Gait.torso_lean`; past the bound, every walk of the gait
    is a fall at once.

    Parameters
    ----------
    gait : Gait
        The gait.

    Returns
    -------
    tuple
        (lean in rad, past the bound: bool, the bound in rad).
    """
    lean, bound = require_reference(gait).torso_lean(), float(SimulationOptions().max_torso_angle)
    return lean, lean > bound, bound


def lean_from(model) -> str:
    """Where a robot's torso lean is measured from, in words.

    Parameters
    ----------
    model : BipedModel
        The robot.

    Returns
    -------
    str
        'from the vertical' (a torso whose upright angle is 0), else 'from upright
        (torso angle ... rad)' (a torso hanging below the hip).
    """
    up = float(model.description.torso_upright)
    return "from the vertical" if up == 0.0 else f"from upright (torso angle {up:.4g} rad)"


def family_figures(family) -> FamilyFigures:
    """The figures of every member of a gait family (module docstring).

    Parameters
    ----------
    family : GaitFamily
        From :func:`gait_opt.gait_family` or :meth:`gait_opt.GaitFamily.load`.

    Returns
    -------
    FamilyFigures
    """
    rows, falls, bound = [], [], float(SimulationOptions().max_torso_angle)
    for g in family.gaits:
        c = g.check()
        vc = vc_eigenvalue(g)
        lean, past, bound = torso_fall(g)
        if past:
            falls.append(g.options.speed)
        rows.append(dict(speed=g.options.speed, cost_of_transport=cost_of_transport(g),
                         step_length=g.step_length, period=g.T,
                         peak_torque=c["max_abs_torque"],
                         impact_impulse_ratio=c["impact_friction_ratio"],
                         friction_ratio=c["max_friction_ratio"], cost=g.cost,
                         vc_eigenvalue=vc.eigenvalue, vc_status=vc.status,
                         torso_lean=lean))
    cols = {k: [r[k] for r in rows] for k in rows[0]} if rows else {}
    o = family.options
    unstable = [v for v, s in zip(cols.get("speed", []), cols.get("vc_status", []))
                if s != "stable"]
    return FamilyFigures(
        status="ok", message=(f"{len(rows)} members" + (
            f"; the virtual constraints are not stable at {', '.join(f'{v:g}' for v in unstable)}"
            f" m/s" if unstable else "") + (
            f"; the torso leans past the simulator's fall bound at "
            f"{', '.join(f'{v:g}' for v in falls)} m/s (every walk there is a fall)"
            if falls else "")), fall_bound=bound,
        robot=family.robot, branch=[r.branch for r in family.records],
        events=list(family.events), torque_limit=float(np.max(o.torque_limit)), mu=o.mu,
        impact_mu=o.impulse_mu, **cols)
