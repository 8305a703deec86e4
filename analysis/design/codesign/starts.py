"""Starts that fit the gait: the co-design's first M1 chosen on the gait it runs on.

Three sources, screened together by the walker
(:func:`~.screen.fitted_starts`):

- samples scaled to the gait: component i of M1 drawn in ``box`` x c_i, where c_i =
  range(q_a,i^d) / range(q_u^d) over the step is how far the actuated joint i moves per
  radian of the unactuated one (M1 multiplies q_u in the outputs v = M1 q_u + q_a, so
  its natural unit on a gait is this ratio, not 1 radian per radian);
- the deadbeat M1 NLP's designs (:func:`analysis.design.m1_nlp.optimize_m1`: max|lambda|
  = 0, on an a = b = 0 group; submitted beside, passed as ``extra``);
- M1 that mimic the virtual constraints on the gait: q_a^d as a function of q_u^d has
  the slope dq_a^d/dq_u^d = dq_a^d/dt / dq_u^d/dt; outputs v = q_a - slope q_u hold
  that relation to first order, so M1 = -slope, taken at the Poincaré section (0.75 T)
  and as the least-squares slope over the step (:func:`vc_like_m1`).

Every start stable with max|lambda| within the bound walks the paper's perturbation once;
those that converge from it soonest (at most ``screened``) are measured by the walker's
s* (bisection over the kept directions, :func:`analysis.robustness.s_star.s_star_batch`);
the best by the target (s* >= 1 and the paper's perturbation converged in time) are the
starts, and the screen's best scale and the constraint that stops it there (the failing
run's cause, :func:`binds`) say what binds when nothing walks far.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design
from biped_casadi.results import Result
from biped_casadi.simulation import start_states, zero_dynamics_walker
from biped_casadi.simulation.outcome import NOT_CONVERGED

from ...robustness.s_star import s_star_batch
from ...stability.poincare import poincare_map
from ...tasks import task
from ..m1_nlp import optimize_m1

__all__ = ["gait_scale", "vc_like_m1", "deadbeat_starts", "StartScreen", "start_candidates",
           "screen_batch", "paper_convergence", "screen_binds", "binds",
           "failure_binds", "BINDS"]

#: the walker's failure statuses in the words of the constraints that bind
BINDS = {
    "slipped": "friction (the stance foot's cone)",
    "impulse": "the impact impulse ratio (the impulse outside the friction cone)",
    "torque_limit": "the torque limit",
    "scuffed": "the swing foot's clearance (it scuffs the ground)",
    "no_impact": "the swing foot's clearance (no valid strike)",
    "negative_normal_force": "the stance normal force (the foot lifts)",
    "fell": "balance (the robot falls)",
    "singular": "the controller's singularity (eq. 24)",
    NOT_CONVERGED: "convergence (the error is not below 1e-3 after the steps walked)",
    "diverged": "the integration (the state diverges)",
    "out_of_range": "the reference's range (the step lasts too long)",
}


def gait_scale(gait) -> np.ndarray:
    """How far each actuated joint moves per radian of the unactuated one over the step.

    Parameters
    ----------
    gait : Gait
        The gait.

    Returns
    -------
    numpy.ndarray
        (nu,) range(q_a,i^d) / range(q_u^d), at least 0.1 (rad/rad).
    """
    q, _, _ = gait.evaluate(np.linspace(0.0, gait.T, 201))
    ru = max(float(np.ptp(q[0])), 1e-6)
    return np.maximum(np.ptp(q[1:], axis=1) / ru, 0.1)


def vc_like_m1(gait, section: float = 0.75) -> np.ndarray:
    """M1 whose outputs mimic the virtual constraints of the gait to first order.

    Parameters
    ----------
    gait : Gait
        The gait.
    section : float
        Where the slope is taken, fraction of T (the Poincaré section).

    Returns
    -------
    numpy.ndarray
        (2, nu): minus dq_a^d/dq_u^d at ``section`` T, and minus the least-squares slope
        of q_a^d against q_u^d over the step.
    """
    t = np.linspace(0.0, gait.T, 201)
    q, dq, _ = gait.evaluate(t)
    _, dqs, _ = gait.evaluate(np.array([section * gait.T]))
    at = -dqs[1:, 0] / dqs[0, 0]
    fit = -np.array([np.polyfit(q[0], q[i], 1)[0] for i in range(1, gait.model.nq)])
    return np.vstack([at, fit])


@task
def deadbeat_starts(gait) -> np.ndarray:
    """The deadbeat M1 NLP's designs on the gait (a task; none where it fails).

    On the first a = b = 0 group for a robot of four torques, with every component free
    otherwise (:func:`analysis.design.m1_nlp.optimize_m1`).

    Parameters
    ----------
    gait : Gait
        The gait.

    Returns
    -------
    numpy.ndarray
        (k, nu), k = 0 or 1.
    """
    nu = gait.model.nu
    try:
        r = optimize_m1(gait, group=1 if nu == 4 else None, n_random=0)
    except (ValueError, RuntimeError):            # no group on this gait, IPOPT failed
        return np.zeros((0, nu))
    return np.asarray(r.M1, float).reshape(1, nu)


@dataclass
class StartScreen(Result):
    """The starts screened on a gait by the walker's s* (:func:`~.screen.fitted_starts`).

    ``success`` means the screen ran; ``status`` 'walks' when a start has s* > 0,
    'none' otherwise.

    Parameters
    ----------
    status : str
        'walks' or 'none'.
    message : str
        The best start in words.
    starts : numpy.ndarray
        (k, nu) the starts kept, best s* first.
    s_star : numpy.ndarray
        (k,) their s* (to the screen's resolution).
    sources : list of str
        Where each came from ('sample', 'deadbeat', 'virtual constraints', 'given').
    candidates : int
        Starts drawn or given.
    stable : int
        Of them, stable with max ``|lambda|`` within the bound.
    screened : int
        Of them, bisected.
    best : dict
        The best start: ``M1``, ``s_star``, ``s_fail``, ``cause`` (the failing run's
        status and step just above its s*), ``binds`` (that cause in the words of the
        constraints).
    scale : list of float
        The samples' box per component (:func:`gait_scale` x the box).
    refined : dict
        The refinement near the best starts (:func:`.refine.refine_starts`), {} when it
        did not run.
    """

    status: str
    message: str
    starts: np.ndarray
    s_star: np.ndarray
    sources: list
    candidates: int
    stable: int
    screened: int
    best: dict = field(default_factory=dict)
    scale: list = field(default_factory=list)
    refined: dict = field(default_factory=dict)

    SUCCESS = ("walks", "none")


def binds(run, mu: float) -> str:
    """The constraint that stops a failed run, in words.

    Parameters
    ----------
    run : WalkOutcome
        The failing run (its status and impulses).
    mu : float
        The friction coefficient it was walked with.

    Returns
    -------
    str
    """
    status = str(run.status)
    if status == "ok":
        return BINDS[NOT_CONVERGED]
    if status == "slipped" and np.isfinite(run.max_impulse_ratio) \
            and run.max_impulse_ratio >= mu * (1 - 1e-9):
        status = "impulse"
    return BINDS.get(status, status)


@task
def start_candidates(gait, rejoin: float, sampling, eigen_bound: float, extra=(),
                     settings=None) -> dict:
    """The starts to screen (module docstring).

    The given ones, the virtual-constraint ones and samples in the gait's units, those
    stable with max ``|lambda|`` within the bound (given and virtual-constraint ones
    first, then the samples, at most ``sampling.screened``).

    Parameters
    ----------
    gait : Gait
        The gait.
    rejoin : float
        Rejoin time of v_c, fraction of T.
    sampling : StartSampling
        Samples, box, seed, how many are screened.
    eigen_bound : float
        The bound on max ``|lambda|``.
    extra : array_like, optional
        (k, nu) given starts (the deadbeat NLP's, the user's).
    settings : RobustnessSettings, optional
        The protocol: with it, the stable samples that converge soonest from the
        paper's perturbation are screened first (else in the order drawn).

    Returns
    -------
    dict
        ``M1`` (m, nu) the starts to screen, ``sources`` (m,), ``candidates``,
        ``stable`` and ``paper_converges`` (counts), ``scale`` (the samples' box per
        component).
    """
    st, nu = sampling, gait.model.nu
    scale = st.box * gait_scale(gait)
    rng = np.random.default_rng(st.seed)
    given = np.asarray(extra, float).reshape(-1, nu)
    vcl = vc_like_m1(gait)
    n = max(st.samples, 0)
    M = np.vstack([given, vcl, rng.uniform(-scale, scale, (n, nu))])
    src = np.array(["given"] * len(given) + ["virtual constraints"] * len(vcl)
                   + ["sample"] * n)
    jb = poincare_map(gait, rejoin=rejoin).jacobian_batch(M)
    ok = (jb.status == "stable") & (jb.max_abs <= eigen_bound)
    idx = np.flatnonzero(ok)
    # every stable start walks the paper's perturbation once (cheap beside a bisection):
    # those that converge from it soonest are bisected first, the given and virtual
    # constraints' ones always
    conv = np.full(len(idx), np.inf)
    if idx.size and settings is not None:
        w = zero_dynamics_walker(gait, settings.simulation_options(), st.screen_rk4,
                                 jit=True)
        conv = paper_convergence(w, gait, M[idx], rejoin, settings)
    k = len(given) + len(vcl)
    first = idx[idx < k]
    rest = np.flatnonzero(idx >= k)
    rest = rest[np.argsort(conv[rest], kind="stable")]
    idx = np.r_[first, idx[rest][:max(st.screened - len(first), 0)]].astype(int)
    return dict(M1=M[idx], sources=src[idx].tolist(), candidates=len(M),
                stable=int(ok.sum()), scale=scale.tolist(),
                paper_converges=int(np.sum(conv < np.inf)))


def paper_convergence(walker, gait, M1s, rejoin: float, settings) -> np.ndarray:
    """The step from which the paper's perturbation (scale 1) stays below the tolerance,
    walked by ``walker`` from each M1 (inf where it does not within ``settings.steps``).

    Parameters
    ----------
    walker : ZeroDynamicsWalker
        The walker (:func:`biped_casadi.simulation.zero_dynamics_walker`).
    gait : Gait
        The gait.
    M1s : numpy.ndarray
        (m, nu) the outputs.
    rejoin : float
        Rejoin time of v_c, fraction of T.
    settings : RobustnessSettings
        The protocol (steps, tolerance).

    Returns
    -------
    numpy.ndarray
        (m,) the steps.
    """
    q0, dq0 = start_states(gait, np.ones((len(M1s), 2 * gait.model.nq)), 1.0)
    c = walker.walk(q0, dq0, M1s, rejoin, steps=settings.steps).steps_to_converge(
        settings.tol)
    return np.where(np.isfinite(c), c, np.inf)


@task
def screen_batch(gait, kept, M1s, rejoin: float, sampling, settings) -> tuple:
    """s* of a batch of starts by the walker's bisection over the kept directions.

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1s : numpy.ndarray
        (m, nu) the starts.
    rejoin : float
        Rejoin time of v_c.
    sampling : StartSampling
        The screen's RK4 steps and bisection rounds.
    settings : RobustnessSettings
        The protocol.

    Returns
    -------
    tuple
        (s* (m,), s_fail (m,), cause (m,), fraction passing at s_fail (m,), the step
        from which the paper's perturbation stays below the tolerance (m,), inf where
        it does not).
    """
    M1s = np.atleast_2d(np.asarray(M1s, float))
    if not len(M1s):
        return np.zeros(0), np.zeros(0), [], np.zeros(0), np.zeros(0)
    w = zero_dynamics_walker(gait, settings.simulation_options(), sampling.screen_rk4,
                             jit=True)
    bs = s_star_batch(w, gait, [Design.tv(gait, m, rejoin) for m in M1s], kept.directions,
                      settings, rounds=sampling.screen_rounds)
    return (bs.s_star, bs.s_fail, list(bs.cause), bs.pass_fraction,
            paper_convergence(w, gait, M1s, rejoin, settings))


@task
def screen_binds(gait, kept, M1, rejoin: float, scale: float, sampling, settings) -> dict:
    """What stops a start at a scale, on the screen's walker.

    The first failing kept direction (a validity failure before non-convergence, then
    the earliest step) and the constraint it breaks (:func:`failure_binds`).

    Parameters
    ----------
    gait : Gait
        The gait.
    kept : KeptDirections
        Its kept directions.
    M1 : array_like
        The start.
    rejoin : float
        Rejoin time of v_c.
    scale : float
        The scale (just above the start's s*).
    sampling : StartSampling
        The screen's RK4 steps.
    settings : RobustnessSettings
        The protocol.

    Returns
    -------
    dict
        :func:`failure_binds`'s, with ``direction``; {} when every direction passes.
    """
    rs = dataclasses.replace(settings, rk4_steps=sampling.screen_rk4)
    M1 = np.asarray(M1, float)
    q0, dq0 = start_states(gait, kept.directions, scale)
    w = zero_dynamics_walker(gait, rs.simulation_options(), rs.rk4_steps, jit=True)
    B = w.walk(q0, dq0, np.repeat(M1[None], len(q0), 0), rejoin, steps=rs.steps)
    v = B.verdict(rs.tol)
    bad = np.flatnonzero(v != "ok")
    if not bad.size:
        return {}
    j = int(bad[np.lexsort((B.fail_step[bad], v[bad] == NOT_CONVERGED))[0]])
    return dict(failure_binds(Design.tv(gait, M1, rejoin), kept.directions[j], scale, rs),
                direction=j)


def failure_binds(design, direction, scale: float, settings) -> dict:
    """What stops a design's run from one perturbation direction at one scale.

    Parameters
    ----------
    design : Design
        A time-varying design on its gait.
    direction : array_like
        (2 nq,) the perturbation direction.
    scale : float
        Its scale.
    settings : RobustnessSettings
        The protocol (steps, tolerance, mu, torque limit, RK4 steps).

    Returns
    -------
    dict
        ``status`` (the run's verdict), ``step`` (1-based), ``binds`` (in words),
        ``max_impulse_ratio``, ``peak_torque``.
    """
    rs, gait = settings, design.gait
    w = zero_dynamics_walker(gait, rs.simulation_options(), rs.rk4_steps, jit=True)
    q0, dq0 = start_states(gait, np.atleast_2d(direction), float(scale))
    B = w.walk(q0, dq0, np.asarray(design.M1, float)[None], design.rejoin, steps=rs.steps)
    v = str(B.verdict(rs.tol)[0])
    run = B[0]
    return dict(status=v, step=int(B.fail_step[0]) + 1,
                binds=BINDS[NOT_CONVERGED] if v == NOT_CONVERGED else binds(run, rs.mu),
                max_impulse_ratio=float(B.max_impulse_ratio[0]),
                peak_torque=float(B.peak_torque[0]))
