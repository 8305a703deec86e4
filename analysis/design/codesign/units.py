"""The co-design's units of work, each a pure task of typed inputs: the start gait's kept
directions, a candidate's measurement (walker s* and exact max|lambda|), the directions
that fail first, the sampled starts, a start's screening solve and a gait step's exact
periodic gait."""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from biped_casadi import Design
from biped_casadi.simulation import start_states, zero_dynamics_walker
from biped_casadi.simulation.speed_profile import simulate_profile
from gait_opt import Gait, GaitOptimizationError
from gait_opt.polish import polish

from ...robustness.s_star import RobustnessResult, _robustness, _run_summary
from ...stability.poincare import poincare_map
from ...stability.vc_map import vc_eigenvalue
from ...tasks import task
from .functions import TranscriptionSettings, _node_functions
from .problem import Problem, Solve, solve
from .settings import IpoptLimits, StartSampling

__all__ = ["Measured", "Screened", "GaitStep", "vc_radius", "measure", "hardest", "own_orbit",
           "sampled_starts", "screen", "gait_step", "fixed_problem", "paper_first",
           "kept_first"]


@dataclass
class Measured:
    """A design measured by the walker: s* over the kept directions and max ``|lambda|``
    of A^z (full AD).

    Parameters
    ----------
    robustness : RobustnessResult
        The walker's bisection.
    max_abs : float
        max ``|lambda|``.
    """

    robustness: RobustnessResult
    max_abs: float


@dataclass
class Screened:
    """A start's screening solve.

    Parameters
    ----------
    M1 : numpy.ndarray
        The start.
    active : list of int
        The kept directions it was solved on besides the paper's.
    solve : Solve
        The solve.
    """

    M1: np.ndarray
    active: list
    solve: Solve


@dataclass
class GaitStep:
    """The exact periodic gait of a gait step's solution, or why there is none.

    Parameters
    ----------
    gait : Gait or None
        The polished gait.
    rejected : str
        Why the step is not a valid gait ('' when it is).
    """

    gait: object
    rejected: str = ""


@task
def node_kernel(model, nG: int) -> bool:
    """Build (or load) the compiled RK4 node of the co-design's transcription for a robot
    and a number of gait columns (:func:`~.functions._node_functions`).

    The co-design submits it ahead of the solves that need the node, so one worker
    compiles it while the others work instead of waiting for it inside their solves.

    Parameters
    ----------
    model : BipedModel
        The robot.
    nG : int
        Gait columns (0: the gait fixed).

    Returns
    -------
    bool
        Whether the node runs on the four-lane kernel (else on the scalar Function).
    """
    return _node_functions(model, int(nG)).kernel is not None


@task
def vc_radius(gait) -> float:
    """``|eigenvalue|`` of virtual constraints on a gait (the co-design's eigenvalue
    bound).

    Parameters
    ----------
    gait : Gait
        The gait.

    Returns
    -------
    float
    """
    return float(abs(vc_eigenvalue(gait).eigenvalue))


@task
def measure(gait, kept, M1, rejoin: float, settings) -> Measured:
    """Walker s* over the kept directions and max ``|lambda|`` (AD) of one design.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1 : array_like
        The outputs.
    rejoin : float
        Rejoin time of v_c, fraction of T.
    settings : RobustnessSettings
        The protocol.

    Returns
    -------
    Measured
    """
    M1 = np.asarray(M1, float)
    r = _robustness(Design.tv(gait, M1, rejoin), settings, kept, None)
    if not r.paper:
        # the paper's direction is not among the kept ones (virtual constraints do not
        # walk from it at full scale): its run is measured all the same (the target)
        w = zero_dynamics_walker(gait, settings.simulation_options(), settings.rk4_steps,
                                 jit=True)
        q0, dq0 = start_states(gait, np.ones((1, 2 * gait.model.nq)), 1.0)
        r.paper = _run_summary(w.walk(q0, dq0, M1[None], rejoin, steps=settings.steps), 0,
                               settings.tol)
    lam = poincare_map(gait, rejoin=rejoin).analyse(M1, method="ad").max_abs
    return Measured(r, float(lam))


