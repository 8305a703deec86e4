"""The co-design's method: starts, scenario exchange, gait steps, verification
(the package docstring of :mod:`analysis.design.codesign`)."""
from __future__ import annotations

import json
import math
import time

import casadi as ca
import numpy as np

from biped_casadi.caching import Claimed, shared_result, source_digest
from biped_casadi.control.output_law import decoupling_denominator
from biped_casadi.control.zero_dynamics import denominator_samples
from biped_casadi.files import write_text_atomic
from biped_casadi.simulation import start_states, zero_dynamics_walker
from gait_opt import Gait, GaitOptions, default_gait
from gait_opt.cache import cache_path
from gait_opt.errors import GaitOptimizationError
from gait_opt.polish import polish

from ...robustness.basin import basin
from ...robustness.s_star import Design, kept_directions, robustness
from ...stability.poincare import poincare_map
from ...stability.vc_map import vc_eigenvalue
from ..verification import hidden_sign_patterns, verify_design
from .functions import FAMILIES, TranscriptionSettings, _node_functions
from .reduced import NLPSolve, NoStrikeAtStart, Reduced, solve_nlp
from .settings import CODESIGNS, CodesignError, CodesignResult, CodesignSettings
from .transcription import Transcription


# ------------------------------------------------------------------ the method
class _Barrier(Exception):
    """Where a prefetching run (:func:`codesign_prefetch`) stops: 'end', the end of the
    co-design's independent units, before its sequential gait steps; 'busy', a unit the
    other process is computing (when it does not wait)."""


