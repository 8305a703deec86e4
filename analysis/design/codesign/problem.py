"""One co-design NLP as a typed value (:class:`Problem`), built anywhere
(:func:`build`), and its IPOPT solve as a task (:func:`solve`, :func:`solve_continued`).

A problem is what defines the reduced NLP of :mod:`.reduced`: the gait, the scenarios'
directions (the paper's first), the steps, whether the gait is free, the rule and its
margins, the error bounds, the rejoin time, the starting design and the bounds on it
(the Jury bound on max ``|lambda|`` and, for a gait step, the trust region).  Building
it is deterministic, so a solve is a pure function of the problem and of IPOPT's limits
(an iteration and an evaluation count): the same result in any process.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.control.output_law import decoupling_denominator
from biped_casadi.control.zero_dynamics import denominator_samples

from ...stability.poincare import poincare_map
from ...tasks import task
from .functions import FAMILIES, TranscriptionSettings
from .reduced import NLPSolve, NoStrikeAtStart, Reduced, solve_nlp
from .settings import IpoptLimits
from .transcription import Transcription

__all__ = ["Problem", "Solve", "build", "solve", "solve_continued", "jury_function"]


@dataclass(frozen=True, eq=False)
class Problem:
    """The reduced co-design NLP on one gait, with its start and bounds.

    Parameters
    ----------
    gait : Gait
        The gait (fixed) or the gait the step starts from (free).
    directions : numpy.ndarray
        (K, 2 nq) the scenarios' perturbation directions, the paper's first (at scale 1,
        bounded by ``paper_tol``), the others at the scale s.
    steps : int
        Steps per scenario (the paper's direction walks one more).
    free : bool
        Whether the gait's Bezier coefficients, T and unactuated start are variables.
    transcription : TranscriptionSettings
        The rule and its margins.
    scenario_tol : float
        Error bound at the last step of the scenarios at scale s.
    paper_tol : float
        Error bound on the paper's direction over its last two steps.
    rejoin : float
        Rejoin time of v_c (fixed in the solve), fraction of T.
    M1 : tuple
        The starting outputs (they also fix the sign of the eq. 24 denominator).
    s0 : float
        The starting scale.
    jury_bound : float, optional
        Bound on max ``|lambda|`` of the gait's A^z(M1) by the Jury conditions (None:
        none).
    trust : tuple, optional
        (alpha rad, T s, x0) radii of a gait step's trust region (free gait only).
    fallback_first : tuple, optional
        The direction that replaces the paper's (still at scale 1) when the paper's cannot
        strike from the start (lowering s does not help a direction at a fixed scale): the
        gait's first kept direction, when it is not the paper's.
    """

    gait: object
    directions: np.ndarray
    steps: int
    free: bool
    transcription: TranscriptionSettings
    scenario_tol: float
    paper_tol: float
    rejoin: float
    M1: tuple
    s0: float
    jury_bound: float | None = None
    trust: tuple | None = None
    fallback_first: tuple | None = None

    @property
    def scenarios(self) -> int:
        """Scenarios of the NLP (the paper's direction included)."""
        return len(self.directions)


@dataclass
class Solve:
    """One IPOPT solve (or a continuation of solves) of a :class:`Problem`.

    Parameters
    ----------
    d : numpy.ndarray
        The design at the last iterate (NaN when no scenario could strike from the
        start).
    lam_g : numpy.ndarray
        The constraints' multipliers there.
    status : str
        IPOPT's return status of the last solve.
    success : bool
        IPOPT's own success flag.
    M1 : numpy.ndarray
        The outputs at the last iterate.
    s : float
        The NLP's scale s there.
    gait_vector : numpy.ndarray or None
        (alpha, T, r0) there, free gait only.
    solves : list of dict
        Every IPOPT solve: status, iterations, evaluations, seconds.
    active : list of dict
        The inequality constraints with the largest multipliers at the last iterate.
    """

    d: np.ndarray
    lam_g: np.ndarray
    status: str
    success: bool
    M1: np.ndarray
    s: float
    gait_vector: np.ndarray | None
    solves: list = field(default_factory=list)
    active: list = field(default_factory=list)

    @property
    def finite(self) -> bool:
        """Whether the solve ended on a design (not NaN)."""
        return bool(np.all(np.isfinite(self.d)))

    @property
    def iterations(self) -> int:
        """IPOPT iterations over every solve."""
        return int(sum(s["iterations"] for s in self.solves))


# ------------------------------------------------------------------ building
@cached(maxsize=16)
def jury_function(gait, rejoin: float):
    """trace and det of A^z(M1) with their gradients: ``jury(M1) -> ((tr, dtr), (det,
    ddet))`` (the 2 x 2 Jury conditions of the NLP; built once per gait and rejoin).

    Parameters
    ----------
    gait : Gait
        The gait.
    rejoin : float
        Rejoin time of v_c, fraction of T.

    Returns
    -------
    callable
    """
    A_fn = poincare_map(gait, rejoin=rejoin).variational.A_fn
    M = ca.SX.sym("M1", gait.model.nu)
    A = A_fn(M)
    tr = A[0, 0] + A[1, 1]
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    f = ca.Function("jury", [M], [tr, ca.gradient(tr, M), det, ca.gradient(det, M)])

    def jury(M1):
        a, b, c, e = (np.array(v).ravel() for v in f(np.asarray(M1, float)))
        return (float(a[0]), b), (float(c[0]), e)
    return jury


def build(p: Problem):
    """The NLP of a problem: (Transcription, Reduced, d0, lb, ub), built afresh.

    Parameters
    ----------
    p : Problem
        The problem.

    Returns
    -------
    tuple
    """
    g = p.gait
    tr = Transcription(g.model, g, p.directions, p.steps + 1, free_gait=p.free,
                       settings=p.transcription)
    red = Reduced(tr)
    red.tols[:] = p.scenario_tol
    red.steps[:] = p.steps
    # the paper's direction at scale 1, below paper_tol from step 4 on (errors are not
    # monotonic: its last two steps are bounded)
    red.scales[0] = 1.0
    red.tols[0] = p.paper_tol
    red.steps[0] = tr.S
    red.tol_from[0] = tr.S - 2
    if p.jury_bound is not None:
        red.jury = (jury_function(g, float(p.rejoin)), float(p.jury_bound))
    # the eq. 24 denominator's sign for the start, and a fixed scale: D11's largest value
    # on the reference (so the margin does not move with the start)
    D11, D12 = denominator_samples(g)
    den = decoupling_denominator(D11, D12, np.asarray(p.M1, float))
    tr.den_scale = float(np.max(np.abs(D11)))
    tr.den_sign = 1.0 if den[0] >= 0 else -1.0
    d0 = np.zeros(red.nd)
    if p.free:
        d0[tr.i_G] = tr.gait_vector(g)
    d0[tr.i_M1], d0[tr.i_rejoin], d0[tr.i_s] = p.M1, p.rejoin, p.s0
    lb, ub = red.bounds()
    lb[tr.i_rejoin] = ub[tr.i_rejoin] = p.rejoin
    if p.trust is not None:
        ra, rT, rx = p.trust
        na = tr.na
        lb[:na] = np.maximum(lb[:na], d0[:na] - ra)
        ub[:na] = np.minimum(ub[:na], d0[:na] + ra)
        lb[na] = max(lb[na], d0[na] - rT)
        ub[na] = min(ub[na], d0[na] + rT)
        lb[na + 1:na + 3] = d0[na + 1:na + 3] - rx
        ub[na + 1:na + 3] = d0[na + 1:na + 3] + rx
    return tr, red, d0, lb, ub


# ------------------------------------------------------------------ solving
def _ipopt(tr, red, d0, lb, ub, limits: IpoptLimits) -> NLPSolve:
    """One IPOPT solve from d0; when a scenario cannot strike from it (a direction just
    added fails early at the start's scale), the start's s is lowered (x 0.8, at most 8
    times) until every scenario strikes."""
    d = np.array(d0, float)
    for _ in range(8):
        try:
            return solve_nlp(red, d, lb, ub, {"max_iter": int(limits.max_iter)},
                             max_evaluations=int(limits.max_evaluations))
        except NoStrikeAtStart:
            d[tr.i_s] *= 0.8
            red._last = None
    return NLPSolve(d=np.full(red.nd, np.nan), lam_g=np.zeros(0),
                    status="no_strike_from_start", success=False, iterations=0, time=0.0,
                    evaluations=0)


def _build_striking(p: Problem):
    """:func:`build`, with the first direction replaced by ``p.fallback_first`` when the
    paper's direction (at its fixed scale 1) does not strike from the start.

    Returns
    -------
    tuple
        (tr, red, d0, lb, ub, note): ``note`` is ``{"first": "kept"}`` when the fallback
        was taken, else empty.
    """
    tr, red, d0, lb, ub = build(p)
    if p.fallback_first is None:
        return tr, red, d0, lb, ub, {}
    red.evaluate(d0)
    if not (red.failures and red.failures[-1][0] == 0):
        red._last = None                  # evaluated again under the caller's bounds
        return tr, red, d0, lb, ub, {}
    dirs = np.array(p.directions, float)
    dirs[0] = np.asarray(p.fallback_first, float)
    return (*build(replace(p, directions=dirs, fallback_first=None)), {"first": "kept"})


def _record(res: NLPSolve, tr) -> dict:
    """A solve's record; ``node`` says what walked its nodes: the four-lane kernel, or
    the scalar Function where this process could not build the kernel (which rounds
    differently: a run whose solves ran on both is not bit-identical to one on either)."""
    return dict(status=res.status, iterations=res.iterations, evaluations=res.evaluations,
                time=round(res.time, 2),
                node="kernel" if tr.node.kernel is not None else "scalar")


def _solved(tr, red, res: NLPSolve, records: list) -> Solve:
    finite = bool(np.all(np.isfinite(res.d)))
    return Solve(d=res.d, lam_g=res.lam_g, status=res.status, success=res.success,
                 M1=res.d[tr.i_M1].copy(), s=float(res.d[tr.i_s]),
                 gait_vector=res.d[tr.i_G].copy() if tr.free else None, solves=records,
                 active=active_constraints(red, res) if finite else [])


@task
def solve(problem: Problem, limits: IpoptLimits) -> Solve:
    """One IPOPT solve of a problem from its start.

    Parameters
    ----------
    problem : Problem
        The NLP.
    limits : IpoptLimits
        Iterations and evaluations.

    Returns
    -------
    Solve
    """
    tr, red, d0, lb, ub, note = _build_striking(problem)
    res = _ipopt(tr, red, d0, lb, ub, limits)
    return _solved(tr, red, res, [dict(_record(res, tr), **note)])


@task
def solve_continued(problem: Problem, limits: IpoptLimits, paper_steps: int) -> Solve:
    """Solve with the paper's error bound reached by continuation: when the start exceeds
    it, the bound goes down from the start's error in at most ``paper_steps`` solves (a
    factor of at least 5 each), every solve warm-started from the last.

    Parameters
    ----------
    problem : Problem
        The NLP.
    limits : IpoptLimits
        Iterations and evaluations of each solve.
    paper_steps : int
        Largest number of continuation solves before the last.

    Returns
    -------
    Solve
    """
    tr, red, d0, lb, ub, note = _build_striking(problem)
    target = red.tols[0]
    red.tols[0] = np.inf
    red.evaluate(d0)
    e0 = max(float(np.max(np.abs(i["err"]))) for i in red.info
             if i["k"] == 0 and i["j"] >= red.tol_from[0])
    n = int(np.clip(np.ceil(np.log(max(e0, target) / target) / np.log(5.0)), 0, paper_steps))
    res, records = None, []
    for i in range(n, -1, -1):
        red.tols[0] = max(target, target * (e0 / target) ** (i / max(n, 1))) if i else target
        red._last = None
        res = _ipopt(tr, red, d0 if res is None else res.d, lb, ub, limits)
        records.append(dict(_record(res, tr), paper_bound=float(red.tols[0]), **note))
        if not np.all(np.isfinite(res.d)):
            break
    return _solved(tr, red, res, records)


def active_constraints(red, res: NLPSolve, limit: int = 8) -> list:
    """The inequality constraints with the largest multipliers at a solve, in words.

    Parameters
    ----------
    red : Reduced
        The NLP.
    res : NLPSolve
        Its solve.
    limit : int
        Constraints listed at most.

    Returns
    -------
    list of dict
        ``constraint`` (in words), ``multiplier``, ``row``.
    """
    _, _, _, _, lo, hi = red.evaluate(res.d)
    # equalities (the gait's periodicity, its swing foot on the ground at T, ...) hold
    # with any multiplier: the inequalities with the largest multipliers are what binds
    lam = np.where(np.asarray(lo) == np.asarray(hi), 0.0, np.asarray(res.lam_g))
    order = np.argsort(-np.abs(lam))
    out, seen = [], set()
    top = float(np.max(np.abs(lam), initial=0.0))
    for i in order:
        # a row's two sides, or multipliers below 1e-4 of the largest, bind nothing
        if len(out) == limit or abs(lam[i]) < max(1e-8, 1e-4 * top):
            break
        if red.names[i] in seen:
            continue
        seen.add(red.names[i])
        out.append(dict(constraint=_words(red.names[i]), multiplier=float(lam[i]),
                        row=red.names[i]))
    return out


def _words(name: str) -> str:
    """'torque k1 j0 chunk 2' -> 'torque limit: scenario 1, step 1, tau in [0.2, 0.3] T'."""
    parts = name.split()
    words = FAMILIES.get(parts[0], name)
    rest = " ".join(parts[1:])
    if len(parts) >= 3 and parts[1].startswith("k") and parts[2].startswith("j"):
        k, j = int(parts[1][1:]), int(parts[2][1:])
        who = "the paper's perturbation (scale 1)" if k == 0 else f"scenario {k} (scale s)"
        where = f"{who}, step {j + 1}"
        if len(parts) >= 5 and parts[3] == "chunk":
            c = int(parts[4])
            where += f", tau in [{c / 10:.1f}, {(c + 1) / 10:.1f}] T"
        elif len(parts) > 3:
            where += ", " + " ".join(parts[3:])
        return f"{words}: {where}"
    return f"{words} {rest}".strip()
