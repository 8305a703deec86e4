"""Designs over a gait family: the gait-fixed co-design and the deadbeat M1 NLP at every
speed, one M1 scheduled smoothly over speed (a polynomial fitted to the co-designs) and
one M1 for all speeds, each measured at every speed (max|lambda|, s*, and the basin's
converged fraction and area) beside virtual constraints.

The co-designs of the speeds are independent: they run side by side as flows of the task
engine (:func:`family_designs_flow`), every unit of each kept by its inputs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from biped_casadi import Design
from biped_casadi.results import Result, internal

from ..robustness.basin import basin
from ..robustness.s_star import RobustnessSettings, kept_directions, robustness
from ..tasks import Engine, TaskError, task
from .codesign import QUICK, CodesignSettings, NoDesign, NoDesignFound, given_gait_flow
from .m1_nlp import optimize_m1
from .schedule import M1Schedule

__all__ = ["FamilyDesigns", "family_designs", "family_designs_flow", "deadbeat_m1",
           "smooth_schedule", "LABELS"]

#: the designs measured at every speed, in the order of the figure
LABELS = ("co-design at each speed", "M1 scheduled over speed", "one M1 for all speeds",
          "virtual constraints")


def smooth_schedule(speeds, M1s, rejoin: float, degree: int = 2) -> tuple:
    """M1 scheduled smoothly over speed, fitted through the co-designs.

    A least-squares polynomial per component of M1, sampled at the co-designs' speeds as
    a :class:`M1Schedule` (linear between the samples).

    Parameters
    ----------
    speeds : array_like
        (n,) m/s.
    M1s : array_like
        (n, nu) the co-designs' outputs.
    rejoin : float
        Rejoin time of v_c of every design.
    degree : int
        At most this degree (at most n - 1).

    Returns
    -------
    tuple
        (M1Schedule, the polynomials' coefficients per component, highest power first,
        the degree used).
    """
    v = np.asarray(speeds, float)
    M = np.atleast_2d(np.asarray(M1s, float))
    d = int(min(degree, len(v) - 1))
    coef = [np.polyfit(v, M[:, j], d) for j in range(M.shape[1])]
    values = np.array([[np.polyval(c, x) for c in coef] for x in v])
    return (M1Schedule(tuple(v), tuple(map(tuple, values)), (float(rejoin),) * len(v)),
            [c.tolist() for c in coef], d)


@dataclass
class FamilyDesigns(Result):
    """The designs over a family, measured at every speed (module docstring).

    Parameters
    ----------
    status : str
        'done'.
    message : str
        In words.
    speeds : list of float
        The family's speeds, m/s.
    records : list of dict
        Per speed: ``speed``, the co-design (``M1``, ``rejoin``, its own ``s_star``,
        ``status``), the deadbeat M1 NLP's ``M1`` and ``max_abs`` (or its ``status``
        'failed' and ``message``), and per design of
        :data:`LABELS` its ``max_abs``, ``s_star`` and (with basins) ``basin_fraction``
        and ``basin_area`` (rad x rad/s); a measurement the gait refused (no walkable
        direction: s* undefined) is ``status`` 'failed' and its ``message``.
    schedule : M1Schedule
        M1 over speed (the polynomials sampled at the family's speeds).
    fit : dict
        The polynomials: ``degree`` and ``coefficients`` per component of M1.
    single : dict
        The one M1 for all speeds (the co-design of the speed nearest ``single_speed``).
    settings : dict
        The s* protocol's settings.
    gaits : list
        The family's gaits (left out of ``to_dict()``).
    """

    status: str
    message: str
    speeds: list
    records: list
    schedule: M1Schedule
    fit: dict
    single: dict
    settings: dict
    gaits: list = internal(default_factory=list)

    SUCCESS = ("done",)


@task
def deadbeat_m1(gait, group):
    """The deadbeat M1 NLP on one a = b = 0 group (a task).

    Parameters
    ----------
    gait : Gait
        The gait.
    group : int or None
        The group (None: all components free).

    Returns
    -------
    M1Result
    """
    return optimize_m1(gait, group=group, n_random=0)


def _measure(engine, designs: dict, rs: RobustnessSettings, basin_n) -> dict:
    """Submit s* (and basins) of every (label -> design) of one gait."""
    g = next(iter(designs.values())).gait
    kept = engine.submit(kept_directions, g, rs)
    out = {}
    for label, d in designs.items():
        out[label] = (engine.submit(robustness, d, rs, kept),
                      engine.submit(basin, d, basin_n, refine=4) if basin_n else None)
    return out


#: the errors by which one gait of a family refuses a computation (no non-singular
#: start, no walkable direction, no start for the co-design NLP): recorded for its speed
REFUSALS = ("ValueError", "CodesignError", "NoDesign")


def _refused(ref):
    """``ref``'s result, or its :class:`TaskError` when that is one of
    :data:`REFUSALS`: a record of its speed, not the end of the family; any other
    failure is raised."""
    try:
        return ref.result()
    except TaskError as e:
        if e.message.split(":", 1)[0] not in REFUSALS:
            raise
        return e


def _failed(e: TaskError) -> dict:
    return dict(status="failed", message=e.message.split(": ", 1)[-1])


def _row(refs) -> dict:
    r, b = _refused(refs[0]), (_refused(refs[1]) if refs[1] is not None else None)
    row = _failed(r) if isinstance(r, TaskError) else dict(max_abs=float(r.max_abs),
                                                            s_star=float(r.s_star))
    if b is not None and not isinstance(b, TaskError):
        cell = (b.q_u[1] - b.q_u[0]) * (b.dq_u[1] - b.dq_u[0])
        row.update(basin_fraction=float(b.converged_fraction),
                   basin_area=float(np.sum(b.outcome == "converged") * cell))
    return row


@task
def family_designs_flow(engine, gaits: list, settings: CodesignSettings,
                        rs: RobustnessSettings, basin_n, single_speed: float = 0.75
                        ) -> FamilyDesigns:
    """:func:`family_designs` as a flow of tasks.

    Every speed's co-design side by side, then every design measured at every speed
    side by side.

    Parameters
    ----------
    engine : Engine
        Where the units run.
    gaits : list of Gait
        The family's gaits, in order of speed.
    settings : CodesignSettings
        The co-design at each speed (its gait fixed).
    rs : RobustnessSettings
        The s* protocol.
    basin_n : int or None
        Cells per axis of the basins (None: no basins).
    single_speed : float
        The one M1 for all speeds is the co-design of the speed nearest this, m/s.

    Returns
    -------
    FamilyDesigns
    """
    speeds = [round(float(g.speed), 12) for g in gaits]
    # a speed without a design is a record of why, not the end of the family
    cds = [engine.spawn(given_gait_flow, g.model, settings, g) for g in gaits]
    dead = [engine.submit(deadbeat_m1, g, 1 if g.model.nu == 4 else None) for g in gaits]
    cd = [_refused(c) for c in cds]
    cd = [NoDesignFound(message=_failed(c)["message"], details={})
          if isinstance(c, TaskError) else c for c in cd]
    have = [i for i, c in enumerate(cd) if not isinstance(c, NoDesignFound)]
    if not have:
        raise NoDesign("no speed of the family has a design: " + "; ".join(
            f"{v:g} m/s: {c.message}" for v, c in zip(speeds, cd)))
    rejoin = float(cd[have[0]].design.rejoin)
    schedule, coef, degree = smooth_schedule([speeds[i] for i in have],
                                             [cd[i].design.M1 for i in have], rejoin)
    k = min(have, key=lambda i: abs(speeds[i] - single_speed))
    single = dict(M1=list(cd[k].design.M1), rejoin=rejoin, from_speed=speeds[k])
    lo, hi = speeds[have[0]], speeds[have[-1]]
    measured = [_measure(engine, {
        **({} if isinstance(c, NoDesignFound) else {LABELS[0]: c.design}),
        LABELS[1]: Design.tv(g, schedule.at(min(max(v, lo), hi))[0], rejoin),
        LABELS[2]: Design.tv(g, single["M1"], rejoin), LABELS[3]: Design.vc(g)},
        rs, basin_n) for g, v, c in zip(gaits, speeds, cd)]
    records = []
    for v, c, d, m in zip(speeds, cd, dead, measured):
        own = (dict(status="no_design", message=c.message) if isinstance(c, NoDesignFound)
               else dict(M1=list(c.design.M1), rejoin=rejoin, s_star=float(c.s_star),
                         status=c.status))
        records.append(dict(speed=v, codesign=own, deadbeat=_deadbeat(d),
                            designs={label: _row(refs) for label, refs in m.items()}))
        engine.say(f"{v:g} m/s: " + ", ".join(
            f"{lab}: s* {r['s_star']:.3g}" if "s_star" in r else f"{lab}: {r['message']}"
            for lab, r in records[-1]["designs"].items()))
    return FamilyDesigns(status="done", message=_message(records), speeds=speeds,
                         records=records, schedule=schedule,
                         fit=dict(degree=degree, coefficients=coef), single=single,
                         settings=dict(rs.__dict__), gaits=list(gaits))


def _deadbeat(ref) -> dict:
    """The deadbeat M1 NLP's record at one speed: its ``M1`` and ``max_abs``, or
    ``status`` 'failed' and ``message`` when it refused the gait (no non-singular start
    on the group: a record of that speed, not the end of the family)."""
    r = _refused(ref)
    return _failed(r) if isinstance(r, TaskError) else dict(
        M1=np.asarray(r.M1).tolist(), max_abs=float(r.max_abs))


def _message(records) -> str:
    walk = {lab: sum(r["designs"].get(lab, {}).get("s_star", 0) >= 1 for r in records)
            for lab in LABELS}
    return (f"{len(records)} speeds; s* >= 1 at " + ", ".join(
        f"{n} for {lab}" for lab, n in walk.items()))


def family_designs(family, settings: CodesignSettings | None = None,
                   rs: RobustnessSettings | None = None, basin_n: int | None = 41,
                   single_speed: float = 0.75, progress=None, scheduler=None,
                   workers: int | None = None, cache=None) -> FamilyDesigns:
    """Designs over a gait family, measured at every speed.

    The co-design and the deadbeat M1 at every speed, an M1 schedule over speed and one
    M1 for all, each measured at every speed beside virtual constraints.

    Parameters
    ----------
    family : GaitFamily or list of Gait
        The gaits (made with the robust design's gait options for the co-design to walk:
        :data:`analysis.design.ROBUST_GAIT`).
    settings : CodesignSettings, optional
        The co-design at each speed (default :data:`~analysis.design.codesign.QUICK`:
        the gait fixed, v_c rejoining at 0.75 T).
    rs : RobustnessSettings, optional
        The s* protocol (default: all defaults).
    basin_n : int or None
        Cells per axis of each basin (None: no basins).
    single_speed : float
        The one M1 for all speeds is the co-design nearest this speed, m/s.
    progress : callable, optional
        One line per speed.
    scheduler : str or Client, optional
        Where the units run (:func:`analysis.tasks.resolve_scheduler`).
    workers : int, optional
        Processes of a local cluster.
    cache : str or Path, optional
        The cache folder.

    Returns
    -------
    FamilyDesigns
    """
    gaits = list(getattr(family, "gaits", family))
    if len(gaits) < 2:
        raise ValueError("family: at least two gaits")
    with Engine(scheduler, workers, cache=cache, log=progress) as eng:
        return eng.spawn(family_designs_flow, gaits, settings or QUICK,
                         rs or RobustnessSettings(), basin_n, float(single_speed)).result()

