"""Whether a walk that failed in MuJoCo failed because the feet's contact is too stiff for
MuJoCo's time step, and what a softer contact costs.

MuJoCo's contact is a damped spring that the solver asks the penetration to follow; its
time constant (``solref``) must be at least two time steps (MuJoCo's modelling guide;
MuJoCo silently raises a shorter one to that: ``mjDSBL_REFSAFE``, ``make
ref[0]>=2*timestep`` in its header), and the stiff settings sit exactly there (4 ms at
2 ms).  :mod:`.timestep` resolves that spring better by shortening the time step; the
other way is a softer spring at the same time step, which MuJoCo's step then resolves in
more time steps.  Softer means the feet sink further into the floor and each impact
lasts longer, so the walk drifts from the gait (:file:`docs/howto/mujoco.md` measures
both ways on six robots).

:func:`check_contact` runs only after a walk failed: the same walk (the same start, design,
time step and steps) again with the contact's time constant multiplied by each of
:data:`FACTORS` in turn (each at least two time steps), until one walks every step.  It
says 'too_stiff' and the ``--solref`` to use when one walks, 'not_stiffness' when none
does.  Each walk tried records what the softer contact costs: its speed error against the
gait and the deepest a foot went into the floor (``MujocoWalk.max_penetration``), beside
the same figures of the walk that walked at a finer time step with the walk's contact,
when the time step check found one.  The factors are the trial's steps, like the time
step check's divisors, not thresholds fitted on a robot: 1.5 and 2 are the next time
constants above two time steps on the stiff settings' time grid (3 and 4 time steps).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..results import Result
from .mjcf import MAX_SOLREF
from .walk import MujocoLoop

__all__ = ["ContactCheck", "check_contact", "FACTORS", "run_record"]

#: the softer contacts tried after a failed walk: the time constant times 1.5, then times 2
FACTORS = (1.5, 2.0)


@dataclass
class ContactCheck(Result):
    """Whether a walk failed because its contact is too stiff for the time step.

    Parameters
    ----------
    status : str
        'not_needed' (the walk walked: nothing was tried), 'too_stiff' (it failed, and
        the same walk at a softer contact walked every step), 'not_stiffness' (the softer
        contacts failed too).
    message : str
        One line: for 'too_stiff' the ``--solref`` to use and what it costs.
    timestep : float
        The walk's time step (kept in every walk tried), s.
    solref : float
        The walk's contact time constant, as MuJoCo compiled it, s.
    suggested_solref : float or None
        The stiffest softer contact tried that walked every step ('too_stiff' only), s.
    tried : list of dict
        The walks at softer contacts, in order (:func:`run_record`, with ``solref`` and
        ``contact_steps``, the time constant in time steps).
    reference : dict or None
        The walk the costs are compared with: the one at the walk's contact and the
        time step the time step check suggested (``timestep``, ``solref``,
        ``speed_error``, ``max_penetration``); None when it suggested none.
    """

    status: str
    message: str
    timestep: float
    solref: float
    suggested_solref: float | None
    tried: list
    reference: dict | None

    SUCCESS = ("not_needed",)


def run_record(loop: MujocoLoop, q0, dq0, steps: int) -> dict:
    """Walk a loop and record what a check reports of it.

    Parameters
    ----------
    loop : MujocoLoop
    q0, dq0 : array_like
        The start.
    steps : int

    Returns
    -------
    dict
        ``timestep``, ``solref``, ``status``, ``steps_walked``, ``speed_error``,
        ``max_penetration`` (m, the deepest a foot went into the floor),
        ``landing_travel`` (m, :attr:`~biped_casadi.mujoco.MujocoWalk.landing_travel`),
        ``message``, ``wall_time``.
    """
    w = loop.run(q0, dq0, steps)
    return dict(timestep=float(loop.settings.timestep), solref=contact_time_constant(loop),
                status=w.status, steps_walked=w.steps_walked, speed_error=w.speed_error,
                max_penetration=w.max_penetration, landing_travel=w.landing_travel,
                message=w.message, wall_time=w.wall_time)


def contact_time_constant(loop: MujocoLoop) -> float:
    """The feet's contact time constant as MuJoCo compiled it (MuJoCo's default when the
    settings leave it), s."""
    return float(loop.m.geom_solref[loop.feet[0], 0])


def _cost(r: dict) -> str:
    return (f"speed error {100 * r['speed_error']:+.2f} %, feet up to "
            f"{1e3 * r['max_penetration']:.3g} mm into the floor")


def check_contact(loop: MujocoLoop, q0, dq0, steps: int, walk, timestep_check=None,
                  factors=FACTORS) -> ContactCheck:
    """After a walk in MuJoCo, whether a softer contact walks it (module docstring).

    Parameters
    ----------
    loop : MujocoLoop
        The loop that walked it (its design, time step, law and options are reused).
    q0, dq0 : array_like
        The walk's start.
    steps : int
        The steps it was asked to walk.
    walk : MujocoWalk
        Its result; a walk that walked is not walked again.
    timestep_check : TimestepCheck, optional
        The time step check of the same walk: the walk it found at a finer time step, if
        any, is the reference of the costs.
    factors : sequence of float
        The contact's time constant is multiplied by each in turn (each > 1) until a walk
        walks (default :data:`FACTORS`); a product below two time steps is raised to two,
        one above :data:`~biped_casadi.mujoco.mjcf.MAX_SOLREF` is skipped.

    Returns
    -------
    ContactCheck
    """
    dt = float(loop.settings.timestep)
    solref = contact_time_constant(loop)
    reference = None
    if timestep_check is not None and timestep_check.suggested_timestep is not None:
        r = next(t for t in timestep_check.tried
                 if t["timestep"] == timestep_check.suggested_timestep)
        reference = dict(timestep=r["timestep"], solref=solref, speed_error=r["speed_error"],
                         max_penetration=r["max_penetration"])
    base = dict(timestep=dt, solref=solref, reference=reference)
    if walk.status == "walked":
        return ContactCheck(status="not_needed", message="", suggested_solref=None, tried=[],
                            **base)
    tried = []
    for f in factors:
        if not f > 1:
            raise ValueError(f"factors must be above 1 (a softer contact), got {f!r}")
        soft = float(f"{max(f * solref, 2 * dt):.12g}")   # as --solref would give it
        if soft > MAX_SOLREF:
            continue
        r = run_record(loop.with_settings(solref=soft), q0, dq0, steps)
        r["contact_steps"] = soft / dt
        tried.append(r)
        if r["status"] == "walked":
            ref = ("" if reference is None else
                   f"; at --timestep {reference['timestep']:g} and solref {solref:g} s: "
                   + _cost(reference))
            msg = (f"a softer contact walks: at the same time step {dt:g} s, solref {soft:g} s "
                   f"({soft / dt:.3g} time steps) walks all {steps} steps ({_cost(r)}{ref}); "
                   f"try --solref {soft:g}")
            return ContactCheck(status="too_stiff", message=msg, suggested_solref=soft,
                                tried=tried, **base)
    if not tried:
        msg = (f"the contact ({solref:g} s) cannot be made softer (at most {MAX_SOLREF:g} s "
               "here)")
    else:
        runs = ", ".join(f"solref {t['solref']:g} s: {t['status']} after {t['steps_walked']} "
                         "step(s)" for t in tried)
        msg = (f"not the contact's stiffness: the same walk at {dt:g} s with a softer contact "
               f"fails too ({runs})")
    return ContactCheck(status="not_stiffness", message=msg, suggested_solref=None,
                        tried=tried, **base)
