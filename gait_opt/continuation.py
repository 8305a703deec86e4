"""Natural-parameter continuation of the reference-gait NLP in the speed, and
:func:`gait_family`, the family of gaits over a grid of speeds it builds
(:class:`gait_opt.family.GaitFamily`).

One NLP serves every speed: the transcription with the speed as its parameter
(:func:`gait_opt.transcription.build_problem` with ``speed_parameter=True``), built once
per set of node margins, with two IPOPT instances on it: a cold one (the built-in
guess, IPOPT's default start) for the first speed, and a warm one
(``warm_start_init_point``: primal and dual values, bound pushes of 1e-9) for every
other.  The start of a warm solve is the secant predictor through the last two
solutions (primal and duals extrapolated to the new speed); before two solutions exist,
the first step is an eighth of the requested one.  A step whose warm solve fails (IPOPT
status other than success, or more than :data:`WARM_MAX_ITER` iterations, or a
constraint family still violated) is halved, down to :data:`MIN_STEP_FRACTION` of the
requested step; then the family ends there.  IPOPT stops on iteration counts only.

At a solution, the active inequality families are those with a row within 1e-6 (relative)
of its bound; a change of the active set between neighbours is a kink of the family
(a constraint becomes active).  A fold shows as a failure at ever smaller steps while
the rate of change of the parameters, |d theta / d v| (theta = T and the Bezier
coefficients), grows; the family's end says when the last rates grew that way.
See docs/theory.md, "Gait families".
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import GaitOptimizationError
from .family import SPEED_TOL, GaitFamily, MemberRecord, check_speeds
from .family_file import options_record
from .gait import Gait
from .options import GaitOptions
from .polish import polish
from .transcription import (FIXED_BY, MARGINS, build_problem, constraint_violations,
                            describe_violations, initial_guess, make_solver,
                            warm_start_vector)

__all__ = ["gait_family", "SpeedNLP", "NLPPoint", "Advance", "advance", "active_families",
           "describe_failure", "fold_suspected", "WARM_MAX_ITER", "MIN_STEP_FRACTION",
           "FIRST_STEP_FRACTION"]

#: a warm solve taking more IPOPT iterations than this counts as a failed step (halved)
WARM_MAX_ITER = 60
#: the smallest step tried, a fraction of the requested one, before the family ends
MIN_STEP_FRACTION = 1 / 64
#: without a secant yet, the first step is this fraction of the requested one
FIRST_STEP_FRACTION = 1 / 8
#: IPOPT options of the warm solver
WARM_IPOPT = dict(warm_start_init_point="yes", warm_start_bound_push=1e-9,
                  warm_start_bound_frac=1e-9, warm_start_slack_bound_push=1e-9,
                  warm_start_slack_bound_frac=1e-9, warm_start_mult_bound_push=1e-9,
                  mu_init=1e-6)
SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass
class NLPPoint:
    """One IPOPT solution of the parametric NLP: the speed, the primal ``w`` and dual
    ``lam_g``, ``lam_x`` values, the constraint values ``g``, IPOPT's ``status`` and
    ``iterations``, the constraint families still ``violations`` ([(name, amount)]),
    the objective ``cost`` (unscaled) and the wall ``time`` of the solve."""

    speed: float
    w: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    g: np.ndarray
    status: str
    iterations: int
    violations: list
    cost: float
    time: float

    @property
    def ok(self) -> bool:
        """IPOPT succeeded and no constraint family is violated."""
        return self.status in SUCCESS and not self.violations


class SpeedNLP:
    """The gait NLP with the speed as its parameter, with a cold and a warm IPOPT.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : GaitOptions
        The problem (its ``speed`` is not used: each solve gives its own).
    margins : dict, optional
        Node margins of the path constraints (see :func:`gait_opt.solve_gait`).
    verbose : bool
        Print IPOPT's iterations.
    """

    def __init__(self, model, options: GaitOptions, margins: dict | None = None,
                 verbose: bool = False):
        t0 = time.perf_counter()
        self.model = model
        self.options = options.for_model(model)
        self.margins = dict(margins or {})
        self.prob = build_problem(model, self.options, self.margins, speed_parameter=True)
        self.cold = make_solver(self.prob, self.options, verbose)
        cap = min(WARM_MAX_ITER, int(self.options.ipopt.get("max_iter", WARM_MAX_ITER)))
        warm = {**self.options.ipopt, **WARM_IPOPT, "max_iter": cap}
        self.warm = make_solver(self.prob, self.options.replace(ipopt=warm), verbose)
        self.build_time = time.perf_counter() - t0

    def _bounds(self):
        p = self.prob
        return dict(lbx=p.lbx, ubx=p.ubx, lbg=p.lbg, ubg=p.ubg)

    def _point(self, solver, speed, sol, t0) -> NLPPoint:
        stats = solver.stats()
        g = np.array(sol["g"]).ravel()
        return NLPPoint(
            speed=float(speed), w=np.array(sol["x"]).ravel(),
            lam_g=np.array(sol["lam_g"]).ravel(), lam_x=np.array(sol["lam_x"]).ravel(),
            g=g, status=stats.get("return_status", "unknown"),
            iterations=int(stats.get("iter_count", -1)),
            violations=constraint_violations(self.prob, g),
            cost=float(sol["f"]) / self.prob.cost_scale, time=time.perf_counter() - t0)

    def solve_cold(self, speed: float, w0=None) -> NLPPoint:
        """Solve at ``speed`` from the built-in guess (or a primal start ``w0``).

        Parameters
        ----------
        speed : float
            m/s.
        w0 : array_like, optional
            A decision vector to start from (IPOPT's default start otherwise).

        Returns
        -------
        NLPPoint
        """
        t0 = time.perf_counter()
        if w0 is None:
            w0 = initial_guess(self.model, self.options.replace(speed=float(speed)))
        sol = self.cold(x0=w0, p=float(speed), **self._bounds())
        return self._point(self.cold, speed, sol, t0)

    def solve_warm(self, speed: float, start: NLPPoint) -> NLPPoint:
        """Solve at ``speed`` from a primal-dual start (IPOPT's warm start).

        Parameters
        ----------
        speed : float
            m/s.
        start : NLPPoint
            The start: ``w``, ``lam_g``, ``lam_x`` (a predictor; its ``speed`` is not
            used).

        Returns
        -------
        NLPPoint
        """
        t0 = time.perf_counter()
        w0 = np.clip(start.w, self.prob.lbx, self.prob.ubx)
        sol = self.warm(x0=w0, lam_g0=start.lam_g, lam_x0=start.lam_x, p=float(speed),
                        **self._bounds())
        return self._point(self.warm, speed, sol, t0)

    def unpack(self, point: NLPPoint):
        """(T, alpha, x0) of a solution: step time, Bezier coefficients, (q_u, dq_u)(0).

        Parameters
        ----------
        point : NLPPoint

        Returns
        -------
        tuple
            (float, numpy.ndarray (nu, M + 1), numpy.ndarray (2,)).
        """
        T, alpha, Xs, _, _ = (np.array(v) for v in self.prob.unpack(point.w))
        return float(T.item()), alpha, Xs[:, 0]


def _predict(points: list, speed: float) -> NLPPoint:
    """The secant predictor at ``speed`` through the last two points (the last point
    itself when there is one)."""
    last = points[-1]
    if len(points) < 2:
        return last
    prev = points[-2]
    k = (speed - last.speed) / (last.speed - prev.speed)
    ext = {n: getattr(last, n) + k * (getattr(last, n) - getattr(prev, n))
           for n in ("w", "lam_g", "lam_x")}
    return NLPPoint(speed=speed, g=last.g, status="predicted", iterations=0,
                    violations=[], cost=last.cost, time=0.0, **ext)


def _rate(a: NLPPoint, b: NLPPoint, n_theta: int) -> float:
    """|d theta / d v| between two solutions (theta = T and the Bezier coefficients)."""
    return float(np.max(np.abs(b.w[:n_theta] - a.w[:n_theta])) / abs(b.speed - a.speed))


@dataclass
class Advance:
    """The outcome of :func:`advance`: the solution at the target speed (or None),
    the ``substeps`` taken, the warm solves that ``failed`` (halved), the IPOPT
    ``iterations`` over all of them, the last failed solve (``failure``), the rates
    |d theta / d v| of the accepted substeps (``rates``) and the wall ``time``."""

    point: NLPPoint | None
    substeps: int
    failed: int
    iterations: int
    failure: NLPPoint | None
    rates: list = field(default_factory=list)
    time: float = 0.0

    @property
    def reached(self) -> bool:
        """The target speed was reached."""
        return self.point is not None


def advance(nlp: SpeedNLP, points: list, target: float, step: float) -> Advance:
    """Continue from the last of ``points`` to ``target`` (module docstring).

    Accepted intermediate solutions are appended to ``points`` (they feed the secant).

    Parameters
    ----------
    nlp : SpeedNLP
    points : list of NLPPoint
        The solutions so far, in order of speed (at least one).
    target : float
        The speed to reach, m/s.
    step : float
        The requested step (the grid's); halving stops at ``MIN_STEP_FRACTION`` of it.

    Returns
    -------
    Advance
    """
    t0 = time.perf_counter()
    n_theta = 1 + nlp.model.nu * (nlp.options.bezier_degree + 1)
    h_min = abs(step) * MIN_STEP_FRACTION * (1 - 1e-9)
    h = (target - points[-1].speed) * (FIRST_STEP_FRACTION if len(points) < 2 else 1.0)
    substeps = failed = iterations = 0
    failure, rates = None, []
    while True:
        here = points[-1].speed
        remaining = target - here
        if abs(remaining) <= 1e-12:
            break
        h = remaining if abs(h) >= abs(remaining) else h
        trial = here + h
        p = nlp.solve_warm(trial, _predict(points, trial))
        iterations += p.iterations
        if p.ok:
            rates.append(_rate(points[-1], p, n_theta))
            first = len(points) == 1          # the secant exists from now on
            points.append(p)
            substeps += 1
            h = target - trial if first else 2 * h
            continue
        failed += 1
        failure = p
        h = h / 2
        if abs(h) < h_min:
            return Advance(None, substeps, failed, iterations, failure, rates,
                           time.perf_counter() - t0)
    return Advance(points[-1], substeps, failed, iterations, failure, rates,
                   time.perf_counter() - t0)


def active_families(nlp: SpeedNLP, point: NLPPoint, tol: float = 1e-6) -> list:
    """The inequality constraint families with a row at its bound at a solution.

    Parameters
    ----------
    nlp : SpeedNLP
    point : NLPPoint
    tol : float
        A row within ``tol * max(1, |bound|)`` of its bound is active.

    Returns
    -------
    list of str
        Family names (those of the transcription, plus 'step time bounds' and 'knee
        limits' for the variable bounds), in the transcription's order.
    """
    prob = nlp.prob
    names = []
    for name, a, b in prob.groups:
        lo, hi, g = prob.lbg[a:b], prob.ubg[a:b], point.g[a:b]
        if _at_bound(lo, hi, g, tol):
            names.append(name)
    w = point.w
    if _at_bound(prob.lbx[:1], prob.ubx[:1], w[:1], tol):
        names.append("step time bounds")
    na = nlp.model.nu * (nlp.options.bezier_degree + 1)
    lo, hi = prob.lbx[1:1 + na], prob.ubx[1:1 + na]
    knees = np.isfinite(lo) & (lo > -np.pi) | np.isfinite(hi) & (hi < np.pi)
    if knees.any() and _at_bound(lo[knees], hi[knees], w[1:1 + na][knees], tol):
        names.append("knee limits")
    return names


def _at_bound(lo, hi, v, tol) -> bool:
    """Some row of an inequality (lo < hi) within tolerance of a finite bound."""
    ineq = lo < hi
    with np.errstate(invalid="ignore"):
        near_lo = np.isfinite(lo) & (v - lo <= tol * np.maximum(1.0, np.abs(lo)))
        near_hi = np.isfinite(hi) & (hi - v <= tol * np.maximum(1.0, np.abs(hi)))
    return bool(np.any(ineq & (near_lo | near_hi)))


def describe_failure(adv: Advance) -> str:
    """IPOPT's status and the violated families of the last failed solve, in words.

    Parameters
    ----------
    adv : Advance

    Returns
    -------
    str
    """
    p = adv.failure
    if p is None:
        return "no solve"
    return (f"IPOPT status '{p.status}' after {p.iterations} iterations at {p.speed:.6g} "
            f"m/s; violated at the last iterate: {describe_violations(p.violations)}")


def fold_suspected(rates: list) -> bool:
    """Whether the parameters' rate of change grew like at a fold.

    Parameters
    ----------
    rates : list of float
        |d theta / d v| of the accepted steps before a failure, in order.

    Returns
    -------
    bool
        The last rate is more than 3 times the median of those before (at least four).
    """
    if len(rates) < 4:
        return False
    return rates[-1] > 3 * float(np.median(rates[:-1]))


# ------------------------------------------------------------------ the family
def _member(model, opts, points, adv, state, max_refinements):
    """Polish the solution at the target speed, check it on the dense grid, and tighten
    the node margins where an active constraint is exceeded between the nodes (as
    :func:`gait_opt.solve_gait`; the margins stay for the rest of the family).  Returns
    (gait, record); raises GaitOptimizationError when the polish fails."""
    t0 = time.perf_counter()
    v = points[-1].speed
    opts_v = opts.replace(speed=v)
    iterations = adv.iterations
    for attempt in range(1 + max_refinements):
        point = points[-1]
        T, alpha, x0 = state["nlp"].unpack(point)
        alpha_p, x0_p, T_p, hist = polish(model, opts_v, alpha, x0, T)
        gait = Gait(model, opts_v, alpha_p, x0_p, T_p)
        viol = gait.violations()
        fixable = [(FIXED_BY.get(n, n), a) for n, a in viol if FIXED_BY.get(n, n) in MARGINS]
        if not fixable or len(fixable) < len(viol) or attempt == max_refinements:
            break
        margins = dict(state["nlp"].margins)
        for n, a in fixable:
            margins[n] = margins.get(n, 0.0) + 2 * a + 1e-9
        new = SpeedNLP(model, opts, margins)
        state["build_time"] += new.build_time
        again = new.solve_warm(v, point)
        iterations += again.iterations
        if not again.ok:
            break                       # keep this gait and report its violations
        state["nlp"], points[-1] = new, again
    change = float(np.max(np.abs(np.r_[(alpha_p - alpha).ravel(), x0_p - x0, T_p - T])))
    margins = dict(state["nlp"].margins)
    gait.solver_stats = dict(
        status=point.status, iterations=iterations, polish_residuals=hist,
        polish_change=change, dense_grid_violations=[list(x) for x in viol],
        family=dict(substeps=adv.substeps, failed_steps=adv.failed, margins=margins))
    record = MemberRecord(
        speed=float(v), status="ok" if not viol else "violates", iterations=iterations,
        substeps=adv.substeps, failed_steps=adv.failed,
        time=adv.time + time.perf_counter() - t0, T=gait.T, step_length=gait.step_length,
        cost=gait.cost, orbit_residual=gait.orbit_residual()["worst"],
        polish_residual=hist[-1], polish_change=change,
        active=active_families(state["nlp"], points[-1]), margins=margins,
        violations=[list(x) for x in viol])
    return gait, record


def _events(prev: MemberRecord | None, rec: MemberRecord) -> list:
    """Changes of the active set from one member to the next."""
    if prev is None:
        return []
    return ([dict(speed=rec.speed, constraint=c, change="active")
             for c in rec.active if c not in prev.active]
            + [dict(speed=rec.speed, constraint=c, change="inactive")
               for c in prev.active if c not in rec.active])


def _ended(adv: Advance, target: float, last: float, rates: list) -> dict:
    """The family's end: where, why, in words."""
    p = adv.failure
    fold = fold_suspected(rates)
    detail = describe_failure(adv) + (
        f" at steps down to {MIN_STEP_FRACTION:g} of the grid's; the rate |d theta / d v| "
        f"grew to {rates[-1]:.3g} from a median of {float(np.median(rates[:-1])):.3g} "
        f"before (a fold: the family turns back)" if fold else
        f" at steps down to {MIN_STEP_FRACTION:g} of the grid's")
    return dict(speed=float(target), last=float(last), reason="fold" if fold else "infeasible",
                detail=detail, ipopt_status=p.status if p is not None else None,
                violations=[list(x) for x in (p.violations if p is not None else [])])


def _reachable(opts, v):
    """ValueError when the step-length and step-time bounds exclude speed ``v``."""
    (l_lo, l_hi), (t_lo, t_hi) = opts.step_length_bounds, opts.step_time_bounds
    if not l_lo / t_hi <= v <= l_hi / t_lo:
        raise ValueError(
            f"speeds: {v:g} m/s is out of reach of step_length_bounds ({l_lo:g}, {l_hi:g}) "
            f"m and step_time_bounds ({t_lo:g}, {t_hi:g}) s, which allow "
            f"{l_lo / t_hi:.3g} to {l_hi / t_lo:.3g} m/s")


def _resumable(path, model, opts, speeds):
    """The family saved at ``path`` for the same robot, options and speeds, or None when
    there is no file; ValueError when the file holds another request."""
    if not Path(path).exists():
        return None
    fam = GaitFamily.load(path, model)
    same = (options_record(fam.options) == options_record(opts)
            and len(fam.speeds) == len(speeds)
            and np.allclose(fam.speeds, speeds, rtol=0, atol=SPEED_TOL))
    if not same:
        raise ValueError(f"path: {path} holds a gait family of other options or speeds "
                         f"({len(fam.speeds)} speeds from {fam.speeds[0]:g} to "
                         f"{fam.speeds[-1]:g} m/s); remove it, choose another file, or "
                         f"start afresh (resume=False)")
    return fam


def gait_family(model, speeds, options: GaitOptions | None = None, *, path=None,
                resume: bool = True, progress=None, verbose: bool = False,
                max_refinements: int = 3) -> GaitFamily:
    """Reference gaits at every speed of a grid, by continuation (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot.
    speeds : sequence of float
        At least two strictly increasing speeds, m/s (:func:`gait_opt.speed_range`).
    options : GaitOptions, optional
        The problem (default SPEC section 2); its ``speed`` is replaced by each speed.
    path : str or Path, optional
        Save the family there after every member (atomically); with ``resume``,
        continue a partial family found there made for the same robot, options and
        speeds (a finished one is returned as it is).
    resume : bool
        Continue from ``path`` when it holds such a family (False: start afresh and
        replace it).
    progress : callable, optional
        Called with one line of text per member.
    verbose : bool
        Print IPOPT's iterations.
    max_refinements : int
        Node-margin refinements per member (as :func:`gait_opt.solve_gait`).

    Returns
    -------
    GaitFamily

    Raises
    ------
    ValueError
        Bad ``speeds`` or ``options``; a speed out of reach of the step-length and
        step-time bounds; ``path`` holding a family of another request.
    GaitOptimizationError
        No gait at the first speed.
    """
    speeds = check_speeds(speeds)
    if options is not None and not isinstance(options, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(options).__name__}")
    opts = (options or GaitOptions()).for_model(model)
    for v in speeds:
        _reachable(opts, v)
    family = _resumable(path, model, opts, speeds) if (path is not None and resume) else None
    if family is not None and family.status != "partial":
        return family
    if family is None:
        family = GaitFamily(status="partial", message="started", robot=model.params.name,
                            speeds=speeds.tolist(), records=[], options=opts)
    return _run(model, opts, speeds, family, path, progress, verbose, max_refinements)


def _start(model, opts, state, family, speed):
    """(points, Advance or None): the solution to continue from.  A new family: a cold
    solve at its first speed (the Advance says whether it succeeded).  A resumed one:
    the last member re-solved from its own gait (a primal start) to recover the duals."""
    nlp = state["nlp"]
    if not family.gaits:
        p = nlp.solve_cold(speed)
        return ([p] if p.ok else []), Advance(p if p.ok else None, int(p.ok), int(not p.ok),
                                              p.iterations, None if p.ok else p, [], p.time)
    last = family.records[-1].speed
    p = nlp.solve_cold(last, warm_start_vector(model, opts, family.gaits[-1]))
    if not p.ok:
        raise GaitOptimizationError(f"resuming the family: the last member ({last:g} m/s) "
                                    f"could not be re-solved: {p.status}", status=p.status)
    return [p], None


def _run(model, opts, speeds, family, path, progress, verbose, max_refinements):
    """Continue ``family`` over the speeds it lacks, saving after each member."""
    t_start = time.perf_counter()
    nlp = SpeedNLP(model, opts, family.records[-1].margins if family.records else {}, verbose)
    state = dict(nlp=nlp, build_time=nlp.build_time)
    points, rates = [], []
    for i in range(len(family.gaits), len(speeds)):
        v = float(speeds[i])
        adv = None
        if not points:
            points, adv = _start(model, opts, state, family, v)
        if adv is None:
            adv = advance(state["nlp"], points, v, v - float(speeds[i - 1]))
            rates += adv.rates
        if not adv.reached:
            if not family.gaits:
                raise GaitOptimizationError(
                    f"no gait at the first speed {v:g} m/s: {describe_failure(adv)}",
                    status=adv.failure.status, violations=adv.failure.violations)
            family.end = _ended(adv, v, family.records[-1].speed, rates)
            break
        try:
            gait, rec = _member(model, opts, points, adv, state, max_refinements)
        except GaitOptimizationError as e:
            if not family.gaits:
                raise
            family.end = dict(speed=v, last=family.records[-1].speed, reason="polish_failed",
                              detail=str(e), ipopt_status=None, violations=[])
            break
        family.events += _events(family.records[-1] if family.records else None, rec)
        family.records.append(rec)
        family.gaits.append(gait)
        t_start = _progress(family, speeds, t_start, state, path, progress, rec)
    _finish(family, speeds, t_start, state)
    if path is not None:
        family.save(path)
    return family


def _progress(family, speeds, t_start, state, path, progress, rec):
    """Book-keeping after a member: times, status, the saved file, the progress line."""
    t_start = _finish(family, speeds, t_start, state)
    if path is not None:
        family.save(path)
    if progress is not None:
        progress(f"{len(family.gaits)}/{len(speeds)} {rec.speed:g} m/s: T {rec.T:.4f} s, "
                 f"step {rec.step_length:.4f} m, {rec.iterations} IPOPT iterations, orbit "
                 f"residual {rec.orbit_residual:.1e}" + (
                     f", VIOLATES {describe_violations(rec.violations)}"
                     if rec.violations else ""))
    return t_start


def _finish(family, speeds, t_start, state) -> float:
    """Status, message and times of the family so far; returns the new time origin."""
    now = time.perf_counter()
    family.total_time += now - t_start
    family.build_time += state["build_time"]
    state["build_time"] = 0.0
    v = family.member_speeds
    bad = [r.speed for r in family.records if r.violations]
    span = f"{v[0]:g} to {v[-1]:g} m/s" if v.size else "no speed"
    if family.end is not None:
        e = family.end
        family.status = "ended"
        family.message = (f"the family covers {span} and ends before {e['speed']:g} m/s "
                          f"({e['reason']}: {e['detail']})")
    elif len(v) < len(speeds):
        family.status = "partial"
        family.message = f"{len(v)} of {len(speeds)} speeds done ({span})"
    elif bad:
        family.status = "violates"
        family.message = (f"the family covers {span}; constraints exceeded between the "
                          f"nodes at {', '.join(f'{s:g}' for s in bad)} m/s")
    else:
        family.status = "complete"
        worst = max(r.orbit_residual for r in family.records)
        family.message = (f"the family covers {span} ({len(v)} gaits, every one a "
                          f"periodic orbit to {worst:.1e})")
    return now
