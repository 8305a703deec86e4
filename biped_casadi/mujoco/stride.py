"""MuJoCo's own stride map: its limit cycle, and its eigenvalues from rollouts.

The section is the toolkit's (docs: theory §4): tau = 0.75 T after each touchdown, the
reduced state x = (q_u, dq_u) (:attr:`MujocoStep.section`).  On it the exact A^z of the
toolkit is defined, so MuJoCo's stride map x_k -> x_{k+1} there is the engine's twin of
A^z (for virtual constraints, whose zero dynamics is autonomous, the multipliers on a
time section are the exact one and 0).

- The limit cycle: a walk of ``cycle_steps`` steps from the gait; the cycle is the mean
  section state over its second half, and how well the state repeats is said by its
  spread there (the jitter).  At dt = 2 ms MuJoCo's loop has no clean cycle: touchdowns
  fall on the time grid, and the step durations wander over a dozen time steps.
- The eigenvalues: rollouts from the gait's start with (q_u, dq_u) moved by ``size`` (by
  default five times the cycle's jitter, 0.02 to 0.2 rad/s) in ``directions`` directions
  of the plane (halved while many rollouts fail), each ``fit_steps`` steps; every pair of
  consecutive section states (x_k, x_{k+1}) of the rollouts and of the cycle's walk
  enters one least-squares fit of x_{k+1} = c + Lambda x_k, and the eigenvalues of
  Lambda are MuJoCo's.  Small perturbations fail: below about 1e-3 they are lost in the
  jitter (MuJoCo's own "eigenvalues" then exceed 1); perturbations of tenths of a rad/s
  stand out of it.  The fit's residual, against the deviations it explains, says how
  far to trust them.
- When the fit is not determined by its data it is not presented as MuJoCo's (status
  'undetermined', :func:`undetermined_reason`): a multiplier of modulus 1 or more on a
  cycle the walk settled on (the rollouts left the linear range: the cycle attracts its
  walk) or a perturbation no larger than the cycle's jitter.  A large residual alone is
  not such a case: a strongly contracting design's rollouts reach the contact's noise
  within a step, and its fit (relative residual 0.94-0.99 in ``biped reproduce``) still
  brackets the exact eigenvalue; the residual and the bootstrap spread are printed.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..control.design import Design
from ..results import Result
from .mjcf import STIFF, ContactSettings
from .walk import MujocoLoop

__all__ = ["LimitCycle", "StrideMap", "limit_cycle", "stride_map", "fit_stride_map",
           "undetermined_reason", "HALVINGS", "JITTER_FACTOR", "SIZE_RANGE",
           "APPROACH_RATIOS", "APPROACH_STEADY"]

#: when more than a quarter of the rollouts fail, the perturbation is halved (up to this
#: many times): a design with a small basin (a deadbeat one) has little jitter too
HALVINGS = 3
#: the default perturbation of dq_u: this many times the cycle's jitter ...
JITTER_FACTOR = 5.0
#: ... within this range, rad/s (tiny perturbations are lost in the jitter, large ones
#: meet the torque limit and the bounce of the touchdown: the map is no longer linear)
SIZE_RANGE = (0.02, 0.2)
#: the walk's approach to its cycle counts as steady when its last this many step ratios
#: (above ten times the jitter, from step 3 on) ...
APPROACH_RATIOS = 5
#: ... differ by at most this
APPROACH_STEADY = 0.02


@dataclass
class LimitCycle(Result):
    """MuJoCo's limit cycle near the gait.

    Parameters
    ----------
    status : str
        'ok', or the walk's status when it did not walk its steps.
    message : str
        A summary line.
    steps : int
        Steps walked.
    section : list of float
        (q_u, dq_u) at tau = 0.75 T, the mean over the second half of the walk.
    jitter : list of float
        The largest distance of a section state there from that mean, per component:
        how well the state repeats (rad, rad/s).
    section_distance : list of float
        ``section`` minus the gait's (q_u^d, dq_u^d)(0.75 T): the cycle's distance from
        the gait's fixed point.
    pre_impact_distance : list of float
        The mean (q_u, dq_u) errors at touchdown over the second half.
    speed_error, period_error : float
        Relative errors of the mean speed and step duration there.
    approach : float
        The factor by which the walk's section state approached the cycle a step, where
        that factor was steady (within :data:`APPROACH_STEADY` over its last
        :data:`APPROACH_RATIOS` steps above ten times the jitter): MuJoCo's slowest
        multiplier, measured without perturbing; nan when not steady.
    approach_steps : list of int
        The first and last step of the walk it was measured over ([] when nan).
    """

    status: str
    message: str
    steps: int
    section: list
    jitter: list
    section_distance: list
    pre_impact_distance: list
    speed_error: float
    period_error: float
    approach: float = math.nan
    approach_steps: list = dataclasses.field(default_factory=list)

    SUCCESS = ("ok",)


@dataclass
class StrideMap(Result):
    """MuJoCo's stride map on the section tau = 0.75 T, fitted from rollouts.

    Parameters
    ----------
    status : str
        'ok'; 'rollouts_failed' when more than a quarter of the rollouts stopped before
        their steps (the fit then rests on the others, and is doubtful); 'undetermined'
        when the fit is not determined by its data (:func:`undetermined_reason`; ``A``
        and ``eigenvalues`` are then the fit's, not MuJoCo's); 'failed' when too few
        steps were walked to fit.
    message : str
        A summary line.
    A : list
        The 2 x 2 Lambda of x_{k+1} = c + Lambda x_k.
    eigenvalues : list
        Its eigenvalues (complex as [re, im] in ``to_dict()``).
    max_abs : float
        Their largest modulus.
    max_abs_spread : float
        The standard deviation of max|lambda| over 200 bootstrap resamples of the pairs
        (seeded): how well the rollouts determine it.
    fixed_point : list of float
        The fit's fixed point (I - Lambda)^-1 c, (q_u, dq_u).
    residual : list of float
        RMS residual of the fit per component (rad, rad/s).
    relative_residual : float
        The residual against the RMS deviation of the fitted x_{k+1} from the fixed point
        (per component, the larger): near 0 the fit explains the rollouts, near 1 it
        explains nothing.
    pairs : int
        Pairs in the fit.
    directions, fit_steps : int
        Rollouts and the steps of each.
    size : list of float
        The perturbation of (q_u, dq_u) at the start of the rollouts, rad and rad/s (the
        one used, after any halving).
    failed_rollouts : int
        Rollouts that stopped before their steps (their pairs up to there are used).
    cycle : LimitCycle
        The limit cycle.
    reason : str
        Why the fit is not determined by its data when the status is 'undetermined'
        (:func:`undetermined_reason`), else ''.
    """

    status: str
    message: str
    A: list
    eigenvalues: list
    max_abs: float
    max_abs_spread: float
    fixed_point: list
    residual: list
    relative_residual: float
    pairs: int
    directions: int
    fit_steps: int
    size: list
    failed_rollouts: int
    cycle: LimitCycle
    reason: str = ""

    SUCCESS = ("ok",)


def _sections(w) -> np.ndarray:
    """(n, 2) section states of a walk's steps, up to the first step without one."""
    out = []
    for s in w.steps:
        if s.section is None:
            break
        out.append(s.section)
    return np.array(out, float).reshape(-1, 2)


