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
elsewhere: the design, the perturbation, the torque limit, ...).

A walk can also walk at a time step that does not resolve its landings: the robust
design's swing foot strikes at 1.64 m/s, and at 2 ms MuJoCo's stiff contact throws the
new stance foot up to 4.7 mm up and 16 mm forward (its ``impact_travel``, the bounce
included), where at 1 ms it moves at most 1.2 mm.  A landing that moves the new stance
foot more than :data:`BOUNCE_TOLERANCE` of the gait's step length (the largest
``impact_travel`` of steps 2 on, :attr:`~biped_casadi.mujoco.MujocoWalk.landing_travel`)
counts as not resolved: the check names it ('bounces', nothing run again) and, asked to
refine (``--timestep auto``), walks it at the finer time steps until its landings are
within the tolerance ('too_coarse'; the finest that walked when none is); after a failed
walk too, the time step suggested is the first whose landings are within it.  The time the
foot spends off the floor does not tell: it stays 24-45 ms at 0.25 ms.  The strike speed of
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

__all__ = ["TimestepCheck", "check_timestep", "strike_velocity", "DIVISORS",
           "BOUNCE_TOLERANCE"]

#: the finer time steps tried after a failed walk: dt / 2, then dt / 4
DIVISORS = (2, 4)

#: the most a landing may move the new stance foot (its ``impact_travel``, the bounce
#: included) in a walk whose time step resolves it, as a fraction of the gait's step
#: length: 1 %, four times the 0.26 % of RABBIT's landings at 1 ms (1.33 mm of its 0.52 m
#: step; the robust design's at 1 ms 1.16 mm), a third of the robust design's 3 % at 2 ms
BOUNCE_TOLERANCE = 0.01


