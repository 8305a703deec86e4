"""The stages of ``biped reproduce`` that ask which controllers walk, each a flow of
tasks with a typed result: s* of the deadbeat outputs and virtual constraints, the
paper's full perturbation in full order, basins, the sampling search's design, the
robust co-design, its trade-off, and the robust designs' s*, runs and basins."""
from __future__ import annotations

from dataclasses import dataclass, field


from biped_casadi import (PAPER_SIZES, RABBIT_DESCRIPTION, Design, SimulationOptions,
                          perturbed_initial_state, simulate)
from gait_opt import GaitOptions, optimize_gait

from ..design import robust_gait
from ..design.codesign import TODAY_DESIGN, codesign_flow, tradeoff_flow
from ..reporting.constants import PAPER
from ..robustness import RobustnessSettings, basin_to_boundary, kept_directions, robustness
from ..tasks import task
from .options import Resolution
from .paper import StageResult

__all__ = ["SimStage", "BasinStage", "SearchStage", "RobustStage", "simulate_design",
           "stage_robustness", "stage_sim", "stage_basins", "stage_search",
           "stage_robust_design", "stage_tradeoff", "stage_robustness_robust",
           "stage_sim_robust", "stage_basins_robust", "BASIN_REFINE"]

#: basins on the adaptive grid (``refine``): every 4th row and column first, the boundary
#: cell by cell, each on a window grown until it holds the basin's boundary
#: (:func:`analysis.robustness.basin_to_boundary`)
BASIN_REFINE = 4


@dataclass
class SimStage(StageResult):
    """Full-order runs from the paper's perturbation: (result, label) pairs, and the gait
    of the first runs."""

    runs: list = field(default_factory=list)
    gait: object = None


@dataclass
class BasinStage(StageResult):
    """Basins of attraction and their labels."""

    basins: list = field(default_factory=list)
    labels: list = field(default_factory=list)
    title: str = ""


@dataclass
class SearchStage(StageResult):
    """The sampling search's shipped design on its gait, its s* rows and its basin."""

    gait: object = None
    design: object = None
    rows: list = field(default_factory=list)
    basin: object = None


@dataclass
class RobustStage(StageResult):
    """The robust co-design (None for a robot it is not calibrated for)."""

    result: object = None


def _sim_options(res: Resolution) -> SimulationOptions:
    return SimulationOptions(steps=res.sim_steps, mu=0.6)


@task
def simulate_design(design: Design, sizes: tuple, options: SimulationOptions):
    """A full-order run of a design from the perturbation ``sizes`` (rad, rad/s on every
    joint) of its gait's start (a task).

    Parameters
    ----------
    design : Design
        The design on its gait.
    sizes : tuple of float
        (q error, dq error).
    options : SimulationOptions
        Steps and validity thresholds.

    Returns
    -------
    SimulationResult
    """
    q0, dq0 = perturbed_initial_state(design.gait, *sizes)
    return simulate(design.controller_for(), q0, dq0, options)


def _brief(r) -> dict:
    """A run's status, steps to converge and validity margins (for summary.json)."""
    return dict(status=r.status, message=r.message, steps=len(r.steps),
                steps_to_converge=r.steps_to_converge(),
                qu_errors=r.qu_error[:len(r.steps)].tolist(),
                dqu_errors=r.dqu_error[:len(r.steps)].tolist(),
                peak_torque=r.peak_torque, min_normal_force=r.min_normal_force,
                max_friction_ratio=r.max_friction_ratio, max_impulse_ratio=r.max_impulse_ratio,
                failure_time=r.failure_time)


def s_star_rows(engine, gait_name: str, gait, cands, st: RobustnessSettings) -> list:
    """s* of every (label, design) on one gait, side by side: rows for summary.json."""
    kept = engine.submit(kept_directions, gait, st)
    refs = [(label, engine.submit(robustness, Design.of(d, gait), st, kept))
            for label, d in cands]
    rows = []
    for label, ref in refs:
        r = ref.result()
        rows.append(dict(label=label, gait=gait_name, **r.to_dict()))
        engine.say(f"   {gait_name} gait, {label}: s* = {r.s_star:.4g}")
    return rows