@task
def hardest(gait, kept, M1, rejoin: float, s: float, n: int, settings) -> list:
    """The n kept directions (not the paper's) that fail first or end worst at scale s.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1 : array_like
        The outputs.
    rejoin : float
        Rejoin time of v_c.
    s : float
        The scale.
    n : int
        How many.
    settings : RobustnessSettings
        The protocol (steps, validity thresholds, RK4 steps).

    Returns
    -------
    list of int
        Indices into the kept directions.
    """
    rs = settings
    w = zero_dynamics_walker(gait, rs.simulation_options(), rs.rk4_steps, jit=True)
    q0, dq0 = start_states(gait, kept.directions, s)
    B = w.walk(q0, dq0, np.asarray(M1, float), rejoin, steps=rs.steps)
    err = np.where(B.status == "ok", np.nan_to_num(B.final_error, nan=1e3),
                   1e6 - B.fail_step.astype(float))
    return [int(i) for i in np.argsort(-err) if i != 0][:n]


@task
def sampled_starts(gait, kept, rejoin: float, sampling: StartSampling, eigen_bound: float,
                   settings) -> tuple:
    """Random M1 with max ``|lambda|`` within ``eigen_bound`` from which the walker walks
    the paper's perturbation at scale 1, in the order drawn.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions (the paper's first).
    rejoin : float
        Rejoin time of v_c.
    sampling : StartSampling
        How many, in which box, which seed.
    eigen_bound : float
        The bound on max ``|lambda|``.
    settings : RobustnessSettings
        The protocol.

    Returns
    -------
    tuple
        (the starts (k, nu), how many of the samples were stable within the bound).
    """
    st, rs = sampling, settings
    nu = gait.model.nu
    if st.samples <= 0 or st.kept <= 0:
        return np.zeros((0, nu)), 0
    rng = np.random.default_rng(st.seed)
    M = rng.uniform(-st.box, st.box, (st.samples, nu))
    jb = poincare_map(gait, rejoin=rejoin).jacobian_batch(M)
    ok = (jb.status == "stable") & (jb.max_abs <= eigen_bound)
    M = M[ok][:8 * st.kept]
    if len(M):
        w = zero_dynamics_walker(gait, rs.simulation_options(), 200, jit=True)
        q0, dq0 = start_states(gait, np.repeat(kept.directions[:1], len(M), 0), 1.0)
        B = w.walk(q0, dq0, M, rejoin, steps=rs.steps)
        M = M[B.verdict(rs.tol) == "ok"][:st.kept]
    return M, int(ok.sum())


@task
def own_orbit(gait, settings) -> str:
    """Why virtual constraints do not walk one step from the gait's own orbit, or ''.

    Parameters
    ----------
    gait : Gait
        The gait.
    settings : RobustnessSettings
        The protocol (friction coefficient, torque limit).

    Returns
    -------
    str
        The full-order simulator's message for the orbit's first invalid state (e.g.
        'fell: ... torso angle 2.0546 rad'), empty when the step is valid.
    """
    run = simulate_profile([Design.vc(gait)], options=settings.simulation_options())
    return "" if run.status == "ok" else re.sub(r"^step \d+: ", "", run.message)


def paper_first(kept, active) -> np.ndarray:
    """The NLP's directions: the paper's perturbation first (at scale 1: the kept first
    one when it is the paper's, else the paper's itself), then the ``active`` kept ones.

    Parameters
    ----------
    kept : KeptDirections
        The gait's kept directions.
    active : list of int
        Kept directions besides the first.

    Returns
    -------
    numpy.ndarray
    """
    d = kept.directions
    first = d[:1] if np.all(d[0] == 1) else np.ones((1, d.shape[1]))
    return np.vstack([first, d[list(active)]]) if len(active) else first


