"""How well the toolkit's exact analysis predicts MuJoCo: a design walked in MuJoCo
(:mod:`biped_casadi.mujoco`), MuJoCo's stride map beside the exact eigenvalues of A^z.

The exact eigenvalues are the toolkit's: for a time-varying design those of A^z
(:func:`~analysis.stability.poincare_eigenvalues`), for virtual constraints the one
eigenvalue of their 1-D restricted map (:func:`~analysis.stability.vc_eigenvalue`) and 0,
which is what the map on the time section tau = 0.75 T has (a shift along the autonomous
orbit is forgotten at the next impact).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_casadi import Design, Perturbation
from biped_casadi.caching import cached
from biped_casadi.mujoco import (MujocoLoop, STIFF, ContactSettings, StrideMap, stride_map)
from biped_casadi.results import Result

from .stability import poincare_eigenvalues, vc_eigenvalue

__all__ = ["exact_eigenvalues", "EngineCheck", "engine_check", "largest_scale"]


def exact_eigenvalues(design: Design) -> list:
    """The toolkit's exact eigenvalues of a design's stride map on the section tau = 0.75 T.

    Parameters
    ----------
    design : Design
        The design on its gait.

    Returns
    -------
    list of complex
        Largest modulus first: A^z's two (time-varying), or (lambda_vc, 0).
    """
    return list(_exact(design))


@cached(maxsize=16)
def _exact(design: Design) -> tuple:
    """:func:`exact_eigenvalues`, once per design in a process (its two contacts)."""
    if design.M1 is None:
        return complex(vc_eigenvalue(design.gait).eigenvalue), 0j
    ev = np.asarray(poincare_eigenvalues(design.gait, design).eigenvalues, complex)
    return tuple(complex(e) for e in ev[np.argsort(-np.abs(ev))])


@dataclass
class EngineCheck(Result):
    """One design in MuJoCo at one setting, beside the exact analysis.

    Its walks, the largest perturbation it survives, MuJoCo's stride map and the exact
    eigenvalues.

    Parameters
    ----------
    status : str
        'walked' when the walk from the gait walked all its steps, else its status.
    message : str
        A summary line.
    label : str
        The design's name.
    design : dict
        Its ``to_dict()``.
    settings : dict
        MuJoCo's settings.
    walk : dict
        The walk from the gait (:class:`~biped_casadi.mujoco.MujocoWalk` without its logs).
    perturbed : dict
        The walk from the paper's perturbation at ``scale``.
    scale : float
        The scale of that perturbation.
    largest_scale : float
        The largest scale of the paper's perturbation (0.01 rad, 0.1 rad/s on every joint)
        in the ladder tried that walked ``scale_steps`` steps, 0 when none did.
    scale_steps : int
        Steps those walks had to walk.
    stride : StrideMap
        MuJoCo's stride map and limit cycle.
    exact : list of complex
        The toolkit's eigenvalues (:func:`exact_eigenvalues`).
    exact_max_abs : float
        Their largest modulus.
    """

    status: str
    message: str
    label: str
    design: dict
    settings: dict
    walk: dict
    perturbed: dict
    scale: float
    largest_scale: float
    scale_steps: int
    stride: StrideMap
    exact: list
    exact_max_abs: float

    SUCCESS = ("walked",)


def _brief(w) -> dict:
    d = w.to_dict()
    d["dqu_errors"] = [s.dqu_error for s in w.steps]
    d["qu_errors"] = [s.qu_error for s in w.steps]
    d["speeds"] = [s.speed for s in w.steps]
    d["periods"] = [s.period for s in w.steps]
    d.pop("steps", None)
    return d


def largest_scale(loop: MujocoLoop, steps: int = 30, scales=(1, 2, 3, 4, 6, 8),
                  known: dict | None = None) -> float:
    """The largest scale of the paper's perturbation a loop walks ``steps`` steps from.

    Scales are tried in increasing order until one fails.

    Parameters
    ----------
    loop : MujocoLoop
        The closed loop.
    steps : int
        Steps to walk.
    scales : sequence of float
        The ladder, increasing.
    known : dict, optional
        Scale -> whether a walk from it already walked (not walked again).

    Returns
    -------
    float
        The last scale before the first failure (0 when the first fails).
    """
    best = 0.0
    g = loop.gait
    known = dict(known or {})
    for s in scales:
        ok = known.get(float(s))
        if ok is None:
            q0, dq0 = Perturbation.paper(g.model.nq).scaled(float(s)).initial_state(g)
            ok = loop.run(q0, dq0, steps).status == "walked"
        if not ok:
            break
        best = float(s)
    return best


def engine_check(design: Design, settings: ContactSettings = STIFF, label: str = "",
                 steps: int = 100, scale: float = 2.0, scale_steps: int = 30,
                 scales=(1, 2, 3, 4, 6, 8), law: str = "c", **stride) -> EngineCheck:
    """A design in MuJoCo beside the toolkit's exact analysis.

    Parameters
    ----------
    design : Design
        The design on its gait.
    settings : ContactSettings
        MuJoCo's settings.
    label : str
        The design's name in the record.
    steps : int
        Steps of the walk from the gait.
    scale : float
        Scale of the paper's perturbation of the perturbed walk (``scale_steps`` steps).
    scale_steps : int
        Steps of the perturbed walks.
    scales : sequence of float
        The ladder of :func:`largest_scale`.
    law : {'c', 'python'}
        The law in the loop.
    **stride
        Options of :func:`~biped_casadi.mujoco.stride_map` (``directions``, ``size``,
        ``fit_steps``); its cycle is measured on the walk from the gait.

    Returns
    -------
    EngineCheck
    """
    loop = MujocoLoop(design, settings, law)
    g = design.gait
    w = loop.run(g.q(0.0), g.dq(0.0), steps)
    q0, dq0 = Perturbation.paper(g.model.nq).scaled(scale).initial_state(g)
    wp = loop.run(q0, dq0, scale_steps)
    best = largest_scale(loop, scale_steps, scales, {float(scale): wp.status == "walked"})
    sm = stride_map(design, settings, law, loop=loop, walk=w, **stride)
    ex = exact_eigenvalues(design)
    label = label or design.label()
    msg = (f"{label} ({settings.contact}): {w.status} {w.steps_walked}/{steps} steps, speed "
           f"{_pct(w.speed_error)}, period {_pct(w.period_error)}; scale {scale:g}: "
           f"{wp.status} {wp.steps_walked}/{scale_steps}; largest scale {best:g}; MuJoCo "
           + (f"max|lambda| {sm.max_abs:.3g}" if sm.status != "undetermined" else
              f"stride map not determined ({sm.reason})")
           + f" (exact {max(abs(e) for e in ex):.3g})")
    return EngineCheck(status=w.status, message=msg, label=label, design=design.to_dict(),
                       settings=settings.to_dict(), walk=_brief(w), perturbed=_brief(wp),
                       scale=float(scale), largest_scale=best, scale_steps=int(scale_steps),
                       stride=sm, exact=ex, exact_max_abs=float(max(abs(e) for e in ex)))


def _pct(x) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:+.2f} %"
