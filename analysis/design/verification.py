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

from biped_casadi import (Design, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, directions, simulate)
from biped_casadi.results import Result, internal
from biped_casadi.simulation import (WalkBatch, failure_text, simulator, start_states,
                                     zero_dynamics_walker)

from ..robustness.s_star import RobustnessSettings, robustness
from ..stability.poincare import poincare_map
from ..stability.vc_map import vc_eigenvalue
from ..tasks import Engine, task

__all__ = ["DesignCheck", "verify_design", "HiddenPatterns", "hidden_sign_patterns",
           "verify_flow", "submit_check", "finish_check", "design_check", "s_star_bisection",
           "full_order_runs", "paper_run", "eigenvalue_check", "closed_loop_library"]


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

    def paper_outcome(self, tol: float) -> str:
        """How the walk from the paper's perturbation ended, in words.

        Parameters
        ----------
        tol : float
            The error it had to fall below.

        Returns
        -------
        str
            'below TOL from step N', or the walk's status when it never got there.
        """
        conv = self.steps_to_converge
        return f"below {tol:g} from step {conv}" if conv else str(self.paper_status)


@task
def s_star_bisection(design: Design, kept, settings: RobustnessSettings):
    """Step 1 of the protocol: s* by the walker's bisection (a task).

    Parameters
    ----------
    design : Design
        The design on its gait.
    kept : KeptDirections
        The gait's kept directions.
    settings : RobustnessSettings
        The protocol's settings.

    Returns
    -------
    RobustnessResult
    """
    return robustness(design, settings, kept=kept)


def _options(st: RobustnessSettings) -> SimulationOptions:
    return SimulationOptions(steps=st.steps, mu=st.mu, torque_limit=st.torque_limit, jit=True)


@task
def closed_loop_library(design: Design, settings: RobustnessSettings) -> str:
    """Step 0: compile the design's full-order closed loop, which the runs of steps 2 and 3
    share (a task).  Submitted before them, it compiles in one process while the others
    work, instead of the runs that start together waiting on one another's compile.

    Parameters
    ----------
    design : Design
        The design on its gait.
    settings : RobustnessSettings
        Steps, mu, torque limit.

    Returns
    -------
    str
        What the simulator was built for (the compiled library is kept by content in the
        cache folder).
    """
    sim = simulator(design.controller_for(), _options(settings))
    return f"{sim.controller.name} closed loop, {sim.options.rk4_steps} RK4 steps per T"


@task
def full_order_runs(design: Design, kept, settings: RobustnessSettings, scale: float,
                    library: str = "") -> dict:
    """Step 2: the full-order simulator from every kept direction at one scale (a task).

    Parameters
    ----------
    design : Design
        The design on its gait.
    kept : KeptDirections
        The kept directions.
    settings : RobustnessSettings
        Steps, tolerance, mu, torque limit.
    scale : float
        The perturbation's scale.
    library : str
        :func:`closed_loop_library`'s result (its ref makes this task come after it).

    Returns
    -------
    dict
        ``scale``, ``outcomes`` (one verdict per direction) and ``passed``.
    """
    gait, dirs, st = design.gait, kept.directions, settings
    ctrl = design.controller_for()
    q0, dq0 = start_states(gait, dirs, np.full(len(dirs), scale))
    runs = WalkBatch.concat([simulate(ctrl, q0[i], dq0[i], _options(st))
                             for i in range(len(dirs))])
    out = [str(v) for v in runs.verdict(st.tol)]
    return dict(scale=float(scale), outcomes=out, passed=int(sum(o == "ok" for o in out)))


@task
def paper_run(design: Design, kept, settings: RobustnessSettings, library: str = ""):
    """Step 3: the full-order run from the paper's perturbation (at scale 1).

    Parameters
    ----------
    design : Design
        The design on its gait.
    kept : KeptDirections
        The kept directions (not used: the run is from the paper's perturbation, kept
        or not; the argument keeps the protocol's signature).
    settings : RobustnessSettings
        Steps, mu, torque limit.
    library : str
        :func:`closed_loop_library`'s result (its ref makes this task come after it).

    Returns
    -------
    SimulationResult
    """
    # the paper's perturbation itself (the first kept direction is the paper's only when
    # virtual constraints walk from it at full scale)
    paper = np.ones((1, 2 * design.gait.model.nq))
    q0, dq0 = start_states(design.gait, paper, [1.0])
    return simulate(design.controller_for(), q0[0], dq0[0], _options(settings))


@task
def eigenvalue_check(design: Design) -> tuple:
    """Step 4: max ``|lambda|`` of A^z by full AD, and the virtual constraints' on the same
    gait (a task).

    Parameters
    ----------
    design : Design
        A time-varying design on its gait.

    Returns
    -------
    tuple of float
        (max ``|lambda|``, ``|eigenvalue|`` of virtual constraints).
    """
    g = design.gait
    max_abs = poincare_map(g, rejoin=design.rejoin).analyse(np.array(design.M1),
                                                            method="ad").max_abs
    return float(max_abs), float(abs(vc_eigenvalue(g).eigenvalue))