@task
def stage_robustness(engine, gait_stage, m1_stage, res: Resolution) -> StageResult:
    """s* of virtual constraints, the deadbeat designs of both a = b = 0 groups and the
    paper's printed M1 on the default gait."""
    g, m1 = gait_stage.result().gait, m1_stage.result()
    cands = [("virtual constraints", None)]
    for name in ("group1", "group2"):
        if name in m1.results:
            cands.append((f"deadbeat M1, {name.replace('group', 'group ')}",
                          Design(m1.results[name])))
    if g.model.description == RABBIT_DESCRIPTION:
        cands.append(("the paper's printed M1", Design(PAPER["example_M1"])))
    st = res.robustness
    return StageResult(dict(robustness=dict(settings=dict(st.__dict__),
                                            rows=s_star_rows(engine, "default", g, cands, st))))


def _runs(engine, todo, res: Resolution) -> tuple:
    """Full-order runs of (key, label, design) from the paper's perturbation, side by
    side: (summary runs, [(result, label)])."""
    refs = [(key, label, engine.submit(simulate_design, d, tuple(PAPER_SIZES), _sim_options(res)))
            for key, label, d in todo]
    runs, pairs = {}, []
    for key, label, ref in refs:
        r = ref.result()
        runs[key] = dict(label=label, **_brief(r))
        pairs.append((r, label))
        engine.say(f"   {label}: {r.status}")
    return runs, pairs


@task
def stage_sim(engine, gait_stage, m1_stage, res: Resolution) -> SimStage:
    """The paper's full perturbation (0.01 rad, 0.1 rad/s on every joint, mu = 0.6, the
    robot's torque limit) in full order: virtual constraints and the chosen deadbeat M1
    on the default gait."""
    g, M1 = gait_stage.result().gait, m1_stage.result().chosen
    runs, pairs = _runs(engine, [
        ("default_vc", "virtual constraints (default gait)", Design.vc(g)),
        ("default_deadbeat", f"deadbeat M1 = [{', '.join(f'{v:.3g}' for v in M1)}] "
                             "(default gait)", Design.tv(g, M1))], res)
    return SimStage(dict(simulation=dict(perturbation=list(PAPER_SIZES), mu=0.6, runs=runs)),
                    pairs, g)


def _basins(engine, todo, n: int) -> list:
    refs = [engine.submit(basin_to_boundary, d, n, refine=BASIN_REFINE) for d in todo]
    return [r.result() for r in refs]


def _log_basins(engine, name, bs):
    engine.say(f"   {name}: " + ", ".join(f"{b.controller} {100 * b.converged_fraction:.1f} %"
                                         for b in bs))


@task
def stage_basins(engine, gait_stage, m1_stage, res: Resolution) -> BasinStage:
    """Basins on the Poincaré section: the deadbeat M1 beside virtual constraints on the
    default gait."""
    g, M1 = gait_stage.result().gait, m1_stage.result().chosen
    bs = _basins(engine, [Design.tv(g, M1), Design.vc(g)], res.basin_n)
    _log_basins(engine, "default", bs)
    return BasinStage(dict(basins=dict(default=[b.to_dict() for b in bs])), bs,
                      ["deadbeat M1", "virtual constraints"],
                      "Basins on the default gait: deadbeat M1 and virtual constraints")