class _Codesign:
    """The stages of :func:`codesign`, with the state they share."""

    def __init__(self, model, st: CodesignSettings, gait, progress, share=None, cache=None,
                 prefetch: bool = False, wait: bool = True):
        if share not in (None, "forward", "backward"):
            raise ValueError(f"share must be None, 'forward' or 'backward', got {share!r}")
        self.model, self.st = model, st
        self.share, self.cache = share, cache
        self.prefetch = bool(prefetch)
        #: False (prefetching only): stop at a unit another process is computing
        self.wait = bool(wait)
        #: units this process computed and units it read (another process's, or kept)
        self.computed, self.read = 0, 0
        self.unit_key = _key(model, st, gait)
        self.say = progress or (lambda msg: None)
        #: the rejoin fraction of the solves now (st.rejoin, then each of st.rejoin_choices)
        self.rejoin = float(st.rejoin)
        self._juries = {}
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
    def unit(self, name, inputs, compute):
        """``compute()``: a unit of work.  With ``share`` set it is done once among the
        processes running this co-design on one cache folder
        (:func:`biped_casadi.caching.shared_result`: one computing it, the others waiting
        for its result), each taking the independent units in its own order
        (:meth:`order`), so two processes split them.  Every IPOPT solve is a unit (its
        wall-time limit makes it the one result that could differ between processes),
        so both follow the same path and return the same design."""
        if self.share is None:
            return compute()
        try:
            value, read = shared_result(self.unit_path(name, inputs), compute,
                                        wait=self.wait)
        except Claimed:
            raise _Barrier("busy") from None     # (wait=False) the other process has it
        if read:
            self.read += 1
        else:
            self.computed += 1
        return value

    def unit_path(self, name, inputs):
        return CODESIGNS.path(dict(self.unit_key, unit=name, inputs=inputs), self.cache,
                              suffix=".unit.pkl")

    def order(self, items) -> list:
        """Independent units in this process's order: as given, or last first for
        ``share='backward'``."""
        items = list(items)
        return items[::-1] if self.share == "backward" else items

    def kept(self, gait):
        return self.unit("kept directions", dict(gait=gait.cache_key),
                         lambda: kept_directions(gait, self.rs))

    def measure(self, gait, kept, M1):
        """Walker s* over the kept directions and max|lambda| (AD) of a design."""
        M1 = np.asarray(M1, float)

        def compute():
            r = robustness(gait, Design(tuple(M1), self.rejoin), self.rs,
                           kept=kept)
            lam = poincare_map(gait, rejoin=self.rejoin).analyse(
                M1, method="ad").max_abs
            return r, float(lam)
        return self.unit("measure", dict(gait=gait.cache_key, M1=M1.tolist(),
                                         rejoin=self.rejoin,
                                         kept=np.asarray(kept.directions).tolist()), compute)

    def hardest(self, gait, kept, M1, s, n):
        """The n kept directions (not the paper's) that fail first or end worst at scale s."""
        rs = self.rs
        w = zero_dynamics_walker(gait, rs.simulation_options(), rs.rk4_steps, jit=True)
        dirs = kept.directions
        q0, dq0 = start_states(gait, dirs, s)
        B = w.walk(q0, dq0, np.array(M1), self.rejoin, steps=rs.steps)
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
        return abs(vc_eigenvalue(gait).eigenvalue)

    def _jury(self, gait):
        """trace and det of A^z(M1) with their gradients (one Function per gait and
        rejoin, built once)."""
        key = (gait.cache_key, self.rejoin)
        if key not in self._juries:
            self._juries[key] = self._build_jury(gait)
        return self._juries[key]

    def _build_jury(self, gait):
        A_fn = poincare_map(gait, rejoin=self.rejoin).variational.A_fn
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
        D11, D12 = denominator_samples(gait)
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

    def solve(self, tr, red, d0, lb, ub, label, max_iter=None, max_time=None,
              max_evaluations=None):
        """One IPOPT solve from d0 (a unit, :meth:`unit`).  When a scenario cannot strike
        from d0 (a direction just added fails early at the start's scale), the start's s
        is lowered (x 0.8, at most 8 times) until every scenario strikes."""
        limits = dict(max_iter=max_iter or self.st.max_iter,
                      max_wall_time=max_time or self.st.max_solve_time,
                      max_evaluations=max_evaluations or self.st.max_evaluations)
        d0 = np.array(d0, float)

        def compute():
            d = d0.copy()
            for _ in range(8):
                try:
                    return solve_nlp(red, d, lb, ub, {
                        "max_iter": limits["max_iter"],
                        "max_wall_time": limits["max_wall_time"]},
                        max_evaluations=limits["max_evaluations"])
                except NoStrikeAtStart:
                    d[tr.i_s] *= 0.8
                    red._last = None
            return NLPSolve(d=np.full(red.nd, np.nan), lam_g=np.zeros(0),
                            status="no_strike_from_start", success=False, iterations=0,
                            time=0.0, evaluations=0)
        res = self.unit("solve", dict(label=label, d0=d0.tolist(),
                                      lb=np.asarray(lb, float).tolist(),
                                      ub=np.asarray(ub, float).tolist(),
                                      problem=_problem(tr, red), limits=limits), compute)
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

        def compute():
            rng = np.random.default_rng(st.seed)
            M = rng.uniform(-st.box, st.box, (st.samples, m.nu))
            jb = poincare_map(g, rejoin=self.rejoin).jacobian_batch(M)
            ok = (jb.status == "stable") & (jb.max_abs <= st.eigen_margin * self.lam_vc(g))
            M = M[ok][:8 * st.sampled_starts]
            if len(M):
                w = zero_dynamics_walker(g, rs.simulation_options(), 200, jit=True)
                q0, dq0 = start_states(g, np.repeat(kept.directions[:1], len(M), 0), 1.0)
                B = w.walk(q0, dq0, M, self.rejoin, steps=rs.steps)
                M = M[B.verdict(rs.tol) == "ok"][:st.sampled_starts]
            return M, int(ok.sum())
        M, stable = self.unit("sampled starts", dict(gait=g.cache_key, rejoin=self.rejoin),
                              compute)
        self.stage("sampled starts", drawn=st.samples, stable=stable, kept=len(M))
        return list(M)

    def fixed_problem(self, gait, kept, M1, active, s0):
        """The gait-fixed NLP on the paper's direction and the ``active`` kept directions,
        its start (M1, the current rejoin, s0) and its bounds (the rejoin fixed):
        (tr, red, d0, lb, ub)."""
        tr, red = self.nlp(gait, kept.directions[[0] + list(active)], free=False,
                           paper_tol=self.st.paper_tol)
        self.denominator(tr, gait, M1)
        d0 = np.zeros(red.nd)
        d0[tr.i_M1], d0[tr.i_rejoin], d0[tr.i_s] = M1, self.rejoin, s0
        lb, ub = red.bounds()
        lb[tr.i_rejoin] = ub[tr.i_rejoin] = self.rejoin
        return tr, red, d0, lb, ub

    def solve_round(self, gait, kept, M1, active, rnd, s0, max_iter=None, label="",
                    screen=False):
        """One NLP solve with the gait fixed (exchange round ``rnd``) and the walker's
        verification of its design: the round's record and the candidate.  ``screen``:
        one solve on the screening budget (no continuation of the paper's bound)."""
        st = self.st
        tr, red, d0, lb, ub = self.fixed_problem(gait, kept, M1, active, s0)
        self.say(f"NLP, gait fixed: {tr.K} scenarios x {tr.S} steps ({label})")
        if screen:
            res = self.solve(tr, red, d0, lb, ub, label, st.screen_iter, st.screen_time,
                             st.screen_evaluations)
        else:
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
                    ok=ok, failure=r.failure, rejoin=self.rejoin)

    def fixed_phase(self, starts):
        """Every start screened by a short first solve (ranked by the NLP's own s); the
        best is verified and continues with scenario exchange."""
        st, gait, kept = self.st, self.gait0, self.kept0

        def screen(i, M1, label):
            active = self.hardest(gait, kept, M1, st.s_start, st.initial_active)
            tr, red, d0, lb, ub = self.fixed_problem(gait, kept, M1, active, st.s_start)
            self.say(f"NLP, gait fixed: {tr.K} scenarios x {tr.S} steps ({label})")
            res = self.solve(tr, red, d0, lb, ub, label, st.screen_iter, st.screen_time,
                             st.screen_evaluations)
            return dict(active=active, res=res, record=self.solves.pop(), i_s=tr.i_s,
                        i_M1=tr.i_M1)

        done = {}
        for i in self.order(range(len(starts))):            # the starts are independent
            label = f"start {i + 1} of {len(starts)}"
            done[i] = self.unit("screen", dict(M1=np.asarray(starts[i]).tolist()),
                                lambda i=i, label=label: screen(i, starts[i], label))
        screened = []
        for i, M1 in enumerate(starts):
            u, label = done[i], f"start {i + 1} of {len(starts)}"
            res = u["res"]
            self.solves.append(u["record"])
            s_nlp = float(res.d[u["i_s"]]) if np.all(np.isfinite(res.d)) else -np.inf
            self.say(f"  {label}: IPOPT {res.status} ({res.iterations} it, {res.time:.1f} s): "
                     f"NLP s {s_nlp:.4g}")
            self.rounds.append(dict(phase="start", label=label, M1_start=np.asarray(M1).tolist(),
                                    nlp_status=res.status, nlp_s=s_nlp,
                                    M1=res.d[u["i_M1"]].tolist()))
            screened.append((res.success, s_nlp, M1, res, u["active"]))
        screened.sort(key=lambda t: (not t[0], -t[1]))       # converged solves first
        best = None
        for _, s_nlp, M1, res, active in screened[:2]:
            if np.isfinite(s_nlp):
                tr, red, *_ = self.fixed_problem(gait, kept, M1, active, st.s_start)
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

    def rejoin_phase(self, best):
        """The rejoin time of v_c as a decision: the gait-fixed NLP solved at each of
        ``rejoin_choices`` from the best design (v_c's third derivative jumps at t_c,
        which makes the walker's rule kinked in t_c: a discrete choice, not a smooth
        variable); the best verified design wins.  Each choice is solved from the
        gait-fixed phase's design (they are independent: two processes split them)."""
        start = best                           # every choice starts from this design
        choices = [float(r) for r in self.st.rejoin_choices
                   if abs(r - start["rejoin"]) >= 1e-12]
        done, n_rounds, n_solves = {}, len(self.rounds), len(self.solves)
        for r in self.order(choices):          # independent: each from the same design
            self.rejoin = r
            done[r] = self.solve_round(start["gait"], start["kept"], start["M1"],
                                       start["active"], 1,
                                       max(min(start["s_star"], start["nlp_s"]) - 0.1, 0.1),
                                       label=f"rejoin {r:g} T", screen=True)
        # the records in the choices' order, whichever end this process took them from
        rank = {f"rejoin {r:g} T": i for i, r in enumerate(choices)}
        for rec, k in ((self.rounds, n_rounds), (self.solves, n_solves)):
            rec[k:] = sorted(rec[k:], key=lambda x: rank.get(x.get("label"), len(rank)))
        for r in choices:
            c = done[r]
            if c is not None and c["ok"] and c["score"] > best["score"]:
                best = c
        self.rejoin = float(best["rejoin"])
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
            # max|lambda| is not exact in the free-gait NLP: the Jury bound on the current
            # gait's A^z(M1), tighter, keeps M1 from raising it while the gait moves a
            # trust region
            red.jury = (self._jury(gait), st.gait_eigen_margin * self.lam_vc(gait))
            self.denominator(tr, gait, M1)
            d0 = np.zeros(red.nd)
            d0[tr.i_G] = tr.gait_vector(gait)
            d0[tr.i_M1], d0[tr.i_rejoin] = M1, self.rejoin
            d0[tr.i_s] = max(best["s_star"] - 0.02, 0.1)
            lb, ub = red.bounds()
            lb[tr.i_rejoin] = ub[tr.i_rejoin] = self.rejoin
            na = tr.na
            lb[:na] = np.maximum(lb[:na], d0[:na] - trust * st.trust_alpha)
            ub[:na] = np.minimum(ub[:na], d0[:na] + trust * st.trust_alpha)
            lb[na] = max(lb[na], d0[na] - trust * st.trust_T)
            ub[na] = min(ub[na], d0[na] + trust * st.trust_T)
            lb[na + 1:na + 3] = d0[na + 1:na + 3] - trust * st.trust_x0
            ub[na + 1:na + 3] = d0[na + 1:na + 3] + trust * st.trust_x0
            self.say(f"NLP, gait free: {tr.K} scenarios x {tr.S} steps, trust region "
                     f"{trust * st.trust_alpha:g} rad (round {rnd + 1})")
            res = self.solve(tr, red, d0, lb, ub, f"gait free, round {rnd + 1}",
                             max_iter=st.gait_iter, max_time=st.gait_solve_time,
                             max_evaluations=st.gait_evaluations)
            if not np.all(np.isfinite(res.d)):
                self.rounds.append(dict(phase="gait free", round=rnd + 1,
                                        nlp_status=res.status, rejected="no solve"))
                trust /= 2
                continue
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
            full = len(kept_new) == st.directions
            if score > best["score"] and lam <= lvc and full:
                best = dict(best, gait=g_new, kept=kept_new, M1=M1n, s_star=r.s_star,
                            nlp_s=s_nlp, red=red, tr=tr, res=res, lam=lam, score=score)
                gait, kept, M1 = g_new, kept_new, M1n
                rec.update(accepted=True)
                self.rounds.append(rec)
            elif score > best["score"] and full and st.repair:
                # the gait step gained s* but max|lambda| (not in the free-gait NLP) grew
                # past the virtual constraints': M1 alone, on the new gait, under the Jury
                # bound, from the step's M1
                rec.update(accepted=False, repaired="M1 re-solved on the new gait")
                self.rounds.append(rec)
                active = self.hardest(g_new, kept_new, M1n, r.s_star, st.initial_active)
                c = self.solve_round(g_new, kept_new, M1n, active, 1,
                                     max(r.s_star - 0.02, 0.1), label=f"gait round "
                                     f"{rnd + 1}: M1 on the new gait")
                if c is not None and c["ok"] and c["score"] > best["score"]:
                    best = c
                    gait, kept, M1 = g_new, kept_new, c["M1"]
                    self.rounds[-1].update(accepted=True)
                else:
                    trust /= 2
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
    """The inequality constraints with the largest multipliers at the best solve, in
    words."""
    red, res = best["red"], best["res"]
    if res is None:
        return []
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


