"""The co-design's method, phase by phase (the package docstring): the starts, the
scenario exchange, the rejoin choice, the trust-region gait steps, the verification.

Each phase is a function of a :class:`Method` (the settings and the records the phases
share) that submits the phase's units (:mod:`.units`, :mod:`.problem`) to an engine and
decides from their results; independent units (the starts' screens, the rejoin choices,
the parts of the verification) run side by side.  Candidates are :class:`Candidate` s.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design
from biped_casadi.simulation import NOT_CONVERGED
from gait_opt import GaitOptions, gait_fields, optimize_gait

from ...robustness.basin import basin
from ...robustness.s_star import kept_directions, robustness, steps_short
from ..verification import finish_check, hidden_sign_patterns, submit_check
from .functions import TranscriptionSettings
from .gait_move import gait_change, move_gait
from .problem import Problem, Solve, solve, solve_continued
from .settings import CodesignResult, CodesignSettings, NoDesign
from .screen import fitted_starts
from .starts import deadbeat_starts, failure_binds
from .units import (fixed_problem, gait_step, hardest, kept_first, measure, node_kernel,
                    own_orbit, paper_first, sampled_starts, screen, vc_radius)

#: the gait options a given gait is moved to (the others stay the given gait's)
MOVED = ("impact_mu", "clearance", "continuation", "continuation_shape")

__all__ = ["Candidate", "Method"]


def _elevated(alpha: np.ndarray, degree: int) -> np.ndarray:
    """Bezier coefficients (rows: joints) raised to ``degree`` (the same polynomials)."""
    a = np.asarray(alpha, float)
    while a.shape[1] - 1 < degree:
        n1 = a.shape[1]                       # the new degree
        w = np.arange(n1 + 1) / n1
        a = np.c_[np.zeros((a.shape[0], 1)), a] * w + np.c_[a, np.zeros((a.shape[0], 1))] * (
            1 - w)
    return a


def _alpha_change(a0, a1) -> float:
    """The largest change of a Bezier coefficient between two gaits, rad (the lower
    degree raised to the higher: an imported gait's degree may differ from the
    co-design's)."""
    n = max(np.shape(a0)[1], np.shape(a1)[1]) - 1
    return float(np.max(np.abs(_elevated(a1, n) - _elevated(a0, n))))


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


def _score(r, by: int = 4, fit: bool = False) -> tuple:
    """(the paper's perturbation converged by step ``by``, s*); with starts that fit the
    gait (a gait the target may be far from): (the target met, s* >= 1, then the sooner
    the paper's perturbation converges, s*, converged by ``by``)."""
    conv = r.paper.get("steps_to_converge", math.inf) if r.paper else math.inf
    conv = math.inf if conv is None or not conv == conv else conv
    if fit:
        far = r.s_star >= 1.0
        return (bool(conv <= by and far), far, -conv if far else 0.0, float(r.s_star),
                bool(conv <= by))
    return (bool(conv <= by), float(r.s_star))


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
    start_gait : Gait, optional
        A given gait to move to the robust gait constraints and co-design from (gait
        free).
    stop_below : float, optional
        With starts that fit the gait: end with :class:`NoDesign` when the start
        screen's best s* is below this (the gait is not worth the solves); at 1 or
        more, also when the paper's perturbation converges from no stable start (the
        target is out of reach: the starts are not bisected).
    """

    engine: object
    model: object
    st: CodesignSettings
    fixed_gait: object = None
    start_gait: object = None
    stop_below: float | None = None
    rounds: list = field(default_factory=list)
    solves: list = field(default_factory=list)

    def __post_init__(self):
        # the robot's defaults filled in (recorded with the result's settings)
        self.st = st = self.st.for_model(self.model)
        # legs without knees: the gait's own rows (a swing foot above the ground) do not
        # hold, so a given gait stays fixed (moved by nothing)
        self.free = st.free_gait and self.fixed_gait is None and not (
            self.start_gait is not None and self.model.scuffing_ignored)
        self.screen, self.moved, self.vc_ref = None, None, None
        #: the drawn starts (without starts that fit the gait): how many, in which box,
        #: how many stable within the eigenvalue bound, the bound
        self.sampled = {}
        self.rs = st.robustness_settings()
        # the verification's limit, or the robot's own: each joint's where they differ
        tl = st.verification.torque_limit
        tl = self.model.description.torque_bound if tl is None else tl
        self.tst = TranscriptionSettings(
            mu=st.verification.mu, torque_limit=tl if isinstance(tl, tuple) else float(tl),
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
                         score=_score(r, self.st.converge_by, self.st.starts.fit_gait),
                         ok=bool(ok), failure=r.failure, solve=res)

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

    def meets_target(self, c: Candidate) -> bool:
        """Whether a candidate meets the target by the walker's measures (s* >= 1, the
        paper's perturbation converged by ``converge_by``, max|lambda| within virtual
        constraints')."""
        return bool(c.ok and c.score[0] and c.s_star >= 1.0 and c.score[-1])

    # ----------------------------------------------------------- phases
    def setup(self):
        """The start gait, its kept directions and the starting M1 (with starts that fit
        the gait: (M1, its screened s*) pairs).

        A given gait to move (``start_gait``) is moved with each effort weight of
        ``settings.move.efforts`` in turn (the first is nearest the given gait; the next
        move is computed beside each screen) until
        the start screen on the moved gait finds a start that meets the target; the
        moved gait whose screen is best is kept."""
        st = self.st
        # the compiled nodes of the solves, built beside the setup (not waited for here)
        self.engine.submit(node_kernel, self.model, 0)
        if self.fixed_gait is not None:
            self.gait0 = self.fixed_gait
            self.say("gait given: M1 only (the gait is fixed)")
            return self._starts()
        if self.start_gait is None:
            self.say(f"start gait {st.gait}")
            opts = GaitOptions(**gait_fields(st.gait, self.model)).for_model(self.model)
            if self.free:
                self.engine.submit(node_kernel, self.model,
                                   self.model.nu * (opts.bezier_degree + 1) + 3)
            self.gait0 = self.run(optimize_gait, self.model, opts)
            return self._starts()
        g = self.start_gait
        if self.free and st.gait_rounds:
            self.engine.submit(node_kernel, self.model,
                               self.model.nu * (g.options.bezier_degree + 1) + 3)
        targets = {k: v for k, v in gait_fields(st.gait, self.model).items() if k in MOVED}
        self.say(f"gait given: moved to the robust gait constraints {targets} near it, "
                 "then co-designed from there")
        tried, last_error = [], None
        efforts = list(st.move.efforts)
        moves = [self.engine.submit(move_gait, g, targets, dataclasses.replace(
            st.move, effort=float(e)), self.tst) for e in efforts[:1]]
        for i, effort in enumerate(efforts):
            self.moved = moves[i].result()
            if i + 1 < len(efforts):
                # the next move runs beside this one's start screen, after the screen's
                # tasks (a lower priority: it fills a worker the screen leaves idle; one
                # ahead only: at most one move is computed in vain)
                name, prio = self.engine.current_stage()
                with self.engine.stage(name, prio - 1):
                    moves.append(self.engine.submit(move_gait, g, targets, dataclasses.replace(
                        st.move, effort=float(efforts[i + 1])), self.tst))
            self.say(f"  effort weight {effort:g}: " + self.moved.message)
            if self.moved.status == "kept" and tried:
                continue                   # nothing new to screen
            self.gait0 = self.moved.gait
            try:
                starts = self._starts(raise_below=False)
            except NoDesign as e:
                last_error = e
                continue
            state = (self.gait0, self.moved, self.kept0, self.vc_ref, self.screen, starts)
            b = self.screen.best
            rank = (self.screen.status == "walks" and b.get("s_star", 0.0) >= 1.0
                    and (b.get("paper_converged_from") or np.inf) <= st.converge_by,
                    float(b.get("s_star", 0.0)))
            tried.append((rank, state))
            if rank[0]:
                break
        if not tried:
            raise last_error
        rank, state = max(tried, key=lambda t: t[0])
        self.gait0, self.moved, self.kept0, self.vc_ref, self.screen, starts = state
        if len(tried) > 1:
            self.say(f"  kept the gait moved with effort weight "
                     f"{self.moved.steps[-1].get('effort', 0):g} (its start screen is best)")
        if self.screen.status == "none":
            raise NoDesign(self.no_design_line(), self.no_design_details())
        return starts

    def _starts(self, raise_below: bool = True):
        """The kept directions of ``gait0`` and the starting M1 on it."""
        st = self.st
        fit = st.starts.fit_gait
        dead = (self.engine.submit(deadbeat_starts, self.gait0)
                if fit and st.starts.deadbeat else None)
        self.kept0 = self.run(kept_directions, self.gait0, self.rs)
        if len(self.kept0) == 0:
            orbit = self.run(own_orbit, self.gait0, self.rs)
            raise NoDesign("codesign: virtual constraints walk from no perturbation "
                           "direction on this gait at full scale (every candidate fails: "
                           + ", ".join(f"{k} {v}" for k, v in self.kept0.rejected.items())
                           + ")" + (f", nor from its own orbit ({orbit})" if orbit else "")
                           + "; the protocol's s* is undefined there: try another gait",
                           dict(directions_rejected=dict(self.kept0.rejected),
                                own_orbit=orbit))
        bound = st.eigen_margin * self.run(vc_radius, self.gait0)
        if not fit:
            M, n_ok = self.run(sampled_starts, self.gait0, self.kept0, self.rejoin, st.starts,
                               bound, self.rs)
            self.sampled = dict(samples=st.starts.samples, box=st.starts.box, stable=n_ok,
                                bound=bound)
            return [np.asarray(m, float) for m in M] + [np.asarray(m, float)
                                                        for m in st.starts.extra]
        self.vc_ref = self.engine.submit(robustness, Design.vc(self.gait0), self.rs,
                                         self.kept0)
        extra = np.vstack([dead.result().reshape(-1, self.model.nu) if dead is not None
                           else np.zeros((0, self.model.nu))]
                          + [np.asarray(m, float).reshape(1, -1) for m in st.starts.extra])
        self.screen = fitted_starts(self.engine, self.gait0, self.kept0, self.rejoin,
                                    st.starts, bound, self.rs, extra,
                                    converge_by=st.converge_by,
                                    target_only=raise_below and self.stop_below is not None
                                    and self.stop_below >= 1.0)
        self.say(f"start screen: {self.screen.stable} of {self.screen.candidates} starts "
                 f"stable within max|lambda| {bound:.3g}; {self.screen.message}")
        if raise_below and (self.screen.status == "none" or (
                self.stop_below is not None
                and float(self.screen.best.get("s_star", 0.0)) < self.stop_below)):
            raise NoDesign(self.no_design_line(), self.no_design_details())
        return list(zip(self.screen.starts, self.screen.s_star))

    # ------------------------------------------------------------ no design
    def no_design_details(self) -> dict:
        """What :meth:`no_design_line` says, as values."""
        out = dict(given_gait="fixed" if self.fixed_gait is not None else "free")
        if self.screen is not None:
            out["start_screen"] = self.screen.to_dict()
        if self.vc_ref is not None:
            out["vc_s_star"] = float(self.vc_ref.result().s_star)
        if self.moved is not None:
            out["gait_move"] = self.moved.to_dict()
        return out

    def no_design_line(self, best=None) -> str:
        """Why there is no design, in one line: the start screen's best scale and the
        constraint that stops it, beside virtual constraints' s*."""
        where = ("on the gait as given" if self.fixed_gait is not None else
                 f"on the gait moved toward the robust gait constraints "
                 f"({self.moved.status}: joints moved by at most "
                 f"{self.moved.change.get('max_joint_change', 0.0):.3g} rad)"
                 if self.moved is not None else "on the start gait")
        sc = self.screen
        if sc is None:
            return f"no design {where}: no start gave a verified design"
        b = sc.best
        if sc.status == "none" and "M1" not in b:
            text = f"no design {where}: {b.get('binds')} ({sc.candidates} starts tried)"
        else:
            s_best = b["s_star"] if best is None else max(best, b["s_star"])
            text = (f"no design {where}: the start screen's best scale is s* {s_best:.3g} "
                    f"({b.get('source')} M1 {np.round(b['M1'], 3).tolist()}), stopped by "
                    f"{b.get('binds')}" + (f" in step {b['step']}" if "step" in b and
                                           b.get("status") != NOT_CONVERGED else ""))
        if self.vc_ref is not None:
            vc = self.vc_ref.result()
            text += (f"; virtual constraints reach s* {vc.s_star:.3g}"
                     + same_steps(vc.max_abs, self.rs))
        return text

    def screen_starts(self, starts) -> Candidate | None:
        """Every start screened by a short solve (side by side); the two best by the
        NLP's s are measured and the first acceptable one is the candidate."""
        st, g, kept = self.st, self.gait0, self.kept0
        ps = dict(self.problem_settings(self.rejoin, g), s_start=st.starts.s_start,
                  initial_active=st.initial_active)
        fit = st.starts.fit_gait
        first = None
        if fit:            # (M1, screened s*): each solved from its own scale
            # the screen's best start, measured as every candidate: when it meets the
            # target already, the solves are not needed
            M1, s0 = np.asarray(starts[0][0], float), float(starts[0][1])
            plain = Solve(d=np.r_[M1, self.rejoin, s0], lam_g=np.zeros(0), status="screened",
                          success=True, M1=M1, s=s0, gait_vector=None)
            first = self.candidate(g, kept, plain, [], "screened start", self.rejoin)
            if self.meets_target(first):
                # one short solve from it (the directions that fail first at its s*):
                # the better of the two by the target's measures
                active = self.run(hardest, g, kept, M1, self.rejoin, max(s0, 0.1),
                                  st.initial_active, self.rs)
                c = self.finish_round(self.solve_round(
                    g, kept, M1, active, max(first.s_star - 0.02, 0.1), "from the screened "
                    "start", self.rejoin, screen_budget=True), kept, "from the screened start")
                return c if c is not None and c.ok and c.score > first.score else first
            pss = [dict(ps, s_start=float(max(s0, 0.1))) for _, s0 in starts]
            starts = [M1 for M1, _ in starts]
        else:
            pss = [ps] * len(starts)
        refs = [self.engine.submit(screen, g, kept, M1, p, st.screen, self.rs)
                for M1, p in zip(starts, pss)]
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
        if fit:
            best = first if first.ok else None
            for (_, u), m in zip(top, ms):
                c = self.candidate(g, kept, u.solve, u.active, "best start", self.rejoin, m)
                if c.ok and (best is None or c.score > best.score):
                    best = c
            return best
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
        if not st.steps_after_target and self.meets_target(best):
            self.say("the design meets the target: the gait stays where it is")
            return best
        gait, kept, M1 = best.gait, best.kept, best.M1
        dirs = list(paper_first(kept, best.active))
        if len(dirs) == 1:
            dirs += [kept.directions[i] for i in self.run(
                hardest, gait, kept, M1, self.rejoin, best.s_star, st.initial_active, self.rs)]
        trust = 1.0
        for rnd in range(st.gait_rounds):
            if rnd and not st.steps_after_target and self.meets_target(best):
                break
            res, p = self._gait_solve(gait, kept, dirs, M1, best.s_star, trust, rnd)
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

    def _gait_solve(self, gait, kept, dirs, M1, s_star, trust, rnd):
        st = self.st
        # max|lambda| is not exact in the free-gait NLP: the Jury bound on the current
        # gait's A^z(M1), tighter, keeps M1 from raising it while the gait moves
        p = Problem(gait=gait, directions=np.array(dirs), steps=st.steps, free=True,
                    transcription=self.tst, scenario_tol=st.scenario_tol,
                    paper_tol=st.paper_tol, rejoin=self.rejoin,
                    M1=tuple(float(v) for v in M1), s0=max(s_star - 0.02, 0.1),
                    jury_bound=st.gait_eigen_margin * self.run(vc_radius, gait),
                    trust=(trust * st.trust.alpha, trust * st.trust.T, trust * st.trust.x0),
                    fallback_first=kept_first(kept))
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
        score = _score(r, st.converge_by, st.starts.fit_gait)
        full = len(kept_new) == st.verification.directions
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
        vc_ref = (self.vc_ref if self.vc_ref is not None and best.gait is self.gait0 else
                  eng.submit(robustness, Design.vc(best.gait), self.rs, best.kept)
                  if st.starts.fit_gait else None)
        bas = eng.submit(basin, design) if st.verification.basin else None
        check = finish_check(eng, design, best.kept, rs10, refs)
        by = st.converge_by
        met = bool(check.s_star >= 1 and check.max_abs <= check.vc_eigenvalue
                   and check.steps_to_converge is not None and check.steps_to_converge <= by)
        msg = (f"co-design ({'gait free' if self.free else 'gait fixed'}): " + check.message
               + ("" if met else "; target (s* >= 1, max|lambda| <= virtual constraints, "
                  f"converged by step {by}) not met"))
        g = best.gait
        g0 = self.start_gait if self.start_gait is not None else self.gait0
        change = dict(T_start=g0.T, T=g.T, max_alpha_change=_alpha_change(g0.alpha,
                                                                            g.alpha))
        if self.start_gait is not None:
            change.update(from_given=gait_change(g0, g))
        last = self.solves[-1] if self.solves else dict(status="not run")
        b = bas.result() if bas is not None else None
        vc_s = float(vc_ref.result().s_star) if vc_ref is not None else float("nan")
        fail = getattr(check.robustness, "failure", None) or {}
        stop = (failure_binds(design, best.kept.directions[fail["direction"]], check.s_fail,
                              rs10) if fail and st.starts.fit_gait else {})
        if vc_ref is not None:
            msg += f"; virtual constraints' s* {vc_s:.4g}" + same_steps(check.vc_eigenvalue,
                                                                       rs10)
        return CodesignResult(
            status="target_met" if met else "target_not_met", message=msg, design=design,
            check=check, gait_free=self.free, gait_change=change,
            hidden=hidden.result().to_dict() if hidden is not None else {},
            basin={} if b is None else dict(converged_fraction=float(b.converged_fraction),
                                            message=b.message),
            nlp_s=best.nlp_s, active_constraints=best.solve.active,
            ipopt=dict(status=last["status"],
                       iterations=int(sum(s["iterations"] for s in self.solves)),
                       evaluations=int(sum(s["evaluations"] for s in self.solves)),
                       solves=self.solves),
            rounds=self.rounds, directions_kept=len(best.kept),
            directions_tried=best.kept.tried, settings=st.to_dict(), vc_s_star=vc_s,
            given_gait=("fixed" if self.fixed_gait is not None else
                        "free" if self.start_gait is not None else ""),
            start_screen=self.screen.to_dict() if self.screen is not None else {},
            binds=stop,
            gait_move=self.moved.to_dict() if self.moved is not None else {})


def same_steps(eigenvalue, rs) -> str:
    """' over the same N steps' after virtual constraints' s* when the protocol's N steps
    are fewer than their rate needs (:func:`~analysis.robustness.steps_short`: then it
    measures how fast they converge, often 0), else ''."""
    return "" if steps_short(eigenvalue, rs) is None else f" over the same {rs.steps} steps"
