"""The one verification protocol of a robust time-varying design, whichever method found it.

Both the sampling search (:mod:`analysis.design.robust_search`) and the co-design NLP
(:mod:`analysis.design.codesign`) report a design through :func:`verify_design`:

1. s* by the bisection of :func:`analysis.robustness.robustness` (the kept directions,
   ``steps`` steps, final error below ``tol``) on the zero-dynamics walker;
2. the full-order simulator from every kept direction at s* (all must walk and converge)
   and just above it (the bisection's s_fail: one fails);
3. the paper's perturbation (direction 0 at s = 1) in full order: the step from which
   the error stays below ``tol``, and the error at every step;
4. max|lambda| of A^z by full AD, against the virtual constraints' eigenvalue on the same
   gait.

:func:`hidden_sign_patterns` adds the generalisation check: sign patterns of the paper's
perturbation never used to choose the design (other seeds, not kept), with a valid start
(swing foot not below the ground) from which virtual constraints walk at scale 1.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_casadi import (SimulationOptions, TimeVaryingController, VirtualConstraintController,
                          directions, simulate)
from biped_casadi.results import Result, internal
from biped_casadi.simulation import WalkBatch, start_states, zero_dynamics_walker
from biped_casadi.control.reference import gait_first

from ..robustness.s_star import Design, RobustnessSettings, robustness
from ..stability.poincare import poincare_map
from ..stability.vc_map import vc_eigenvalue

__all__ = ["DesignCheck", "verify_design", "HiddenPatterns", "hidden_sign_patterns"]


@dataclass
class DesignCheck(Result):
    """A design measured by the verification protocol (module docstring).

    ``success`` means every measurement was made; ``status`` is 'done'.

    Parameters
    ----------
    s_star, s_fail : float
        The bisection's s* and the scale just above it where a direction failed (inf
        when none failed at ``s_max``).
    failure : str
        The failure at ``s_fail`` in words ('' when none).
    verified : dict
        The full-order runs: 'at_s_star' and 'at_s_fail' -> scale, outcome per direction
        and number passed.
    max_abs : float
        max ``|lambda|`` of A^z (full AD).
    vc_eigenvalue : float
        ``|eigenvalue|`` of virtual constraints on the same gait.
    steps_to_converge : int or None
        The paper's perturbation in full order: the step from which the error stays below
        ``tol``; None when the run failed or never converged.
    paper_errors : list of float
        ``max(|q_u err|, |dq_u err|)`` at every step of that run.
    paper_status : str
        That run's status.
    peak_torque : float
        Its largest ``|u|``, N m.
    status : str
        'done'.
    message : str
        The figures in words.
    robustness : RobustnessResult
        The bisection's result (left out of ``to_dict()``).
    paper_run : object
        The full-order run from the paper's perturbation (left out of ``to_dict()``).
    """

    s_star: float
    s_fail: float
    failure: str
    verified: dict
    max_abs: float
    vc_eigenvalue: float
    steps_to_converge: int | None
    paper_errors: list
    paper_status: str
    peak_torque: float
    status: str = "done"
    message: str = ""
    robustness: object = internal(default=None)
    paper_run: object = internal(default=None)

    SUCCESS = ("done",)


@gait_first
def verify_design(gait, design: Design, kept, settings: RobustnessSettings,
                  progress=None, unit=None, order=None) -> DesignCheck:
    """Measure a design by the verification protocol (module docstring).

    Parameters
    ----------
    gait : Reference
        The gait the design runs on.
    design : Design
        M1 and the rejoin time.
    kept : KeptDirections
        The kept directions of this gait (:func:`analysis.robustness.kept_directions`).
    settings : RobustnessSettings
        Steps, tolerance, mu, torque limit, RK4 steps and bisection rounds.
    progress : callable, optional
        Called with one line of text per stage.
    unit, order : callable, optional
        How the walker's bisection and the three sets of full-order runs (at s*, at
        s_fail, the paper's perturbation) are done: ``unit(name, inputs, compute)``
        returns ``compute()`` (default) or a result another process computed,
        ``order(units)`` the order they are taken in (default as listed); the co-design shares them between two
        processes (:meth:`analysis.design.codesign.driver._Codesign.unit`).

    Returns
    -------
    DesignCheck
    """
    model = gait.model
    say = progress or (lambda msg: None)
    unit = unit or (lambda name, inputs, compute: compute())
    order = order or list
    st, dirs = settings, kept.directions
    say("s* of the design (walker bisection) and full-order verification")
    inputs = dict(gait=gait.cache_key, design=design.to_dict(), kept=dirs.tolist(),
                  settings=dict(st.__dict__))
    r = unit("s* bisection", inputs, lambda: robustness(gait, design, st, kept=kept))
    ctrl = TimeVaryingController(gait, np.array(design.M1), rejoin=design.rejoin)
    opts = SimulationOptions(steps=st.steps, mu=st.mu, torque_limit=st.torque_limit, jit=True)

    def runs_at(s):
        q0, dq0 = start_states(gait, dirs, np.full(len(dirs), s))
        runs = WalkBatch.concat([simulate(ctrl, q0[i], dq0[i], opts) for i in range(len(dirs))])
        out = [str(v) for v in runs.verdict(st.tol)]
        return dict(scale=s, outcomes=out, passed=int(sum(o == "ok" for o in out)))

    def paper_run():
        q0, dq0 = start_states(gait, dirs[:1], [1.0])
        return simulate(ctrl, q0[0], dq0[0], opts)

    todo = [(label, s, lambda s=s: runs_at(s))
            for label, s in (("at_s_star", r.s_star), ("at_s_fail", r.s_fail))
            if math.isfinite(s)] + [("paper", 1.0, paper_run)]
    done = {label: unit("full order", dict(inputs, label=label, scale=s), compute)
            for label, s, compute in order(todo)}
    verified = {label: done[label] for label, _, _ in todo if label != "paper"}
    paper = done["paper"]
    errs = paper.unactuated_errors().tolist()
    conv = paper.steps_to_converge(st.tol)
    conv = int(conv) if math.isfinite(conv) else None
    max_abs = poincare_map(gait, rejoin=design.rejoin).analyse(
        np.array(design.M1), method="ad").max_abs
    lam_vc = abs(vc_eigenvalue(gait).eigenvalue)
    fail = r.failure
    failure = (f"{fail['status']} in step {fail['step']} (direction {fail['direction']})"
               if fail else "")
    msg = (f"s* = {r.s_star:.4g}" + (f" ({failure} at {r.s_fail:.4g})" if fail else "")
           + f"; max|lambda| {max_abs:.3g} (virtual constraints {lam_vc:.3g}); paper's "
           f"perturbation: " + (f"below {st.tol:g} from step {conv}" if conv else paper.status))
    return DesignCheck(s_star=r.s_star, s_fail=r.s_fail, failure=failure, verified=verified,
                       max_abs=float(max_abs), vc_eigenvalue=float(lam_vc),
                       steps_to_converge=conv, paper_errors=errs, paper_status=str(paper.status),
                       peak_torque=float(paper.peak_torque), message=msg, robustness=r,
                       paper_run=paper)


@dataclass
class HiddenPatterns(Result):
    """The generalisation check of :func:`hidden_sign_patterns`.

    ``success`` means the patterns were walked; ``status`` is 'done'.

    Parameters
    ----------
    patterns : int
        Valid hidden sign patterns walked.
    candidates : int
        Sign patterns tried to find them.
    by_scale : dict
        Scale -> {'passed': number walking ``steps`` valid steps and ending below
        ``tol`` (walker), 'outcomes': per pattern}.
    full_order : dict
        Scale 1 in the full-order simulator: {'passed', 'outcomes'}.
    status : str
        'done'.
    message : str
        The figures in words.
    directions : numpy.ndarray
        The patterns (left out of ``to_dict()``).
    """

    patterns: int
    candidates: int
    by_scale: dict
    full_order: dict
    status: str = "done"
    message: str = ""
    directions: np.ndarray = internal(default=None)

    SUCCESS = ("done",)


@gait_first
def hidden_sign_patterns(gait, design: Design, kept, settings: RobustnessSettings,
                         scales=(1.0, 1.25), n: int = 12, seeds=(7, 11, 13)) -> HiddenPatterns:
    """Walk the design from sign patterns never used to choose it (module docstring).

    Parameters
    ----------
    gait : Reference
        The gait.
    design : Design
        The design.
    kept : KeptDirections
        The kept directions (excluded from the patterns).
    settings : RobustnessSettings
        Steps, tolerance, mu, torque limit, RK4 steps.
    scales : tuple of float
        Scales walked (the walker); scale 1 also in full order.
    n : int
        Patterns wanted.
    seeds : tuple of int
        Seeds of :func:`biped_casadi.directions` the patterns come from.

    Returns
    -------
    HiddenPatterns
    """
    model = gait.model
    st = settings
    opts = SimulationOptions(steps=st.steps, mu=st.mu, torque_limit=st.torque_limit, jit=True)
    vc = VirtualConstraintController(gait)
    found, tried = [], 0
    for seed in seeds:
        for d in directions(60, model.nq, seed)[1:]:
            if len(found) == n:
                break
            if not np.all(np.abs(d) == 1) or any(np.array_equal(d, k) for k in kept.directions) \
                    or any(np.array_equal(d, f) for f in found):
                continue
            tried += 1
            q0, dq0 = start_states(gait, d[None], [1.0])
            if float(model.swing_foot(q0[0])[1]) < -opts.ground_tolerance:
                continue
            if str(simulate(vc, q0[0], dq0[0], opts).status) == "ok":
                found.append(d)
    hidden = np.array(found).reshape(-1, 2 * model.nq)
    walker = zero_dynamics_walker(gait, st.simulation_options(), st.rk4_steps, jit=True)
    by_scale = {}
    for s in scales:
        q0, dq0 = start_states(gait, hidden, s)
        B = walker.walk(q0, dq0, np.array(design.M1), design.rejoin, steps=st.steps)
        v = [str(x) for x in B.verdict(st.tol)]
        by_scale[repr(float(s))] = dict(passed=int(sum(x == "ok" for x in v)), outcomes=v)
    ctrl = TimeVaryingController(gait, np.array(design.M1), rejoin=design.rejoin)
    q0, dq0 = start_states(gait, hidden, 1.0)
    runs = WalkBatch.concat([simulate(ctrl, q0[i], dq0[i], opts) for i in range(len(hidden))]) \
        if len(hidden) else None
    fo = [str(x) for x in runs.verdict(st.tol)] if runs is not None else []
    full = dict(passed=int(sum(x == "ok" for x in fo)), outcomes=fo)
    msg = (f"{len(hidden)} hidden sign patterns (of {tried} tried): "
           + ", ".join(f"{v['passed']} walk at s = {k}" for k, v in by_scale.items())
           + f"; full order at s = 1: {full['passed']}")
    return HiddenPatterns(patterns=len(hidden), candidates=tried, by_scale=by_scale,
                          full_order=full, message=msg, directions=hidden)