def limit_cycle(loop: MujocoLoop, steps: int = 60, walk=None) -> tuple:
    """Walk ``steps`` steps from the gait and measure the cycle it settles on.

    Parameters
    ----------
    loop : MujocoLoop
        The closed loop.
    steps : int
        Steps to walk (>= 4); the cycle is measured over the second half.
    walk : MujocoWalk, optional
        A walk of the loop from the gait's start already made (then nothing is walked
        and ``steps`` is ignored).

    Returns
    -------
    tuple
        (LimitCycle, the walk).
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 4:
        raise ValueError(f"steps must be an integer >= 4, got {steps!r}")
    g = loop.gait
    w = walk if walk is not None else loop.run(g.q(0.0), g.dq(0.0), steps)
    X = _sections(w)
    half = X[len(X) // 2:]
    late = w.steps[len(w.steps) // 2:]
    nan2 = [math.nan, math.nan]
    if w.status != "walked" or len(half) < 2:
        return LimitCycle(status=w.status, message=f"no cycle: {w.message}",
                          steps=w.steps_walked, section=nan2, jitter=nan2,
                          section_distance=nan2, pre_impact_distance=nan2,
                          speed_error=math.nan, period_error=math.nan), w
    mean = half.mean(axis=0)
    jitter = np.abs(half - mean).max(axis=0)
    dist = mean - np.array(loop.x_star)
    pre = np.mean([[s.qu_error, s.dqu_error] for s in late], axis=0)
    speed = sum(s.step_length for s in late) / sum(s.period for s in late)
    period = float(np.mean([s.period for s in late]))
    factor, over = _approach(X, mean, jitter)
    return LimitCycle(
        status="ok",
        message=(f"MuJoCo's cycle over steps {len(w.steps) - len(late) + 1}-{len(w.steps)}: "
                 f"(q_u, dq_u) at 0.75 T off the gait's by ({dist[0]:+.3g} rad, "
                 f"{dist[1]:+.3g} rad/s), repeating to ({jitter[0]:.2g}, {jitter[1]:.2g})"),
        steps=w.steps_walked, section=mean.tolist(), jitter=jitter.tolist(),
        section_distance=dist.tolist(), pre_impact_distance=pre.tolist(),
        speed_error=speed / float(g.speed) - 1.0, period_error=period / loop.T - 1.0,
        approach=factor, approach_steps=over), w


def _approach(X, mean, jitter) -> tuple:
    """(factor, [first, last step]) of the walk's steady approach to the cycle
    (:attr:`LimitCycle.approach`), or (nan, [])."""
    D = np.linalg.norm(X - mean, axis=1)
    above = D > 10 * np.linalg.norm(jitter)
    k = [i for i in range(2, len(D) - 1) if above[i] and above[i + 1]]
    if len(k) < APPROACH_RATIOS or k[-1] - k[-APPROACH_RATIOS] != APPROACH_RATIOS - 1:
        return math.nan, []
    k = np.array(k[-APPROACH_RATIOS:])
    r = D[k + 1] / D[k]
    if np.ptp(r) > APPROACH_STEADY:
        return math.nan, []
    return float(np.mean(r)), [int(k[0]) + 1, int(k[-1]) + 2]


def fit_stride_map(X0, X1) -> tuple:
    """Least-squares fit of x_{k+1} = c + Lambda x_k.

    Parameters
    ----------
    X0, X1 : array_like
        (n, 2) states and their successors.

    Returns
    -------
    tuple
        (Lambda (2, 2), c (2,), RMS residual per component (2,)).
    """
    X0, X1 = np.asarray(X0, float), np.asarray(X1, float)
    if X0.shape != X1.shape or X0.ndim != 2 or X0.shape[0] < 4:
        raise ValueError(f"X0, X1 must be (n, 2) with n >= 4, got {X0.shape} and {X1.shape}")
    Phi = np.column_stack([np.ones(len(X0)), X0])
    coef, *_ = np.linalg.lstsq(Phi, X1, rcond=None)
    c, Lam = coef[0], coef[1:].T
    res = X1 - Phi @ coef
    return Lam, c, np.sqrt(np.mean(res**2, axis=0))


def stride_map(design: Design, settings: ContactSettings = STIFF, law: str = "c",
               cycle_steps: int = 60, directions: int = 16, size=None,
               fit_steps: int = 4, loop: MujocoLoop | None = None,
               walk=None) -> StrideMap:
    """MuJoCo's limit cycle and stride-map eigenvalues of a design (module docstring).

    Parameters
    ----------
    design : Design
        The design on its gait.
    settings : ContactSettings
        MuJoCo's settings (default :data:`~biped_casadi.mujoco.STIFF`).
    law : {'c', 'python'}
        The law in the loop.
    cycle_steps : int
        Steps of the walk that finds the cycle.
    directions : int
        Rollouts: directions theta_j = 2 pi j / directions in the (q_u, dq_u) plane.
    size : tuple of float, optional
        (rad, rad/s): the start's q_u moves by size[0] cos theta_j, its dq_u by size[1]
        sin theta_j; halved while more than a quarter of the rollouts fail
        (:data:`HALVINGS` times at most).  Default: large against the cycle's jitter,
        dq_u by :data:`JITTER_FACTOR` times its jitter within :data:`SIZE_RANGE`, q_u by
        a tenth of that (the paper's ratio).
    fit_steps : int
        Steps of each rollout (its first ``fit_steps - 1`` pairs enter the fit).
    loop : MujocoLoop, optional
        A loop already built for the design and settings.
    walk : MujocoWalk, optional
        A walk of that loop from the gait's start already made: the cycle is measured on
        it instead of a walk of ``cycle_steps``.

    Returns
    -------
    StrideMap
    """
    design = Design.require(design)
    for name, v, lo in (("directions", directions, 3), ("fit_steps", fit_steps, 2)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
    if size is not None:
        size = np.asarray(size, float).ravel()
        if size.shape != (2,) or not np.all(np.isfinite(size)) or np.any(size <= 0):
            raise ValueError(f"size must be two positive numbers (rad, rad/s), got "
                             f"{size.tolist()}")
    if loop is None:
        loop = MujocoLoop(design, settings, law)
    cycle, w = limit_cycle(loop, cycle_steps, walk)
    if size is None:
        jit = cycle.jitter[1] if math.isfinite(cycle.jitter[1]) else SIZE_RANGE[1]
        dq = min(max(JITTER_FACTOR * jit, SIZE_RANGE[0]), SIZE_RANGE[1])
        size = np.array([dq / 10, dq])
    X = _sections(w)
    for _ in range(HALVINGS + 1):           # smaller perturbations while many fail
        failed, P0, P1 = _rollouts(loop, size, directions, fit_steps)
        if failed <= directions // 4:
            break
        size = size / 2
    pairs0, pairs1 = [X[:-1]] + P0, [X[1:]] + P1
    X0, X1 = np.vstack(pairs0), np.vstack(pairs1)
    nan = [[math.nan, math.nan], [math.nan, math.nan]]
    if len(X0) < 4 or cycle.status != "ok":
        return StrideMap(status="failed", message="too few steps walked to fit a stride map "
                         f"({cycle.message})", A=nan, eigenvalues=[], max_abs=math.nan,
                         max_abs_spread=math.nan,
                         fixed_point=nan[0], residual=nan[0], relative_residual=math.nan,
                         pairs=len(X0), directions=directions, fit_steps=fit_steps,
                         size=size.tolist(), failed_rollouts=failed, cycle=cycle)
    Lam, c, res = fit_stride_map(X0, X1)
    try:
        xf = np.linalg.solve(np.eye(2) - Lam, c)
    except np.linalg.LinAlgError:
        xf = np.array([math.nan, math.nan])
    dev = np.sqrt(np.mean((X1 - xf) ** 2, axis=0))
    rel = float(np.max(res / np.where(dev > 0, dev, np.inf)))
    ev = np.linalg.eigvals(Lam)
    ev = ev[np.argsort(-np.abs(ev))]
    mx = float(np.max(np.abs(ev)))
    spread = _bootstrap(X0, X1)
    bad = failed > directions // 4
    why = undetermined_reason(mx, cycle, size)
    head = ("" if not bad else f"{failed} of {directions} rollouts failed: ") + \
        "MuJoCo's stride map: "
    if why:
        head = f"MuJoCo's stride map not determined by its rollouts ({why}); the fit's "
    return StrideMap(
        status="undetermined" if why else "rollouts_failed" if bad else "ok",
        message=(head + f"eigenvalues {_fmt(ev)} (max |lambda| {mx:.3g} "
                 f"+- {spread:.2g}) from {len(X0)} pairs, relative residual {rel:.2g}; "
                 f"{cycle.message}"),
        A=Lam.tolist(), eigenvalues=[complex(e) for e in ev], max_abs=mx,
        max_abs_spread=spread,
        fixed_point=xf.tolist(), residual=res.tolist(), relative_residual=rel,
        pairs=int(len(X0)), directions=int(directions), fit_steps=int(fit_steps),
        size=size.tolist(), failed_rollouts=int(failed), cycle=cycle, reason=why)


def undetermined_reason(max_abs: float, cycle: LimitCycle, size) -> str:
    """Why a stride-map fit is not determined by its data, or ''.

    Parameters
    ----------
    max_abs : float
        The fit's max|lambda|.
    cycle : LimitCycle
        The cycle its walk settled on.
    size : array_like
        The rollouts' perturbation of (q_u, dq_u), rad and rad/s.

    Returns
    -------
    str
        '' when the fit may be read as MuJoCo's map, else the reason in a few words.
    """
    jit = np.asarray(cycle.jitter, float)
    if np.all(np.asarray(size, float) <= jit):
        return (f"perturbation ({size[0]:.2g} rad, {size[1]:.2g} rad/s) within the cycle's "
                f"jitter ({jit[0]:.2g}, {jit[1]:.2g})")
    if not max_abs < 1.0:
        return (f"max|lambda| {max_abs:.3g} >= 1 on a cycle MuJoCo's walk settled on: the "
                "rollouts left the map's linear range")
    return ""


def _rollouts(loop, size, directions, fit_steps) -> tuple:
    """(failed rollouts, their section states, their successors) from the gait's start
    moved by ``size`` in ``directions`` directions of the (q_u, dq_u) plane."""
    g = loop.gait
    q0, dq0 = np.array(g.q(0.0), float), np.array(g.dq(0.0), float)
    failed, P0, P1 = 0, [], []
    for j in range(directions):
        th = 2 * math.pi * j / directions
        q, dq = q0.copy(), dq0.copy()
        q[0] += size[0] * math.cos(th)
        dq[0] += size[1] * math.sin(th)
        r = loop.run(q, dq, fit_steps)
        failed += r.status != "walked"
        Xr = _sections(r)
        P0.append(Xr[:-1])
        P1.append(Xr[1:])
    return failed, P0, P1


def _bootstrap(X0, X1, n: int = 200, seed: int = 0) -> float:
    """Standard deviation of max|lambda| over ``n`` resamples of the pairs."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        i = rng.integers(0, len(X0), len(X0))
        try:
            Lam, _, _ = fit_stride_map(X0[i], X1[i])
        except np.linalg.LinAlgError:
            continue
        out.append(np.max(np.abs(np.linalg.eigvals(Lam))))
    return float(np.std(out)) if out else math.nan


def _fmt(ev) -> str:
    return "[" + ", ".join(f"{e.real:.3g}" if abs(e.imag) < 1e-12 else
                           f"{e.real:.3g}{e.imag:+.3g}j" for e in ev) + "]"