@task
def stage_search(engine, model, res: Resolution) -> SearchStage:
    """The sampling search's shipped design (``biped m1 --robust --method search``) on its
    gait, evaluated by the same stages (not searched again): s* of it and of virtual
    constraints on that gait, and its basin."""
    fields = robust_gait().for_model(model)            # the clearance scaled with the leg
    g3 = engine.submit(optimize_gait, model, GaitOptions(**fields).for_model(model)).result()
    ds = Design.tv(g3, TODAY_DESIGN, 0.75)
    b = engine.submit(basin_to_boundary, ds, res.basin_n, refine=BASIN_REFINE)
    rows = s_star_rows(engine, "search", g3, [("virtual constraints", None),
                                              ("the sampling search's design", ds)],
                       res.robustness)
    return SearchStage(dict(search_design=dict(
        M1=list(ds.M1), rejoin=ds.rejoin, gait_options=dict(fields),
        note="the sampling search's shipped design (biped m1 --robust --method search), "
             "evaluated here by the same stages, not searched again")),
        gait=g3, design=ds, rows=rows, basin=b.result())


@task
def stage_robust_design(engine, model, res: Resolution) -> RobustStage:
    """The robust time-varying design by the co-design NLP: the gait co-designed in the
    full run (the settings of ``biped m1 --robust``), fixed in the quick one."""
    r = engine.spawn(codesign_flow, model, res.codesign).result()
    engine.say(f"   {r.message}")
    return RobustStage(dict(robust_design=dict(r.to_dict(),
                                               method="co-design NLP (biped m1 --robust)")), r)


@task
def stage_tradeoff(engine, robust_stage, res: Resolution) -> StageResult:
    """The (max|lambda|, s*) trade-off traced by the NLP on the co-design's gait."""
    r = robust_stage.result().result
    pts = engine.spawn(tradeoff_flow, r.design, float(r.s_star), res.codesign,
                       (0.25, 0.5, 0.75, 1.0)).result()
    return StageResult(dict(robust_design=dict(tradeoff=pts)))


@task
def stage_robustness_robust(engine, robust_stage, search_stage, res: Resolution
                            ) -> StageResult:
    """s* of the co-design and of virtual constraints on its gait, beside the sampling
    search's rows."""
    rb, ss = robust_stage.result().result, search_stage.result()
    g2 = rb.gait
    mine = ("robust design (co-design NLP)", rb.design)
    st = res.robustness
    if g2.cache_key == ss.gait.cache_key:
        rows = s_star_rows(engine, "robust", g2, [("virtual constraints", None), mine,
                                                  ("the sampling search's design",
                                                   ss.design)], st)
    else:
        rows = s_star_rows(engine, "robust", g2, [("virtual constraints", None), mine], st) \
            + ss.rows
    return StageResult(dict(robustness=dict(rows=rows)))


@task
def stage_sim_robust(engine, robust_stage, search_stage, res: Resolution) -> SimStage:
    """The same runs for virtual constraints and the co-design on the co-design's gait and
    for the sampling search's design on its gait."""
    rb, ss = robust_stage.result().result, search_stage.result()
    g2 = rb.gait
    runs, pairs = _runs(engine, [
        ("robust_vc", "virtual constraints (the co-design's gait)", Design.vc(g2)),
        ("robust_design", "robust design, co-design NLP (its gait)", rb.design),
        ("search_design", "the sampling search's design (its gait)", ss.design)], res)
    return SimStage(dict(simulation=dict(runs=runs)), pairs, g2)


@task
def stage_basins_robust(engine, robust_stage, search_stage, res: Resolution) -> BasinStage:
    """The basins of the co-design, the sampling search's design and virtual
    constraints."""
    rb, ss = robust_stage.result().result, search_stage.result()
    g2 = rb.gait
    b_rob, b_vc = _basins(engine, [rb.design, Design.vc(g2)], res.basin_n)
    bs = [b_rob, ss.basin, b_vc]
    _log_basins(engine, "robust", bs)
    labels = ["robust design (co-design NLP)", "the sampling search's design",
              "virtual constraints"]
    same = ss.gait.cache_key == g2.cache_key
    title = ("Basins: the co-design, the sampling search's design"
             + (" and virtual constraints on one gait" if same else
                " (on its gait) and virtual constraints (the co-design's gait)"))
    return BasinStage(dict(basins=dict(robust=[b.to_dict() for b in bs], robust_labels=labels)),
                      bs, labels, title)

