"""The reproduction's small study of speed: a gait family at a few speeds (the robust
design's gait options), the co-design's M1 and virtual constraints measured at each
speed (max|lambda|, s*), and one speed change walked in full order by both."""
from __future__ import annotations

from dataclasses import dataclass, field

from biped_casadi import Design
from gait_opt import GaitOptions, gait_family

from ..design import ROBUST_GAIT
from ..robustness import RobustnessSettings, kept_directions, robustness
from ..tasks import task
from .options import Resolution
from .paper import StageResult

__all__ = ["FamilyStage", "family_of", "stage_family", "family_speeds"]


@dataclass
class FamilyStage(StageResult):
    """The family's gaits and the designs measured on them (``records`` as
    :class:`analysis.design.family.FamilyDesigns`' for its figure)."""

    speeds: list = field(default_factory=list)
    gaits: list = field(default_factory=list)
    records: list = field(default_factory=list)


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
def stage_family(engine, model, robust_stage, res: Resolution) -> FamilyStage:
    """The family at a few speeds with the robust gait's options; at each speed s* and
    max|lambda| of the co-design's M1 (one M1 for all speeds) and of virtual
    constraints."""
    d0 = robust_stage.result().result.design
    fam = engine.submit(family_of, model, family_speeds(res),
                        GaitOptions(**ROBUST_GAIT).for_model(model)).result()
    rs = RobustnessSettings(directions=8, rounds=6) if res.quick else RobustnessSettings()
    refs = []
    for v, g in zip(fam.member_speeds, fam.gaits):
        kept = engine.submit(kept_directions, g, rs)
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
    summary = dict(family=dict(speeds=[float(x) for x in fam.member_speeds],
                               message=fam.message, status=fam.status,
                               members=[r.to_dict() for r in fam.records], records=records,
                               M1=list(d0.M1), rejoin=d0.rejoin))
    return FamilyStage(summary, [float(x) for x in fam.member_speeds], list(fam.gaits),
                       records)
