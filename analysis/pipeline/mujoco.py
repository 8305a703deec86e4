"""The reproduction's stage "in MuJoCo": each design of the report walked in MuJoCo with
its exported C law, at the stiff settings and at MuJoCo's default contact, beside the
exact analysis (:func:`analysis.in_mujoco.engine_check`), and its figure.

Self-contained: one task per design computing an
:class:`~analysis.in_mujoco.EngineCheck`, a flow gathering them into the summary's
``mujoco`` record, a figure task; the report's section is
:func:`analysis.reporting.in_mujoco.mujoco_lines`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from biped_casadi import Design
from biped_casadi.mujoco import ContactSettings
from biped_casadi.results import json_safe

from ..in_mujoco import engine_check
from ..reporting.plots import mujoco_eigen_plot
from ..tasks import task
from .figures import figure_files
from .options import Resolution
from .paper import StageResult

__all__ = ["MujocoStage", "check_in_mujoco", "stage_mujoco", "mujoco_figure", "CONTACTS"]

#: the settings of the section: the recommended stiff ones and MuJoCo's default contact
CONTACTS = ("stiff", "default")


@dataclass
class MujocoStage(StageResult):
    """The designs in MuJoCo: one row per design and contact (for the figure)."""

    rows: list = field(default_factory=list)


def _budget(res: Resolution) -> dict:
    """Steps and rollouts (the run's resolution: 100 steps in a full run, fewer in a
    quick one)."""
    return dict(steps=res.mujoco_steps, scale_steps=res.mujoco_scale_steps,
                scales=tuple(res.mujoco_scales), directions=res.mujoco_directions)


@task
def check_in_mujoco(design: Design, contacts: tuple, label: str, budget: dict) -> list:
    """One design in MuJoCo at each contact (a task: the contacts share the design's
    compiled law and exact eigenvalues, made once in the process).

    Parameters
    ----------
    design : Design
        The design on its gait.
    contacts : tuple of {'stiff', 'default'}
        MuJoCo's settings (:meth:`~biped_casadi.mujoco.ContactSettings.of`).
    label : str
        The design's name.
    budget : dict
        ``steps``, ``scale_steps``, ``scales``, ``directions``.

    Returns
    -------
    list of EngineCheck
        One per contact, in order.
    """
    out = []
    for contact in contacts:
        b = dict(budget)
        out.append(engine_check(design, ContactSettings.of(contact), label,
                                steps=b.pop("steps"), scale_steps=b.pop("scale_steps"),
                                scales=tuple(b.pop("scales")), **b))
    return out


def _row(label: str, contact: str, r) -> dict:
    """A check as the summary's row."""
    sm = r.stride
    return json_safe(dict(
        label=label, contact=contact, status=r.status, message=r.message,
        settings=r.settings, walk={k: r.walk.get(k) for k in (
            "status", "message", "steps_walked", "n_steps", "speed_error", "period_error",
            "worst_qu_error", "worst_dqu_error", "peak_commanded", "clipped_time",
            "max_slip", "steps_per_second")},
        dqu_errors=r.walk["dqu_errors"], perturbed=dict(
            scale=r.scale, status=r.perturbed["status"],
            steps_walked=r.perturbed["steps_walked"], n_steps=r.perturbed["n_steps"]),
        largest_scale=r.largest_scale, scale_steps=r.scale_steps,
        eigenvalues=sm.eigenvalues, max_abs=sm.max_abs, max_abs_spread=sm.max_abs_spread,
        relative_residual=sm.relative_residual, stride_status=sm.status,
        failed_rollouts=sm.failed_rollouts, directions=sm.directions,
        cycle=sm.cycle.to_dict(), exact=r.exact, exact_max_abs=r.exact_max_abs))


@task
def stage_mujoco(engine, gait_stage, m1_stage, robust_stage, search_stage,
                 res: Resolution) -> MujocoStage:
    """Virtual constraints and the deadbeat M1 on the default gait, the robust co-design
    and the sampling search's design on their gaits, in MuJoCo at the stiff settings and
    at MuJoCo's default contact."""
    g = gait_stage.result().gait
    designs = [("virtual constraints", Design.vc(g)),
               ("deadbeat M1", Design.tv(g, m1_stage.result().chosen)),
               ("robust design (co-design NLP)", robust_stage.result().result.design),
               ("the sampling search's design", search_stage.result().design)]
    budget = _budget(res)
    refs = [(label, engine.submit(check_in_mujoco, d, CONTACTS, label, budget))
            for label, d in designs]
    checks = {}
    for label, ref in refs:
        for c, r in zip(CONTACTS, ref.result()):
            engine.say(f"   {r.message}")
            checks[c, label] = _row(label, c, r)
    rows = [checks[c, label] for c in CONTACTS for label, _ in designs]
    return MujocoStage(dict(mujoco=dict(rows=rows, budget=budget,
                                        settings={c: ContactSettings.of(c).to_dict()
                                                  for c in CONTACTS})), rows)


@task(code="figures")
def mujoco_figure(mujoco_stage) -> dict:
    """The section's figure: MuJoCo's eigenvalues beside the exact ones, errors per step."""
    return dict(mujoco=figure_files(mujoco_eigen_plot(mujoco_stage.rows)))
