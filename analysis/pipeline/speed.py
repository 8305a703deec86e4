"""The reproduction's small study of speed: a gait family at a few speeds (the robust
design's gait options), the co-design's M1 and virtual constraints measured at each
speed (max|lambda|, s*), and one speed change walked in full order by both."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design, SimulationOptions
from gait_opt import GaitOptions, gait_family

from ..design import robust_gait
from ..design.schedule import M1Schedule, profile_gaits
from ..robustness import kept_directions, robustness
from ..robustness.speed import ramp_profile, walk_gaits
from ..tasks import task
from .options import Resolution
from .paper import StageResult

__all__ = ["FamilyStage", "family_of", "ramp_gaits", "ramp_walk", "stage_family",
           "family_speeds", "RAMP"]

#: the reproduction's speed change: up from the family's first speed to its last and back
#: by 0.05 m/s per step (gaits between the members polished from the interpolant), then
#: 8 steps at the first; mu = 0.6, |u| <= 150 N m
RAMP = dict(dv=0.05, hold=8, options=SimulationOptions(mu=0.6, torque_limit=150.0))


@dataclass
class FamilyStage(StageResult):
    """The family's gaits and the designs measured on them (``records`` as
    :class:`analysis.design.designs_over_speed.FamilyDesigns`' for its figure)."""

    speeds: list = field(default_factory=list)
    gaits: list = field(default_factory=list)
    records: list = field(default_factory=list)
    ramps: dict = field(default_factory=dict)


def family_speeds(res: Resolution) -> tuple:
    """The speeds of the reproduction's family, m/s."""
    return (0.6, 0.75, 0.9)


@task
def family_of(model, speeds: tuple, options: GaitOptions):
    """A gait family by continuation (a task).

    Parameters
    ----------
    model : BipedModel
        The robot.
    speeds : tuple of float
        Increasing speeds, m/s.
    options : GaitOptions
        The problem (its speed replaced by each).

    Returns
    -------
    GaitFamily
    """
    return gait_family(model, list(speeds), options)


@task
def ramp_gaits(family, v1: float, v2: float, dv: float, hold: int) -> tuple:
    """The gait of every step of the ramp v1 -> v2 -> v1, then ``hold`` steps at v1
    (a task: polished once for every controller that walks it).

    Parameters
    ----------
    family : GaitFamily
        The gaits.
    v1, v2, dv : float
        The ramp, m/s (:func:`analysis.robustness.speed.ramp_profile`).
    hold : int
        Steps at v1 after it.

    Returns
    -------
    tuple
        (speeds, gaits): a tuple of floats, m/s, and one gait per step.
    """
    speeds = ramp_profile(v1, v2, dv, hold)
    gaits, _ = profile_gaits(family, speeds)
    return tuple(float(v) for v in speeds), tuple(gaits)


@task
def ramp_walk(ramp: tuple, controller: str, M1, rejoin: float, options: SimulationOptions):
    """A speed ramp walked in full order (a task): what
    :func:`analysis.robustness.speed.speed_ramp` walks, on gaits polished beforehand.

    Parameters
    ----------
    ramp : tuple
        (speeds, gaits) of every step (:func:`ramp_gaits`).
    controller : str
        'tv' (one M1 at every speed) or 'vc'.
    M1 : tuple of float or None
        The time-varying design's M1 (``controller`` 'tv').
    rejoin : float
        Its v_c rejoin time, fraction of T.
    options : SimulationOptions
        Validity thresholds.

    Returns
    -------
    ProfileResult
        Without the per-step logs.
    """
    speeds, gaits = ramp
    schedule = M1Schedule.constant(M1, rejoin) if controller == "tv" else None
    r = walk_gaits(gaits, speeds, controller, schedule, options)
    return dataclasses.replace(r, runs=[])


def _ramp_record(r) -> dict:
    """What the report says of a ramp."""
    e = r.errors()
    return dict(status=r.status, message=r.message, steps=len(r.steps),
                planned=len(r.speeds), fail_step=int(r.fail_step),
                largest_error=float(np.nanmax(e)) if np.isfinite(e).any() else None,
                last_error=float(e[-1]) if r.ok else None,
                steps_to_converge=float(r.segments[-1].steps_to_converge) if r.ok else None,
                peak_torque=float(r.peak_torque), friction_margin=float(r.friction_margin))


@task
def stage_family(engine, model, robust_stage, res: Resolution) -> FamilyStage:
    """The family at a few speeds with the robust gait's options; at each speed s* and
    max|lambda| of the co-design's M1 (one M1 for all speeds) and of virtual
    constraints."""
    # the family and its kept directions do not depend on the co-design: submitted first
    speeds = family_speeds(res)
    fam_ref = engine.submit(family_of, model, speeds,
                            GaitOptions(**robust_gait().for_model(model)).for_model(model))
    fam = fam_ref.result()
    rs = res.robustness
    kept_refs = [engine.submit(kept_directions, g, rs) for g in fam.gaits]
    ramp = engine.submit(ramp_gaits, fam_ref, speeds[0], speeds[-1], RAMP["dv"], RAMP["hold"])
    d0 = robust_stage.result().result.design
    ramp_refs = {label: engine.submit(ramp_walk, ramp, c, m1, d0.rejoin, RAMP["options"])
                 for label, c, m1 in (("virtual constraints", "vc", None),
                                      ("the co-design's M1", "tv", tuple(d0.M1)))}
    refs = []
    for v, g, kept in zip(fam.member_speeds, fam.gaits, kept_refs):
        refs.append((float(v), [(label, engine.submit(robustness, d, rs, kept)) for label, d in
                                (("the co-design's M1", Design.tv(g, d0.M1, d0.rejoin)),
                                 ("virtual constraints", Design.vc(g)))]))
    records = []
    for v, rr in refs:
        designs = {}
        for label, ref in rr:
            r = ref.result()
            designs[label] = dict(s_star=float(r.s_star), max_abs=float(r.max_abs),
                                  failure=r.failure)
        records.append(dict(speed=v, designs=designs))
        engine.say(f"{v:g} m/s: " + ", ".join(f"{k} s* {x['s_star']:.3g}"
                                             for k, x in designs.items()))
    ramps = {label: ref.result() for label, ref in ramp_refs.items()}
    for label, r in ramps.items():
        engine.say(f"ramp {speeds[0]:g} -> {speeds[-1]:g} -> {speeds[0]:g} m/s, {label}: "
                   f"{r.status}")
    summary = dict(family=dict(speeds=[float(x) for x in fam.member_speeds],
                               message=fam.message, status=fam.status,
                               members=[r.to_dict() for r in fam.records], records=records,
                               M1=list(d0.M1), rejoin=d0.rejoin,
                               ramp=dict(v1=speeds[0], v2=speeds[-1], dv=RAMP["dv"],
                                         hold=RAMP["hold"], mu=RAMP["options"].mu,
                                         torque_limit=RAMP["options"].torque_limit,
                                         runs={k: _ramp_record(r) for k, r in ramps.items()})))
    return FamilyStage(summary, [float(x) for x in fam.member_speeds], list(fam.gaits),
                       records, ramps)