def _key(model, st, gait):
    return dict(robot=model.params.to_dict(), settings=st.to_dict(),
                gait=None if gait is None else gait.cache_key, code=source_digest())


def codesign_path(model, settings: CodesignSettings | None = None, gait=None,
                  cache=None):
    """The file :func:`codesign` keeps its result in for these inputs.

    Parameters
    ----------
    model, settings, gait, cache :
        As :func:`codesign`.

    Returns
    -------
    pathlib.Path
    """
    return CODESIGNS.path(_key(model, settings or CodesignSettings(), gait), cache)


def codesign(model, settings: CodesignSettings | None = None, gait=None, gait_file=None,
             progress=None, cache=None, use_cache: bool = True,
             share: str | None = None) -> CodesignResult:
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
    share : {None, 'forward', 'backward'}
        Split the units of work with another process running the same co-design on
        the same cache folder: the independent ones (the screening solves of the
        starts, the rejoin choices, the verification's sets of full-order runs) taken
        from opposite ends ('forward' and 'backward'), the sequential ones (the gait
        steps) computed by whichever gets there first while the other waits.  Each unit
        is computed once (a lock file claims it) and read by the other, every IPOPT solve
        among them, so both return the same result.  None: no sharing.  See also
        :func:`codesign_prefetch`.

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
    key = _key(model, st, gait)
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
    run = _Codesign(model, st, gait, progress, share=share, cache=cache)
    best = _independent_phases(run)
    if run.free:
        best = run.gait_phase(best)
        run.stage("gait free", solves=len(run.solves))
    g = best["gait"]
    run.rejoin = float(best["rejoin"])
    design = Design(tuple(float(v) for v in best["M1"]), run.rejoin)
    run.say("verification (protocol of the robust designs)")
    check = verify_design(g, design, best["kept"], st.robustness_settings(rounds=10),
                          progress=run.say, unit=run.unit, order=run.order)
    hidden = run.unit("hidden sign patterns", dict(gait=g.cache_key, design=design.to_dict()),
                      lambda: hidden_sign_patterns(g, design, best["kept"],
                                                   st.robustness_settings()).to_dict()) \
        if st.hidden else {}
    bas = {}
    if st.basin:
        b = basin(g, design)
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
            + ["--rejoin", repr(run.rejoin), "--perturb", "0.01", "0.1", "--mu", repr(st.mu),
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
        design=dict(M1=list(design.M1), rejoin=run.rejoin), gait_file=str(gpath),
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


def _independent_phases(run: _Codesign) -> dict:
    """Setup, the starts and the rejoin choices: the phases whose units two processes
    split (a prefetching run stops after them, :class:`_Barrier`)."""
    st = run.st
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
    if st.rejoin_choices:
        best = run.rejoin_phase(best)
        run.stage("rejoin", rejoin=run.rejoin, solves=len(run.solves))
    if run.prefetch:
        raise _Barrier("end")  # the rest is sequential (gait steps) or needs the design
    return best


def codesign_prefetch(model, settings: CodesignSettings | None = None, progress=None,
                      cache=None, share: str = "backward", wait: bool = True) -> dict:
    """Take part in another process's co-design as far as its independent units go.

    The other process runs ``codesign(share=...)`` on the same cache folder; this call
    returns once the independent units are done (or, ``wait=False``, at the first it
    would wait for).

    This process takes the start screens and the rejoin choices from its end (with
    ``share``, as :func:`codesign`), waiting for the few results the other is computing
    (the start gait, the kept directions), and stops before the gait steps, which are
    sequential: the other process carries on alone while this one does other work, and a
    later ``codesign(share=...)`` here reads every unit and splits the verification.

    Parameters
    ----------
    model, settings, progress, cache :
        As :func:`codesign` (the gait free or fixed by ``settings``; no given gait).
    share : {'forward', 'backward'}
        This process's end of the units.
    wait : bool
        False: never wait for the other process: return at once while its setup is not
        done, and at the first unit it is computing (call again later to take more).

    Returns
    -------
    dict
        ``computed`` and ``read`` (units), ``time`` (s), ``cached`` (the co-design's
        result was already kept: nothing to do), ``ready`` (False: the other process's
        setup is not done, nothing was tried) and ``finished`` (every independent unit
        is done: nothing left to take).

    Raises
    ------
    ValueError
        ``share`` is not 'forward' or 'backward'.
    CodesignError
        As :func:`codesign` (no start gave a verified design).
    """
    if share not in ("forward", "backward"):
        raise ValueError(f"share must be 'forward' or 'backward', got {share!r}")
    st = settings or CodesignSettings()
    t0 = time.perf_counter()
    out = dict(computed=0, read=0, time=0.0, cached=False, ready=True, finished=False)
    if codesign_path(model, st, None, cache).is_file():
        return dict(out, cached=True, finished=True)
    run = _Codesign(model, st, None, progress, share=share, cache=cache, prefetch=True,
                    wait=wait)
    if not wait and not _started(run):
        return dict(out, ready=False)
    try:
        _independent_phases(run)
        finished = True
    except _Barrier as e:
        finished = e.args == ("end",)
    return dict(out, computed=run.computed, read=run.read, time=time.perf_counter() - t0,
                finished=finished)


def _started(run: _Codesign) -> bool:
    """Whether the co-design's setup is done (its start gait kept, its sampled starts a
    unit on disk), so that taking part costs no waiting."""
    opts = GaitOptions(**run.st.gait).for_model(run.model)
    if not cache_path(run.model, opts).is_file():       # where setup() keeps it
        return False
    g = default_gait(run.model, opts)
    return run.unit_path("sampled starts", dict(gait=g.cache_key, rejoin=run.rejoin)).is_file()


def codesign_tradeoff(model, result: CodesignResult, fractions=(0.25, 0.5, 0.75, 1.0),
                      progress=None, cache=None, share: str | None = None) -> list:
    """The (max|lambda|, s*) trade-off traced by the NLP on the co-design's gait.

    For each bound rho = fraction x the virtual constraints' eigenvalue, the fixed-gait
    NLP (the Jury conditions at rho) is solved from the co-design's M1 with the
    scenarios of its last solve, and its design is verified by the walker's bisection
    over the kept directions: each point is a verified s* and its exact max|lambda|.

    Parameters
    ----------
    model : BipedModel
        The robot.
    result : CodesignResult
        A co-design (its gait, M1, settings).
    fractions : tuple of float
        The bounds, as fractions of the virtual constraints' eigenvalue.
    progress : callable, optional
        One line per point.
    cache : str or Path, optional
        Cache folder of the shared points (default :func:`biped_casadi.cache_dir`).
    share : {None, 'forward', 'backward'}
        Split the points with another process tracing the same trade-off on the same
        cache folder (as :func:`codesign`).

    Returns
    -------
    list of dict
        Per bound: ``bound``, the NLP's status and s, the verified ``s_star`` and
        ``max_abs``, and ``M1``.
    """
    st = CodesignSettings(**{k: v for k, v in result.settings.items() if k != "starts"})
    run = _Codesign(model, st, result.gait, progress, share=share, cache=cache)
    run.rejoin = float(result.design["rejoin"])
    gait, M1 = result.gait, np.asarray(result.design["M1"], float)
    kept = run.kept(gait)
    lvc = run.lam_vc(gait)
    active = run.hardest(gait, kept, M1, max(result.s_star, 0.1), st.initial_active)

    def point(f):
        tr, red, d0, lb, ub = run.fixed_problem(gait, kept, M1, active,
                                                max(result.s_star - 0.1, 0.1))
        red.jury = (run._jury(gait), float(f) * lvc)
        res = run.solve(tr, red, d0, lb, ub, f"trade-off at {f:g} x VC")
        if not np.all(np.isfinite(res.d)):
            return dict(bound=f * lvc, nlp_status=res.status, s_star=None, max_abs=None)
        r, lam = run.measure(gait, kept, res.d[tr.i_M1])
        run.say(f"trade-off: bound {f * lvc:.3g}: IPOPT {res.status}, verified s* "
                f"{r.s_star:.4g} at max|lambda| {lam:.3g}")
        return dict(bound=float(f * lvc), nlp_status=res.status,
                    nlp_s=float(res.d[tr.i_s]), s_star=float(r.s_star),
                    max_abs=float(lam), M1=res.d[tr.i_M1].tolist())

    inputs = dict(design=result.design, gait=gait.cache_key, s_star=result.s_star)
    done = {f: run.unit("trade-off", dict(inputs, fraction=float(f)), lambda f=f: point(f))
            for f in run.order(fractions)}
    return [done[f] for f in fractions]


def _problem(tr, red) -> dict:
    """What defines a reduced NLP beyond its start and bounds (the key of a solve unit)."""
    f = lambda v: [float(x) for x in np.ravel(v)]            # noqa: E731
    return dict(gait=tr.gait.cache_key, directions=f(tr.dirs), steps=tr.S, free=tr.free,
                den=[float(tr.den_sign), float(tr.den_scale)], scales=f(red.scales),
                scenario_steps=f(red.steps), tols=f(red.tols), tol_from=f(red.tol_from),
                weights=f(red.weights), s_weight=float(red.s_weight),
                jury=None if red.jury is None else float(red.jury[1]))
