"""A robust time-varying design: the largest s* (:mod:`analysis.robustness.s_star`) subject to
max|lambda(A^z)| <= the virtual-constraint eigenvalue on the same gait (so the design
also converges faster than virtual constraints, near the orbit).

The levers, each measured (see the closing notes of the toolkit and
``notebooks/05_robust_walking.ipynb``): the outputs M1; the time at which v_c rejoins
the reference (the paper: T/2; later is better, up to the Poincaré section); the output
gains (no effect: the closed loop is its zero dynamics); and the gait itself (a
smaller design bound on the impact impulse ratio, the reference continued past T
without the Bezier polynomials' growth).

Search (sampling, then local refinement; a scenario NLP was not used: s* is a
bisection over a discrete pass/fail verdict, and a smooth surrogate of it, tried first,
led local optimisers into unstable designs):

1. the gait of ``gait`` options (cached on disk), its virtual-constraint eigenvalue and
   the kept perturbation directions (virtual constraints walk from them);
2. ``samples`` random M1 in [-box, box]^nu, screened by max|lambda| (variational A^z,
   well under a millisecond each) against the bound;
3. the survivors walked from the paper's perturbation at ``screen_scale``, then from
   every kept direction at that scale (zero-dynamics walker, batched);
4. s* of the survivors by batched bisection;
5. compass search on s* from the ``starts`` best: the 2 nu neighbours M1 +- step e_i of
   a poll walked in one batch, the step halved when none improves;
6. the best design re-measured (finer integration, more bisection rounds) and verified by
   the full-order simulator at s* (every direction walks) and just above (one fails).

The result is cached (the settings, the robot and the code define the key), so a
re-run is instant.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from biped_casadi.caching import ResultStore, task_key
from biped_casadi.files import write_text_atomic
from biped_casadi.control.output_law import check_rejoin
from biped_casadi.numerics import as_number
from biped_casadi.results import Result
from gait_opt import GaitOptions, LegScaled, gait_fields, optimize_gait
from gait_opt.cache import cache_path

from ..stability.poincare import poincare_map
from biped_casadi.simulation import failure_text, start_states

from ..robustness.s_star import Design, RobustnessSettings, kept_directions, s_star_batch
from ..stability.vc_map import vc_eigenvalue
from biped_casadi.simulation import zero_dynamics_walker
from .settings_checks import check_fields, check_gait_fields
from .verification import verify_design

__all__ = ["RobustDesignSettings", "RobustDesignResult", "robust_design", "ROBUST_GAIT",
           "robust_gait"]

#: the gait options of the robust design: the impact impulse kept to a ratio of 0.15
#: (the path friction stays mu = 0.6), the reference continued past T by an
#: acceleration ramp over 0.03 T, a 5 cm swing clearance.  Measured with the default
#: search (s*, 16 directions): impact_mu 0.2 -> 0.945, 0.15 -> 0.969, 0.1 -> 0.875;
#: clearance 0.1 m -> 0.926 (0.945 with impact_mu 0.15).  On RABBIT's legs (0.8 m): the
#: settings' default gait is :func:`robust_gait`, its clearance scaled with the leg length
ROBUST_GAIT = dict(impact_mu=0.15, continuation=0.03, clearance=0.05)


def robust_gait() -> LegScaled:
    """The settings' default gait fields: :data:`ROBUST_GAIT`, scaled to the robot.

    Its clearance scales with the robot's leg length when the gait is built (0.0625 x
    leg; RABBIT exactly 0.05 m).

    Returns
    -------
    LegScaled
    """
    return LegScaled(ROBUST_GAIT)

#: the version of the robust designs kept between sessions (bump it when the search's
#: results for the same settings and code change)
DESIGNS_VERSION = 3


@dataclass(frozen=True)
class RobustDesignSettings:
    """The search of :func:`robust_design` (module docstring); all have defaults.

    Parameters
    ----------
    gait : dict
        GaitOptions fields of the gait to design on (default :func:`robust_gait`:
        :data:`ROBUST_GAIT` with its clearance scaled with the leg length; a plain dict is
        used as given).
    rejoin : float
        Rejoin time of v_c, fraction of T.
    samples : int
        Random M1 drawn.
    box : float
        M1 components drawn in [-box, box].
    seed : int
        Seed of the samples.
    eigen_bound : str or float
        'vc': max ``|lambda|`` <= the virtual-constraint eigenvalue on the gait; a
        number: that bound (enforced by the compass search and on the result).
    screen_eigen : float
        The samples kept as possible starts have max ``|lambda|`` below this (looser
        than the bound: the compass search brings a start under the bound).
    screen_scale : float
        Scale of the screening walks.
    starts : int
        Compass searches, from the best bisected samples.
    step, min_step : float
        First and last step of the compass search (in units of M1).
    max_polls : int
        Polls per compass search.
    search_rk4_steps : int
        RK4 steps per T of the walker during the search (the final s* uses the
        robustness settings' own).
    mu, torque_limit, directions, steps, tol : as :class:`RobustnessSettings`
        Friction coefficient, torque bound (N m, None: the robot's own, each joint's),
        kept directions, steps walked and convergence threshold of every robustness run.
    """

    gait: dict = field(default_factory=robust_gait)
    rejoin: float = 0.75
    samples: int = 40000
    box: float = 12.0
    seed: int = 0
    eigen_bound: str | float = "vc"
    screen_eigen: float = 0.9
    screen_scale: float = 0.5
    starts: int = 3
    step: float = 0.5
    min_step: float = 0.0625
    max_polls: int = 30
    search_rk4_steps: int = 200
    mu: float = 0.6
    torque_limit: float | None = None
    directions: int = 16
    steps: int = 10
    tol: float = 1e-3

    def __post_init__(self):
        check_gait_fields(self.gait)
        object.__setattr__(self, "rejoin", check_rejoin(self.rejoin))
        check_fields(self, ("samples", "starts", "max_polls", "directions", "steps"),
                     ("box", "screen_eigen", "screen_scale", "step", "min_step", "mu",
                      "torque_limit", "tol"))
        check_fields(self, ("seed",), low=0)
        check_fields(self, ("search_rk4_steps",), low=8)
        if self.eigen_bound != "vc":
            object.__setattr__(self, "eigen_bound", as_number(
                self.eigen_bound, "eigen_bound (a number, or 'vc')", positive=True))

    def robustness_settings(self, rk4_steps: int = 400, rounds: int = 10) -> RobustnessSettings:
        """The matching robustness settings, with the given integration and rounds.

        Parameters
        ----------
        rk4_steps : int
            RK4 steps per T of the zero-dynamics walker.
        rounds : int
            Bisection rounds.

        Returns
        -------
        RobustnessSettings
            With ``directions``, ``steps``, ``tol``, ``mu`` and ``torque_limit`` of these
            settings, the other fields at their defaults.
        """
        return RobustnessSettings(directions=self.directions, steps=self.steps, tol=self.tol,
                                  mu=self.mu, torque_limit=self.torque_limit,
                                  rk4_steps=rk4_steps, rounds=rounds)

    def for_model(self, model) -> "RobustDesignSettings":
        """These settings with the gait fields as used on the robot.

        A :class:`~gait_opt.LegScaled` gait (the default) becomes the plain fields with
        its clearance scaled with the leg length (:func:`gait_opt.gait_fields`), so that
        the settings the result records, and its cache key, hold the clearance the
        search used; RABBIT's are :data:`ROBUST_GAIT`'s numbers exactly (same key).  A
        plain dict is used as given.

        Parameters
        ----------
        model : BipedModel
            The robot searched on.

        Returns
        -------
        RobustDesignSettings
        """
        if not isinstance(self.gait, LegScaled):
            return self
        return replace(self, gait=gait_fields(self.gait, model))

    def to_dict(self) -> dict:
        """The settings as a dictionary (the search's part of the cache key).

        Returns
        -------
        dict
            Field name -> value, ``gait`` as a copy of its dictionary.
        """
        return asdict(self)


@dataclass
class RobustDesignResult(Result):
    """The robust design and how it was found.

    ``success`` means the search finished; whether the targets are met is ``status``.

    Parameters
    ----------
    status : str
        'target_met' (s* >= 1, max ``|lambda|`` <= the VC eigenvalue, converged by step
        4) or 'target_not_met'.
    message : str
        The result in words.
    design : dict
        ``M1`` (list of float) and ``rejoin`` (fraction of T).
    gait_options : dict
        The GaitOptions of the gait designed on.
    gait_file : str
        The cached gait's file.
    s_star : float
        As :class:`~analysis.robustness.s_star.RobustnessResult` (bisection on the walker, 10
        rounds).
    s_fail : float
        As :class:`~analysis.robustness.s_star.RobustnessResult`.
    failure : str
        The failure at ``s_fail`` (status, step and direction) in words; '' when none.
    verified : dict
        The full-order simulator's runs at s* (all directions must walk) and at
        s_fail: 'at_s_star' and 'at_s_fail' -> scale, outcome per direction and number
        passed.
    max_abs : float
        max ``|lambda|`` of A^z for this rejoin time (full AD).
    vc_eigenvalue : float
        The virtual-constraint eigenvalue on the gait.
    steps_to_converge : float or None
        The paper's perturbation at s = 1, full order: the step from which the error
        stays below ``tol``; None when that run failed or never converged.
    paper_errors : list of float
        ``max(|q_u err|, |dq_u err|)`` at every step of that run.
    directions_kept : int
        Perturbation directions used.
    directions_tried : int
        Candidate directions tried to keep them.
    tradeoff : list
        The (max ``|lambda|``, s*) Pareto front of every design bisected, as pairs.
    simulate_args : list of str
        The ``biped simulate`` arguments that replay the design from the paper's
        perturbation.
    stages : dict
        What each stage did and how long it took (s).
    elapsed : float
        Wall time of the search, s.
    settings : dict
        :meth:`RobustDesignSettings.to_dict` of the search.
    cached : bool
        Whether the result was read from the cache.
    """

    status: str
    message: str
    design: dict
    gait_options: dict
    gait_file: str
    s_star: float
    s_fail: float
    failure: str
    verified: dict
    max_abs: float
    vc_eigenvalue: float
    steps_to_converge: float | None
    paper_errors: list
    directions_kept: int
    directions_tried: int
    tradeoff: list
    simulate_args: list
    stages: dict
    elapsed: float
    settings: dict
    cached: bool = False

    SUCCESS = ("target_met", "target_not_met")


def _pareto(lam, s):
    """(max|lambda|, s*) pairs not dominated (lower eigenvalue and higher s* is better)."""
    order = np.lexsort((-s, lam))
    front, best = [], -np.inf
    for i in order:
        if s[i] > best:
            front.append([float(lam[i]), float(s[i])])
            best = s[i]
    return front


class _Search:
    """The stages of the search, with the state they share."""

    def __init__(self, model, st: RobustDesignSettings, progress, scheduler=None):
        self.model, self.st, self.scheduler = model, st, scheduler
        self.say = progress or (lambda msg: None)
        self.stages, self.t0 = {}, time.perf_counter()
        self.seen_lam, self.seen_s = [], []

    def stage(self, name, **info):
        now = time.perf_counter()
        self.stages[name] = dict(info, time=round(now - self._last, 2))
        self._last = now

    def setup(self):
        st, m = self.st, self.model
        self._last = time.perf_counter()
        self.say(f"gait {st.gait} (optimised once, then cached)")
        self.options = GaitOptions(**gait_fields(st.gait, m)).with_lengths(m)
        self.gait = optimize_gait(m, self.options, cache=True)
        self.lam_vc = vc_eigenvalue(self.gait).eigenvalue
        self.bound = self.lam_vc if st.eigen_bound == "vc" else float(st.eigen_bound)
        self.stage("gait", T=self.gait.T, vc_eigenvalue=self.lam_vc, bound=self.bound)
        self.say("kept perturbation directions (virtual constraints walk from them)")
        self.rs = st.robustness_settings(rk4_steps=st.search_rk4_steps, rounds=7)
        self.kept = kept_directions(self.gait, self.rs)
        self.dirs = self.kept.directions
        self.stage("directions", kept=len(self.dirs), tried=self.kept.tried)
        self.walker = zero_dynamics_walker(self.gait, self.rs.simulation_options(),
                                           st.search_rk4_steps, jit=True)
        self.pm = poincare_map(self.gait, rejoin=st.rejoin)

    def designs(self, M):
        return [Design(tuple(x), self.st.rejoin) for x in np.atleast_2d(M)]

    def sample(self):
        st, nu = self.st, self.model.nu
        rng = np.random.default_rng(st.seed)
        M = rng.uniform(-st.box, st.box, (st.samples, nu))
        self.say(f"{st.samples} random M1: max|lambda| of A^z (kept below {st.screen_eigen:g})")
        jb = self.pm.jacobian_batch(M)
        status, lam = jb.status, jb.max_abs
        ok = (status == "stable") & (lam < st.screen_eigen)
        M, lam = M[ok], lam[ok]
        self.stage("eigenvalue screen", sampled=st.samples, kept=int(ok.sum()))
        for name, dirs in (("paper direction", self.dirs[:1]), ("all directions", self.dirs)):
            if not len(M):
                break
            self.say(f"screen: {len(M)} designs walked from the {name} at s = {st.screen_scale}")
            keep = np.zeros(len(M), bool)
            for a in range(0, len(M), 256 // len(dirs) or 1):
                part = slice(a, a + (256 // len(dirs) or 1))
                Mp = M[part]
                q0, dq0 = start_states(self.gait, np.tile(dirs, (len(Mp), 1)),
                                       np.full(len(Mp) * len(dirs), st.screen_scale))
                B = self.walker.walk(q0, dq0, np.repeat(Mp, len(dirs), axis=0), st.rejoin,
                                     steps=st.steps)
                err = B.final_error.reshape(len(Mp), len(dirs))
                good = (B.status == "ok").reshape(len(Mp), len(dirs)) & (err < st.tol)
                keep[part] = good.all(axis=1)
            M, lam = M[keep], lam[keep]
            self.stage(f"screen ({name})", kept=len(M))
        self.say(f"s* of the {len(M)} survivors (batched bisection)")
        res = s_star_batch(self.walker, self.gait, self.designs(M), self.dirs, self.rs,
                           scheduler=self.scheduler)
        under = lam <= self.bound
        self.seen_lam += list(lam[under])
        self.seen_s += list(res.s_star[under])
        self.stage("bisection", designs=len(M), best=float(res.s_star.max()) if len(M) else 0.0,
                   scenario_steps=res.scenario_steps)
        return M, res.s_star, res.pass_fraction

    def score(self, M):
        """s* (+ a tie-breaker) of designs; designs over the eigenvalue bound score below 0."""
        M = np.atleast_2d(M)
        jb = self.pm.jacobian_batch(M)
        status, lam = jb.status, jb.max_abs
        score = np.where(np.isfinite(lam), -lam, -1e3)
        ok = (status == "stable") & (lam <= self.bound)
        if ok.any():
            r = s_star_batch(self.walker, self.gait, self.designs(M[ok]), self.dirs, self.rs,
                             rounds=8, scheduler=self.scheduler)
            score[ok] = r.s_star + 1e-3 * r.pass_fraction
            self.seen_lam += list(lam[ok])
            self.seen_s += list(r.s_star)
        return score

    def refine(self, starts):
        st = self.st
        best_x, best_f = None, -np.inf
        for n, x in enumerate(starts, 1):
            fx, step, polls = float(self.score(x)[0]), st.step, 0
            while step >= st.min_step and polls < st.max_polls:
                polls += 1
                E = np.eye(len(x))
                N = np.vstack([x + sgn * step * E[i] for i in range(len(x)) for sgn in (1, -1)])
                f = self.score(N)
                j = int(np.argmax(f))
                if f[j] > fx + 1e-9:
                    x, fx = N[j], float(f[j])
                else:
                    step /= 2
                self.say(f"compass search {n}/{len(starts)}, poll {polls}: s* {max(fx, 0):.4f}, "
                         f"step {step:g}")
            if fx > best_f:
                best_x, best_f = x, fx
        self.stage("compass search", starts=len(starts), best=best_f)
        return best_x

    def verify(self, M1):
        """The final numbers, by the one verification protocol
        (:func:`analysis.design.verification.verify_design`): s* (walker, finer),
        full-order runs at s* and s_fail, the paper's perturbation at s = 1."""
        st = self.st
        check = verify_design(Design.tv(self.gait, tuple(M1), st.rejoin), self.kept,
                              st.robustness_settings(), progress=self.say)
        self.stage("verification", s_star=check.s_star, full_order=check.verified)
        return check


def robust_design(model, settings: RobustDesignSettings | None = None, progress=None,
                  cache=None, use_cache: bool = True, scheduler=None) -> RobustDesignResult:
    """Find the robust time-varying design (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot.
    settings : RobustDesignSettings, optional
        The search (default: all defaults).
    progress : callable, optional
        Called with one line of text per stage.
    cache : str or Path, optional
        Folder of cached results (default :func:`biped_casadi.cache_dir`).
    use_cache : bool
        Read a cached result for the same settings (and write the new one).
    scheduler : str or dask.distributed.Client, optional
        Run the bisections on a Dask cluster's workers (the results are the same).

    Returns
    -------
    RobustDesignResult
        The best design, its s* and how it was found.
    """
    st = (settings or RobustDesignSettings()).for_model(model)
    path = ResultStore(cache).path(task_key("analysis.design.robust_design", DESIGNS_VERSION,
                                            "numerical", (model, st)), ".json")
    if use_cache and path.is_file():
        try:
            d = json.loads(path.read_text())
            d["cached"] = True
            d.pop("success", None)
            return RobustDesignResult(**d)
        except (ValueError, TypeError, OSError):
            pass                                       # damaged: recompute
    search = _Search(model, st, progress, scheduler)
    search.setup()
    M, s, frac = search.sample()
    if len(M) == 0:
        raise ValueError("robust design: no sampled M1 passed the screens; try more samples, "
                         "a larger box or another gait")
    order = np.lexsort((-frac, -s))
    best = search.refine(M[order[:st.starts]])
    if best is None or not search.pm.analyse(best).max_abs <= search.bound:
        raise ValueError("robust design: the compass search found no design within the "
                         "eigenvalue bound; try more samples or starts")
    check = search.verify(best)
    r, verified, conv, errs, max_abs = (check.robustness, check.verified, check.steps_to_converge,
                                        check.paper_errors, check.max_abs)
    met = bool(r.s_star >= 1 and max_abs <= search.lam_vc and conv is not None and conv <= 4)
    design = dict(M1=[float(v) for v in best], rejoin=st.rejoin)
    gait_file = str(cache_path(model, search.options, cache))
    args = (["--gait", gait_file, "--controller", "tv", "--m1"]
            + [repr(float(v)) for v in best]
            + ["--rejoin", repr(st.rejoin), "--perturb", "0.01", "0.1", "--mu", repr(st.mu),
               "--steps", str(st.steps)]
            + ([] if st.torque_limit is None else ["--torque-limit", repr(st.torque_limit)]))
    fail = r.failure
    msg = (f"robust design: s* = {r.s_star:.4g} with max|lambda| = {max_abs:.3g} "
           f"(virtual constraints {search.lam_vc:.3g}); from the paper's perturbation "
           + check.paper_outcome(st.tol)
           + (f"; just above s*: {failure_text(fail['status'], fail['step'])}" if fail else "")
           + ("" if met else "; target (s* >= 1, converged by step 4) not met"))
    result = RobustDesignResult(
        status="target_met" if met else "target_not_met", message=msg, design=design,
        gait_options=search.options.to_dict(), gait_file=gait_file, s_star=r.s_star,
        s_fail=r.s_fail, failure=(f"{failure_text(fail['status'], fail['step'])} (direction "
                                  f"{fail['direction']})" if fail else ""),
        verified=verified, max_abs=max_abs, vc_eigenvalue=search.lam_vc,
        steps_to_converge=conv, paper_errors=errs, directions_kept=len(search.dirs),
        directions_tried=search.kept.tried,
        tradeoff=_pareto(np.array(search.seen_lam), np.array(search.seen_s)),
        simulate_args=args, stages=search.stages,
        elapsed=time.perf_counter() - search.t0, settings=st.to_dict())
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_text_atomic(path, json.dumps(result.to_dict(), indent=1))
        except OSError:
            pass                                      # a read-only cache is not fatal
    return result