@dataclass
class TimestepCheck(Result):
    """Whether a walk failed because MuJoCo's time step is too coarse.

    Parameters
    ----------
    status : str
        'not_needed' (the walk walked and its landings stayed within the tolerance:
        nothing was tried), 'too_coarse' (it failed, or its landings bounced beyond the
        tolerance, and the same walk at a finer time step walked every step),
        'bounces' (it walked but its landings bounced beyond the tolerance, and it was
        not walked again, or the finer time steps failed), 'not_timestep' (it failed and
        the finer time steps failed too).
    message : str
        One line naming the likely cause and, for 'too_coarse', the ``--timestep`` to use.
    timestep : float
        The walk's time step, s.
    walk : dict
        That walk's ``status``, ``steps_walked``, ``message`` and ``landing_travel``
        (m, :attr:`~biped_casadi.mujoco.MujocoWalk.landing_travel`).
    suggested_timestep : float or None
        ('too_coarse' only) the coarsest time step tried that walked every step with its
        landings within the tolerance, else the finest that walked, s.
    tried : list of dict
        The walks at finer time steps, in order: ``timestep``, ``solref``, ``status``,
        ``steps_walked``, ``speed_error``, ``max_penetration`` (the deepest a foot went
        into the floor, m), ``landing_travel`` (m), ``message``, ``wall_time``
        (:func:`~biped_casadi.mujoco.contact.run_record`).
    strike_velocity : list of float
        The gait's swing foot velocity (x, z) at the impact, m/s.
    strike_travel : float
        How far the foot moves into the floor in one time step at that speed (``|v_z| dt``), m.
    contact_steps : float
        The feet's contact time constant (solref) in time steps: 2 at the stiff settings,
        the least MuJoCo allows.
    bounce_limit : float
        The most a landing may move the new stance foot: the tolerance times the gait's
        step length, m.
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
    bounce_limit: float

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


def _lands(r: dict, limit: float) -> bool:
    """Whether a walk (a :func:`~biped_casadi.mujoco.contact.run_record`) walked every
    step and its landings moved the new stance foot at most ``limit`` (m; a walk of one
    step has no landing to judge)."""
    return r["status"] == "walked" and not r["landing_travel"] > limit


def _finer(loop: MujocoLoop, q0, dq0, steps: int, divisors, limit: float) -> list:
    """The walk again at each finer time step in turn, until one walks and lands within
    ``limit``; their records."""
    tried, dt = [], float(loop.settings.timestep)
    for k in divisors:
        if dt / k < MIN_TIMESTEP:
            continue
        tried.append(run_record(loop.at_timestep(dt / k), q0, dq0, steps))
        if _lands(tried[-1], limit):
            break
    return tried


def _mm(x: float) -> str:
    return f"{1e3 * x:.3g} mm"


def check_timestep(loop: MujocoLoop, q0, dq0, steps: int, walk, divisors=DIVISORS,
                   refine: bool = False, tolerance: float = BOUNCE_TOLERANCE) -> TimestepCheck:
    """After a walk in MuJoCo, whether its failure or its landings are the time step's.

    See the module docstring.

    Parameters
    ----------
    loop : MujocoLoop
        The loop that walked it (its design, settings, law and options are reused).
    q0, dq0 : array_like
        The walk's start.
    steps : int
        The steps it was asked to walk.
    walk : MujocoWalk
        Its result; a walk that walked and landed within the tolerance is not walked
        again.
    divisors : sequence of int
        The time step is divided by each in turn until a walk walks and lands within the
        tolerance (default :data:`DIVISORS`); those below MuJoCo's smallest time step are
        skipped.
    refine : bool
        Whether a walk that walked but whose landings bounced beyond the tolerance is
        walked again at the finer time steps too (``--timestep auto``); without, such a
        walk is only named ('bounces').
    tolerance : float
        The most a landing may move the new stance foot (its impact travel, the bounce
        included), as a fraction of the gait's step length (default
        :data:`BOUNCE_TOLERANCE`).

    Returns
    -------
    TimestepCheck
    """
    dt, limit = float(loop.settings.timestep), tolerance * loop.step_length
    v = strike_velocity(loop.gait)
    speed = abs(float(v[1]))                            # into the floor
    solref = contact_time_constant(loop)
    strike = (f"the swing foot strikes the floor at {speed:.2g} m/s, {1e3 * speed * dt:.2g} "
              f"mm per time step, on a contact of time constant {solref:g} s = "
              f"{solref / dt:.3g} time steps")
    travel = walk.landing_travel
    base = dict(timestep=dt, walk=dict(status=walk.status, steps_walked=walk.steps_walked,
                                       message=walk.message, landing_travel=travel),
                bounce_limit=limit, strike_velocity=v.tolist(), strike_travel=speed * dt,
                contact_steps=solref / dt)
    if _lands(dict(status=walk.status, landing_travel=travel), limit):
        return TimestepCheck(status="not_needed", message="", suggested_timestep=None,
                             tried=[], **base)
    bounced = walk.status == "walked"
    bounce = (f"the landings move the new stance foot up to {_mm(travel)} after a touchdown "
              f"(more than {_mm(limit)}, {100 * tolerance:g} % of the step)")
    if bounced and not refine:
        msg = (f"{bounce}: a bounce if MuJoCo's time step {dt:g} s is too coarse for this "
               f"robot's foot strike ({strike}), a slide if the friction is too low; "
               "--timestep auto walks it at the finer time step that resolves it")
        return TimestepCheck(status="bounces", message=msg, suggested_timestep=None, tried=[],
                             **base)
    tried = _finer(loop, q0, dq0, steps, divisors, limit)
    walked = [t for t in tried if t["status"] == "walked"]
    if walked:                                  # the first that lands, else the finest
        r = next((t for t in walked if _lands(t, limit)), walked[-1])
        fine = r["timestep"]
        still = "" if _lands(r, limit) else (
            f"; its landings still move the foot up to {_mm(r['landing_travel'])}, the "
            "finest time step tried (not the time step alone: the friction?)")
        if bounced:
            msg = (f"likely cause: {bounce}: MuJoCo's time step {dt:g} s is too coarse for "
                   f"this robot's foot strike ({strike}): at {fine:g} s they move it at most "
                   f"{_mm(r['landing_travel'])}{still}; try --timestep {fine:g}")
        else:
            msg = (f"likely cause: MuJoCo's time step {dt:g} s is too coarse for this "
                   f"robot's foot strike ({strike}): the same walk at {fine:g} s walks all "
                   f"{steps} steps{still}; try --timestep {fine:g}")
        return TimestepCheck(status="too_coarse", message=msg, suggested_timestep=fine,
                             tried=tried, **base)
    runs = ", ".join(f"{t['timestep']:g} s: {t['status']} after {t['steps_walked']} "
                     f"step(s)" for t in tried)
    if bounced:
        msg = f"{bounce}; at a finer time step the walk fails ({runs or 'none tried'})"
        return TimestepCheck(status="bounces", message=msg, suggested_timestep=None,
                             tried=tried, **base)
    if not tried:
        msg = (f"the time step {dt:g} s cannot be made finer (MuJoCo's smallest here is "
               f"{MIN_TIMESTEP:g} s)")
    else:
        msg = (f"not the time step: the same walk at a finer time step fails too ({runs}); "
               "look at the design, the start and the torque limit")
    return TimestepCheck(status="not_timestep", message=msg, suggested_timestep=None,
                         tried=tried, **base)
