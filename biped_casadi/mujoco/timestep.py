"""Whether a walk that failed in MuJoCo failed because MuJoCo's time step is too coarse.

MuJoCo's documentation asks for a contact time constant (``solref``) of at least two
time steps; the stiff settings sit exactly there (4 ms at 2 ms).  That holds for every
robot, yet a robot whose swing foot strikes the floor hard can still fall at 2 ms and
walk at 1 and 0.5 ms: measured on the imported robots of the MuJoCo how-to, the one that
fell (Casia) strikes the floor at 1.65 m/s, 3.3 mm per 2 ms step, where the robots that
walked strike at 0.3 to 0.65 m/s; at 2 ms its new stance foot slid 5.5 and 10.5 mm during
its impacts (0.2 mm at most for the others) and each step came slower than the last until
the swing foot came down behind the stance foot.  What counts is the contact's time
constant in time steps, not the time step alone: the same robot walks at 2 ms with solref
6 ms (3 time steps) and fails at 1 ms with solref 2 ms and at 0.5 ms with 1 ms (2 each);
a finer time step at the same solref raises that ratio.

One robot that fails is too few to fit a threshold on the strike speed, so the verdict
is the cheapest one that rests on no threshold: the same walk (the same
start, design, contact and steps) again at a half and at a quarter of the time step,
only after a walk failed.  :func:`check_timestep` says 'too_coarse' and the time step
to use when one of them walks every step, 'not_timestep' when none does (the cause is
elsewhere: the design, the perturbation, the torque limit, ...).  The strike speed of
the gait, the foot's travel into the floor in one time step and the contact's time
constant in time steps are recorded beside it.  The other remedy, a softer contact at the
same time step, is :mod:`.contact`'s.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..results import Result
from .contact import contact_time_constant, run_record
from .mjcf import MIN_TIMESTEP
from .walk import MujocoLoop

__all__ = ["TimestepCheck", "check_timestep", "strike_velocity", "DIVISORS"]

#: the finer time steps tried after a failed walk: dt / 2, then dt / 4
DIVISORS = (2, 4)


@dataclass
class TimestepCheck(Result):
    """Whether a walk failed because MuJoCo's time step is too coarse.

    Parameters
    ----------
    status : str
        'not_needed' (the walk walked: nothing was tried), 'too_coarse' (it failed, and
        the same walk at a finer time step walked every step), 'not_timestep' (the finer
        time steps failed too).
    message : str
        One line naming the likely cause and, for 'too_coarse', the ``--timestep`` to use.
    timestep : float
        The walk's time step, s.
    walk : dict
        That walk's ``status``, ``steps_walked`` and ``message``.
    suggested_timestep : float or None
        The coarsest time step tried that walked every step ('too_coarse' only), s.
    tried : list of dict
        The walks at finer time steps, in order: ``timestep``, ``solref``, ``status``,
        ``steps_walked``, ``speed_error``, ``max_penetration`` (the deepest a foot went
        into the floor, m), ``message``, ``wall_time``
        (:func:`~biped_casadi.mujoco.contact.run_record`).
    strike_velocity : list of float
        The gait's swing foot velocity (x, z) at the impact, m/s.
    strike_travel : float
        How far the foot moves into the floor in one time step at that speed (``|v_z| dt``), m.
    contact_steps : float
        The feet's contact time constant (solref) in time steps: 2 at the stiff settings,
        the least MuJoCo allows.
    """

    status: str
    message: str
    timestep: float
    walk: dict
    suggested_timestep: float | None
    tried: list
    strike_velocity: list
    strike_travel: float
    contact_steps: float

    SUCCESS = ("not_needed",)


def strike_velocity(gait) -> np.ndarray:
    """The swing foot's velocity (x, z) at the end of the gait's step (its impact), m/s.

    Parameters
    ----------
    gait : Reference
        The gait.

    Returns
    -------
    numpy.ndarray
        (2,).
    """
    T = float(gait.T)
    v = gait.model.swing_foot_velocity(gait.q(T), gait.dq(T))
    return np.array([float(v[0]), float(v[1])])


def check_timestep(loop: MujocoLoop, q0, dq0, steps: int, walk,
                   divisors=DIVISORS) -> TimestepCheck:
    """After a walk in MuJoCo, whether its failure is the time step's (module docstring).

    Parameters
    ----------
    loop : MujocoLoop
        The loop that walked it (its design, settings, law and options are reused).
    q0, dq0 : array_like
        The walk's start.
    steps : int
        The steps it was asked to walk.
    walk : MujocoWalk
        Its result; a walk that walked is not walked again.
    divisors : sequence of int
        The time step is divided by each in turn until a walk walks (default
        :data:`DIVISORS`); those below MuJoCo's smallest time step are skipped.

    Returns
    -------
    TimestepCheck
    """
    s = loop.settings
    dt = float(s.timestep)
    v = strike_velocity(loop.gait)
    speed = abs(float(v[1]))                            # into the floor
    solref = contact_time_constant(loop)
    strike = (f"the swing foot strikes the floor at {speed:.2g} m/s, {1e3 * speed * dt:.2g} "
              f"mm per time step, on a contact of time constant {solref:g} s = "
              f"{solref / dt:.3g} time steps")
    base = dict(timestep=dt, walk=dict(status=walk.status, steps_walked=walk.steps_walked,
                                       message=walk.message),
                strike_velocity=v.tolist(), strike_travel=speed * dt,
                contact_steps=solref / dt)
    if walk.status == "walked":
        return TimestepCheck(status="not_needed", message="", suggested_timestep=None,
                             tried=[], **base)
    tried = []
    for k in divisors:
        fine = dt / k
        if fine < MIN_TIMESTEP:
            continue
        r = run_record(loop.at_timestep(fine), q0, dq0, steps)
        tried.append(r)
        if r["status"] == "walked":
            msg = (f"likely cause: MuJoCo's time step {dt:g} s is too coarse for this robot's "
                   f"foot strike ({strike}): the same walk at {fine:g} s walks all {steps} "
                   f"steps; try --timestep {fine:g}")
            return TimestepCheck(status="too_coarse", message=msg, suggested_timestep=fine,
                                 tried=tried, **base)
    if not tried:
        msg = (f"the time step {dt:g} s cannot be made finer (MuJoCo's smallest here is "
               f"{MIN_TIMESTEP:g} s)")
    else:
        runs = ", ".join(f"{t['timestep']:g} s: {t['status']} after {t['steps_walked']} "
                         f"step(s)" for t in tried)
        msg = (f"not the time step: the same walk at a finer time step fails too ({runs}); "
               "look at the design, the start and the torque limit")
    return TimestepCheck(status="not_timestep", message=msg, suggested_timestep=None,
                         tried=tried, **base)