def design_check(r, verified: dict, paper, eigen: tuple, settings: RobustnessSettings
                 ) -> DesignCheck:
    """The protocol's measurements as one :class:`DesignCheck`.

    Parameters
    ----------
    r : RobustnessResult
        The bisection (:func:`s_star_bisection`).
    verified : dict
        Label -> :func:`full_order_runs` at s* ('at_s_star') and s_fail ('at_s_fail').
    paper : SimulationResult
        :func:`paper_run`.
    eigen : tuple
        :func:`eigenvalue_check`.
    settings : RobustnessSettings
        The protocol's settings.

    Returns
    -------
    DesignCheck
    """
    st = settings
    errs = paper.unactuated_errors().tolist()
    conv = paper.steps_to_converge(st.tol)
    conv = int(conv) if math.isfinite(conv) else None
    max_abs, lam_vc = eigen
    fail = r.failure
    failure = (f"{failure_text(fail['status'], fail['step'])} (direction {fail['direction']})"
               if fail else "")
    check = DesignCheck(s_star=r.s_star, s_fail=r.s_fail, failure=failure, verified=verified,
                        max_abs=float(max_abs), vc_eigenvalue=float(lam_vc),
                        steps_to_converge=conv, paper_errors=errs,
                        paper_status=str(paper.status), peak_torque=float(paper.peak_torque),
                        robustness=r, paper_run=paper)
    check.message = (f"s* = {r.s_star:.4g}" + (f" ({failure} at {r.s_fail:.4g})" if fail else "")
                     + f"; max|lambda| {max_abs:.3g} (virtual constraints {lam_vc:.3g}); "
                     f"paper's perturbation: {check.paper_outcome(st.tol)}")
    return check


def submit_check(engine, design: Design, kept, settings: RobustnessSettings):
    """Submit the protocol's tasks: (the bisection, the paper's run, the eigenvalues,
    the compiled closed loop the full-order runs share) as the engine's futures;
    :func:`finish_check` waits for them and adds the full-order runs at s* and just
    above.

    Parameters
    ----------
    engine : Engine
        Where the tasks run.
    design, kept, settings :
        As :func:`verify_design`.

    Returns
    -------
    tuple of Ref
    """
    library = engine.submit(closed_loop_library, design, settings)
    return (engine.submit(s_star_bisection, design, kept, settings),
            engine.submit(paper_run, design, kept, settings, library),
            engine.submit(eigenvalue_check, design), library)


def finish_check(engine, design: Design, kept, settings: RobustnessSettings, refs) -> DesignCheck:
    """The check from the refs of :func:`submit_check`, after the full-order runs at s*
    and at s_fail (run side by side).

    Parameters
    ----------
    engine : Engine
        Where the tasks run.
    design, kept, settings :
        As :func:`verify_design`.
    refs : tuple of Ref
        From :func:`submit_check`.

    Returns
    -------
    DesignCheck
    """
    bis, paper, eigen, library = refs
    r = bis.result()
    runs = {label: engine.submit(full_order_runs, design, kept, settings, s, library)
            for label, s in (("at_s_star", r.s_star), ("at_s_fail", r.s_fail))
            if math.isfinite(s)}
    return design_check(r, {k: v.result() for k, v in runs.items()}, paper.result(),
                        eigen.result(), settings)


@task
def verify_flow(engine, design: Design, kept, settings: RobustnessSettings) -> DesignCheck:
    """:func:`verify_design` as a flow of tasks (the bisection, the paper's run and the
    eigenvalues side by side, then the full-order runs at s* and just above).

    Parameters
    ----------
    engine : Engine
        Where the tasks run.
    design, kept, settings :
        As :func:`verify_design`.

    Returns
    -------
    DesignCheck
    """
    return finish_check(engine, design, kept, settings,
                        submit_check(engine, design, kept, settings))


def verify_design(design: Design, kept, settings: RobustnessSettings, progress=None,
                  scheduler="synchronous") -> DesignCheck:
    """Measure a design by the verification protocol (module docstring).

    Parameters
    ----------
    design : Design
        A time-varying design on its gait.
    kept : KeptDirections
        The kept directions of this gait (:func:`analysis.robustness.kept_directions`).
    settings : RobustnessSettings
        Steps, tolerance, mu, torque limit, RK4 steps and bisection rounds.
    progress : callable, optional
        Called with one line of text before the work starts.
    scheduler : str or Client, optional
        Where its tasks run (:func:`analysis.tasks.resolve_scheduler`; default: this
        process).

    Returns
    -------
    DesignCheck
    """
    design = Design.require(design)
    if design.M1 is None:
        raise ValueError("design: the protocol measures a time-varying design")
    if progress is not None:
        progress("s* of the design (walker bisection) and full-order verification")
    with Engine(scheduler, cache=False) as eng:
        return eng.spawn(verify_flow, design, kept, settings).result()


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


@task
def hidden_sign_patterns(design: Design, kept, settings: RobustnessSettings,
                         scales=(1.0, 1.25), n: int = 12, seeds=(7, 11, 13)) -> HiddenPatterns:
    """Walk the design from sign patterns never used to choose it (module docstring).

    Parameters
    ----------
    design : Design
        The design on its gait.
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
    design = Design.require(design)
    gait = design.gait
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
           + ", ".join(f"{v['passed']} of {len(hidden)} walk at s = {k}"
                       for k, v in by_scale.items())
           + f"; full order at s = 1: {full['passed']} of {len(hidden)}")
    return HiddenPatterns(patterns=len(hidden), candidates=tried, by_scale=by_scale,
                          full_order=full, message=msg, directions=hidden)