def kept_first(kept) -> tuple | None:
    """The gait's first kept direction when it is not the paper's (the NLP's first
    direction when the paper's cannot strike from the start), else None.

    Parameters
    ----------
    kept : KeptDirections
        The gait's kept directions.

    Returns
    -------
    tuple or None
    """
    d0 = kept.directions[0]
    return None if np.all(d0 == 1) else tuple(float(v) for v in d0)


def fixed_problem(gait, kept, M1, active, s0: float, *, steps: int, tst: TranscriptionSettings,
                  scenario_tol: float, paper_tol: float, rejoin: float,
                  jury_bound: float) -> Problem:
    """The gait-fixed NLP on the paper's direction and the ``active`` kept directions.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1 : array_like
        The start.
    active : list of int
        Kept directions besides the paper's.
    s0 : float
        The starting scale.
    steps : int
        Steps per scenario.
    tst : TranscriptionSettings
        Rule and margins.
    scenario_tol, paper_tol : float
        Error bounds.
    rejoin : float
        Rejoin time of v_c.
    jury_bound : float
        Bound on max ``|lambda|``.

    Returns
    -------
    Problem
    """
    return Problem(gait=gait, directions=paper_first(kept, active), steps=steps,
                   free=False, transcription=tst, scenario_tol=scenario_tol,
                   paper_tol=paper_tol, rejoin=float(rejoin),
                   M1=tuple(float(v) for v in np.asarray(M1, float)), s0=float(s0),
                   jury_bound=float(jury_bound), fallback_first=kept_first(kept))


@task
def screen(gait, kept, M1, problem_settings: dict, limits: IpoptLimits, settings) -> Screened:
    """One start's screening: the directions that fail first from it at the starting
    scale, then one short solve of the gait-fixed NLP on them.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1 : array_like
        The start.
    problem_settings : dict
        Keyword arguments of :func:`fixed_problem` (``steps``, ``tst``, ...), with
        ``s_start`` and ``initial_active``.
    limits : IpoptLimits
        The screening budget.
    settings : RobustnessSettings
        The protocol.

    Returns
    -------
    Screened
    """
    ps = dict(problem_settings)
    s0, n = ps.pop("s_start"), ps.pop("initial_active")
    active = hardest(gait, kept, M1, ps["rejoin"], s0, n, settings)
    p = fixed_problem(gait, kept, M1, active, s0, **ps)
    return Screened(np.asarray(M1, float), active, solve(p, limits))


@task
def gait_step(gait, gait_vector, nlp_status: str) -> GaitStep:
    """A gait step's solution made an exact periodic orbit and checked on the dense grid.

    Parameters
    ----------
    gait : Gait
        The gait the step started from (its options).
    gait_vector : numpy.ndarray
        (vec alpha, T, r0) of the step's solution.
    nlp_status : str
        IPOPT's status (kept in the gait's statistics).

    Returns
    -------
    GaitStep
    """
    model, opts = gait.model, gait.options
    na = model.nu * (opts.bezier_degree + 1)
    G = np.asarray(gait_vector, float)
    alpha = G[:na].reshape(model.nu, opts.bezier_degree + 1, order="F")
    T, r0 = float(G[na]), G[na + 1:]
    try:
        a2, x2, T2, _ = polish(model, opts, alpha, r0, T)
        g_new = Gait(model, opts, a2, x2, T2,
                     solver_stats=dict(method="codesign", nlp_status=nlp_status))
        bad = g_new.violations()
    except (GaitOptimizationError, ValueError) as e:
        return GaitStep(None, f"the gait step is not a valid gait: {[('polish', str(e))]}")
    if bad:
        return GaitStep(None, f"the gait step is not a valid gait: {bad}")
    return GaitStep(g_new)
