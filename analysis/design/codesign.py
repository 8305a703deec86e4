"""Robust co-design (issue 20): one NLP chooses M1 and, by default, the gait itself, against
perturbation scenarios walked by the walker's own rule.

The NLP (:mod:`analysis.design.codesign_nlp`).  Decision variables: the outputs M1, the
perturbation scale s (maximised) and, with the gait free, the gait's Bezier
coefficients alpha, its duration T and its unactuated start (q_u^d(0), dq_u^d(0)), under
the constraints of :mod:`gait_opt.transcription` on the gait's own nominal step.  Each
scenario starts at the gait's start plus the perturbation of its direction at scale s
(the full 10-state perturbation, as in the paper) -- the paper's own direction at the
fixed scale 1 -- and walks ``steps`` steps of the closed-loop hybrid zero dynamics with
the walker's fixed-grid RK4 and its strike; every node, strike and impact keeps the
walker's validity conditions with margins.  At the last step the paper's direction is
below ``paper_tol`` (the paper's claim: converged from step 4) and the other scenarios
below ``scenario_tol``.  With the gait fixed, max|lambda(A^z)| is bounded by the 2x2 Jury
conditions on A^z (exact in M1 by AD of the variational equation) at ``eigen_margin``
times the virtual constraints' eigenvalue; with the gait free it is verified after each
gait step.  The rejoin time of v_c is fixed per solve (``rejoin``): v_c's third
derivative jumps at t_c, which makes the walker's discrete rule kinked in t_c each time
it crosses an RK4 stage.

The method.  "Every kept direction walks" is a semi-infinite constraint; it is met by
scenario exchange (a cutting-plane method): the NLP is solved on the paper's direction
and the few directions that fail first; the design is verified on every kept direction
with the walker's bisection (:func:`analysis.robustness.robustness`); the direction that
fails just above the verified s* joins the scenarios, and the NLP is solved again from
its last design.  With the gait free, each gait step is taken inside a trust region
around the current gait, made exactly periodic (:func:`gait_opt.polish.polish`), its
kept directions re-derived (the protocol's rule: virtual constraints walk from them at
scale 1), and accepted only when the verified s* improves with max|lambda| at most the
virtual constraints' eigenvalue on the new gait.

The result is verified by the one protocol (:func:`analysis.design.verification.verify_design`):
s* (walker bisection, full-order simulator at s* and just above), the paper's perturbation
in full order, max|lambda| against virtual constraints, and sign patterns never seen
(:func:`analysis.design.verification.hidden_sign_patterns`).  Results are cached.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field

import casadi as ca
import numpy as np

from biped_casadi.caching import DiskCache, source_digest
from biped_casadi.control.output_law import decoupling_denominator
from biped_casadi.control.zero_dynamics import denominator_samples
from biped_casadi.files import write_text_atomic
from biped_casadi.results import Result, internal
from biped_casadi.simulation import start_states, zero_dynamics_walker
from gait_opt import Gait, GaitOptions, default_gait
from gait_opt.cache import cache_path
from gait_opt.errors import GaitOptimizationError
from gait_opt.polish import polish

from ..robustness.basin import basin
from ..robustness.s_star import Design, RobustnessSettings, kept_directions, robustness
from ..stability.poincare import poincare_map
from ..stability.vc_map import vc_eigenvalue
from .codesign_nlp import (FAMILIES, Reduced, Transcription, TranscriptionSettings,
                           _node_functions, solve_nlp)
from .robust_search import ROBUST_GAIT
from .verification import hidden_sign_patterns, verify_design

__all__ = ["CodesignSettings", "CodesignResult", "codesign", "TODAY_DESIGN", "CODESIGNS",
           "QUICK", "FULL"]

#: the sampling search's shipped design on :data:`ROBUST_GAIT` (M1; v_c rejoining at
#: 0.75 T): s* 0.969, the co-design's first warm start
TODAY_DESIGN = (-8.2618, 2.5374, 0.0034, 8.5090)

#: the co-designs kept between sessions
CODESIGNS = DiskCache("codesign", version=1)


@dataclass(frozen=True)
class CodesignSettings:
    """The co-design of :func:`codesign` (module docstring); all have defaults.

    Parameters
    ----------
    gait : dict
        GaitOptions fields of the gait to start from (and whose constraints the free
        gait keeps); default :data:`ROBUST_GAIT`.
    free_gait : bool
        Co-design the gait (else only M1 moves, on the given or start gait).
    rejoin : float
        Rejoin time of v_c, fraction of T.
    steps : int
        Steps per NLP scenario.
    paper_tol : float
        Error bound at the last NLP step of the paper's direction at scale 1.
    scenario_tol : float
        Error bound at the last NLP step of the other scenarios (at scale s).
    initial_active : int
        Kept directions in the first NLP besides the paper's: those that fail first for
        the starting design.
    max_active : int
        Largest number of kept directions in the NLP.
    exchange_rounds : int
        NLP solves with the gait fixed (each followed by the walker's verification).
    gait_rounds : int
        Gait steps (free gait only).
    trust_alpha, trust_T, trust_x0 : float
        Trust region of a gait step: rad on every Bezier coefficient, s on T, and
        rad, rad/s on the unactuated start.
    starts : tuple
        Starting M1s besides the sampled ones (:data:`FULL` adds today's search design;
        from it the NLP ends in the region of large M1, s* 0.4-0.9, measured).
    samples : int
        Random M1 drawn in [-box, box]^nu for the sampled starts (0: none).
    box : float
        Their box.
    sampled_starts : int
        Sampled M1 kept as starts: the first drawn with max ``|lambda|`` within the bound
        from which the walker walks the paper's perturbation at scale 1.
    seed : int
        Seed of the samples.
    s_start : float
        Scale of the first NLP's starting point.
    eigen_margin : float
        max ``|lambda|`` is kept at most this fraction of the virtual constraints'
        eigenvalue in the NLP.
    max_iter : int
        IPOPT iterations per solve.
    screen_iter, screen_time : int, float
        IPOPT iterations and wall time (s) of the first solve from each start; the start
        whose solve reaches the largest s continues.
    paper_steps : int
        Continuation solves that bring the paper's error bound down from the start's.
    max_solve_time : float
        Wall time per IPOPT solve, s.
    transcription : dict
        :class:`~analysis.design.codesign_nlp.TranscriptionSettings` fields (rule and
        margins).
    mu, torque_limit, directions, walk_steps, tol : as :class:`RobustnessSettings`
        Friction coefficient, torque bound (N m, None: the robot's), kept directions,
        steps walked and convergence threshold of every verification.
    hidden : bool
        Check the design on hidden sign patterns (at 1 and 1.25).
    basin : bool
        Compute the 101 x 101 basin of the result.
    """

    gait: dict = field(default_factory=lambda: dict(ROBUST_GAIT))
    free_gait: bool = True
    rejoin: float = 0.75
    steps: int = 4
    paper_tol: float = 8e-4
    scenario_tol: float = 0.5
    initial_active: int = 2
    max_active: int = 8
    exchange_rounds: int = 4
    gait_rounds: int = 2
    trust_alpha: float = 0.05
    trust_T: float = 0.025
    trust_x0: float = 0.25
    starts: tuple = ()
    samples: int = 2000
    box: float = 1.0
    sampled_starts: int = 5
    seed: int = 0
    s_start: float = 0.9
    eigen_margin: float = 0.98
    max_iter: int = 100
    screen_iter: int = 40
    screen_time: float = 8.0
    paper_steps: int = 3
    max_solve_time: float = 40.0
    transcription: dict = field(default_factory=dict)
    mu: float = 0.6
    torque_limit: float | None = None
    directions: int = 16
    walk_steps: int = 10
    tol: float = 1e-3
    hidden: bool = True
    basin: bool = False

    def robustness_settings(self, rounds: int = 8) -> RobustnessSettings:
        """The protocol's settings (400 RK4 steps per T, ``rounds`` bisection rounds).

        Parameters
        ----------
        rounds : int
            Bisection rounds.

        Returns
        -------
        RobustnessSettings
        """
        return RobustnessSettings(directions=self.directions, steps=self.walk_steps,
                                  tol=self.tol, mu=self.mu, torque_limit=self.torque_limit,
                                  rounds=rounds)

    def to_dict(self) -> dict:
        """The settings as a dictionary (part of the cache key).

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["starts"] = [list(map(float, s)) for s in self.starts]
        return d


#: the settings of a quick reproduction (about 15 s warm): the gait fixed, two
#: exchange rounds, no hidden patterns
QUICK = CodesignSettings(free_gait=False, exchange_rounds=2, hidden=False)
#: the settings of a full reproduction: the gait free, today's design and three sampled
#: starts, three gait steps, the basin
FULL = CodesignSettings(starts=(TODAY_DESIGN,), sampled_starts=8, gait_rounds=3, basin=True)


@dataclass
class CodesignResult(Result):
    """The co-designed controller (and gait), verified.

    ``success`` means the co-design ran to its verification; whether the targets are met
    is ``status``.

    Parameters
    ----------
    status : str
        'target_met' (s* >= 1, max ``|lambda|`` <= the virtual constraints' eigenvalue,
        the paper's perturbation converged by step 4) or 'target_not_met'.
    message : str
        The result in words.
    design : dict
        ``M1`` (list) and ``rejoin`` (fraction of T).
    gait_file : str
        The gait the design runs on.
    gait_options : dict
        Its GaitOptions.
    gait_free : bool
        Whether the gait was co-designed.
    gait_change : dict
        T before and after, the largest change of a Bezier coefficient (rad).
    s_star, s_fail : float
        The protocol's s* and the scale just above where a kept direction fails.
    failure : str
        That failure in words.
    verified : dict
        Full-order runs at s* and s_fail (:class:`~analysis.design.verification.DesignCheck`).
    max_abs : float
        max ``|lambda|`` of A^z (full AD).
    vc_eigenvalue : float
        Virtual constraints' ``|eigenvalue|`` on the same gait.
    steps_to_converge : int or None
        The paper's perturbation, full order: the step from which the error stays below
        ``tol``.
    paper_errors : list of float
        The error at every step of that run.
    peak_torque : float
        Its largest ``|u|``, N m.
    hidden : dict
        The hidden sign patterns (:class:`~analysis.design.verification.HiddenPatterns`), or {}.
    basin : dict
        The basin's fractions, or {}.
    nlp_s : float
        The best NLP's own s (over its scenarios).
    active_constraints : list of dict
        The constraints with the largest multipliers at the last solve, in words.
    ipopt : dict
        The solves: status, iterations and time of each, and their totals.
    rounds : list of dict
        Every solve and verification (s of the NLP, verified s*, scenarios).
    directions_kept : int
        Kept directions on the final gait.
    directions_tried : int
        Candidates tried to keep them.
    simulate_args : list of str
        ``biped simulate`` arguments that replay the design from the paper's perturbation.
    stages : dict
        Time per stage, s.
    elapsed : float
        Wall time, s.
    settings : dict
        :meth:`CodesignSettings.to_dict`.
    cached : bool
        Read from the cache.
    gait : Gait
        The gait (left out of ``to_dict()``).
    """

    status: str
    message: str
    design: dict
    gait_file: str
    gait_options: dict
    gait_free: bool
    gait_change: dict
    s_star: float
    s_fail: float
    failure: str
    verified: dict
    max_abs: float
    vc_eigenvalue: float
    steps_to_converge: int | None
    paper_errors: list
    peak_torque: float
    hidden: dict
    basin: dict
    nlp_s: float
    active_constraints: list
    ipopt: dict
    rounds: list
    directions_kept: int
    directions_tried: int
    simulate_args: list
    stages: dict
    elapsed: float
    settings: dict
    cached: bool = False
    gait: object = internal(default=None)

    SUCCESS = ("target_met", "target_not_met")


class CodesignError(ValueError):
    """IPOPT failed on the co-design NLP, or the request is infeasible (the message says
    which solver, its status and what to try)."""


# ------------------------------------------------------------------ the method
class _Codesign:
    """The stages of :func:`codesign`, with the state they share."""

    def __init__(self, model, st: CodesignSettings, gait, progress):
        self.model, self.st = model, st
        self.say = progress or (lambda msg: None)
        self.fixed_gait = gait
        self.free = st.free_gait and gait is None
        self.tst = TranscriptionSettings(mu=st.mu, torque_limit=float(
            st.torque_limit if st.torque_limit is not None else model.params.torque_limit),
            **st.transcription)
        self.rs = st.robustness_settings()
        self.t0 = self._last = time.perf_counter()
        self.stages, self.rounds, self.solves = {}, [], []
        self.lam = None

    def stage(self, name, **info):
        now = time.perf_counter()
        self.stages[name] = dict(info, time=round(now - self._last, 2))
        self._last = now

    # -------------------------------------------------------------- helpers
    def kept(self, gait):
        return kept_directions(self.model, gait, self.rs)

    def measure(self, gait, kept, M1):
        """Walker s* over the kept directions and max|lambda| (AD) of a design."""
        r = robustness(self.model, gait, Design(tuple(M1), self.st.rejoin), self.rs, kept=kept)
        lam = poincare_map(self.model, gait, rejoin=self.st.rejoin).analyse(
            np.array(M1), method="ad").max_abs
        return r, float(lam)

    def hardest(self, gait, kept, M1, s, n):
        """The n kept directions (not the paper's) that fail first or end worst at scale s."""
        rs = self.rs
        w = zero_dynamics_walker(self.model, gait, rs.simulation_options(), rs.rk4_steps, jit=True)
        dirs = kept.directions
        q0, dq0 = start_states(gait, dirs, s)
        B = w.walk(q0, dq0, np.array(M1), self.st.rejoin, steps=rs.steps)
        err = np.where(B.status == "ok", np.nan_to_num(B.final_error, nan=1e3), 1e6
                       - B.fail_step.astype(float))
        order = [int(i) for i in np.argsort(-err) if i != 0]
        return order[:n]

    def nlp(self, gait, dirs, free, paper_tol=None):
        """The reduced NLP on ``gait``: the paper's direction first, at scale 1 with the
        bound ``paper_tol`` (None: at scale s, bounded like the others)."""
        st = self.st
        tr = Transcription(self.model, gait, dirs, st.steps + (paper_tol is not None),
                           free_gait=free, settings=self.tst)
        red = Reduced(tr)
        red.tols[:] = st.scenario_tol
        red.steps[:] = st.steps
        if paper_tol is not None:
            # the paper's direction at scale 1, below paper_tol from step 4 on (errors are
            # not monotonic: its last two steps are bounded)
            red.scales[0] = 1.0
            red.tols[0] = paper_tol
            red.steps[0] = tr.S
            red.tol_from[0] = tr.S - 2
        if not free:
            red.jury = (self._jury(gait), st.eigen_margin * self.lam_vc(gait))
        return tr, red

    def score(self, r):
        """(the paper's perturbation converges by step 4 in the walker, s*): designs are
        compared by this, lexicographically."""
        conv = r.paper.get("steps_to_converge", math.inf) if r.paper else math.inf
        return (bool(conv <= 4), float(r.s_star))

    def lam_vc(self, gait):
        return abs(vc_eigenvalue(self.model, gait).eigenvalue)

    def _jury(self, gait):
        A_fn = poincare_map(self.model, gait, rejoin=self.st.rejoin).variational.A_fn
        M = ca.SX.sym("M1", self.model.nu)
        A = A_fn(M)
        tr = A[0, 0] + A[1, 1]
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        f = ca.Function("jury", [M], [tr, ca.gradient(tr, M), det, ca.gradient(det, M)])

        def jury(M1):
            a, b, c, e = (np.array(v).ravel() for v in f(np.asarray(M1, float)))
            return (float(a[0]), b), (float(c[0]), e)
        return jury

    def denominator(self, tr, gait, M1):
        """The eq. 24 denominator's sign for M1 and a fixed scale: D11's largest value
        on the reference (so the margin does not move with the start)."""
        D11, D12 = denominator_samples(self.model, gait)
        den = decoupling_denominator(D11, D12, np.asarray(M1, float))
        tr.den_scale = float(np.max(np.abs(D11)))
        tr.den_sign = 1.0 if den[0] >= 0 else -1.0

    def continued(self, tr, red, d0, lb, ub, label, max_iter=None):
        """Solve with the paper's error bound reached by continuation: when the start
        exceeds it, the bound goes down from the start's error in at most
        ``paper_steps`` solves (a factor of at least 5 each), every solve warm-started."""
        if not np.isfinite(red.scales[0]):
            return self.solve(tr, red, d0, lb, ub, label, max_iter)
        target = red.tols[0]
        red.tols[0] = np.inf
        red.evaluate(d0)
        e0 = max(float(np.max(np.abs(i["err"]))) for i in red.info
                 if i["k"] == 0 and i["j"] >= red.tol_from[0])
        n = int(np.clip(np.ceil(np.log(max(e0, target) / target) / np.log(5.0)), 0,
                        self.st.paper_steps))
        res = None
        for i in range(n, -1, -1):
            red.tols[0] = max(target, target * (e0 / target) ** (i / max(n, 1))) if i else target
            red._last = None
            res = self.solve(tr, red, d0 if res is None else res.d, lb, ub,
                             label + (f", paper bound {red.tols[0]:.2g}" if n else ""),
                             max_iter)
            if not np.all(np.isfinite(res.d)):
                break
        return res

    def solve(self, tr, red, d0, lb, ub, label, max_iter=None, max_time=None):
        res = solve_nlp(red, d0, lb, ub, {"max_iter": max_iter or self.st.max_iter,
                                          "max_wall_time": max_time or self.st.max_solve_time})
        self.solves.append(dict(label=label, status=res.status, iterations=res.iterations,
                                time=round(res.time, 2), evaluations=res.evaluations,
                                scenarios=tr.K))
        return res

    # -------------------------------------------------------------- phases
    def setup(self):
        st = self.st
        # the compiled node functions build while the gait and the directions are made
        from concurrent.futures import ThreadPoolExecutor
        pool = ThreadPoolExecutor(2)
        nG = self.model.nu * (GaitOptions(**st.gait).bezier_degree + 1) + 3
        self._compiling = [pool.submit(_node_functions, self.model, n)
                           for n in ([0, nG] if self.free else [0])]
        pool.shutdown(wait=False)
        if self.fixed_gait is not None:
            self.gait0 = self.fixed_gait
            self.say("gait given: M1 only (the gait is fixed)")
        else:
            self.say(f"start gait {st.gait} (optimised once, then cached)")
            self.gait0 = default_gait(self.model, GaitOptions(**st.gait))
        self.kept0 = self.kept(self.gait0)
        for f in self._compiling:
            f.result()
        if len(self.kept0) == 0:
            raise CodesignError("codesign: virtual constraints walk from no perturbation "
                                "direction on this gait at full scale; try another gait")
        self.stage("setup", T=self.gait0.T, kept=len(self.kept0), tried=self.kept0.tried)

    def sampled(self):
        """Sampled starts (see :class:`CodesignSettings`): random M1 with max ``|lambda|``
        within the bound from which the walker walks the paper's perturbation at scale 1,
        in the order drawn."""
        st, m = self.st, self.model
        if st.samples <= 0 or st.sampled_starts <= 0:
            return []
        g, kept, rs = self.gait0, self.kept0, self.rs
        rng = np.random.default_rng(st.seed)
        M = rng.uniform(-st.box, st.box, (st.samples, m.nu))
        jb = poincare_map(m, g, rejoin=st.rejoin).jacobian_batch(M)
        ok = (jb.status == "stable") & (jb.max_abs <= st.eigen_margin * self.lam_vc(g))
        M = M[ok][:8 * st.sampled_starts]
        if len(M):
            w = zero_dynamics_walker(m, g, rs.simulation_options(), 200, jit=True)
            q0, dq0 = start_states(g, np.repeat(kept.directions[:1], len(M), 0), 1.0)
            B = w.walk(q0, dq0, M, st.rejoin, steps=rs.steps)
            M = M[B.verdict(rs.tol) == "ok"][:st.sampled_starts]
        self.stage("sampled starts", drawn=st.samples, stable=int(ok.sum()), kept=len(M))
        return list(M)

    def solve_round(self, gait, kept, M1, active, rnd, s0, max_iter=None, label=""):
        """One NLP solve with the gait fixed (exchange round ``rnd``) and the walker's
        verification of its design: the round's record and the candidate."""
        st = self.st
        dirs = kept.directions[[0] + list(active)]
        tr, red = self.nlp(gait, dirs, free=False, paper_tol=st.paper_tol)
        self.denominator(tr, gait, M1)
        d0 = np.zeros(red.nd)
        d0[tr.i_M1], d0[tr.i_rejoin], d0[tr.i_s] = M1, st.rejoin, s0
        lb, ub = red.bounds()
        lb[tr.i_rejoin] = ub[tr.i_rejoin] = st.rejoin
        self.say(f"NLP, gait fixed: {tr.K} scenarios x {tr.S} steps ({label})")
        res = self.continued(tr, red, d0, lb, ub, label, max_iter)
        if not np.all(np.isfinite(res.d)):
            return None
        return self.candidate(gait, kept, tr, red, res, active, label)

    def candidate(self, gait, kept, tr, red, res, active, label):
        """A solve's design verified by the walker: its record and the candidate."""
        M1n, s_nlp = res.d[tr.i_M1], float(res.d[tr.i_s])
        r, lam = self.measure(gait, kept, M1n)
        self.rounds.append(dict(phase="gait fixed", label=label, nlp_status=res.status,
                                nlp_s=s_nlp, s_star=r.s_star, failure=r.failure, max_abs=lam,
                                paper_steps=r.paper.get("steps_to_converge"),
                                scenarios=[0] + list(active), M1=M1n.tolist()))
        self.say(f"  IPOPT {res.status} ({res.iterations} it, {res.time:.1f} s): NLP s "
                 f"{s_nlp:.4g}; verified s* {r.s_star:.4g}, max|lambda| {lam:.3g}, paper "
                 f"converged from step {r.paper.get('steps_to_converge')}")
        ok = lam <= self.lam_vc(gait) and r.s_star > 0
        return dict(gait=gait, kept=kept, M1=M1n, s_star=r.s_star, nlp_s=s_nlp, red=red,
                    tr=tr, res=res, lam=lam, active=list(active), score=self.score(r),
                    ok=ok, failure=r.failure)

    def fixed_phase(self, starts):
        """Every start screened by a short first solve (ranked by the NLP's own s); the
        best is verified and continues with scenario exchange."""
        st, gait, kept = self.st, self.gait0, self.kept0
        screened = []
        for i, M1 in enumerate(starts):
            active = self.hardest(gait, kept, M1, st.s_start, st.initial_active)
            tr, red = self.nlp(gait, kept.directions[[0] + active], free=False,
                               paper_tol=st.paper_tol)
            self.denominator(tr, gait, M1)
            d0 = np.zeros(red.nd)
            d0[tr.i_M1], d0[tr.i_rejoin], d0[tr.i_s] = M1, st.rejoin, st.s_start
            lb, ub = red.bounds()
            lb[tr.i_rejoin] = ub[tr.i_rejoin] = st.rejoin
            label = f"start {i + 1} of {len(starts)}"
            self.say(f"NLP, gait fixed: {tr.K} scenarios x {tr.S} steps ({label})")
            res = self.solve(tr, red, d0, lb, ub, label, st.screen_iter, st.screen_time)
            s_nlp = float(res.d[tr.i_s]) if np.all(np.isfinite(res.d)) else -np.inf
            self.say(f"  IPOPT {res.status} ({res.iterations} it, {res.time:.1f} s): NLP s "
                     f"{s_nlp:.4g}")
            self.rounds.append(dict(phase="start", label=label, M1_start=np.asarray(M1).tolist(),
                                    nlp_status=res.status, nlp_s=s_nlp,
                                    M1=res.d[tr.i_M1].tolist()))
            screened.append((res.success, s_nlp, tr, red, res, active))
        screened.sort(key=lambda t: (not t[0], -t[1]))       # converged solves first
        best = None
        for _, s_nlp, tr, red, res, active in screened[:2]:
            if np.isfinite(s_nlp):
                c = self.candidate(gait, kept, tr, red, res, active, "best start")
                if c["ok"]:
                    best = c
                    break
        if best is None:
            return None
        cur = best
        for rnd in range(1, st.exchange_rounds):
            active = list(cur["active"])
            fdir = cur["failure"].get("direction") if cur["failure"] else None
            if fdir is not None and fdir != 0 and fdir not in active \
                    and len(active) < st.max_active:
                active.append(int(fdir))
            elif rnd > 1:
                break                      # nothing new to add: the exchange has converged
            c = self.solve_round(gait, kept, cur["M1"], active, rnd,
                                 max(min(cur["s_star"], cur["nlp_s"]) - 0.02, 0.1),
                                 label=f"exchange round {rnd}")
            if c is None:
                break
            if c["ok"]:
                cur = c
                if c["score"] > best["score"]:
                    best = c
        return best

    def gait_phase(self, best):
        """Gait steps in a trust region around the current gait."""
        st, model = self.st, self.model
        gait, kept, M1 = best["gait"], best["kept"], best["M1"]
        dirs = [kept.directions[i] for i in [0] + list(best.get("active", []))]
        if len(dirs) == 1:
            dirs += [kept.directions[i] for i in self.hardest(gait, kept, M1, best["s_star"],
                                                             st.initial_active)]
        trust = 1.0
        for rnd in range(st.gait_rounds):
            tr, red = self.nlp(gait, np.array(dirs), free=True, paper_tol=st.paper_tol)
            self.denominator(tr, gait, M1)
            d0 = np.zeros(red.nd)
            d0[tr.i_G] = tr.gait_vector(gait)
            d0[tr.i_M1], d0[tr.i_rejoin] = M1, st.rejoin
            d0[tr.i_s] = max(best["s_star"] - 0.02, 0.1)
            lb, ub = red.bounds()
            lb[tr.i_rejoin] = ub[tr.i_rejoin] = st.rejoin
            na = tr.na
            lb[:na] = np.maximum(lb[:na], d0[:na] - trust * st.trust_alpha)
            ub[:na] = np.minimum(ub[:na], d0[:na] + trust * st.trust_alpha)
            lb[na] = max(lb[na], d0[na] - trust * st.trust_T)
            ub[na] = min(ub[na], d0[na] + trust * st.trust_T)
            lb[na + 1:na + 3] = d0[na + 1:na + 3] - trust * st.trust_x0
            ub[na + 1:na + 3] = d0[na + 1:na + 3] + trust * st.trust_x0
            self.say(f"NLP, gait free: {tr.K} scenarios x {tr.S} steps, trust region "
                     f"{trust * st.trust_alpha:g} rad (round {rnd + 1})")
            res = self.solve(tr, red, d0, lb, ub, f"gait free, round {rnd + 1}")
            alpha, T, r0, M1n, _, s_nlp = tr.unpack(res.d)
            try:
                opts = gait.options
                a2, x2, T2, _ = polish(model, opts, alpha, r0, T)
                g_new = Gait(model, opts, a2, x2, T2,
                             solver_stats=dict(method="codesign", nlp_status=res.status))
                bad = g_new.violations()
            except (GaitOptimizationError, ValueError) as e:
                g_new, bad = None, [("polish", str(e))]
            rec = dict(phase="gait free", round=rnd + 1, nlp_status=res.status, nlp_s=s_nlp,
                       scenarios=len(dirs), T=float(T), trust=trust * st.trust_alpha)
            if g_new is None or bad:
                rec.update(rejected=f"the gait step is not a valid gait: {bad}")
                self.rounds.append(rec)
                trust /= 2
                continue
            kept_new = self.kept(g_new)
            r, lam = self.measure(g_new, kept_new, M1n)
            lvc = self.lam_vc(g_new)
            rec.update(s_star=r.s_star, failure=r.failure, max_abs=lam, vc_eigenvalue=lvc,
                       kept=len(kept_new), M1=M1n.tolist())
            self.say(f"  IPOPT {res.status} ({res.iterations} it, {res.time:.1f} s): NLP s "
                     f"{s_nlp:.4g}; new gait T {T2:.4g} s, verified s* {r.s_star:.4g} over "
                     f"{len(kept_new)} kept directions, max|lambda| {lam:.3g} (VC {lvc:.3g})")
            score = self.score(r)
            if score > best["score"] and lam <= lvc and len(kept_new) == st.directions:
                best = dict(best, gait=g_new, kept=kept_new, M1=M1n, s_star=r.s_star,
                            nlp_s=s_nlp, red=red, tr=tr, res=res, lam=lam, score=score)
                gait, kept, M1 = g_new, kept_new, M1n
                rec.update(accepted=True)
            else:
                trust /= 2
                rec.update(accepted=False)
            self.rounds.append(rec)
            if r.failure:
                d_fail = kept_new.directions[r.failure["direction"]]
                if not any(np.array_equal(d_fail, x) for x in dirs) \
                        and len(dirs) <= st.max_active:
                    dirs.append(d_fail)
        return best


def _active(best, limit: int = 8):
    """The constraints with the largest multipliers at the best solve, in words."""
    red, res = best["red"], best["res"]
    if res is None:
        return []
    red.evaluate(res.d)
    lam = np.asarray(res.lam_g)
    order = np.argsort(-np.abs(lam))
    out = []
    for i in order[:limit]:
        if abs(lam[i]) < 1e-8:
            break
        out.append(dict(constraint=_words(red.names[i], best.get("labels")),
                        multiplier=float(lam[i]), row=red.names[i]))
    return out


def _words(name, labels=None):
    """'torque k1 j0 chunk 2' -> 'torque limit: scenario 1, step 1, tau in [0.2, 0.3] T'."""
    parts = name.split()
    fam = parts[0]
    words = FAMILIES.get(fam, name)
    rest = " ".join(parts[1:])
    if len(parts) >= 3 and parts[1].startswith("k") and parts[2].startswith("j"):
        k, j = int(parts[1][1:]), int(parts[2][1:])
        who = "the paper's perturbation (scale 1)" if k == 0 else (
            labels[k] if labels else f"scenario {k} (scale s)")
        where = f"{who}, step {j + 1}"
        if len(parts) >= 5 and parts[3] == "chunk":
            c = int(parts[4])
            where += f", tau in [{c / 10:.1f}, {(c + 1) / 10:.1f}] T"
        elif len(parts) > 3:
            where += ", " + " ".join(parts[3:])
        return f"{words}: {where}"
    return f"{words} {rest}".strip()


def codesign(model, settings: CodesignSettings | None = None, gait=None, gait_file=None,
             progress=None, cache=None, use_cache: bool = True) -> CodesignResult:
    """Co-design the robust time-varying controller (and the gait) by the NLP.

    Parameters
    ----------
    model : BipedModel
        The robot.
    settings : CodesignSettings, optional
        The co-design (default: all defaults, the gait free).
    gait : Gait, optional
        Fix the gait to this one (only M1 moves).
    gait_file : str or Path, optional
        The file ``gait`` was read from (for the replay arguments).
    progress : callable, optional
        Called with one line of text per stage.
    cache : str or Path, optional
        Folder of cached results (default :func:`biped_casadi.cache_dir`).
    use_cache : bool
        Read a cached result for the same inputs (and write the new one).

    Returns
    -------
    CodesignResult

    Raises
    ------
    CodesignError
        When IPOPT fails on every start or no design verifies (the message names the
        solver, its status and what to try).
    """
    st = settings or CodesignSettings()
    if gait is not None and gait.model.params != model.params:
        raise ValueError("gait: made for other robot parameters than the model")
    key = dict(robot=model.params.to_dict(), settings=st.to_dict(),
               gait=None if gait is None else gait.cache_key, code=source_digest())
    path = CODESIGNS.path(key, cache)
    if use_cache and path.is_file():
        try:
            d = json.loads(path.read_text())
            d["cached"] = True
            d.pop("success", None)
            g = Gait.load(d["gait_file"], model=model)
            return CodesignResult(**d, gait=g)
        except (ValueError, TypeError, OSError, KeyError):
            pass                                     # damaged or gait gone: recompute
    run = _Codesign(model, st, gait, progress)
    run.setup()
    starts = [np.asarray(M1, float) for M1 in run.sampled()] + [
        np.asarray(M1, float) for M1 in st.starts]
    best = run.fixed_phase(starts)
    run.stage("gait fixed", solves=len(run.solves))
    if best is None:
        last = run.solves[-1] if run.solves else {}
        raise CodesignError(
            f"codesign: IPOPT ({last.get('status', 'not run')}) found no verified design "
            f"from {len(starts)} start(s); try other starts, more samples, a smaller "
            f"s_start or more iterations")
    if run.free:
        best = run.gait_phase(best)
        run.stage("gait free", solves=len(run.solves))
    g = best["gait"]
    design = Design(tuple(float(v) for v in best["M1"]), st.rejoin)
    run.say("verification (protocol of the robust designs)")
    check = verify_design(model, g, design, best["kept"], st.robustness_settings(rounds=10),
                          progress=run.say)
    hidden = (hidden_sign_patterns(model, g, design, best["kept"], st.robustness_settings())
              .to_dict() if st.hidden else {})
    bas = {}
    if st.basin:
        b = basin(model, g, design)
        bas = dict(converged_fraction=float(b.converged_fraction), message=b.message)
    run.stage("verification", s_star=check.s_star)
    if run.free and g is not run.gait0:
        gpath = CODESIGNS.path(dict(key, what="gait"), cache).with_suffix(".gait.json")
        gpath.parent.mkdir(parents=True, exist_ok=True)
        g.save(gpath)
    elif gait is not None and gait_file is not None:
        gpath = gait_file
    else:
        gpath = cache_path(model, run.gait0.options, cache) if gait is None else \
            CODESIGNS.path(dict(key, what="gait"), cache).with_suffix(".gait.json")
        if not gpath.is_file():
            gpath.parent.mkdir(parents=True, exist_ok=True)
            g.save(gpath)
    met = bool(check.s_star >= 1 and check.max_abs <= check.vc_eigenvalue
               and check.steps_to_converge is not None and check.steps_to_converge <= 4)
    args = (["--gait", str(gpath), "--controller", "tv", "--m1"]
            + [repr(float(v)) for v in design.M1]
            + ["--rejoin", repr(st.rejoin), "--perturb", "0.01", "0.1", "--mu", repr(st.mu),
               "--steps", str(st.walk_steps)]
            + ([] if st.torque_limit is None else ["--torque-limit", repr(st.torque_limit)]))
    tot_it = sum(s["iterations"] for s in run.solves)
    tot_t = sum(s["time"] for s in run.solves)
    last = run.solves[-1]
    msg = (f"co-design ({'gait free' if run.free else 'gait fixed'}): " + check.message
           + ("" if met else "; target (s* >= 1, max|lambda| <= virtual constraints, "
              "converged by step 4) not met"))
    change = dict(T_start=run.gait0.T, T=g.T,
                  max_alpha_change=float(np.max(np.abs(g.alpha - run.gait0.alpha))))
    result = CodesignResult(
        status="target_met" if met else "target_not_met", message=msg,
        design=dict(M1=list(design.M1), rejoin=st.rejoin), gait_file=str(gpath),
        gait_options=g.options.to_dict(), gait_free=run.free, gait_change=change,
        s_star=check.s_star, s_fail=check.s_fail, failure=check.failure,
        verified=check.verified, max_abs=check.max_abs, vc_eigenvalue=check.vc_eigenvalue,
        steps_to_converge=check.steps_to_converge, paper_errors=check.paper_errors,
        peak_torque=check.peak_torque, hidden=hidden, basin=bas, nlp_s=best["nlp_s"],
        active_constraints=_active(best),
        ipopt=dict(status=last["status"], iterations=tot_it, time=round(tot_t, 2),
                   solves=run.solves),
        rounds=run.rounds, directions_kept=len(best["kept"]),
        directions_tried=best["kept"].tried, simulate_args=args, stages=run.stages,
        elapsed=time.perf_counter() - run.t0, settings=st.to_dict(), gait=g)
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_text_atomic(path, json.dumps(result.to_dict(), indent=1))
        except OSError:
            pass
    return result
