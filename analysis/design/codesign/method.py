"""The co-design's method, phase by phase (the package docstring): the starts, the
scenario exchange, the rejoin choice, the trust-region gait steps, the verification.

Each phase is a function of a :class:`Method` (the settings and the records the phases
share) that submits the phase's units (:mod:`.units`, :mod:`.problem`) to an engine and
decides from their results; independent units (the starts' screens, the rejoin choices,
the parts of the verification) run side by side.  Candidates are :class:`Candidate` s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design
from gait_opt import GaitOptions, optimize_gait

from ...robustness.basin import basin
from ...robustness.s_star import kept_directions
from ..verification import finish_check, hidden_sign_patterns, submit_check
from .functions import TranscriptionSettings
from .problem import Problem, Solve, solve, solve_continued
from .settings import CodesignError, CodesignResult, CodesignSettings
from .units import (fixed_problem, gait_step, hardest, measure, node_kernel, sampled_starts,
                    screen, vc_radius)

__all__ = ["Candidate", "Method"]


@dataclass
class Candidate:
    """A design found by a solve and measured by the walker.

    Parameters
    ----------
    gait : Gait
        Its gait.
    kept : KeptDirections
        The gait's kept directions.
    M1 : numpy.ndarray
        The outputs.
    rejoin : float
        Rejoin time of v_c.
    s_star : float
        The walker's s* over the kept directions.
    nlp_s : float
        The NLP's own s.
    max_abs : float
        max ``|lambda|`` (AD).
    active : list of int
        The kept directions of its NLP besides the paper's.
    score : tuple
        (the paper's perturbation converges by step 4, s*): compared lexicographically.
    ok : bool
        max ``|lambda|`` at most the virtual constraints' and s* > 0.
    failure : dict
        The first failure above s*.
    solve : Solve
        The solve that found it.
    """

    gait: object
    kept: object
    M1: np.ndarray
    rejoin: float
    s_star: float
    nlp_s: float
    max_abs: float
    active: list
    score: tuple
    ok: bool
    failure: dict
    solve: Solve


def _score(r) -> tuple:
    conv = r.paper.get("steps_to_converge", math.inf) if r.paper else math.inf
    return (bool(conv <= 4), float(r.s_star))


@dataclass
class Method:
    """One co-design: its settings, the engine it runs on, and the records of its solves
    and rounds (in the method's order, whichever process computed them).

    Parameters
    ----------
    engine : Engine
        Where the units run.
    model : BipedModel
        The robot.
    st : CodesignSettings
        The settings.
    fixed_gait : Gait, optional
        The gait, when it is not co-designed.
    """

    engine: object
    model: object
    st: CodesignSettings
    fixed_gait: object = None
    rounds: list = field(default_factory=list)
    solves: list = field(default_factory=list)

    def __post_init__(self):
        st = self.st
        self.free = st.free_gait and self.fixed_gait is None
        self.rs = st.robustness_settings()
        tl = st.verification.torque_limit
        self.tst = TranscriptionSettings(
            mu=st.verification.mu, torque_limit=float(tl if tl is not None
                                                      else self.model.params.torque_limit),
            **st.transcription)
        self.rejoin = float(st.rejoin)

    # ----------------------------------------------------------- helpers
    def run(self, fn, *args):
        """A unit's result (submitted and waited for)."""
        return self.engine.submit(fn, *args).result()

    def say(self, msg: str):
        self.engine.say(msg)

    def problem_settings(self, rejoin: float, gait) -> dict:
        """Keyword arguments of :func:`fixed_problem` on ``gait`` at ``rejoin``."""
        st = self.st
        return dict(steps=st.steps, tst=self.tst, scenario_tol=st.scenario_tol,
                    paper_tol=st.paper_tol, rejoin=float(rejoin),
                    jury_bound=st.eigen_margin * self.run(vc_radius, gait))

    def record_solve(self, label: str, res: Solve, scenarios: int):
        for s in res.solves:
            self.solves.append(dict(s, label=label, scenarios=scenarios))

    def candidate(self, gait, kept, res: Solve, active, label: str, rejoin: float,
                  measured=None) -> Candidate:
        """A solve's design verified by the walker, and its record."""
        m = measured.result() if measured is not None else self.run(
            measure, gait, kept, res.M1, rejoin, self.rs)
        r = m.robustness
        self.rounds.append(dict(phase="gait fixed", label=label, nlp_status=res.status,
                                nlp_s=res.s, s_star=r.s_star, failure=r.failure,
                                max_abs=m.max_abs,
                                paper_steps=r.paper.get("steps_to_converge"),
                                scenarios=[0] + list(active), M1=res.M1.tolist()))
        self.say(f"  IPOPT {res.status} ({res.iterations} it): NLP s {res.s:.4g}; verified "
                 f"s* {r.s_star:.4g}, max|lambda| {m.max_abs:.3g}, paper converged from "
                 f"step {r.paper.get('steps_to_converge')}")
        ok = m.max_abs <= self.run(vc_radius, gait) and r.s_star > 0
        return Candidate(gait=gait, kept=kept, M1=res.M1, rejoin=float(rejoin),
                         s_star=r.s_star, nlp_s=res.s, max_abs=m.max_abs, active=list(active),
                         score=_score(r), ok=bool(ok), failure=r.failure, solve=res)

    def solve_round(self, gait, kept, M1, active, s0: float, label: str, rejoin: float,
                    screen_budget: bool = False):
        """Submit one gait-fixed solve (continued to the paper's bound, or on the
        screening budget): (its ref, its problem, its active directions) for
        :meth:`finish_round`."""
        p = fixed_problem(gait, kept, M1, active, s0, **self.problem_settings(rejoin, gait))
        self.say(f"NLP, gait fixed: {p.scenarios} scenarios x {p.steps + 1} steps ({label})")
        ref = (self.engine.submit(solve, p, self.st.screen) if screen_budget else
               self.engine.submit(solve_continued, p, self.st.solve, self.st.paper_steps))
        return ref, p, list(active)

    def finish_round(self, pending, kept, label: str):
        """The candidate of a :meth:`solve_round` (None when it ended on no design)."""
        ref, p, active = pending
        res = ref.result()
        self.record_solve(label, res, p.scenarios)
        if not res.finite:
            return None
        return self.candidate(p.gait, kept, res, active, label, p.rejoin)

    # ----------------------------------------------------------- phases
    def setup(self):
        """The start gait, its kept directions and the starting M1."""
        st = self.st
        # the compiled nodes of the solves, built beside the setup (not waited for here)
        self.engine.submit(node_kernel, self.model, 0)
        if self.fixed_gait is not None:
            self.gait0 = self.fixed_gait
            self.say("gait given: M1 only (the gait is fixed)")
        else:
            self.say(f"start gait {st.gait}")
            opts = GaitOptions(**st.gait).for_model(self.model)
            if self.free:
                self.engine.submit(node_kernel, self.model,
                                   self.model.nu * (opts.bezier_degree + 1) + 3)
            self.gait0 = self.run(optimize_gait, self.model, opts)
        self.kept0 = self.run(kept_directions, self.gait0, self.rs)
        if len(self.kept0) == 0:
            raise CodesignError("codesign: virtual constraints walk from no perturbation "
                                "direction on this gait at full scale; try another gait")
        bound = st.eigen_margin * self.run(vc_radius, self.gait0)
        M, _ = self.run(sampled_starts, self.gait0, self.kept0, self.rejoin, st.starts, bound,
                        self.rs)
        return [np.asarray(m, float) for m in M] + [np.asarray(m, float)
                                                    for m in st.starts.extra]

    def screen_starts(self, starts) -> Candidate | None:
        """Every start screened by a short solve (side by side); the two best by the
        NLP's s are measured and the first acceptable one is the candidate."""
        st, g, kept = self.st, self.gait0, self.kept0
        ps = dict(self.problem_settings(self.rejoin, g), s_start=st.starts.s_start,
                  initial_active=st.initial_active)
        refs = [self.engine.submit(screen, g, kept, M1, ps, st.screen, self.rs) for M1 in starts]
        screened = []
        for i, ref in enumerate(refs):
            u, label = ref.result(), f"start {i + 1} of {len(starts)}"
            res = u.solve
            self.record_solve(label, res, 1 + len(u.active))
            s_nlp = res.s if res.finite else -np.inf
            self.say(f"  {label}: IPOPT {res.status} ({res.iterations} it): NLP s {s_nlp:.4g}")
            self.rounds.append(dict(phase="start", label=label, M1_start=u.M1.tolist(),
                                    nlp_status=res.status, nlp_s=s_nlp, M1=res.M1.tolist()))
            screened.append((res.success, s_nlp, u))
        screened.sort(key=lambda t: (not t[0], -t[1]))       # converged solves first
        top = [(s, u) for _, s, u in screened[:2] if np.isfinite(s)]
        ms = [self.engine.submit(measure, g, kept, u.solve.M1, self.rejoin, self.rs)
              for _, u in top]
        for (_, u), m in zip(top, ms):
            c = self.candidate(g, kept, u.solve, u.active, "best start", self.rejoin, m)
            if c.ok:
                return c
        return None

    def exchange(self, best: Candidate) -> Candidate:
        """Scenario exchange with the gait fixed: the direction that fails just above the
        verified s* joins the scenarios and the NLP is solved again from the last
        design (``exchange_rounds - 1`` rounds)."""
        st, cur = self.st, best
        for rnd in range(1, st.exchange_rounds):
            active = list(cur.active)
            fdir = cur.failure.get("direction") if cur.failure else None
            if fdir is not None and fdir != 0 and fdir not in active \
                    and len(active) < st.max_active:
                active.append(int(fdir))
            elif rnd > 1:
                break                  # nothing new to add: the exchange has converged
            label = f"exchange round {rnd}"
            c = self.finish_round(self.solve_round(
                cur.gait, cur.kept, cur.M1, active, max(min(cur.s_star, cur.nlp_s) - 0.02, 0.1),
                label, cur.rejoin), cur.kept, label)
            if c is None:
                break
            if c.ok:
                cur = c
                if c.score > best.score:
                    best = c
        return best

    def choose_rejoin(self, best: Candidate) -> Candidate:
        """The rejoin time of v_c as a discrete decision: the gait-fixed NLP at each of
        ``rejoin_choices`` from the best design (side by side); the best verified one
        wins (v_c's third derivative jumps at the rejoin time, which makes the walker's
        rule kinked in it)."""
        start = best
        choices = [float(r) for r in self.st.rejoin_choices
                   if abs(r - start.rejoin) >= 1e-12]
        s0 = max(min(start.s_star, start.nlp_s) - 0.1, 0.1)
        pending = [(r, self.solve_round(start.gait, start.kept, start.M1, start.active, s0,
                                        f"rejoin {r:g} T", r, screen_budget=True))
                   for r in choices]
        for r, sub in pending:
            c = self.finish_round(sub, start.kept, f"rejoin {r:g} T")
            if c is not None and c.ok and c.score > best.score:
                best = c
        self.rejoin = float(best.rejoin)
        return best

    def gait_steps(self, best: Candidate) -> Candidate:
        """Gait steps in a trust region around the current gait, each made an exact
        periodic orbit and accepted only when the verified s* improves with max
        ``|lambda|`` at most the virtual constraints' on the new gait."""
        st = self.st
        gait, kept, M1 = best.gait, best.kept, best.M1
        dirs = [kept.directions[i] for i in [0] + list(best.active)]
        if len(dirs) == 1:
            dirs += [kept.directions[i] for i in self.run(
                hardest, gait, kept, M1, self.rejoin, best.s_star, st.initial_active, self.rs)]
        trust = 1.0
        for rnd in range(st.gait_rounds):
            res, p = self._gait_solve(gait, dirs, M1, best.s_star, trust, rnd)
            if not res.finite:
                self.rounds.append(dict(phase="gait free", round=rnd + 1,
                                        nlp_status=res.status, rejected="no solve"))
                trust /= 2
                continue
            rec = dict(phase="gait free", round=rnd + 1, nlp_status=res.status, nlp_s=res.s,
                       scenarios=len(dirs), T=float(res.gait_vector[-3]),
                       trust=trust * st.trust.alpha)
            step = self.run(gait_step, gait, res.gait_vector, res.status)
            if step.gait is None:
                rec.update(rejected=step.rejected)
                self.rounds.append(rec)
                trust /= 2
                continue
            best, gait, kept, M1, trust, r, kept_new = self._judge_step(
                best, step.gait, res, rec, gait, kept, M1, trust, rnd)
            if r.failure:
                d_fail = kept_new.directions[r.failure["direction"]]
                if not any(np.array_equal(d_fail, x) for x in dirs) \
                        and len(dirs) <= st.max_active:
                    dirs.append(d_fail)
        return best

    def _gait_solve(self, gait, dirs, M1, s_star, trust, rnd):
        st = self.st
        # max|lambda| is not exact in the free-gait NLP: the Jury bound on the current
        # gait's A^z(M1), tighter, keeps M1 from raising it while the gait moves
        p = Problem(gait=gait, directions=np.array(dirs), steps=st.steps, free=True,
                    transcription=self.tst, scenario_tol=st.scenario_tol,
                    paper_tol=st.paper_tol, rejoin=self.rejoin,
                    M1=tuple(float(v) for v in M1), s0=max(s_star - 0.02, 0.1),
                    jury_bound=st.gait_eigen_margin * self.run(vc_radius, gait),
                    trust=(trust * st.trust.alpha, trust * st.trust.T, trust * st.trust.x0))
        self.say(f"NLP, gait free: {p.scenarios} scenarios x {st.steps + 1} steps, trust "
                 f"region {trust * st.trust.alpha:g} rad (round {rnd + 1})")
        res = self.run(solve, p, st.gait_step)
        self.record_solve(f"gait free, round {rnd + 1}", res, p.scenarios)
        return res, p

    def _judge_step(self, best, g_new, res, rec, gait, kept, M1, trust, rnd):
        """Accept, repair or reject a gait step (its record in ``rec``)."""
        st = self.st
        kept_new = self.run(kept_directions, g_new, self.rs)
        m = self.run(measure, g_new, kept_new, res.M1, self.rejoin, self.rs)
        r, lam, lvc = m.robustness, m.max_abs, self.run(vc_radius, g_new)
        rec.update(s_star=r.s_star, failure=r.failure, max_abs=lam, vc_eigenvalue=lvc,
                   kept=len(kept_new), M1=res.M1.tolist())
        self.say(f"  IPOPT {res.status} ({res.iterations} it): NLP s {res.s:.4g}; new gait T "
                 f"{g_new.T:.4g} s, verified s* {r.s_star:.4g} over {len(kept_new)} kept "
                 f"directions, max|lambda| {lam:.3g} (VC {lvc:.3g})")
        score, full = _score(r), len(kept_new) == st.verification.directions
        if score > best.score and lam <= lvc and full:
            best = Candidate(gait=g_new, kept=kept_new, M1=res.M1, rejoin=self.rejoin,
                             s_star=r.s_star, nlp_s=res.s, max_abs=lam, active=best.active,
                             score=score, ok=True, failure=r.failure, solve=res)
            gait, kept, M1 = g_new, kept_new, res.M1
            rec.update(accepted=True)
            self.rounds.append(rec)
        elif score > best.score and full and st.repair:
            # the step gained s* but max|lambda| (not in the free-gait NLP) grew past the
            # virtual constraints': M1 alone on the new gait, under the Jury bound
            rec.update(accepted=False, repaired="M1 re-solved on the new gait")
            self.rounds.append(rec)
            active = self.run(hardest, g_new, kept_new, res.M1, self.rejoin, r.s_star,
                              st.initial_active, self.rs)
            label = f"gait round {rnd + 1}: M1 on the new gait"
            c = self.finish_round(self.solve_round(g_new, kept_new, res.M1, active,
                                                   max(r.s_star - 0.02, 0.1), label,
                                                   self.rejoin), kept_new, label)
            if c is not None and c.ok and c.score > best.score:
                best = c
                gait, kept, M1 = g_new, kept_new, c.M1
                self.rounds[-1].update(accepted=True)
            else:
                trust /= 2
        else:
            trust /= 2
            rec.update(accepted=False)
            self.rounds.append(rec)
        return best, gait, kept, M1, trust, r, kept_new

    # ----------------------------------------------------------- the result
    def verify(self, best: Candidate) -> CodesignResult:
        """The result measured by the protocol (its parts side by side) and the hidden
        sign patterns; the targets, the records, the design."""
        st, eng = self.st, self.engine
        design = Design.tv(best.gait, best.M1, best.rejoin)
        self.say("verification (protocol of the robust designs)")
        rs10 = st.robustness_settings(rounds=10)
        refs = submit_check(eng, design, best.kept, rs10)
        hidden = (eng.submit(hidden_sign_patterns, design, best.kept, self.rs)
                  if st.verification.hidden else None)
        bas = eng.submit(basin, design) if st.verification.basin else None
        check = finish_check(eng, design, best.kept, rs10, refs)
        met = bool(check.s_star >= 1 and check.max_abs <= check.vc_eigenvalue
                   and check.steps_to_converge is not None and check.steps_to_converge <= 4)
        msg = (f"co-design ({'gait free' if self.free else 'gait fixed'}): " + check.message
               + ("" if met else "; target (s* >= 1, max|lambda| <= virtual constraints, "
                  "converged by step 4) not met"))
        g = best.gait
        last = self.solves[-1] if self.solves else dict(status="not run")
        b = bas.result() if bas is not None else None
        return CodesignResult(
            status="target_met" if met else "target_not_met", message=msg, design=design,
            check=check, gait_free=self.free,
            gait_change=dict(T_start=self.gait0.T, T=g.T, max_alpha_change=float(
                np.max(np.abs(g.alpha - self.gait0.alpha)))),
            hidden=hidden.result().to_dict() if hidden is not None else {},
            basin={} if b is None else dict(converged_fraction=float(b.converged_fraction),
                                            message=b.message),
            nlp_s=best.nlp_s, active_constraints=best.solve.active,
            ipopt=dict(status=last["status"],
                       iterations=int(sum(s["iterations"] for s in self.solves)),
                       evaluations=int(sum(s["evaluations"] for s in self.solves)),
                       solves=self.solves),
            rounds=self.rounds, directions_kept=len(best.kept),
            directions_tried=best.kept.tried, settings=st.to_dict())

