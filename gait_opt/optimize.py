"""Optimal cyclic reference gait (docs: theory §2): IPOPT on the transcribed problem
(:mod:`gait_opt.transcription`), the exact periodic orbit (:mod:`gait_opt.polish`), and
a check of every path constraint on a dense grid, with the node bounds tightened and
the problem re-solved where a constraint is exceeded between the nodes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import rabbit
from biped_casadi.caching import task
from biped_casadi.model.torque_limits import torque_limit_words
from biped_casadi.results import Result, internal

from .cache import cached_gait
from .errors import GaitOptimizationError
from .gait import Gait
from .gait_checks import clearance_dip
from .options import GaitOptions, require_model
from .polish import polish
from .transcription import (FIXED_BY, MARGINS, _grid, build_problem, constraint_violations,
                            describe_violations, guess_step, initial_guess, make_solver,
                            warm_start_vector)

__all__ = ["optimize_gait", "GaitSolveResult", "GaitOptimizationError",
           "solve_collocation", "CollocationResult"]


def _check_reachable(opts: GaitOptions):
    """The speed constraint x_end = v T with the step-length and step-time bounds."""
    (l_lo, l_hi), (t_lo, t_hi) = opts.step_length_bounds, opts.step_time_bounds
    v_lo, v_hi = l_lo / t_hi, l_hi / t_lo
    if not v_lo <= opts.speed <= v_hi:
        raise GaitOptimizationError(
            f"no feasible gait: speed {opts.speed:g} m/s is out of reach of "
            f"step_length_bounds ({l_lo:g}, {l_hi:g}) m and step_time_bounds ({t_lo:g}, "
            f"{t_hi:g}) s, which allow {v_lo:.3g} to {v_hi:.3g} m/s; violated constraint "
            f"family: speed. IPOPT was not run (status 'not_run'). Try a speed in that "
            f"range or wider bounds.", status="not_run",
            violations=[("speed", float(max(v_lo - opts.speed, opts.speed - v_hi)))])


@dataclass
class CollocationResult:
    """IPOPT's solution of the transcribed problem, before the polish: ``T``, ``alpha``
    (nu x (M+1)), ``Xs`` (2 x (N+1), x at interval starts), ``Xc`` (2 x N d, x at the
    collocation points), ``cost`` (the NLP objective, unscaled), IPOPT's ``status`` and
    ``iterations``, its ``timing`` (seconds per callback), ``build_time``, ``solve_time``."""

    T: float
    alpha: np.ndarray
    Xs: np.ndarray
    Xc: np.ndarray
    cost: float
    status: str
    iterations: int
    timing: dict
    build_time: float
    solve_time: float


def solve_collocation(model, opts: GaitOptions, *, verbose: bool = False,
                      warm_start=None, margins: dict | None = None) -> CollocationResult:
    """Build the NLP (path constraints tightened by ``margins``), run IPOPT from the
    built-in guess (or ``warm_start``, a Gait) and return the raw solution; raises
    :class:`GaitOptimizationError` when IPOPT fails or a constraint family is still
    violated."""
    opts = opts.for_model(model)
    _check_reachable(opts)
    t0 = time.perf_counter()
    prob = build_problem(model, opts, margins)
    solver = make_solver(prob, opts, verbose)
    t_build = time.perf_counter() - t0
    w0 = (initial_guess(model, opts) if warm_start is None
          else warm_start_vector(model, opts, warm_start))
    sol = solver(x0=w0, lbx=prob.lbx, ubx=prob.ubx, lbg=prob.lbg, ubg=prob.ubg)
    stats = solver.stats()
    t_solve = time.perf_counter() - t0 - t_build
    viol = constraint_violations(prob, np.array(sol["g"]).ravel())
    status = stats.get("return_status", "unknown")
    if not stats.get("success", False) or viol:
        raise GaitOptimizationError(
            f"no feasible gait: IPOPT status '{status}' after {stats.get('iter_count', '?')} "
            f"iterations (speed {opts.speed:g} m/s, mu {opts.mu:g}, "
            f"{torque_limit_words(opts.torque_limit)}); violated constraint families at the last iterate: "
            f"{describe_violations(viol)}. Try a lower speed, a larger mu or torque_limit, "
            f"wider step_length_bounds, or more IPOPT iterations (option "
            f"ipopt={{'max_iter': ...}}, --max-iter on the command line).",
            status=status, violations=viol)
    T, alpha, Xs, Xc, _ = (np.array(v) for v in prob.unpack(sol["x"]))
    return CollocationResult(
        T=float(T.item()), alpha=alpha, Xs=Xs, Xc=Xc,
        cost=float(sol["f"]) / prob.cost_scale, status=status,
        iterations=int(stats.get("iter_count", -1)),
        timing={k[7:]: float(v) for k, v in stats.items() if k.startswith("t_wall_")},
        build_time=t_build, solve_time=t_solve)


@dataclass
class GaitSolveResult(Result):
    """Outcome of one solve (what :func:`optimize_gait` returns as a gait or raises).

    ``success`` means IPOPT succeeded, a gait was found and nothing is violated.

    Parameters
    ----------
    status : str
        IPOPT's return status (or 'not_run' when the request is out of reach before
        IPOPT, 'polish_failed' when the exact orbit could not be found).
    message : str
        What happened, in words.
    iterations : int
        IPOPT iterations over every pass.
    total_time : float
        Wall time, s.
    violations : list
        [family, amount] of the constraint families violated on the dense grid (empty
        for a valid gait), worst first.
    refinements : list
        One dict per pass when node bounds were tightened and the problem re-solved
        (empty when one pass sufficed).
    gait : Gait or None
        The polished gait (None when no gait was found); left out of ``to_dict()``.
    """

    status: str
    message: str
    iterations: int
    total_time: float
    violations: list = field(default_factory=list)
    refinements: list = field(default_factory=list)
    gait: Gait | None = internal(default=None)

    SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")

    @property
    def success(self) -> bool:
        """IPOPT succeeded, a gait was found and nothing is violated."""
        return self.status in self.SUCCESS and not self.violations and self.gait is not None


def _options(model, options, overrides) -> GaitOptions:
    opts = options or GaitOptions()
    if not isinstance(opts, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(opts).__name__}")
    return (opts.replace(**overrides) if overrides else opts).for_model(model)


def _margin_family(gait, name: str) -> str:
    """The family of :data:`MARGINS` whose node margin fixes a dense-grid violation.

    The swing foot dipping under its clearance bound before the first constrained point
    or after the last (where foot and bound meet the ground) is fixed by the foot's
    slopes at the step's ends: a margin at the nodes only narrows such a dip.
    """
    family = FIXED_BY.get(name, name)
    if family == "swing-foot clearance":
        s = np.concatenate(_grid(gait.options))
        s = s[(s > 1e-9) & (s < 1 - 1e-9)]
        if not s.min() <= clearance_dip(gait) <= s.max():
            return "swing-foot clearance at the ends"
    return family


def _solve(model, options: GaitOptions | None = None, *, verbose: bool = False,
           warm_start=None, max_refinements: int = 3, **overrides) -> GaitSolveResult:
    """Solve the reference-gait problem (docs: theory, the reference gait).

    The path constraints are imposed at the nodes; the polished gait is then checked on
    a dense grid (``Gait.violations``).  Where an active constraint is exceeded between
    the nodes (torque, normal force, friction, clearance, torso lean), its node bound is
    tightened by twice the excess and the problem solved again from the gait found, at
    most ``max_refinements`` times.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : GaitOptions, optional
        Default: docs: theory §2.
    verbose : bool
        Print IPOPT's iterations.
    warm_start : Gait, optional
        A previous gait of the same Bezier degree to start from.
    max_refinements : int
        Re-solves allowed for constraints exceeded between the nodes.
    **overrides
        Replace single option fields (``optimize_gait(m, speed=1.0)``).

    Returns
    -------
    GaitSolveResult
        With the gait, IPOPT's status and what remains violated.
    """
    opts = _options(model, options, overrides)
    t0 = time.perf_counter()
    guessed = warm_start is None           # the first pass starts from the built-in guess
    margins, passes, best = {}, [], None
    for attempt in range(1 + max_refinements):
        try:
            r = solve_collocation(model, opts, verbose=verbose, warm_start=warm_start,
                                  margins=margins)
            t_p = time.perf_counter()
            alpha_p, x0_p, T_p, hist = polish(model, opts, r.alpha, r.Xs[:, 0], r.T)
        except GaitOptimizationError as e:
            if best is None:
                return GaitSolveResult(status=e.status or "failed", message=str(e),
                                       iterations=0, total_time=time.perf_counter() - t0,
                                       violations=[list(v) for v in e.violations])
            passes.append(dict(margins=dict(margins), failed=str(e)))
            break                   # keep the previous gait and report its violations
        t_polish = time.perf_counter() - t_p
        gait = Gait(model, opts, alpha_p, x0_p, T_p)
        viol = gait.violations()          # the dense grid, between the nodes too
        passes.append(dict(iterations=r.iterations, margins=dict(margins),
                           violations=[list(v) for v in viol]))
        best = (gait, r, viol, hist, t_polish, (alpha_p, x0_p, T_p))
        fixable = [(_margin_family(gait, n), v) for n, v in viol
                   if FIXED_BY.get(n, n) in MARGINS]
        if not fixable or len(fixable) < len(viol) or attempt == max_refinements:
            break
        for n, v in fixable:          # tighten the node bounds by twice the excess
            margins[n] = margins.get(n, 0.0) + 2 * v + 1e-9
        warm_start = gait
    gait, r, viol, hist, t_polish, (alpha_p, x0_p, T_p) = best
    total = time.perf_counter() - t0
    iterations = sum(p.get("iterations", 0) for p in passes)
    gait.solver_stats = dict(
        status=r.status, iterations=iterations,
        build_time=r.build_time, solve_time=r.solve_time, polish_time=t_polish,
        total_time=total, ipopt_timing=r.timing, ipopt_cost=r.cost,
        polish_residuals=hist,
        polish_change=float(np.max(np.abs(np.r_[(alpha_p - r.alpha).ravel(),
                                                x0_p - r.Xs[:, 0], T_p - r.T]))),
        dense_grid_violations=[list(v) for v in viol])
    if guessed:                            # its step, scaled to the robot and speed
        L0, T0 = guess_step(model, opts)
        gait.solver_stats["initial_guess"] = dict(step_length=L0, T=T0)
    if len(passes) > 1:
        gait.solver_stats["refinements"] = passes
    message = ("optimal gait found" if not viol else
               "a gait was found but violates between the nodes: " + describe_violations(viol))
    return GaitSolveResult(status=r.status, message=message, iterations=iterations,
                           total_time=total, violations=[list(v) for v in viol],
                           refinements=passes if len(passes) > 1 else [], gait=gait)


@task
def optimize_gait(model=None, options: GaitOptions | None = None, *, cache: bool = False,
                  cache_dir=None, progress=None, verbose: bool = False, warm_start=None,
                  max_refinements: int = 3, **overrides) -> Gait:
    """The optimal cyclic reference gait of a robot and options: the one gait solve.

    Direct collocation with IPOPT, the exact periodic orbit (the polish), and a check of
    every path constraint on a dense grid, with node bounds tightened and the problem
    re-solved where a constraint is exceeded between the nodes.

    Parameters
    ----------
    model : BipedModel, optional
        The robot (default RABBIT).
    options : GaitOptions, optional
        The problem (default: the default problem, docs: theory).
    cache : bool
        Read the gait from the on-disk cache of solved gaits when it is there (and keep
        a new one there): solved once per machine (:mod:`gait_opt.cache`).
    cache_dir : str or Path, optional
        That cache's folder (default :func:`biped_casadi.cache_dir`).
    progress : callable, optional
        Called with one line of text before a solve that is not cached.
    verbose : bool
        Print IPOPT's iterations.
    warm_start : Gait, optional
        A previous gait of the same Bezier degree to start from.
    max_refinements : int
        Re-solves allowed for constraints exceeded between the nodes.
    **overrides
        Replace single option fields (``optimize_gait(m, speed=1.0)``).

    Returns
    -------
    Gait
        The polished gait; ``gait.solver_stats`` holds IPOPT's status, iterations and
        timings, ``solver_stats['dense_grid_violations']`` what remains violated between
        the nodes (empty for a valid gait), ``solver_stats['initial_guess']`` the step
        length and T of the built-in guess when it was started from (they scale with the
        robot's leg and the speed) and, with ``cache``, ``solver_stats['cache']``
        ('hit' or why it was computed).

    Raises
    ------
    GaitOptimizationError
        With IPOPT's status and the violated constraint families when no gait is found.
    TypeError
        When ``model`` is not a robot model.
    """
    model = rabbit() if model is None else model
    require_model(model)
    opts = _options(model, options, overrides)
    if cache:
        return cached_gait(model, opts, cache_dir, progress,
                           lambda: optimize_gait(model, opts, verbose=verbose,
                                                 warm_start=warm_start,
                                                 max_refinements=max_refinements))
    if progress is not None:
        progress(f"optimising the reference gait of {model.params.name} (a few seconds) ...")
    res = _solve(model, opts, verbose=verbose, warm_start=warm_start,
                 max_refinements=max_refinements)
    if res.gait is None:
        raise GaitOptimizationError(res.message, status=res.status,
                                    violations=[tuple(v) for v in res.violations])
    return res.gait
